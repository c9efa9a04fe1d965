#include "server/geometry/mesh_lod.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <tuple>

#include <gtest/gtest.h>

#include "server/geometry/test_scenes.h"
#include "server/geometry/tsdf_volume.h"

namespace exo {
namespace {

using geometry::MeshLodOptions;
using geometry::MeshLodStats;
using geometry::SimplifyMesh;
using geometry_test::LookAt;
using geometry_test::MakeFrame;
using geometry_test::Plane;
using geometry_test::RenderDepth;
using geometry_test::Sphere;
using geometry_test::Union;

// Chunks of a fused scene: a sphere of radius 0.3 m in front of a wall (2 cm voxels).
std::vector<MeshChunk> FusedChunks() {
  TsdfOptions o;
  o.voxel_size_m = 0.02f;
  TsdfVolume vol(o);
  const auto cam = PinholeCamera::FromFov(160, 120, 1.2);
  const auto hit = Union({Sphere({0, 0, 0}, 0.3), Plane({0, 0, 1}, -0.6)});
  for (double a = -0.6; a <= 0.6; a += 0.2) {
    const glm::dvec3 eye(1.2 * std::sin(a), 0.3 * a, 1.2 * std::cos(a));
    const Rigid3d pose = LookAt(eye, {0, 0, -0.2}, {0, 1, 0});
    Frame f = MakeFrame(cam, pose, RenderDepth(cam, pose, hit));
    EXPECT_TRUE(vol.Integrate(f, LocalOrigin{}).ok());
  }
  return vol.ExtractDirtyChunks();
}

// Distance of a point to the scene's analytic surface (sphere or wall).
double SurfaceDistance(const glm::dvec3& p) {
  return std::min(std::abs(glm::length(p) - 0.3), std::abs(p.z + 0.6));
}

// Edges used by exactly one triangle of a mesh, as position pairs (the chunk's open boundary).
std::set<std::pair<std::tuple<float, float, float>, std::tuple<float, float, float>>> BorderEdges(
    const TriangleMesh& m) {
  using P = std::tuple<float, float, float>;
  std::map<std::pair<P, P>, int> uses;
  for (size_t t = 0; t < m.indices.size(); t += 3) {
    const glm::vec3 p0 = m.positions[m.indices[t]], p1 = m.positions[m.indices[t + 1]],
                    p2 = m.positions[m.indices[t + 2]];
    if (p0 == p1 || p1 == p2 || p0 == p2) continue;  // zero-area triangles of marching cubes
    for (int j = 0; j < 3; ++j) {
      const glm::vec3 a = m.positions[m.indices[t + j]], b = m.positions[m.indices[t + (j + 1) % 3]];
      P pa{a.x, a.y, a.z}, pb{b.x, b.y, b.z};
      if (pb < pa) std::swap(pa, pb);
      ++uses[{pa, pb}];
    }
  }
  std::set<std::pair<P, P>> border;
  for (const auto& [e, n] : uses)
    if (n == 1) border.insert(e);
  return border;
}

TEST(MeshLod, ZeroErrorReturnsTheInput) {
  const auto chunks = FusedChunks();
  ASSERT_FALSE(chunks.empty());
  MeshLodStats st;
  const TriangleMesh out = SimplifyMesh(chunks[0].mesh, MeshLodOptions{}, &st);
  EXPECT_EQ(out.indices, chunks[0].mesh.indices);
  EXPECT_EQ(out.positions, chunks[0].mesh.positions);
  EXPECT_EQ(st.triangles_in, st.triangles_out);
}

TEST(MeshLod, OptionsValidate) {
  EXPECT_TRUE(MeshLodOptions{}.Validate().ok());
  EXPECT_TRUE(MeshLodOptions{0.01}.Validate().ok());
  EXPECT_FALSE(MeshLodOptions{-0.01}.Validate().ok());
  EXPECT_FALSE(MeshLodOptions{std::nan("")}.Validate().ok());
  EXPECT_FALSE(MeshLodOptions{INFINITY}.Validate().ok());
}

// Simplifying every chunk under a 1 cm bound: far fewer triangles, every vertex still on the
// surface within the bound (+ the TSDF's own half-voxel error), each chunk's open boundary
// untouched, and the union of the simplified chunks still closed: after welding bitwise-equal
// positions every edge away from the volume's outer rim is shared by exactly two triangles.
TEST(MeshLod, SimplifiedChunksStayAccurateAndCrackFree) {
  const auto chunks = FusedChunks();
  ASSERT_GT(chunks.size(), 10u);
  const double bound = 0.01;
  size_t in = 0, out_tris = 0;
  double max_in_err = 0, max_out_err = 0;
  TriangleMesh full, simple;
  for (const MeshChunk& c : chunks) {
    MeshLodStats st;
    const TriangleMesh s = SimplifyMesh(c.mesh, MeshLodOptions{bound}, &st);
    in += c.mesh.num_triangles();
    out_tris += s.num_triangles();
    EXPECT_EQ(st.triangles_out, s.num_triangles());
    EXPECT_LE(st.error_m, bound * 1.0001);
    for (uint32_t i : s.indices) ASSERT_LT(i, s.positions.size());
    EXPECT_EQ(s.normals.size(), c.mesh.normals.empty() ? 0u : s.positions.size());
    for (const glm::vec3& p : c.mesh.positions) max_in_err = std::max(max_in_err, SurfaceDistance(p));
    for (const glm::vec3& p : s.positions) max_out_err = std::max(max_out_err, SurfaceDistance(p));
    EXPECT_EQ(BorderEdges(s), BorderEdges(c.mesh)) << "chunk " << c.id << ": open boundary changed";
    full.Append(c.mesh);
    simple.Append(s);
  }
  EXPECT_LT(out_tris * 2, in) << in << " -> " << out_tris;
  // Vertices are a subset of the input's: their distance to the surface is the input's.
  EXPECT_LE(max_out_err, max_in_err + 1e-6);
  // The welded union has the same outer rim as the full mesh: no new crack anywhere.
  EXPECT_EQ(BorderEdges(simple), BorderEdges(full));
  // Centroids of the simplified triangles lie within the bound (+ half a voxel of TSDF error) of
  // the analytic surface: simplification did not cut corners off the sphere.
  double worst = 0;
  for (size_t t = 0; t < simple.indices.size(); t += 3) {
    const glm::dvec3 c = (glm::dvec3(simple.positions[simple.indices[t]]) +
                          glm::dvec3(simple.positions[simple.indices[t + 1]]) +
                          glm::dvec3(simple.positions[simple.indices[t + 2]])) / 3.0;
    worst = std::max(worst, SurfaceDistance(c));
  }
  EXPECT_LT(worst, bound + 0.5 * 0.02) << "triangle centroid off the surface";
}

TEST(MeshLod, DegenerateInputComesBackUnchanged) {
  TriangleMesh one;
  one.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  one.indices = {0, 1, 2};
  EXPECT_EQ(SimplifyMesh(one, MeshLodOptions{0.1}).indices, one.indices);
  TriangleMesh bad = one;
  bad.indices = {0, 1, 2, 0, 2, 7};  // index out of range
  EXPECT_EQ(SimplifyMesh(bad, MeshLodOptions{0.1}).indices, bad.indices);
  EXPECT_TRUE(SimplifyMesh(TriangleMesh{}, MeshLodOptions{0.1}).empty());
}

}  // namespace
}  // namespace exo
