#include "server/geometry/tsdf_volume.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <tuple>

#include <gtest/gtest.h>

#include "common/datasets/seven_scenes.h"
#include "common/datasets/test_fixture.h"
#include "server/geometry/test_scenes.h"

namespace exo {
namespace {

using geometry_test::LookAt;
using geometry_test::MakeFrame;
using geometry_test::Plane;
using geometry_test::RenderDepth;
using geometry_test::Sphere;

PinholeCamera SmallCamera() { return PinholeCamera::FromFov(160, 120, 1.2); }

TsdfOptions Opts(float voxel = 0.02f) {
  TsdfOptions o;
  o.voxel_size_m = voxel;
  return o;
}

// 14 views around a sphere: 6 axis directions and 8 diagonals.
std::vector<glm::dvec3> SphereViewDirs() {
  std::vector<glm::dvec3> dirs = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
  for (int sx : {-1, 1})
    for (int sy : {-1, 1})
      for (int sz : {-1, 1}) dirs.push_back(glm::normalize(glm::dvec3(sx, sy, sz)));
  return dirs;
}

void IntegrateSphere(TsdfVolume* vol, const glm::dvec3& centre_w, double radius,
                     const LocalOrigin& origin, double distance = 1.0) {
  const auto cam = SmallCamera();
  const auto hit = Sphere(centre_w, radius);
  for (const glm::dvec3& d : SphereViewDirs()) {
    const Rigid3d pose = LookAt(centre_w + d * distance, centre_w, {0.3, 0.2, 1.0});
    Frame f = MakeFrame(cam, pose, RenderDepth(cam, pose, hit));
    ASSERT_TRUE(vol->Integrate(f, origin).ok());
  }
}

TriangleMesh Concat(const std::vector<MeshChunk>& chunks) {
  TriangleMesh m;
  for (const auto& c : chunks) m.Append(c.mesh);
  return m;
}

double MeshArea(const TriangleMesh& m) {
  double a = 0;
  for (size_t t = 0; t < m.indices.size(); t += 3) {
    const glm::dvec3 p0 = m.positions[m.indices[t]], p1 = m.positions[m.indices[t + 1]],
                     p2 = m.positions[m.indices[t + 2]];
    a += 0.5 * glm::length(glm::cross(p1 - p0, p2 - p0));
  }
  return a;
}

TEST(TsdfOptions, ValidateRejectsBadValues) {
  EXPECT_TRUE(TsdfOptions().Validate().ok());
  TsdfOptions o;
  o.voxel_size_m = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.voxel_size_m = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.truncation_m = 0.5f * o.voxel_size_m;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.block_size = 1;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.max_depth_m = o.min_depth_m;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.num_threads = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.alloc_stride = 0;
  EXPECT_FALSE(o.Validate().ok());
}

// Vertices of a fused sphere lie on the analytic surface (within half a voxel), normals point
// outward, and the surface is closed across chunk seams: after welding bitwise-equal vertex
// positions of all chunks, every edge is shared by exactly two triangles. Fails if boundary
// cubes skip the neighbour blocks' voxels (cracks) or if vertex placement differs per chunk.
TEST(TsdfVolume, SphereIsAccurateAndCrackFree) {
  TsdfVolume vol(Opts(0.02f));
  const double r = 0.3;
  IntegrateSphere(&vol, {0, 0, 0}, r, LocalOrigin{});
  const auto chunks = vol.ExtractDirtyChunks();
  ASSERT_GT(chunks.size(), 10u);
  const TriangleMesh m = Concat(chunks);
  ASSERT_GT(m.num_triangles(), 1000u);

  double sum_err = 0, max_err = 0;
  int outward = 0;
  for (size_t i = 0; i < m.positions.size(); ++i) {
    const glm::dvec3 p = m.positions[i];
    const double err = std::abs(glm::length(p) - r);
    sum_err += err;
    max_err = std::max(max_err, err);
    outward += glm::dot(glm::dvec3(m.normals[i]), p) > 0;
  }
  const double mean_err = sum_err / m.positions.size();
  EXPECT_LT(mean_err, 0.25 * 0.02) << "mean vertex error " << mean_err;
  EXPECT_LT(max_err, 0.5 * 0.02) << "max vertex error " << max_err;
  EXPECT_EQ(outward, int(m.positions.size()));
  // Triangle winding agrees with the outward normal.
  int wound_out = 0;
  for (size_t t = 0; t < m.indices.size(); t += 3) {
    const glm::dvec3 a = m.positions[m.indices[t]], b = m.positions[m.indices[t + 1]],
                     c = m.positions[m.indices[t + 2]];
    wound_out += glm::dot(glm::cross(b - a, c - a), a + b + c) > 0;
  }
  EXPECT_EQ(wound_out, int(m.num_triangles()));

  // Weld across chunks by exact position and count edge uses.
  std::map<std::tuple<float, float, float>, uint32_t> weld;
  std::vector<uint32_t> id(m.positions.size());
  for (size_t i = 0; i < m.positions.size(); ++i) {
    const auto& p = m.positions[i];
    id[i] = weld.try_emplace({p.x, p.y, p.z}, uint32_t(weld.size())).first->second;
  }
  std::map<std::pair<uint32_t, uint32_t>, int> edge_uses;
  for (size_t t = 0; t < m.indices.size(); t += 3)
    for (int j = 0; j < 3; ++j) {
      uint32_t a = id[m.indices[t + j]], b = id[m.indices[t + (j + 1) % 3]];
      if (a > b) std::swap(a, b);
      ++edge_uses[{a, b}];
    }
  int bad = 0;
  for (const auto& [e, n] : edge_uses) bad += n != 2;
  EXPECT_EQ(bad, 0) << "edges not shared by exactly two triangles (cracks or non-manifold)";
  // Closed genus-0 surface: V - E + F = 2.
  EXPECT_EQ(int64_t(weld.size()) - int64_t(edge_uses.size()) + int64_t(m.num_triangles()), 2);
  // Area close to 4 pi r^2.
  EXPECT_NEAR(MeshArea(m), 4 * M_PI * r * r, 0.02 * 4 * M_PI * r * r);
}

// A plane at z = 2 seen head-on and obliquely.
TEST(TsdfVolume, PlaneVerticesWithinHalfVoxel) {
  const float vs = 0.04f;
  TsdfVolume vol(Opts(vs));
  const auto cam = SmallCamera();
  const auto hit = Plane({0, 0, 1}, 2.0);
  for (const glm::dvec3 eye : {glm::dvec3(0, 0, 0), glm::dvec3(0.5, 0, 0.2), glm::dvec3(-0.4, 0.3, 0.1)}) {
    const Rigid3d pose = LookAt(eye, {0.1, 0.05, 2.0}, {0, -1, 0});
    ASSERT_TRUE(vol.Integrate(MakeFrame(cam, pose, RenderDepth(cam, pose, hit)), {}).ok());
  }
  const TriangleMesh m = vol.ExtractAll();
  ASSERT_GT(m.num_triangles(), 100u);
  double max_err = 0;
  for (const auto& p : m.positions) max_err = std::max(max_err, std::abs(double(p.z) - 2.0));
  EXPECT_LT(max_err, 0.5 * vs);
}

// SPEC §11 zero/NaN/inf depth: invalid samples never allocate or update anything. Guard:
// the `!(d >= min && d <= max)` tests in the block selection and voxel update (without them
// 0 allocates blocks at the camera, NaN/Inf produce garbage block keys or endless rays).
TEST(TsdfVolume, InvalidDepthIsSkipped) {
  TsdfVolume vol(Opts(0.02f));
  const auto cam = SmallCamera();
  const float bad[] = {0.0f, -1.0f, std::numeric_limits<float>::quiet_NaN(),
                       std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity(),
                       1e30f, 0.01f};
  ImageF depth(cam.width, cam.height, 1, 0.0f);
  for (int v = 0; v < cam.height; ++v)
    for (int u = 0; u < cam.width; ++u) depth.at(u, v) = bad[(u + 3 * v) % 7];
  Frame f = MakeFrame(cam, Rigid3d::Identity(), depth);
  auto stats = vol.Integrate(f, {});
  ASSERT_TRUE(stats.ok()) << stats.status();
  EXPECT_EQ(stats->valid_pixels, 0u);
  EXPECT_EQ(vol.num_blocks(), 0u);
  EXPECT_TRUE(vol.ExtractDirtyChunks().empty());

  // Half valid plane, half invalid: blocks only where the valid half lies (x < 0 side).
  ImageF half = RenderDepth(cam, Rigid3d::Identity(), Plane({0, 0, 1}, 1.5));
  for (int v = 0; v < cam.height; ++v)
    for (int u = cam.width / 2; u < cam.width; ++u) half.at(u, v) = bad[(u + v) % 6];
  ASSERT_TRUE(vol.Integrate(MakeFrame(cam, Rigid3d::Identity(), half), {}).ok());
  EXPECT_GT(vol.num_blocks(), 0u);
  glm::dvec3 lo, hi;
  ASSERT_TRUE(vol.Bounds(&lo, &hi));
  EXPECT_LE(hi.x, 0.0 + vol.block_size_m() + 1e-6);
  EXPECT_GT(lo.z, 1.5 - 0.1 - vol.block_size_m());
  EXPECT_LT(hi.z, 1.5 + 0.1 + vol.block_size_m());
  const TriangleMesh m = vol.ExtractAll();
  ASSERT_FALSE(m.empty());
  for (const auto& p : m.positions) {
    EXPECT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));
    EXPECT_NEAR(p.z, 1.5, 0.01);
  }
}

TEST(TsdfVolume, BadFramesAreRejectedWithStatus) {
  TsdfVolume vol(Opts());
  const auto cam = SmallCamera();
  Frame f = MakeFrame(cam, Rigid3d::Identity(), ImageF(cam.width / 2, cam.height, 1, 1.0f));
  EXPECT_FALSE(vol.Integrate(f, {}).ok());  // depth size != intrinsics
  f = MakeFrame(cam, Rigid3d::Identity(), ImageF(cam.width, cam.height, 1, 1.0f));
  f.world_from_cam.translation.x = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(vol.Integrate(f, {}).ok());
  f = MakeFrame(cam, Rigid3d::Identity(), ImageF(cam.width, cam.height, 1, 1.0f));
  f.world_from_cam.rotation = glm::dquat(2, 0, 0, 0);  // not unit
  EXPECT_FALSE(vol.Integrate(f, {}).ok());
  f.world_from_cam = Rigid3d::Identity();
  ASSERT_TRUE(vol.Integrate(f, {}).ok());
  // A different origin than the first frame's cannot be mixed into the same volume.
  EXPECT_FALSE(vol.Integrate(f, LocalOrigin{{10, 0, 0}}).ok());
  // A camera far outside the block index range without a LocalOrigin is refused, not wrapped.
  TsdfVolume far(Opts());
  f.world_from_cam.translation = {1e6, 0, 0};
  EXPECT_EQ(far.Integrate(f, {}).status().code(), absl::StatusCode::kOutOfRange);
  EXPECT_TRUE(far.Integrate(f, LocalOrigin{{1e6, 0, 0}}).ok());
}

// Geometry memory grows with observed surface, not with frames: the same view 50 times keeps
// the block count and bytes constant; a new part of the scene adds blocks.
TEST(TsdfVolume, MemoryGrowsWithSurfaceNotFrames) {
  TsdfVolume vol(Opts(0.02f));
  const auto cam = SmallCamera();
  const Rigid3d pose = LookAt({0, 0, 0}, {0, 0, 2}, {0, -1, 0});
  const Frame f = MakeFrame(cam, pose, RenderDepth(cam, pose, Plane({0, 0, 1}, 2.0)));
  ASSERT_TRUE(vol.Integrate(f, {}).ok());
  const size_t blocks = vol.num_blocks();
  vol.ExtractDirtyChunks();
  const size_t bytes = vol.bytes();
  ASSERT_GT(blocks, 10u);
  for (int i = 0; i < 49; ++i) {
    auto s = vol.Integrate(f, {});
    ASSERT_TRUE(s.ok());
    EXPECT_EQ(s->new_blocks, 0u);
    vol.ExtractDirtyChunks();
  }
  EXPECT_EQ(vol.num_blocks(), blocks);
  EXPECT_EQ(vol.bytes(), bytes);
  // Blocks are only allocated in the band: far fewer than a dense grid over the frustum.
  const double band_blocks_bound =
      (2.4 * 2.4 * 0.75 * 0.75) / (vol.block_size_m() * vol.block_size_m()) * 3;
  EXPECT_LT(double(blocks), band_blocks_bound);
  const Rigid3d side = LookAt({3, 0, 0}, {3, 0, 2}, {0, -1, 0});
  ASSERT_TRUE(vol.Integrate(MakeFrame(cam, side, RenderDepth(cam, side, Plane({0, 0, 1}, 2.0))), {}).ok());
  EXPECT_GT(vol.num_blocks(), blocks);
}

// Incremental extraction: only dirty blocks (and their lower neighbours) are re-meshed,
// versions increase per re-extraction, and the latest chunks equal a full extraction.
TEST(TsdfVolume, IncrementalChunksMatchFullExtraction) {
  TsdfVolume vol(Opts(0.02f));
  const auto cam = SmallCamera();
  const auto hit = Sphere({0, 0, 0}, 0.3);
  std::map<uint64_t, MeshChunk> latest;
  const auto dirs = SphereViewDirs();
  size_t first_count = 0;
  for (size_t i = 0; i < dirs.size(); ++i) {
    const Rigid3d pose = LookAt(dirs[i], {0, 0, 0}, {0.3, 0.2, 1.0});
    ASSERT_TRUE(vol.Integrate(MakeFrame(cam, pose, RenderDepth(cam, pose, hit)), {}).ok());
    auto chunks = vol.ExtractDirtyChunks();
    if (i == 0) first_count = chunks.size();
    for (auto& c : chunks) {
      auto it = latest.find(c.id);
      if (it == latest.end()) {
        EXPECT_EQ(c.version, 1u);
      } else {
        EXPECT_EQ(c.version, it->second.version + 1);
      }
      latest[c.id] = std::move(c);
    }
    for (uint64_t id : vol.TakeRemovedChunkIds()) latest.erase(id);
    // Nothing changed since: nothing to extract.
    EXPECT_TRUE(vol.ExtractDirtyChunks().empty());
  }
  EXPECT_GT(first_count, 0u);
  EXPECT_LT(first_count, latest.size());  // the first view sees only part of the sphere
  size_t tris = 0;
  for (const auto& [id, c] : latest) tris += c.mesh.num_triangles();
  const TriangleMesh all = vol.ExtractAll();
  EXPECT_EQ(tris, all.num_triangles());
  EXPECT_EQ(vol.num_dirty_blocks(), 0u);
}

// A surface that moves into the next block empties the old block's chunk: its id is reported
// by TakeRemovedChunkIds.
TEST(TsdfVolume, EmptiedChunksAreReportedRemoved) {
  TsdfOptions o = Opts(0.02f);
  o.max_weight = 4;
  TsdfVolume vol(o);
  const auto cam = SmallCamera();
  const Rigid3d pose = LookAt({0, 0, 0}, {0, 0, 1}, {0, -1, 0});
  // Block edge 0.16 m: z = 0.95 lies in block layer 5, z = 1.01 in layer 6.
  ASSERT_TRUE(vol.Integrate(MakeFrame(cam, pose, RenderDepth(cam, pose, Plane({0, 0, 1}, 0.95))), {}).ok());
  std::set<uint64_t> live;
  for (const auto& c : vol.ExtractDirtyChunks()) {
    live.insert(c.id);
    EXPECT_EQ(UnpackCell(c.id).z, 5);
  }
  ASSERT_FALSE(live.empty());
  const Frame moved = MakeFrame(cam, pose, RenderDepth(cam, pose, Plane({0, 0, 1}, 1.01)));
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(vol.Integrate(moved, {}).ok());
  const auto chunks = vol.ExtractDirtyChunks();
  for (const auto& c : chunks) EXPECT_EQ(UnpackCell(c.id).z, 6);
  const auto removed = vol.TakeRemovedChunkIds();
  EXPECT_EQ(std::set<uint64_t>(removed.begin(), removed.end()), live);
  EXPECT_TRUE(vol.TakeRemovedChunkIds().empty());
}

// SPEC §11, scene 1e5 m from the origin: with a LocalOrigin at the scene the mesh is the same
// as for the scene at the world origin. Guard: poses are re-expressed in the local frame in
// double before anything becomes float (without it vertices would sit at 1e5 m, and float
// spacing there is 7.8 mm, i.e. ~40 % of a voxel).
TEST(TsdfVolume, FarFromOriginGivesSameMesh) {
  const glm::dvec3 far(1e5, -2e5 / 3, 1e5 + 0.123);
  TsdfVolume near_vol(Opts(0.02f)), far_vol(Opts(0.02f));
  IntegrateSphere(&near_vol, {0.05, 0.02, 0.01}, 0.25, LocalOrigin{});
  IntegrateSphere(&far_vol, far + glm::dvec3(0.05, 0.02, 0.01), 0.25, LocalOrigin{far});
  const TriangleMesh a = near_vol.ExtractAll(), b = far_vol.ExtractAll();
  ASSERT_GT(a.num_triangles(), 500u);
  ASSERT_EQ(a.num_triangles(), b.num_triangles());
  ASSERT_EQ(a.num_vertices(), b.num_vertices());
  double max_diff = 0;
  for (size_t i = 0; i < a.positions.size(); ++i)
    max_diff = std::max(max_diff, double(glm::length(a.positions[i] - b.positions[i])));
  EXPECT_LT(max_diff, 1e-4);
  EXPECT_EQ(near_vol.num_blocks(), far_vol.num_blocks());
}

// Colour: a sphere whose upper half is red and lower half blue; vertex colours (linear)
// follow, away from the equator.
TEST(TsdfVolume, VertexColoursFollowInput) {
  TsdfVolume vol(Opts(0.02f));
  const auto cam = SmallCamera();
  const auto hit = Sphere({0, 0, 0}, 0.3);
  for (const glm::dvec3& d : SphereViewDirs()) {
    const Rigid3d pose = LookAt(d, {0, 0, 0}, {0.3, 0.2, 1.0});
    Frame f = MakeFrame(cam, pose, RenderDepth(cam, pose, hit), [](const glm::dvec3& p) {
      return p.z > 0 ? glm::u8vec3(255, 0, 0) : glm::u8vec3(0, 0, 255);
    });
    ASSERT_TRUE(vol.Integrate(f, {}).ok());
  }
  const TriangleMesh m = vol.ExtractAll();
  ASSERT_EQ(m.colors.size(), m.positions.size());
  int checked = 0;
  for (size_t i = 0; i < m.positions.size(); ++i) {
    const float z = m.positions[i].z;
    if (std::abs(z) < 0.06f) continue;
    const glm::vec3 c = m.colors[i];
    if (z > 0) {
      EXPECT_GT(c.x, 0.95f);
      EXPECT_LT(c.z, 0.05f);
    } else {
      EXPECT_GT(c.z, 0.95f);
      EXPECT_LT(c.x, 0.05f);
    }
    ++checked;
  }
  EXPECT_GT(checked, 500);
}

TEST(TsdfVolume, SdfAtMatchesSignedDistance) {
  TsdfVolume vol(Opts(0.02f));
  IntegrateSphere(&vol, {0, 0, 0}, 0.3, LocalOrigin{});
  float s = 0;
  ASSERT_TRUE(vol.SdfAt({0.3f + 0.015f, 0.001f, 0.002f}, &s));
  EXPECT_NEAR(s, 0.015f, 0.006f);
  ASSERT_TRUE(vol.SdfAt({0.0f, -0.3f + 0.02f, 0.001f}, &s));
  EXPECT_NEAR(s, -0.02f, 0.006f);
  EXPECT_FALSE(vol.SdfAt({2.0f, 2.0f, 2.0f}, &s));  // never observed
}

}  // namespace
}  // namespace exo

namespace exo {
namespace {

// Subsampled block allocation (alloc_stride) against per-pixel allocation (stride 1).
struct AllocComparison {
  size_t blocks_full = 0, blocks_sub = 0;
  size_t missing = 0;  // blocks stride 1 allocated that the subsample did not (summed per frame)
  TriangleMesh full, sub;
};

AllocComparison CompareAllocation(const std::vector<Frame>& frames, TsdfOptions o, int stride) {
  AllocComparison r;
  o.alloc_stride = 1;
  TsdfVolume full(o);
  o.alloc_stride = stride;
  TsdfVolume sub(o);
  for (const Frame& f : frames) {
    EXPECT_TRUE(full.Integrate(f, {}).ok());
    EXPECT_TRUE(sub.Integrate(f, {}).ok());
    const auto keys = sub.BlockKeys();
    const absl::flat_hash_set<uint64_t> have(keys.begin(), keys.end());
    for (uint64_t k : full.BlockKeys()) r.missing += !have.contains(k);
  }
  r.blocks_full = full.num_blocks();
  r.blocks_sub = sub.num_blocks();
  r.full = full.ExtractAll();
  r.sub = sub.ExtractAll();
  return r;
}

// Distances from each vertex of `a` to the nearest vertex of `b`, capped at `cap` (vertices
// with no neighbour within `cap` count as `cap`).
std::vector<double> VertexDistances(const TriangleMesh& a, const TriangleMesh& b, double cap) {
  std::vector<double> out;
  absl::flat_hash_map<uint64_t, std::vector<glm::vec3>> grid;
  auto cell = [cap](const glm::vec3& p) {
    return glm::ivec3(std::floor(p.x / cap), std::floor(p.y / cap), std::floor(p.z / cap));
  };
  for (const auto& p : b.positions) grid[PackCell(cell(p))].push_back(p);
  for (const auto& p : a.positions) {
    double best = cap;
    const glm::ivec3 c = cell(p);
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          auto it = grid.find(PackCell(c + glm::ivec3(dx, dy, dz)));
          if (it == grid.end()) continue;
          for (const auto& q : it->second) best = std::min(best, double(glm::length(p - q)));
        }
    out.push_back(best);
  }
  std::sort(out.begin(), out.end());
  return out;
}

// The surface of subsampled allocation equals per-pixel allocation's:
// - allocation is a superset after every frame (no block per-pixel allocation has is missing);
// - triangle counts within 0.5 % and at most 0.5 % of the vertices (either way) farther than
//   0.1 voxel from the other mesh's nearest vertex. Measured (2026-11-25): <= 0.12 % triangles,
//   <= 0.2 % vertices (7-Scenes 1 cm), 0.05 % at 2 cm, 0.03 % synthetic. The rest are bitwise
//   equal. Why not all: the superset blocks receive observations that per-pixel allocation
//   drops (a voxel is observed through a pixel whose own ray band misses the voxel's block),
//   so later frames average slightly different histories there, and fringe cubes that read a
//   superset block get triangles. A single frame therefore gives exact containment (checked in
//   ExpectSingleFrameContained).
void ExpectSameSurface(const AllocComparison& r, double voxel, const char* what) {
  SCOPED_TRACE(what);
  EXPECT_EQ(r.missing, 0u) << "subsampled allocation missed blocks of per-pixel allocation";
  EXPECT_GE(r.blocks_sub, r.blocks_full);
  ASSERT_GT(r.full.num_triangles(), 100u);
  const double tri_full = double(r.full.num_triangles()), tri_sub = double(r.sub.num_triangles());
  EXPECT_LE(std::abs(tri_sub - tri_full) / tri_full, 0.005)
      << "triangles " << tri_full << " (stride 1) vs " << tri_sub;
  const auto ab = VertexDistances(r.full, r.sub, voxel), ba = VertexDistances(r.sub, r.full, voxel);
  auto frac_above = [](const std::vector<double>& d, double x) {
    return double(d.end() - std::upper_bound(d.begin(), d.end(), x)) / d.size();
  };
  EXPECT_LE(frac_above(ab, 0.1 * voxel), 0.005);
  EXPECT_LE(frac_above(ba, 0.1 * voxel), 0.005);
  EXPECT_GE(1.0 - frac_above(ab, 0.0), 0.99) << "per-pixel vertices bitwise present";
  std::printf("%s: blocks %zu (stride 1) vs %zu, triangles %zu vs %zu, vertices not bitwise "
              "equal %.5f / %.5f, >0.1 voxel %.5f / %.5f\n",
              what, r.blocks_full, r.blocks_sub, r.full.num_triangles(), r.sub.num_triangles(),
              frac_above(ab, 0.0), frac_above(ba, 0.0), frac_above(ab, 0.1 * voxel),
              frac_above(ba, 0.1 * voxel));
}

// One frame: every block per-pixel allocation touches exists with the same voxels, so every
// vertex of its mesh is present bitwise in the subsampled mesh (which may add fringe triangles).
void ExpectSingleFrameContained(const Frame& frame, TsdfOptions o, int stride, const char* what) {
  SCOPED_TRACE(what);
  const AllocComparison r = CompareAllocation({frame}, o, stride);
  EXPECT_EQ(r.missing, 0u);
  ASSERT_GT(r.full.num_triangles(), 100u);
  const auto ab = VertexDistances(r.full, r.sub, o.voxel_size_m);
  EXPECT_EQ(ab.back(), 0.0) << "a per-pixel vertex moved or vanished";
  EXPECT_LE(double(r.sub.num_triangles()) / r.full.num_triangles(), 1.005);
}

// A 640x480 room corner with spheres, 4 views: subsampled allocation gives the same surface.
TEST(TsdfAllocation, SubsampledMatchesPerPixelOnSyntheticFrames) {
  const PinholeCamera cam = PinholeCamera::FromFov(640, 480, 1.1);
  const auto hit = geometry_test::Union({Plane({0, 0, 1}, 0.0), Plane({1, 0, 0}, -2.0),
                                         Plane({0, 1, 0}, 2.5), Sphere({0.3, 0.4, 0.5}, 0.5),
                                         Sphere({-1.0, 1.2, 0.3}, 0.3)});
  std::vector<Frame> frames;
  for (int i = 0; i < 4; ++i) {
    const double t = 0.5 * i;
    const Rigid3d pose = LookAt({1.8 * std::cos(t), -1.5 + 0.8 * std::sin(t), 1.6},
                                {-0.5, 0.8, 0.3}, {0, 0, 1});
    frames.push_back(MakeFrame(cam, pose, RenderDepth(cam, pose, hit)));
  }
  for (float voxel : {0.01f, 0.02f, 0.04f})
    for (int stride : {4, 8}) {
      const std::string what = "synthetic voxel " + std::to_string(voxel) + " stride " +
                               std::to_string(stride);
      ExpectSameSurface(CompareAllocation(frames, Opts(voxel), stride), voxel, what.c_str());
      ExpectSingleFrameContained(frames[1], Opts(voxel), stride, what.c_str());
    }
}

// Real Kinect v1 frames (7-Scenes redkitchen, depth edges, holes, noise): same surface.
TEST(TsdfAllocation, SubsampledMatchesPerPixelOnSevenScenes) {
  const std::string dir = testing::SharedDir() + "/data/7scenes-redkitchen";
  auto reader = SevenScenesReader::Open(dir);
  if (!reader.ok()) GTEST_SKIP() << "7-Scenes data not found at " << dir << " (set EXOVIEW_SHARED_DIR)";
  std::vector<Frame> frames;
  for (size_t i = 0; i < std::min<size_t>(40, (*reader)->size()); i += 4) {
    auto f = (*reader)->Load(i);
    ASSERT_TRUE(f.ok()) << f.status();
    frames.push_back(*std::move(f));
  }
  for (float voxel : {0.01f, 0.02f, 0.04f}) {
    TsdfOptions o = Opts(voxel);
    o.max_depth_m = 4.0f;
    for (int stride : {4, 8}) {
      const std::string what =
          "7-Scenes voxel " + std::to_string(voxel) + " stride " + std::to_string(stride);
      ExpectSameSurface(CompareAllocation(frames, o, stride), voxel, what.c_str());
      ExpectSingleFrameContained(frames[5], o, stride, what.c_str());
    }
  }
}

}  // namespace
}  // namespace exo
