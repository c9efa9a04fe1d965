// Accuracy tests of view refinement on the synthetic apartment (common/synth) with known truth:
// exposure 0.5x-2x within 2 %, and seeded pose perturbations up to 2 degrees / 2 cm converging
// to < 0.2 degrees and < 5 mm. 320x240 to stay fast; references are rendered at their true
// poses with known exposures (the stored views), the candidate at its true pose and then given
// a perturbed pose.
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/refinement/testing/room_scene.h"
#include "server/refinement/view_refiner.h"

namespace exo {
namespace {

using refinement_testing::Perturb;

struct SynthSetup {
  std::vector<StoredView> refs;
  StoredView cand;  // true pose, exposure k_cand
  Rigid3d cand_true;
  std::vector<const StoredView*> RefPtrs() const {
    std::vector<const StoredView*> p;
    for (const auto& r : refs) p.push_back(&r);
    return p;
  }
};

StoredView Render(const synth::SynthScene& scene, const Rigid3d& pose, double k, uint64_t id) {
  synth::RenderOptions ro;
  ro.width = 320;
  ro.height = 240;
  synth::FrameNoise fn;
  fn.exposure = k;
  fn.seed = id;
  auto rf = synth::RenderFrame(scene, pose, ro, fn, id);
  EXPECT_TRUE(rf.ok()) << rf.status();
  StoredView v;
  v.id = id;
  v.camera = rf->frame.color_camera;
  v.local_from_cam = rf->true_world_from_cam;
  v.color = std::move(rf->frame.color);
  v.depth_m = std::move(rf->frame.depth_m);
  v.exposure = static_cast<float>(1.0 / k);  // what refinement would have stored
  return v;
}

// Apartment walk, candidate frame 48 of 120 (a view with depth variation), references the
// stored views 3 and 6 frames either side with exposures 0.7x..1.4x.
const SynthSetup& Apartment() {
  static const SynthSetup* setup = [] {
    auto* s = new SynthSetup;
    synth::SceneOptions so;
    so.seed = 1;
    auto scene = synth::MakeScene(synth::SceneKind::kApartment, so);
    EXPECT_TRUE(scene.ok()) << scene.status();
    synth::TrajectoryOptions to;
    to.num_frames = 120;
    auto traj = synth::MakeTrajectory(*scene, synth::TrajectoryKind::kWalk, to);
    EXPECT_TRUE(traj.ok()) << traj.status();
    const int kCand = 48;
    const int offsets[4] = {-6, -3, 3, 6};
    const double ks[4] = {0.7, 1.25, 0.85, 1.4};
    for (int i = 0; i < 4; ++i)
      s->refs.push_back(Render(*scene, (*traj)[kCand + offsets[i]].local_from_cam, ks[i], i + 1));
    s->cand_true = (*traj)[kCand].local_from_cam;
    s->cand = Render(*scene, s->cand_true, 1.0, 10);
    return s;
  }();
  return *setup;
}

double RotErrDeg(const Rigid3d& a, const Rigid3d& b) {
  return RotationAngleRad(a.rotation, b.rotation) * 180.0 / M_PI;
}
double TransErrMm(const Rigid3d& a, const Rigid3d& b) {
  return 1000.0 * glm::length(a.translation - b.translation);
}

TEST(SynthSceneRefinementTest, ApartmentExposureHalfToDoubleWithin2Percent) {
  const SynthSetup& s = Apartment();
  synth::SceneOptions so;
  so.seed = 1;
  auto scene = synth::MakeScene(synth::SceneKind::kApartment, so);
  ASSERT_TRUE(scene.ok());
  for (double k : {0.5, 0.7, 1.4, 2.0}) {
    StoredView cand = Render(*scene, s.cand_true, k, 20);
    auto r = RefineView(cand, s.RefPtrs(), RefinementOptions{});
    ASSERT_TRUE(r.ok()) << r.status();
    EXPECT_LT(std::abs(r->exposure * k - 1.0), 0.02) << "k " << k << " E " << r->exposure;
  }
}

TEST(SynthSceneRefinementTest, ApartmentPoseUpTo2Deg2CmConvergesIn95PercentOfTrials) {
  const SynthSetup& s = Apartment();
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> rot(0.5, 2.0), tr(0.005, 0.02);
  int converged = 0;
  const int kTrials = 20;
  for (int t = 0; t < kTrials; ++t) {
    StoredView cand = s.cand;
    const double rd = rot(rng), tm = tr(rng);
    cand.local_from_cam = Perturb(s.cand_true, rd, tm, 100 + t);
    auto r = RefineView(cand, s.RefPtrs(), RefinementOptions{});
    ASSERT_TRUE(r.ok()) << r.status();
    const double er = RotErrDeg(r->local_from_cam, s.cand_true);
    const double et = TransErrMm(r->local_from_cam, s.cand_true);
    const bool ok = er < 0.2 && et < 5.0;
    converged += ok;
    if (!ok)
      std::printf("trial %d (%.2f deg, %.1f mm): %.3f deg %.2f mm free %d rel %.3f outlier %d\n", t,
                  rd, 1000 * tm, er, et, r->pose_free_directions, r->relative_residual,
                  r->rejected_outlier);
    EXPECT_LE(r->cost_after, r->cost_before + 1e-12);
    EXPECT_LT(std::abs(r->exposure - 1.0), 0.02);
  }
  EXPECT_GE(converged, 19) << converged << " of " << kTrials;
}

}  // namespace
}  // namespace exo
