#include "common/cell_surface.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace exo {
namespace {

struct Mesh {
  std::vector<glm::vec3> positions;
  std::vector<uint32_t> indices;
  void Add(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c) {
    const uint32_t base = uint32_t(positions.size());
    positions.insert(positions.end(), {glm::vec3(a), glm::vec3(b), glm::vec3(c)});
    indices.insert(indices.end(), {base, base + 1, base + 2});
  }
};

// Random triangles: small ones (inside a cell or across a plane), large ones across many cells,
// triangles lying in a cell plane (x = k q) or a hair off it (the float floor(x / q) of their
// points then differs from the double one), degenerate ones, near and far from the origin.
Mesh RandomMesh(double q, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0), u01(0.0, 1.0);
  Mesh m;
  for (int t = 0; t < 3000; ++t) {
    const double far = t % 5 == 0 ? 60.0 : 4.0;
    const glm::dvec3 o(far * u(rng), far * u(rng), 3.0 * u(rng));
    const double size = q * (t % 3 == 0 ? 4.0 * u01(rng) : 0.6 * u01(rng));
    glm::dvec3 a = o, b = o + size * glm::dvec3(u(rng), u(rng), u(rng)),
               c = o + size * glm::dvec3(u(rng), u(rng), u(rng));
    if (t % 7 == 0) {  // in (or 1e-9 m off) the plane x = k q
      const double x = std::round(o.x / q) * q - (t % 14 == 0 ? 1e-9 : 0.0);
      a.x = b.x = c.x = x;
    }
    if (t % 11 == 0) c = b;  // degenerate: a segment
    m.Add(a, b, c);
  }
  return m;
}

// The point of triangle t at barycentric (s, r), rounded to float as a rasterised G-buffer holds
// it, and its cell as blend_shade.glsl assigns it: floor(x / q) in float.
glm::vec3 PointOn(const Mesh& m, size_t t, double s, double r) {
  const glm::dvec3 a(m.positions[m.indices[3 * t]]), b(m.positions[m.indices[3 * t + 1]]),
      c(m.positions[m.indices[3 * t + 2]]);
  return glm::vec3(a + s * (b - a) + r * (c - a));
}
glm::dvec3 Unit(std::mt19937& rng) {
  std::normal_distribution<double> g;
  glm::dvec3 d;
  do d = {g(rng), g(rng), g(rng)}; while (glm::length(d) < 1e-3);
  return glm::normalize(d);
}
CellId ShaderCell(const glm::vec3& x, double q) {
  return PackCell(glm::ivec3(glm::floor(x / float(q))));
}

// Every sampled point of every triangle (vertices, edges, interior) lies in the box and the ball
// of the cell the shader assigns it to: no slack needed for points on the triangles (only 1e-5
// relative for the float rounding of the point itself). Guards: without the float margin of the
// clipping, the points of the triangles 1e-9 m below a cell plane have no bound in the cell above
// it; without the slack in the clipping margin, displaced points near a cell face do not either.
void ExpectContainsEveryPoint(const Mesh& m, const CellSurfaceBounds& bounds, double q,
                              std::mt19937& rng) {
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  int checked = 0;
  for (size_t t = 0; t < m.indices.size() / 3; ++t) {
    for (int k = 0; k < 40; ++k) {
      double s = u01(rng), r = u01(rng);
      if (s + r > 1.0) s = 1.0 - s, r = 1.0 - r;
      if (k < 3) s = k == 1, r = k == 2;  // the vertices
      if (k >= 3 && k < 6) r = 0.0;       // an edge
      const glm::vec3 x = PointOn(m, t, s, r);
      const auto it = bounds.find(ShaderCell(x, q));
      ASSERT_NE(it, bounds.end()) << "triangle " << t << " point " << k << " has no cell bound";
      const CellSurfaceBound& b = it->second;
      const double tol = 1e-5 * (glm::length(glm::dvec3(x)) + q);
      const glm::dvec3 xd(x);
      ASSERT_LE(glm::length(xd - b.centre), b.radius + tol) << "triangle " << t;
      ASSERT_LE(glm::length(xd - b.centre), CellSurfaceBallRadius(b, q));
      for (int a = 0; a < 3; ++a) {
        ASSERT_GE(xd[a], b.lo[a] - tol) << "triangle " << t << " axis " << a;
        ASSERT_LE(xd[a], b.hi[a] + tol) << "triangle " << t << " axis " << a;
      }
      // A rasterised point off its triangle by up to the slack (any direction): inside the ball
      // of whatever cell it falls in, which therefore has a bound.
      const double slack = CellSurfaceSlackM(q, glm::length(xd));
      const glm::vec3 y(xd + 0.99 * slack * u01(rng) * Unit(rng));
      const auto jt = bounds.find(ShaderCell(y, q));
      ASSERT_NE(jt, bounds.end()) << "triangle " << t << " point " << k << " displaced";
      ASSERT_LE(glm::length(glm::dvec3(y) - jt->second.centre),
                CellSurfaceBallRadius(jt->second, q))
          << "triangle " << t << " displaced";
      ++checked;
    }
  }
  EXPECT_EQ(checked, int(m.indices.size() / 3) * 40);
}

TEST(CellSurfaceTest, BoundsContainEveryProxyPointOfTheirCell) {
  std::mt19937 rng(11);
  for (double q : {0.3, 0.5}) {
    const Mesh m = RandomMesh(q, rng);
    const CellSurfaceBounds bounds = SurfaceBoundsPerCell(m.positions, m.indices, CellGrid{q});
    ExpectContainsEveryPoint(m, bounds, q, rng);
    for (const auto& [cell, b] : bounds)  // never looser than the cube's ball
      ASSERT_LE(b.radius, 0.5 * std::sqrt(3.0) * q * (1.0 + 1e-2) + 1e-4 * glm::length(b.centre));
  }
}

// Two chunks' bounds merged per cell bound the union: the mesh split in two halves, each half's
// bounds computed alone and merged, contains every point of both.
TEST(CellSurfaceTest, MergedChunkBoundsContainBothSurfaces) {
  std::mt19937 rng(12);
  const double q = 0.4;
  const Mesh m = RandomMesh(q, rng);
  Mesh half[2];
  for (size_t t = 0; t < m.indices.size() / 3; ++t) {
    const glm::dvec3 a(m.positions[m.indices[3 * t]]), b(m.positions[m.indices[3 * t + 1]]),
        c(m.positions[m.indices[3 * t + 2]]);
    half[t % 2].Add(a, b, c);
  }
  CellSurfaceBounds merged = SurfaceBoundsPerCell(half[0].positions, half[0].indices, CellGrid{q});
  for (const auto& [cell, b] :
       SurfaceBoundsPerCell(half[1].positions, half[1].indices, CellGrid{q})) {
    auto [it, fresh] = merged.try_emplace(cell, b);
    if (!fresh) MergeSurfaceBound(b, &it->second);
  }
  ExpectContainsEveryPoint(m, merged, q, rng);
}

// Informative: a floor (z = 0, a cell plane) tiled by two triangles per cell gives each floor cell
// a ball of radius q / sqrt 2 (plus the margins), 0.82 of the cube's q sqrt 3 / 2; a wall
// piece in one corner of a cell a much smaller one.
TEST(CellSurfaceTest, FlatCellGetsTheSquaresBall) {
  const double q = 0.5;
  Mesh m;
  for (int i = -4; i < 4; ++i)
    for (int j = -4; j < 4; ++j) {
      const glm::dvec3 p(i * q, j * q, 0.0);
      m.Add(p, p + glm::dvec3(q, 0, 0), p + glm::dvec3(q, q, 0));
      m.Add(p, p + glm::dvec3(q, q, 0), p + glm::dvec3(0, q, 0));
    }
  m.Add({5.05, 5.05, 0.05}, {5.1, 5.05, 0.05}, {5.05, 5.1, 0.1});  // small piece in cell (10,10,0)
  const CellSurfaceBounds bounds = SurfaceBoundsPerCell(m.positions, m.indices, CellGrid{q});
  const CellSurfaceBound& b = bounds.at(PackCell({1, 2, 0}));
  EXPECT_NEAR(b.radius, q / std::sqrt(2.0), 6e-3 * q);  // + the clipping margin (~0.3 % of q)
  EXPECT_NEAR(b.centre.z, 0.0, 1e-9);
  EXPECT_LT(CellSurfaceBallRadius(b, q), 0.84 * 0.5 * std::sqrt(3.0) * q);
  const CellSurfaceBound& s = bounds.at(PackCell({10, 10, 0}));
  EXPECT_LT(s.radius, 0.06);
  EXPECT_NEAR(s.centre.x, 5.075, 1e-6);
}

}  // namespace
}  // namespace exo
