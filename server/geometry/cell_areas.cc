#include "server/geometry/cell_areas.h"

#include <algorithm>

#include <cmath>
#include <limits>

#include "common/cell_surface.h"
#include "common/status.h"

namespace exo {
namespace {

using Polygon = std::vector<glm::dvec3>;

double PolygonArea(const Polygon& p) {
  glm::dvec3 acc(0.0);
  for (size_t i = 1; i + 1 < p.size(); ++i) acc += glm::cross(p[i] - p[0], p[i + 1] - p[0]);
  return 0.5 * glm::length(acc);
}

// Recursively clips along axes 0, 1, 2 and accumulates piece areas per cell.
void ClipInto(const Polygon& poly, int axis, const CellGrid& grid,
              absl::flat_hash_map<CellId, double>* out) {
  if (poly.size() < 3) return;
  if (axis == 3) {
    glm::dvec3 c(0.0);
    for (const auto& p : poly) c += p;
    c /= double(poly.size());
    const double a = PolygonArea(poly);
    if (a > 0) (*out)[grid.IdOf(c)] += a;
    return;
  }
  const double q = grid.cell_size_m;
  double lo = poly[0][axis], hi = lo;
  for (const auto& p : poly) lo = std::min(lo, p[axis]), hi = std::max(hi, p[axis]);
  const int64_t k0 = int64_t(std::floor(lo / q)), k1 = int64_t(std::floor(hi / q));
  if (k0 == k1) {
    ClipInto(poly, axis + 1, grid, out);
    return;
  }
  Polygon rest = poly, below, above;
  for (int64_t k = k0 + 1; k <= k1 && rest.size() >= 3; ++k) {
    SplitPolygon(rest, axis, double(k) * q, &below, &above);
    ClipInto(below, axis + 1, grid, out);
    rest.swap(above);
  }
  ClipInto(rest, axis + 1, grid, out);
}

}  // namespace

CellAreas::CellAreas(const CellGrid& grid) : grid_(grid) { EXO_CHECK(grid.cell_size_m > 0); }

absl::flat_hash_map<CellId, double> CellAreas::AreaPerCell(const TriangleMesh& mesh,
                                                           const CellGrid& grid) {
  absl::flat_hash_map<CellId, double> out;
  if (mesh.indices.size() < 3) return out;
  // Fast path for a whole mesh in one cell (a TSDF chunk is 8 voxels wide, cells are >= 0.3 m):
  // the per-triangle fast path below would add every area to that cell in this order, so one
  // running sum gives the same bits.
  {
    glm::dvec3 lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
    for (const glm::vec3& p : mesh.positions) {
      const glm::dvec3 d(p);
      lo = glm::min(lo, d);
      hi = glm::max(hi, d);
    }
    const CellId c0 = grid.IdOf(lo);
    if (grid.IdOf(hi) == c0) {  // floor(p / q) is monotonic per axis: every vertex is in c0
      double sum = 0.0;
      bool any = false;
      for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
        const glm::dvec3 a(mesh.positions[mesh.indices[t]]), b(mesh.positions[mesh.indices[t + 1]]),
            c(mesh.positions[mesh.indices[t + 2]]);
        const double area = 0.5 * glm::length(glm::cross(b - a, c - a));
        if (area > 0) {
          sum += area;
          any = true;
        }
      }
      if (any) out[c0] = sum;
      return out;
    }
  }
  Polygon tri(3);
  CellId last_cell = 0;
  double* last_slot = nullptr;
  for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
    for (int j = 0; j < 3; ++j) tri[j] = glm::dvec3(mesh.positions[mesh.indices[t + j]]);
    // Fast path: the whole triangle in one cell (the usual case when cells >> voxels).
    const CellId c0 = grid.IdOf(tri[0]);
    if (grid.IdOf(tri[1]) == c0 && grid.IdOf(tri[2]) == c0) {
      const double a = 0.5 * glm::length(glm::cross(tri[1] - tri[0], tri[2] - tri[0]));
      if (a > 0) {
        // Consecutive triangles are mostly in the same cell: its accumulator is kept (the same
        // additions in the same order as a lookup per triangle).
        if (last_slot == nullptr || last_cell != c0) {
          last_slot = &out[c0];
          last_cell = c0;
        }
        *last_slot += a;
      }
      continue;
    }
    ClipInto(tri, 0, grid, &out);
    last_slot = nullptr;  // inserts may have rehashed the map
  }
  return out;
}

void CellAreas::Apply(const absl::flat_hash_map<CellId, double>& contrib, double sign) {
  for (const auto& [cell, a] : contrib) {
    changed_.insert(cell);
    int& n = chunk_count_[cell];
    n += sign > 0 ? 1 : -1;
    if (n <= 0) {
      // Last contributor gone: erase instead of keeping a rounding residue.
      chunk_count_.erase(cell);
      area_.erase(cell);
    } else {
      area_[cell] += sign * a;
    }
  }
}

void CellAreas::UpdateChunk(const MeshChunk& chunk) {
  RemoveChunk(chunk.id);
  auto contrib = AreaPerCell(chunk.mesh, grid_);
  if (contrib.empty()) return;
  Apply(contrib, +1.0);
  per_chunk_[chunk.id] = std::move(contrib);
}

void CellAreas::RemoveChunk(uint64_t chunk_id) {
  auto it = per_chunk_.find(chunk_id);
  if (it == per_chunk_.end()) return;
  Apply(it->second, -1.0);
  per_chunk_.erase(it);
}

double CellAreas::Area(CellId cell) const {
  auto it = area_.find(cell);
  return it == area_.end() ? 0.0 : std::max(0.0, it->second);
}

double CellAreas::TotalArea() const {
  double s = 0;
  for (const auto& [c, a] : area_) s += a;
  return s;
}

namespace {
template <typename K, typename V>
struct KeyValue {
  K first;
  V second;
};
template <typename K, typename V>
std::vector<KeyValue<K, V>> Sorted(const absl::flat_hash_map<K, V>& m) {
  std::vector<KeyValue<K, V>> v;
  v.reserve(m.size());
  for (const auto& [k, x] : m) v.push_back({k, x});
  std::sort(v.begin(), v.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  return v;
}
template <typename K, typename V>
absl::flat_hash_map<K, V> MapOf(const std::vector<KeyValue<K, V>>& v) {
  absl::flat_hash_map<K, V> m;
  m.reserve(v.size());
  for (const auto& [k, x] : v) m[k] = x;
  return m;
}
}  // namespace

void CellAreas::SaveState(StateWriter* w) const {
  w->Put<uint64_t>(per_chunk_.size());
  for (const auto& [chunk, cells] : Sorted(per_chunk_)) {
    w->Put(chunk);
    w->PutVec(Sorted(cells));
  }
  w->PutVec(Sorted(area_));
  w->PutVec(Sorted(chunk_count_));
  std::vector<CellId> changed(changed_.begin(), changed_.end());
  std::sort(changed.begin(), changed.end());
  w->PutVec(changed);
}

absl::Status CellAreas::LoadState(StateReader* r) {
  per_chunk_.clear();
  uint64_t n = 0;
  r->Count(&n, sizeof(uint64_t) * 2);
  for (uint64_t i = 0; r->ok() && i < n; ++i) {
    uint64_t chunk = 0;
    std::vector<KeyValue<CellId, double>> cells;
    if (r->Get(&chunk) && r->GetVec(&cells)) per_chunk_[chunk] = MapOf(cells);
  }
  std::vector<KeyValue<CellId, double>> area;
  std::vector<KeyValue<CellId, int>> count;
  std::vector<CellId> changed;
  r->GetVec(&area) && r->GetVec(&count) && r->GetVec(&changed);
  area_ = MapOf(area);
  chunk_count_ = MapOf(count);
  changed_ = absl::flat_hash_set<CellId>(changed.begin(), changed.end());
  return r->Status("cell areas");
}

std::vector<CellId> CellAreas::TakeChangedCells() {
  std::vector<CellId> out(changed_.begin(), changed_.end());
  changed_.clear();
  return out;
}

}  // namespace exo
