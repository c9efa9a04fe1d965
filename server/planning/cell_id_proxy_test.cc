// Tests of the cell-id LOD (cell_id_proxy.h): vertex clustering keeps a surface where it is,
// drops collapsed triangles and most of the triangle count, rejects bad input.
#include "server/planning/cell_id_proxy.h"

#include <cmath>

#include <gtest/gtest.h>

namespace exo::planning {
namespace {

// n x n quads (2 triangles each) on the plane z = z0 over [x0, x0 + size]^2.
TriangleMesh Plane(int n, double size, double x0, double z0) {
  TriangleMesh m;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i)
      m.positions.emplace_back(float(x0 + size * i / n), float(x0 + size * j / n), float(z0));
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const uint32_t a = j * (n + 1) + i, b = a + 1, c = a + n + 1, d = c + 1;
      m.indices.insert(m.indices.end(), {a, b, d, a, d, c});
    }
  return m;
}

double Area(const TriangleMesh& m) {
  double s = 0;
  for (size_t t = 0; t < m.indices.size(); t += 3) {
    const glm::dvec3 a(m.positions[m.indices[t]]), b(m.positions[m.indices[t + 1]]),
        c(m.positions[m.indices[t + 2]]);
    s += 0.5 * glm::length(glm::cross(b - a, c - a));
  }
  return s;
}

TEST(ClusterSimplifyTest, FlatSurfaceStaysInPlaceWithFarFewerTriangles) {
  // 2 m plane of 2 cm quads (20000 triangles) at z = 0.3, off the 0.25 m cluster grid's centres
  // (a grid-centre representative would move it to z = 0.375: guards "mean of the members").
  const TriangleMesh m = Plane(100, 2.0, 0.01, 0.3);
  ClusterStats st;
  auto s = ClusterSimplify(m, 0.25, &st);
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_EQ(st.triangles_in, 20000u);
  EXPECT_EQ(st.triangles_out, s->num_triangles());
  EXPECT_LT(s->num_triangles(), 400u);   // >= 50x fewer
  EXPECT_GT(s->num_triangles(), 50u);
  for (const glm::vec3& p : s->positions) EXPECT_NEAR(p.z, 0.3f, 1e-5f);
  // No triangle with a repeated vertex (guards the collapse test), all indices valid.
  for (size_t t = 0; t < s->indices.size(); t += 3) {
    EXPECT_NE(s->indices[t], s->indices[t + 1]);
    EXPECT_NE(s->indices[t + 1], s->indices[t + 2]);
    EXPECT_NE(s->indices[t], s->indices[t + 2]);
  }
  for (uint32_t i : s->indices) EXPECT_LT(i, s->positions.size());
  // Interior kept: only a border strip of <= half a cluster is lost (4 m^2 -> >= 3 m^2).
  EXPECT_GT(Area(*s), 3.0);
  EXPECT_LE(Area(*s), 4.0 + 1e-6);
}

TEST(ClusterSimplifyTest, TinyClusterKeepsTheMesh) {
  const TriangleMesh m = Plane(10, 1.0, 0.0, 0.0);
  auto s = ClusterSimplify(m, 1e-4);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->num_triangles(), m.num_triangles());
  EXPECT_NEAR(Area(*s), 1.0, 1e-5);
}

TEST(ClusterSimplifyTest, RejectsBadInput) {
  TriangleMesh m = Plane(2, 1.0, 0.0, 0.0);
  EXPECT_FALSE(ClusterSimplify(m, 0.0).ok());
  EXPECT_FALSE(ClusterSimplify(m, std::nan("")).ok());
  EXPECT_FALSE(ClusterSimplify(m, -1.0).ok());
  m.indices.push_back(999);
  m.indices.push_back(0);
  m.indices.push_back(1);
  EXPECT_FALSE(ClusterSimplify(m, 0.1).ok());  // index out of range
  auto e = ClusterSimplify(TriangleMesh{}, 0.1);
  ASSERT_TRUE(e.ok());
  EXPECT_TRUE(e->empty());
}

}  // namespace
}  // namespace exo::planning
