#include <cmath>
#include <set>

#include <gtest/gtest.h>

#include "common/raster/rasterizer.h"
#include "common/synth/material.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace exo::synth {
namespace {

RenderOptions Small() {
  RenderOptions o;
  o.width = 160;
  o.height = 120;
  return o;
}

TEST(SynthSceneTest, DeterministicValidMeshes) {
  for (SceneKind k : {SceneKind::kVillage, SceneKind::kApartment}) {
    auto a = MakeScene(k, {});
    auto b = MakeScene(k, {});
    ASSERT_TRUE(a.ok() && b.ok());
    EXPECT_TRUE(ValidateMesh(a->mesh).ok());
    EXPECT_EQ(a->mesh.positions, b->mesh.positions);
    EXPECT_EQ(a->mesh.indices, b->mesh.indices);
    ASSERT_EQ(a->mesh.material.size(), a->mesh.num_triangles());
    std::set<uint32_t> used(a->mesh.material.begin(), a->mesh.material.end());
    for (uint32_t m : used) EXPECT_LT(m, uint32_t(Material::kCount));
    EXPECT_GE(used.size(), 6u) << a->name << " uses too few materials";
    EXPECT_FALSE(a->solids.empty());
  }
  auto village = MakeVillage({});
  auto apt = MakeApartment({});
  // Tens of metres outdoors, a flat indoors.
  EXPECT_GT(village->ExtentM(), 60);
  EXPECT_LT(village->ExtentM(), 150);
  EXPECT_GT(apt->ExtentM(), 10);
  EXPECT_LT(apt->ExtentM(), 25);
  SceneOptions other;
  other.seed = 2;
  auto v2 = MakeVillage(other);
  ASSERT_TRUE(v2.ok());
  EXPECT_NE(v2->mesh.positions, village->mesh.positions);
  // Subdivision bounds the edge length.
  for (size_t t = 0; t < village->mesh.num_triangles(); t += 7) {
    const auto& P = village->mesh.positions;
    const auto* i = &village->mesh.indices[3 * t];
    EXPECT_LE(glm::length(P[i[0]] - P[i[1]]), 2.0 * std::sqrt(2.0) + 1e-4);
  }
  SceneOptions bad;
  bad.max_edge_m = 0.001;
  EXPECT_FALSE(MakeVillage(bad).ok());
}

// Removable objects (issue 18): a chair in the apartment, a cart in the village; the scene with
// them minus them is the scene built without them, and a render differs only where the object
// is (its pixels are nearer than the background there).
TEST(SynthSceneTest, RemovableObjectsRenderWithAndWithout) {
  for (SceneKind k : {SceneKind::kVillage, SceneKind::kApartment}) {
    SceneOptions with_opt;
    with_opt.removable_objects = true;
    auto with = MakeScene(k, with_opt);
    auto plain = MakeScene(k, {});
    ASSERT_TRUE(with.ok() && plain.ok());
    EXPECT_TRUE(plain->removable.empty());
    ASSERT_EQ(with->removable.size(), 1u);
    const RemovableObject& o = with->removable[0];
    EXPECT_EQ(o.name, k == SceneKind::kApartment ? "chair" : "cart");
    EXPECT_GT(o.num_triangles, 12u);
    EXPECT_EQ(with->solids.size(), plain->solids.size() + 1);
    auto without = RemoveObjects(*with);
    ASSERT_TRUE(without.ok()) << without.status();
    EXPECT_EQ(without->mesh.indices, plain->mesh.indices);
    EXPECT_EQ(without->mesh.material, plain->mesh.material);
    EXPECT_EQ(without->solids.size(), plain->solids.size());
    EXPECT_TRUE(without->removable.empty());
    EXPECT_EQ(RemoveObjects(*with, {"piano"}).status().code(), absl::StatusCode::kNotFound);
    // A camera 1.5 m from the object, looking at it.
    const glm::dvec3 c = o.bounds.Centre();
    const Rigid3d pose = LookAt(c + glm::dvec3(1.2, 0.9, 1.6 - c.z), c);
    auto a = RenderFrame(*with, pose, Small());
    auto b = RenderFrame(*without, pose, Small());
    ASSERT_TRUE(a.ok() && b.ok());
    int nearer = 0, differ_elsewhere = 0;
    for (int y = 0; y < 120; ++y)
      for (int x = 0; x < 160; ++x) {
        const float za = a->frame.depth_m.at(x, y), zb = b->frame.depth_m.at(x, y);
        if (za + 1e-4f < zb || (za > 0 && zb == 0)) {
          ++nearer;
          continue;
        }
        EXPECT_NEAR(za, zb, 1e-4);
        for (int ch = 0; ch < 3; ++ch)
          differ_elsewhere += a->frame.color.at(x, y, ch) != b->frame.color.at(x, y, ch);
      }
    EXPECT_GT(nearer, 400) << o.name << " barely visible";
    EXPECT_LT(nearer, 160 * 120 / 2);
    // Only where the object touches the ground (its legs' feet are at the floor's own depth).
    EXPECT_LE(differ_elsewhere, 60) << o.name;
  }
}

TEST(SynthTrajectoryTest, HilbertCurveVisitsGridWithUnitSteps) {
  for (int order : {1, 2, 3, 4}) {
    const auto pts = HilbertCurve(order);
    const int n = 1 << order;
    ASSERT_EQ(pts.size(), size_t(n * n));
    std::set<std::pair<int, int>> cells;
    for (size_t i = 0; i < pts.size(); ++i) {
      const int x = int(std::lround(pts[i].x * (n - 1))), y = int(std::lround(pts[i].y * (n - 1)));
      cells.insert({x, y});
      if (i > 0) {
        const double step = glm::length(pts[i] - pts[i - 1]) * (n - 1);
        EXPECT_NEAR(step, 1.0, 1e-9) << "order " << order << " i " << i;
      }
    }
    EXPECT_EQ(cells.size(), pts.size());
  }
}

TEST(SynthTrajectoryTest, LookAtConvention) {
  const Rigid3d p = LookAt({1, 2, 3}, {1, 12, 3});  // looking north (+y)
  const glm::dmat3 R = p.RotationMatrix();
  EXPECT_NEAR(glm::length(R * glm::dvec3(0, 0, 1) - glm::dvec3(0, 1, 0)), 0, 1e-12);  // forward
  EXPECT_NEAR(glm::length(R * glm::dvec3(1, 0, 0) - glm::dvec3(1, 0, 0)), 0, 1e-12);  // right=east
  EXPECT_NEAR(glm::length(R * glm::dvec3(0, 1, 0) - glm::dvec3(0, 0, -1)), 0, 1e-12);  // down
  EXPECT_TRUE(ValidateQuaternion(p.rotation).ok());
}

// Every frame of every trajectory is in free space (not inside walls, furniture, buildings),
// consecutive frames are close (smooth), and there are N of them.
TEST(SynthTrajectoryTest, TrajectoriesStayInFreeSpace) {
  for (SceneKind k : {SceneKind::kVillage, SceneKind::kApartment}) {
    auto scene = MakeScene(k, {});
    ASSERT_TRUE(scene.ok());
    for (TrajectoryKind tk : {TrajectoryKind::kFlyover, TrajectoryKind::kWalk}) {
      TrajectoryOptions to;
      to.num_frames = 400;
      auto traj = MakeTrajectory(*scene, tk, to);
      if (tk == TrajectoryKind::kFlyover && scene->indoor) {
        EXPECT_FALSE(traj.ok());
        continue;
      }
      ASSERT_TRUE(traj.ok()) << traj.status();
      ASSERT_EQ(traj->size(), 400u);
      double max_step = 0, max_turn_per_m = 0;
      for (size_t i = 0; i < traj->size(); ++i) {
        const Rigid3d& p = (*traj)[i].local_from_cam;
        EXPECT_TRUE(scene->IsFree(p.translation, 0.2))
            << scene->name << "/" << TrajectoryKindName(tk) << " frame " << i << " at "
            << p.translation.x << "," << p.translation.y << "," << p.translation.z;
        if (tk == TrajectoryKind::kWalk) {
          EXPECT_NEAR(p.translation.z, scene->eye_height_m, 1e-6);
        } else {
          EXPECT_NEAR(p.translation.z, scene->flyover_altitude_m, 1e-6);
        }
        if (i > 0) {
          const Rigid3d& q = (*traj)[i - 1].local_from_cam;
          max_step = std::max(max_step, glm::length(p.translation - q.translation));
          const double step = glm::length(p.translation - q.translation);
          max_turn_per_m = std::max(
              max_turn_per_m, glm::degrees(RotationAngleRad(p.rotation, q.rotation)) / step);
          EXPECT_GT((*traj)[i].timestamp_s, (*traj)[i - 1].timestamp_s);
        }
      }
      EXPECT_LT(max_step, 1.0) << scene->name;
      EXPECT_LT(max_turn_per_m, 40.0) << scene->name;  // smooth heading (deg per metre)
      std::printf("%s/%s: max step %.3f m, max turn %.1f deg/m\n", scene->name.c_str(),
                  TrajectoryKindName(tk), max_step, max_turn_per_m);
    }
  }
}

TEST(SynthTrajectoryTest, TestPosesAreFreeSeededAndLookAtContent) {
  for (SceneKind k : {SceneKind::kVillage, SceneKind::kApartment}) {
    auto scene = MakeScene(k, {});
    ASSERT_TRUE(scene.ok());
    const PinholeCamera cam = Small().Camera();
    TestPoseOptions o;
    o.count = 20;
    auto a = MakeTestPoses(*scene, cam, o);
    auto b = MakeTestPoses(*scene, cam, o);
    ASSERT_TRUE(a.ok()) << a.status();
    ASSERT_EQ(a->size(), 20u);
    for (size_t i = 0; i < a->size(); ++i) {
      EXPECT_EQ((*a)[i].translation, (*b)[i].translation);
      EXPECT_TRUE(scene->IsFree((*a)[i].translation, 0.5));
      RasterOptions ro;
      auto r = Rasterize(scene->mesh, cam, (*a)[i], ro);
      ASSERT_TRUE(r.ok());
      EXPECT_GE(double(r->pixels_covered) / (cam.width * cam.height), 0.85 * o.min_coverage);
    }
    o.seed = 8;
    auto c = MakeTestPoses(*scene, cam, o);
    ASSERT_TRUE(c.ok());
    EXPECT_NE((*c)[0].translation, (*a)[0].translation);
  }
}

// Near test poses are off the input path (none equals an input pose) but within the stated
// radius of one, free, deterministic for a seed, and look at content.
TEST(SynthTrajectoryTest, NearTestPosesStayNearThePathButOffIt) {
  auto scene = MakeScene(SceneKind::kApartment, {});
  ASSERT_TRUE(scene.ok());
  TrajectoryOptions to;
  to.num_frames = 40;
  auto traj = MakeTrajectory(*scene, TrajectoryKind::kWalk, to);
  ASSERT_TRUE(traj.ok());
  std::vector<Rigid3d> input;
  for (const auto& p : *traj) input.push_back(p.local_from_cam);
  const PinholeCamera cam = Small().Camera();
  auto a = MakeNearTestPoses(*scene, input, cam, 12, 7, false);
  auto b = MakeNearTestPoses(*scene, input, cam, 12, 7, false);
  ASSERT_TRUE(a.ok()) << a.status();
  ASSERT_EQ(a->size(), 12u);
  const double r_h = 0.1 * scene->ExtentM();
  for (size_t i = 0; i < a->size(); ++i) {
    const glm::dvec3 e = (*a)[i].translation;
    EXPECT_EQ(e, (*b)[i].translation);
    EXPECT_TRUE(scene->IsFree(e, 0.5));
    double nearest = 1e30;
    for (const Rigid3d& p : input) {
      const glm::dvec3 d = e - p.translation;
      if (std::abs(d.x) <= r_h && std::abs(d.y) <= r_h && std::abs(d.z) <= 0.3)
        nearest = std::min(nearest, glm::length(d));
    }
    EXPECT_LT(nearest, 1e29) << "pose " << i << " is not near any input pose";
    EXPECT_GT(nearest, 1e-6) << "pose " << i << " is an input pose";
  }
  EXPECT_FALSE(MakeNearTestPoses(*scene, {}, cam, 3, 7, false).ok());
}

// Depth is the z-depth of the geometry: a camera 1.6 m above the apartment floor looking
// straight down sees the floor at 1.6 m in the centre.
TEST(SynthRenderTest, DepthIsGeometryZDepth) {
  auto scene = MakeApartment({});
  ASSERT_TRUE(scene.ok());
  const Rigid3d pose = LookAt({3.5, 3.0, 1.6}, {3.5, 3.0001, 0.0});
  auto f = RenderFrame(*scene, pose, Small());
  ASSERT_TRUE(f.ok()) << f.status();
  ASSERT_TRUE(f->frame.Validate().ok());
  const ImageF& d = f->frame.depth_m;
  EXPECT_NEAR(d.at(80, 60), 1.6, 2e-3);
  EXPECT_NEAR(d.at(79, 59), 1.6, 2e-3);
  for (float z : d.span()) EXPECT_GT(z, 0.0f);  // closed room: no background
}

// Mean absolute horizontal luma gradient of an RGB8 image.
double MeanGradient(const ImageU8& img) {
  double sum = 0;
  for (int y = 0; y < img.height(); ++y)
    for (int x = 1; x < img.width(); ++x)
      for (int c = 0; c < 3; ++c) sum += std::abs(int(img.at(x, y, c)) - int(img.at(x - 1, y, c)));
  return sum / (3.0 * img.height() * (img.width() - 1));
}

// High-frequency textures: frames along both walks have texture detail (flat-coloured boxes
// would give a mean gradient well below 1 level per pixel), and renders are deterministic for
// any thread count.
TEST(SynthRenderTest, TexturedAndDeterministic) {
  for (SceneKind k : {SceneKind::kVillage, SceneKind::kApartment}) {
    auto scene = MakeScene(k, {});
    TrajectoryOptions to;
    to.num_frames = 5;
    auto traj = MakeTrajectory(*scene, TrajectoryKind::kWalk, to);
    ASSERT_TRUE(traj.ok());
    RenderOptions ro;
    ro.width = 320;
    ro.height = 240;
    for (int i : {1, 3}) {
      auto f = RenderFrame(*scene, (*traj)[i].local_from_cam, ro);
      ASSERT_TRUE(f.ok());
      const double grad = MeanGradient(f->frame.color);
      EXPECT_GT(grad, 1.2) << scene->name << " frame " << i;
      std::printf("%s frame %d: mean gradient %.2f\n", scene->name.c_str(), i, grad);
      ro.num_threads = 1;
      auto g = RenderFrame(*scene, (*traj)[i].local_from_cam, ro);
      ro.num_threads = 2;
      EXPECT_EQ(f->frame.color, g->frame.color);
      EXPECT_EQ(f->frame.depth_m, g->frame.depth_m);
    }
  }
}

// Band-limiting: a fine texture (bricks) averaged over a large footprint approaches the mean of
// its fine-footprint samples (the guard fading detail below 2 px; without it a far wall would
// return single point samples that alias).
TEST(SynthRenderTest, MaterialsAreBandLimited) {
  auto scene = MakeVillage({});
  const glm::dvec3 n(0, -1, 0);
  double fine_sum = 0;
  int count = 0;
  double coarse_min = 1e9, coarse_max = -1e9;
  for (int i = 0; i < 400; ++i) {
    const glm::dvec3 p(0.3 + i * 0.0123, 0, 0.2 + i * 0.00177);  // below the windows
    fine_sum += EvalMaterial(*scene, Material::kBrick, p, n, 1e-4).albedo.x;
    ++count;
    const double c = EvalMaterial(*scene, Material::kBrick, p, n, 2.0).albedo.x;
    coarse_min = std::min(coarse_min, c);
    coarse_max = std::max(coarse_max, c);
  }
  const double fine_mean = fine_sum / count;
  EXPECT_LT(coarse_max - coarse_min, 0.06);  // 2 m footprint: no brick/mortar flicker left
  EXPECT_NEAR(0.5 * (coarse_max + coarse_min), fine_mean, 0.25 * fine_mean);
}

// SPEC §11 exposure 0.1x and 10x: exposure multiplies linear intensity before sRGB encoding.
TEST(SynthRenderTest, ExposureScalesLinearIntensity) {
  auto scene = MakeApartment({});
  const Rigid3d pose = LookAt({3.5, 3.0, 1.6}, {6.5, 2.0, 1.0});
  FrameNoise n1, n2;
  n2.exposure = 2.0;
  auto a = RenderFrame(*scene, pose, Small(), n1);
  auto b = RenderFrame(*scene, pose, Small(), n2);
  ASSERT_TRUE(a.ok() && b.ok());
  int checked = 0;
  for (size_t i = 0; i < a->frame.color.size(); ++i) {
    const uint8_t va = a->frame.color.data()[i];
    if (va < 60 || va > 160) continue;  // unsaturated at 2x, away from the quantisation floor
    const double la = Srgb8ToLinear(va), lb = Srgb8ToLinear(b->frame.color.data()[i]);
    ASSERT_NEAR(lb / la, 2.0, 0.08) << int(va);
    ++checked;
  }
  EXPECT_GT(checked, 1000);
  EXPECT_EQ(b->frame.exposure, 2.0);
  // 10x saturates most pixels, 0.1x darkens all of them; both stay valid frames.
  n2.exposure = 10;
  auto hi = RenderFrame(*scene, pose, Small(), n2);
  n2.exposure = 0.1;
  auto lo = RenderFrame(*scene, pose, Small(), n2);
  ASSERT_TRUE(hi.ok() && lo.ok());
  size_t sat = 0;
  for (size_t i = 0; i < hi->frame.color.size(); ++i) {
    sat += hi->frame.color.data()[i] == 255;
    ASSERT_LE(lo->frame.color.data()[i], a->frame.color.data()[i]);
  }
  EXPECT_GT(sat, hi->frame.color.size() / 2);
  n2.exposure = 0;
  EXPECT_FALSE(RenderFrame(*scene, pose, Small(), n2).ok());
}

// Pose noise: the frame carries a pose off by exactly the requested angle/distance, the image
// is rendered from the true pose (identical to the noise-free render).
TEST(SynthRenderTest, PoseNoiseCarriesNoisyPoseOnly) {
  auto scene = MakeVillage({});
  const Rigid3d pose = LookAt({-15, -20, 1.6}, {-15, 0, 1.0});
  FrameNoise noise;
  noise.rotation_deg = 1.5;
  noise.translation_m = 0.05;
  noise.seed = 3;
  auto clean = RenderFrame(*scene, pose, Small());
  auto noisy = RenderFrame(*scene, pose, Small(), noise);
  ASSERT_TRUE(clean.ok() && noisy.ok());
  EXPECT_EQ(clean->frame.color, noisy->frame.color);
  EXPECT_NEAR(glm::degrees(RotationAngleRad(noisy->frame.world_from_cam.rotation,
                                            noisy->true_world_from_cam.rotation)),
              1.5, 1e-6);
  EXPECT_NEAR(glm::length(noisy->frame.world_from_cam.translation -
                          noisy->true_world_from_cam.translation),
              0.05, 1e-9);
  EXPECT_EQ(clean->frame.world_from_cam.translation, clean->true_world_from_cam.translation);
}

// SPEC §11 scene 1e5 m from the origin: rendering happens in the local frame, so the image is
// bit-identical and only the world pose is offset (exactly, in double).
TEST(SynthRenderTest, LargeWorldOffsetKeepsPrecision) {
  SceneOptions far;
  far.origin_in_world = {1e5, -2e5, 30.0};
  auto s0 = MakeVillage({});
  auto s1 = MakeVillage(far);
  ASSERT_TRUE(s0.ok() && s1.ok());
  const Rigid3d pose = LookAt({-15, -20, 1.6}, {-15, 0, 1.0});
  auto a = RenderFrame(*s0, pose, Small());
  auto b = RenderFrame(*s1, pose, Small());
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->frame.color, b->frame.color);
  EXPECT_EQ(a->frame.depth_m, b->frame.depth_m);
  const glm::dvec3 d = b->frame.world_from_cam.translation - a->frame.world_from_cam.translation;
  EXPECT_EQ(d, far.origin_in_world);
}

TEST(SynthRenderTest, BadOptionsAreErrors) {
  auto scene = MakeApartment({});
  RenderOptions ro = Small();
  ro.width = 0;
  EXPECT_FALSE(RenderFrame(*scene, Rigid3d::Identity(), ro).ok());
  ro = Small();
  ro.hfov_deg = 180;
  EXPECT_FALSE(RenderFrame(*scene, Rigid3d::Identity(), ro).ok());
  TrajectoryOptions to;
  to.num_frames = 0;
  EXPECT_FALSE(MakeTrajectory(*scene, TrajectoryKind::kWalk, to).ok());
  EXPECT_FALSE(ParseSceneKind("castle").ok());
  EXPECT_FALSE(ParseTrajectoryKind("swim").ok());
}

}  // namespace
}  // namespace exo::synth
