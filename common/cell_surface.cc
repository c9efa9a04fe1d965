#include "common/cell_surface.h"

#include <algorithm>
#include <cmath>

namespace exo {
namespace {

using Polygon = std::vector<glm::dvec3>;
using CellPoints = std::unordered_map<CellId, std::vector<glm::dvec3>>;

// Scratch polygons of one clipping level (reused: a large triangle is split many times).
struct ClipScratch {
  Polygon below, above, piece, rest;
};

// Clips `poly` along axes axis..2 to the inflated boxes [k q - e, (k + 1) q + e] of every cell it
// reaches and appends each non-empty piece's points to its cell (`cell` holds the indices of the
// axes done).
void ClipToInflatedCells(const Polygon& poly, int axis, glm::ivec3 cell, double q, double e,
                         CellPoints* out, ClipScratch* scratch) {
  if (poly.empty()) return;
  if (axis == 3) {
    auto& pts = (*out)[PackCell(cell)];
    pts.insert(pts.end(), poly.begin(), poly.end());
    return;
  }
  double lo = poly[0][axis], hi = lo;
  for (const auto& p : poly) lo = std::min(lo, p[axis]), hi = std::max(hi, p[axis]);
  const int64_t k0 = int64_t(std::floor((lo - e) / q)), k1 = int64_t(std::floor((hi + e) / q));
  ClipScratch& s = scratch[axis];
  for (int64_t k = k0; k <= k1; ++k) {
    SplitPolygon(poly, axis, double(k) * q - e, &s.below, &s.above);
    SplitPolygon(s.above, axis, double(k + 1) * q + e, &s.piece, &s.rest);
    cell[axis] = int32_t(k);
    ClipToInflatedCells(s.piece, axis + 1, cell, q, e, out, scratch);
  }
}

}  // namespace

void SplitPolygon(const std::vector<glm::dvec3>& poly, int axis, double c,
                  std::vector<glm::dvec3>* below, std::vector<glm::dvec3>* above) {
  below->clear();
  above->clear();
  const size_t n = poly.size();
  for (size_t i = 0; i < n; ++i) {
    const glm::dvec3& a = poly[i];
    const glm::dvec3& b = poly[(i + 1) % n];
    const double da = a[axis] - c, db = b[axis] - c;
    if (da <= 0) below->push_back(a);
    if (da >= 0) above->push_back(a);
    if ((da < 0 && db > 0) || (da > 0 && db < 0)) {
      const glm::dvec3 x = a + (b - a) * (da / (da - db));
      below->push_back(x);
      above->push_back(x);
    }
  }
}

CellSurfaceBounds SurfaceBoundsPerCell(std::span<const glm::vec3> positions,
                                       std::span<const uint32_t> indices, const CellGrid& grid) {
  const double q = grid.cell_size_m;
  CellPoints pts;
  Polygon tri(3);
  ClipScratch scratch[3];
  for (size_t t = 0; t + 2 < indices.size(); t += 3) {
    double extent = 0.0;
    for (int j = 0; j < 3; ++j) {
      tri[j] = glm::dvec3(positions[indices[t + j]]);
      extent = std::max(extent, glm::length(tri[j]));
    }
    const double e = CellSurfaceMarginM(q, extent);
    // Fast path: the triangle's box, inflated by e, inside one cell (the usual case).
    const glm::dvec3 lo = glm::min(tri[0], glm::min(tri[1], tri[2])) - e;
    const glm::dvec3 hi = glm::max(tri[0], glm::max(tri[1], tri[2])) + e;
    const glm::ivec3 c0 = grid.CoordOf(lo);
    if (grid.CoordOf(hi) == c0) {
      auto& p = pts[PackCell(c0)];
      p.insert(p.end(), tri.begin(), tri.end());
      continue;
    }
    ClipToInflatedCells(tri, 0, glm::ivec3(0), q, e, &pts, scratch);
  }
  CellSurfaceBounds out;
  out.reserve(pts.size());
  for (const auto& [cell, p] : pts) {
    CellSurfaceBound b;
    b.lo = b.hi = p[0];
    for (const glm::dvec3& x : p) b.lo = glm::min(b.lo, x), b.hi = glm::max(b.hi, x);
    b.centre = 0.5 * (b.lo + b.hi);
    for (const glm::dvec3& x : p) b.radius = std::max(b.radius, glm::length(x - b.centre));
    out.emplace(cell, b);
  }
  return out;
}

void MergeSurfaceBound(const CellSurfaceBound& b, CellSurfaceBound* into) {
  CellSurfaceBound u;
  u.lo = glm::min(into->lo, b.lo);
  u.hi = glm::max(into->hi, b.hi);
  u.centre = 0.5 * (u.lo + u.hi);
  u.radius = std::min(0.5 * glm::length(u.hi - u.lo),
                      std::max(glm::length(into->centre - u.centre) + into->radius,
                               glm::length(b.centre - u.centre) + b.radius));
  *into = u;
}

}  // namespace exo
