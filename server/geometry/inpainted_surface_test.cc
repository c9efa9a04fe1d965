#include "server/geometry/inpainted_surface.h"

#include <cmath>
#include <cstring>

#include <gtest/gtest.h>

#include "server/geometry/test_scenes.h"

namespace exo::geometry {
namespace {

using geometry_test::LookAt;
using geometry_test::MakeFrame;
using geometry_test::Plane;
using geometry_test::RenderDepth;
using geometry_test::Sphere;
using geometry_test::Union;

// A wall at x = 2 and a ball (the object to remove) in front of it at x = 1.2.
constexpr double kWallX = 2.0, kR = 0.2;
const glm::dvec3 kBall(1.2, 0.0, 0.0);

PinholeCamera Cam() { return PinholeCamera::FromFov(160, 120, 1.2); }
TsdfOptions Opts() {
  TsdfOptions o;
  o.voxel_size_m = 0.02f;
  o.num_threads = 1;
  return o;
}
geometry_test::HitFn WithBall() { return Union({Plane({1, 0, 0}, kWallX), Sphere(kBall, kR)}); }
geometry_test::HitFn WallOnly(double shift = 0.0) { return Plane({1, 0, 0}, kWallX + shift); }
Rigid3d PoseA() { return LookAt({0, 0, 0}, {kWallX, 0, 0}); }
Rigid3d PoseAt(double y) { return LookAt({0.2, y, 0.0}, {kWallX, 0, 0}); }

void Observe(TsdfVolume* v, const Rigid3d& pose, const geometry_test::HitFn& hit) {
  ASSERT_TRUE(v->Integrate(MakeFrame(Cam(), pose, RenderDepth(Cam(), pose, hit)), LocalOrigin{}).ok());
}

// The operator's region: label voxels (2 cm) on the ball's surface (the whole ball was marked).
std::vector<glm::ivec3> BallLabels() {
  std::vector<glm::ivec3> out;
  const double lv = 0.02;
  for (int z = -15; z <= 15; ++z)
    for (int y = -15; y <= 15; ++y)
      for (int x = 40; x <= 80; ++x) {
        const glm::dvec3 c = (glm::dvec3(x, y, z) + 0.5) * lv;
        if (std::abs(glm::length(c - kBall) - kR) < 1.5 * lv) out.push_back({x, y, z});
      }
  return out;
}

// ROI pixels of the keyframe camera: where the ball is nearer than the wall (dilated 2 px).
ImageU8 BallMask(const Rigid3d& pose) {
  const ImageF with = RenderDepth(Cam(), pose, WithBall()), wall = RenderDepth(Cam(), pose, WallOnly());
  ImageU8 m(with.width(), with.height(), 1, 0);
  for (int y = 0; y < m.height(); ++y)
    for (int x = 0; x < m.width(); ++x)
      for (int dy = -2; dy <= 2; ++dy)
        for (int dx = -2; dx <= 2; ++dx) {
          const int u = x + dx, v = y + dy;
          if (u >= 0 && v >= 0 && u < m.width() && v < m.height() &&
              with.at(u, v) + 1e-4f < wall.at(u, v))
            m.at(x, y) = 255;
        }
  return m;
}

TriangleMesh ClientMesh(const InpaintedSurface& s, const TsdfVolume& obs) {
  TriangleMesh all;
  absl::flat_hash_set<uint64_t> keys;
  for (uint64_t k : obs.BlockKeys()) keys.insert(k);
  for (uint64_t k : s.inpainted().BlockKeys()) keys.insert(k);
  for (uint64_t k : keys) {
    const TriangleMesh m = s.ExtractBlock(obs, k);
    if (!m.empty()) all.Append(m);
  }
  return all;
}
// Vertices on the ball's surface (not near the wall), and on the wall behind the ball at `shift`.
int OnBall(const TriangleMesh& m) {
  int n = 0;
  for (const glm::vec3& p : m.positions)
    n += std::abs(glm::length(glm::dvec3(p) - kBall) - kR) < 0.02 && p.x < kWallX - 0.1;
  return n;
}
int OnWallBehindBall(const TriangleMesh& m, double shift, double max_r = 0.15) {
  int n = 0;
  for (const glm::vec3& p : m.positions)
    n += std::abs(p.x - (kWallX + shift)) < 0.005 && std::hypot(p.y, p.z) < max_r;
  return n;
}

TEST(InpaintedSurface, InpaintedDepthOnlyInLipVoxelsObservedUntouchedObjectCarved) {
  TsdfVolume obs(Opts());
  Observe(&obs, PoseA(), WithBall());
  Observe(&obs, PoseAt(0.05), WithBall());
  std::string before;
  {
    StateWriter w;
    obs.SaveState(&w);
    const std::string bytes = w.str();
    before = bytes;
  }
  const TriangleMesh observed_mesh = obs.ExtractAll();
  ASSERT_GT(OnBall(observed_mesh), 100);
  EXPECT_EQ(OnWallBehindBall(observed_mesh, 0.0, 0.1), 0);  // the ball's shadow: never observed

  InpaintedSurface s(Opts());
  const auto labels = BallLabels();
  s.SetRoi(labels, 0.02);
  ASSERT_GT(s.roi_voxels(), labels.size());
  // A perfect inpainted keyframe at A: the wall behind the ball, in the ball's pixels.
  const ImageF wall = RenderDepth(Cam(), PoseA(), WallOnly());
  auto st = s.IntegrateInpainted(obs, wall, BallMask(PoseA()), nullptr, Cam(), PoseA());
  ASSERT_TRUE(st.ok()) << st.status();
  EXPECT_GT(st->pixels, 500u);
  EXPECT_GT(st->voxels_kept, 1000u);
  EXPECT_GT(st->voxels_erased, 100u);  // the rim of the ROI: the wall observed around the ball

  // The observed field is not modified, bit for bit.
  {
    StateWriter w;
    obs.SaveState(&w);
    const std::string bytes = w.str();
    EXPECT_TRUE(before == bytes);
  }
  // Inpainted values live only in L_IP voxels (in the ROI, or where nothing was observed), and
  // the clients' field outside the ROI is the observation wherever there is one.
  const int bs = Opts().block_size;
  size_t ip_voxels = 0, observed_checked = 0;
  for (uint64_t key : s.inpainted().BlockKeys()) {
    const glm::ivec3 base = UnpackCell(key) * bs;
    for (int z = 0; z < bs; ++z)
      for (int y = 0; y < bs; ++y)
        for (int x = 0; x < bs; ++x) {
          const glm::ivec3 g = base + glm::ivec3(x, y, z);
          const TsdfVoxel* v = s.inpainted().VoxelAt(g);
          const TsdfVoxel* o = obs.VoxelAt(g);
          const bool observed = o && o->weight >= Opts().min_extract_weight;
          if (v->weight > 0) {
            ++ip_voxels;
            EXPECT_TRUE(s.InRoi(g) || !observed);
          }
          if (observed && !s.InRoi(g)) {
            ++observed_checked;
            EXPECT_EQ(s.Label(obs, g), VoxelLabel::kObserved);
            EXPECT_EQ(s.ClientVoxel(obs, g), o);
          }
        }
  }
  EXPECT_GT(ip_voxels, 1000u);
  EXPECT_GT(observed_checked, 1000u);
  // Blocks away from the ROI and the inpainted field: the observed mesh, bit for bit.
  size_t same = 0;
  for (uint64_t key : obs.BlockKeys()) {
    if (s.Affects(key)) continue;
    const TriangleMesh a = obs.ExtractBlock(key), b = s.ExtractBlock(obs, key);
    ASSERT_EQ(a.positions.size(), b.positions.size());
    ASSERT_EQ(a.indices, b.indices);
    EXPECT_EQ(0, std::memcmp(a.positions.data(), b.positions.data(),
                             a.positions.size() * sizeof(glm::vec3)));
    EXPECT_EQ(0, std::memcmp(a.normals.data(), b.normals.data(), a.normals.size() * sizeof(glm::vec3)));
    ++same;
  }
  EXPECT_GT(same, 10u);
  // MeshBlockFrom with the volume's own voxels is ExtractBlock, bit for bit (every block).
  for (uint64_t key : obs.BlockKeys()) {
    const TriangleMesh a = obs.ExtractBlock(key);
    const TriangleMesh b =
        obs.MeshBlockFrom(UnpackCell(key), [&](const glm::ivec3& g) { return obs.VoxelAt(g); });
    ASSERT_EQ(a.indices, b.indices);
    ASSERT_EQ(0, std::memcmp(a.positions.data(), b.positions.data(),
                             a.positions.size() * sizeof(glm::vec3)));
  }
  // The clients' mesh: the ball is gone, the wall behind it is there.
  const TriangleMesh client = ClientMesh(s, obs);
  EXPECT_EQ(OnBall(client), 0);
  EXPECT_GT(OnWallBehindBall(client, 0.0, 0.1), 50);
  // Dirty blocks cover every block whose client mesh changed.
  const auto dirty = s.TakeDirtyBlocks();
  for (uint64_t key : obs.BlockKeys())
    if (obs.ExtractBlock(key).num_triangles() != s.ExtractBlock(obs, key).num_triangles())
      EXPECT_TRUE(std::binary_search(dirty.begin(), dirty.end(), key));
  EXPECT_TRUE(s.TakeDirtyBlocks().empty());
}

TEST(InpaintedSurface, LaterObservationsWinTheRemovedObjectStaysRemoved) {
  TsdfVolume obs(Opts());
  Observe(&obs, PoseA(), WithBall());
  InpaintedSurface s(Opts());
  s.SetRoi(BallLabels(), 0.02);
  // A keyframe whose inpainted wall is 4 cm off (hallucinated depth is never exact).
  const ImageF off = RenderDepth(Cam(), PoseA(), WallOnly(0.04));
  ASSERT_TRUE(s.IntegrateInpainted(obs, off, BallMask(PoseA()), nullptr, Cam(), PoseA()).ok());
  EXPECT_GT(OnWallBehindBall(ClientMesh(s, obs), 0.04, 0.08), 20);
  EXPECT_EQ(OnWallBehindBall(ClientMesh(s, obs), 0.0, 0.08), 0);
  // Walk around: the wall behind the ball is observed from the sides (the hole is seen), and the
  // ball from every side (it is still there physically).
  for (double y : {-0.9, -0.6, 0.6, 0.9}) Observe(&obs, PoseAt(y), WithBall());
  const TriangleMesh client = ClientMesh(s, obs);
  EXPECT_GT(OnWallBehindBall(client, 0.0, 0.08), 20);   // the observation replaced the fill
  EXPECT_EQ(OnWallBehindBall(client, 0.04, 0.08), 0);
  EXPECT_GT(OnBall(obs.ExtractAll()), 100);  // the observed volume has the ball ...
  EXPECT_EQ(OnBall(client), 0);              // ... the clients do not
  // Clearing the region and the inpainted field gives the observed mesh back.
  s.SetRoi({}, 0.02);
  s.ClearInpainted();
  EXPECT_TRUE(s.empty());
  EXPECT_EQ(ClientMesh(s, obs).num_triangles(), obs.ExtractAll().num_triangles());
}

TEST(InpaintedSurface, BadInput) {
  TsdfVolume obs(Opts());
  InpaintedSurface s(Opts());
  const ImageF depth(160, 120, 1, 1.0f);
  EXPECT_FALSE(s.IntegrateInpainted(obs, depth, ImageU8(80, 60, 1, 255), nullptr, Cam(), PoseA()).ok());
  EXPECT_FALSE(s.IntegrateInpainted(obs, depth, ImageU8(160, 120, 1, 255), nullptr,
                                    PinholeCamera::FromFov(80, 60, 1.2), PoseA()).ok());
  const ImageU8 bad_color(160, 120, 1, 0);
  EXPECT_FALSE(s.IntegrateInpainted(obs, depth, ImageU8(160, 120, 1, 255), &bad_color, Cam(), PoseA()).ok());
  // An empty mask fuses nothing.
  auto st = s.IntegrateInpainted(obs, depth, ImageU8(160, 120, 1, 0), nullptr, Cam(), PoseA());
  ASSERT_TRUE(st.ok());
  EXPECT_EQ(st->pixels, 0u);
  EXPECT_EQ(st->voxels_kept, 0u);
  InpaintedSurfaceOptions o;
  o.carve_margin_voxels = -1;
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace exo::geometry
