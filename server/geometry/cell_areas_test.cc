#include "server/geometry/cell_areas.h"

#include <cmath>
#include <map>

#include <gtest/gtest.h>

#include "server/geometry/test_scenes.h"
#include "server/geometry/tsdf_volume.h"

namespace exo {
namespace {

double MeshArea(const TriangleMesh& m) {
  double a = 0;
  for (size_t t = 0; t < m.indices.size(); t += 3) {
    const glm::dvec3 p0 = m.positions[m.indices[t]], p1 = m.positions[m.indices[t + 1]],
                     p2 = m.positions[m.indices[t + 2]];
    a += 0.5 * glm::length(glm::cross(p1 - p0, p2 - p0));
  }
  return a;
}

// A triangle spanning four cells is split exactly. Guard: the clipping (assigning the whole
// triangle to its centroid's cell would put all 2 m^2 in cell (0,0,0)).
TEST(CellAreas, TriangleIsClippedToCells) {
  TriangleMesh m;
  m.positions = {{0, 0, 0.25f}, {2, 0, 0.25f}, {0, 2, 0.25f}};
  m.indices = {0, 1, 2};
  const CellGrid grid{1.0};
  const auto a = CellAreas::AreaPerCell(m, grid);
  auto at = [&](int x, int y) {
    auto it = a.find(PackCell({x, y, 0}));
    return it == a.end() ? 0.0 : it->second;
  };
  EXPECT_NEAR(at(0, 0), 1.0, 1e-9);
  EXPECT_NEAR(at(1, 0), 0.5, 1e-9);
  EXPECT_NEAR(at(0, 1), 0.5, 1e-9);
  EXPECT_NEAR(at(1, 1), 0.0, 1e-9);
  // Negative coordinates: floor, not truncation toward zero.
  m.positions = {{-0.5f, -0.5f, -0.5f}, {0.5f, -0.5f, -0.5f}, {-0.5f, 0.5f, -0.5f}};
  const auto b = CellAreas::AreaPerCell(m, grid);
  double sum = 0;
  for (const auto& [c, v] : b) sum += v;
  EXPECT_NEAR(sum, 0.5, 1e-9);
  EXPECT_NEAR(b.at(PackCell({-1, -1, -1})), 0.25, 1e-9);
  EXPECT_NEAR(b.at(PackCell({0, -1, -1})), 0.125, 1e-9);
  EXPECT_NEAR(b.at(PackCell({-1, 0, -1})), 0.125, 1e-9);
}

// Incremental maintenance over a stream of fused frames: after every chunk replacement the
// per-cell areas equal a from-scratch computation on the current mesh, and their sum equals
// the mesh area. Removing everything leaves no cells (no rounding residue).
TEST(CellAreas, IncrementalSumEqualsMeshArea) {
  using namespace geometry_test;
  TsdfOptions o;
  o.voxel_size_m = 0.02f;
  TsdfVolume vol(o);
  CellAreas areas(CellGrid{0.1});
  const auto cam = PinholeCamera::FromFov(160, 120, 1.2);
  const auto hit = Union({Sphere({0, 0, 0}, 0.3), Plane({0, 0, 1}, -0.35)});
  std::vector<glm::dvec3> eyes = {{1, 0, 0.3}, {0, 1, 0.4}, {-1, 0.2, 0.5}, {0, -1, 0.6}, {0.1, 0, 1.2}};
  std::map<uint64_t, MeshChunk> latest;
  for (const auto& eye : eyes) {
    const Rigid3d pose = LookAt(eye, {0, 0, 0}, {0.3, 0.2, 1.0});
    ASSERT_TRUE(vol.Integrate(MakeFrame(cam, pose, RenderDepth(cam, pose, hit)), {}).ok());
    for (auto& c : vol.ExtractDirtyChunks()) {
      areas.UpdateChunk(c);
      latest[c.id] = std::move(c);
    }
    for (uint64_t id : vol.TakeRemovedChunkIds()) {
      areas.RemoveChunk(id);
      latest.erase(id);
    }
    EXPECT_FALSE(areas.TakeChangedCells().empty());
    TriangleMesh all;
    for (const auto& [id, c] : latest) all.Append(c.mesh);
    const double mesh_area = MeshArea(all);
    EXPECT_NEAR(areas.TotalArea(), mesh_area, 1e-6 * mesh_area);
    const auto fresh = CellAreas::AreaPerCell(all, areas.grid());
    EXPECT_EQ(fresh.size(), areas.num_cells());
    for (const auto& [cell, a] : fresh) EXPECT_NEAR(areas.Area(cell), a, 1e-9);
  }
  EXPECT_GT(areas.num_cells(), 50u);
  for (const auto& [id, c] : latest) areas.RemoveChunk(id);
  EXPECT_EQ(areas.num_cells(), 0u);
  EXPECT_EQ(areas.TotalArea(), 0.0);
  EXPECT_EQ(areas.Area(PackCell({0, 0, 0})), 0.0);
}

}  // namespace
}  // namespace exo
