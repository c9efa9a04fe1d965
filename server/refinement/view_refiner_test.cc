// Tests of view refinement on an analytic ray-cast room with known pose and exposure.
#include "server/refinement/view_refiner.h"

#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "server/refinement/testing/room_scene.h"

namespace exo {
namespace {

using refinement_testing::LookAt;
using refinement_testing::Perturb;
using refinement_testing::RenderRoom;
using refinement_testing::RoomScene;

struct RoomSetup {
  RoomScene scene;
  PinholeCamera cam;
  std::vector<StoredView> refs;
  Rigid3d cand_true;
  std::vector<const StoredView*> RefPtrs() const {
    std::vector<const StoredView*> p;
    for (const auto& r : refs) p.push_back(&r);
    return p;
  }
};

RoomSetup MakeSetup(int num_refs, int w = 160, int h = 120, RoomScene scene = {}) {
  RoomSetup s;
  s.scene = scene;
  s.cam = PinholeCamera::FromFov(w, h, 65.0 * M_PI / 180.0);
  const glm::dvec3 target{0.3, 0.3, 2.5};
  s.cand_true = LookAt({0.0, -0.1, -1.4}, target);
  const glm::dvec3 eyes[4] = {{-0.35, -0.2, -1.6}, {0.4, 0.0, -1.5}, {0.1, -0.35, -1.2},
                              {-0.2, 0.15, -1.8}};
  for (int i = 0; i < num_refs; ++i) {
    StoredView v = RenderRoom(s.scene, s.cam, LookAt(eyes[i], target + glm::dvec3(0.1 * i, 0, 0)), 1.0);
    v.id = i + 1;
    s.refs.push_back(std::move(v));
  }
  return s;
}

double RotErrDeg(const Rigid3d& a, const Rigid3d& b) {
  return RotationAngleRad(a.rotation, b.rotation) * 180.0 / M_PI;
}
double TransErrM(const Rigid3d& a, const Rigid3d& b) {
  return glm::length(a.translation - b.translation);
}


// Relative exposure error against the truth 1/k (candidate rendered at k x the references).
double ExposureRelErr(double e, double k) { return std::abs(e * k - 1.0); }

TEST(ViewRefinerTest, ExposureHalfToDoubleRecoveredWithin2Percent) {
  const RoomSetup s = MakeSetup(4);
  const auto refs = s.RefPtrs();
  for (double k : {0.5, 0.7, 1.0, 1.4, 2.0}) {
    StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, k, 1.0, 3);
    cand.local_from_cam = Perturb(s.cand_true, 1.0, 0.01, 5);
    auto r = RefineView(cand, refs, RefinementOptions{});
    ASSERT_TRUE(r.ok()) << r.status();
    EXPECT_LT(ExposureRelErr(r->exposure, k), 0.02) << "k=" << k << " E=" << r->exposure;
    EXPECT_FALSE(r->rejected_outlier);
  }
}

// The reference-pyramid cache changes nothing but the time: bit-identical results with and
// without it, hits on the second call, and a view whose colour changed under the same id is
// rebuilt (a stale pyramid would give a different exposure: guard = the colour fingerprint).
TEST(ViewRefinerTest, CacheGivesIdenticalResultsAndDetectsReplacedViews) {
  RoomSetup s = MakeSetup(3);
  StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 1.3, 1.0, 7);
  cand.local_from_cam = Perturb(s.cand_true, 1.0, 0.01, 8);
  RefinementCache cache;
  auto plain = RefineView(cand, s.RefPtrs(), RefinementOptions{});
  auto first = RefineView(cand, s.RefPtrs(), RefinementOptions{}, &cache);
  auto second = RefineView(cand, s.RefPtrs(), RefinementOptions{}, &cache);
  ASSERT_TRUE(plain.ok() && first.ok() && second.ok());
  EXPECT_EQ(cache.misses(), 3);
  EXPECT_EQ(cache.hits(), 3);
  for (const auto* r : {&*first, &*second}) {
    EXPECT_EQ(r->exposure, plain->exposure);
    EXPECT_EQ(r->local_from_cam.translation, plain->local_from_cam.translation);
    EXPECT_EQ(r->local_from_cam.rotation, plain->local_from_cam.rotation);
  }
  // Same ids, references re-rendered 1.5x brighter: the candidate's exposure must follow.
  for (auto& r : s.refs) {
    const ViewId id = r.id;
    r = RenderRoom(s.scene, s.cam, r.local_from_cam, 1.5);
    r.id = id;
  }
  auto brighter = RefineView(cand, s.RefPtrs(), RefinementOptions{}, &cache);
  ASSERT_TRUE(brighter.ok());
  EXPECT_EQ(cache.misses(), 6);
  EXPECT_NEAR(brighter->exposure * 1.3 / 1.5, 1.0, 0.02) << brighter->exposure;
  // Large sample blocks (max_samples 300: blocks of >= 2 cells) select samples from the cached
  // per-cell picks: identical to the uncached call. A reference whose depth changes under the
  // same id (colour unchanged) is rebuilt (the picks depend on its valid depth).
  RefinementOptions sparse;
  sparse.max_samples = 300;
  auto sparse_plain = RefineView(cand, s.RefPtrs(), sparse);
  auto sparse_cached = RefineView(cand, s.RefPtrs(), sparse, &cache);
  ASSERT_TRUE(sparse_plain.ok() && sparse_cached.ok());
  EXPECT_EQ(cache.misses(), 6);
  EXPECT_EQ(sparse_cached->exposure, sparse_plain->exposure);
  EXPECT_EQ(sparse_cached->local_from_cam.translation, sparse_plain->local_from_cam.translation);
  EXPECT_EQ(sparse_cached->num_samples, sparse_plain->num_samples);
  ImageF& d = s.refs[0].depth_m;
  for (int y = 0; y < d.height(); ++y)
    for (int x = 0; x < d.width() / 2; ++x) d.at(x, y) = 0.f;  // left half: no depth
  auto holes_plain = RefineView(cand, s.RefPtrs(), sparse);
  auto holes_cached = RefineView(cand, s.RefPtrs(), sparse, &cache);
  ASSERT_TRUE(holes_plain.ok() && holes_cached.ok());
  EXPECT_EQ(cache.misses(), 7);
  EXPECT_EQ(holes_cached->num_samples, holes_plain->num_samples);
  EXPECT_EQ(holes_cached->exposure, holes_plain->exposure);
}

// Significance gate (guard: min_pose_gain_over_disagreement): a candidate already at its
// true pose, with noisy references, gains less than the references' own disagreement from any
// pose update, so the input pose is returned bit-exact; with the gate off the pose moves
// (fails if the gate is removed). A 1 deg / 1 cm error is still corrected with the gate on.
TEST(ViewRefinerTest, InsignificantPoseUpdateKeepsTheInputPose) {
  RoomSetup s = MakeSetup(0);
  const glm::dvec3 target{0.3, 0.3, 2.5};
  const glm::dvec3 eyes[4] = {{-0.35, -0.2, -1.6}, {0.4, 0.0, -1.5}, {0.1, -0.35, -1.2},
                              {-0.2, 0.15, -1.8}};
  for (int i = 0; i < 4; ++i) {
    StoredView v = RenderRoom(s.scene, s.cam, LookAt(eyes[i], target), 1.0, 3.0, 40 + i);
    v.id = i + 1;
    s.refs.push_back(std::move(v));
  }
  StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 1.2, 3.0, 50);
  cand.local_from_cam = s.cand_true;
  RefinementOptions gate_on, gate_off;
  gate_off.min_pose_gain_over_disagreement = 0.0;
  auto on = RefineView(cand, s.RefPtrs(), gate_on);
  auto off = RefineView(cand, s.RefPtrs(), gate_off);
  ASSERT_TRUE(on.ok() && off.ok());
  EXPECT_TRUE(on->pose_update_insignificant);
  EXPECT_EQ(on->local_from_cam.translation, s.cand_true.translation);
  EXPECT_EQ(on->local_from_cam.rotation, s.cand_true.rotation);
  EXPECT_LT(ExposureRelErr(on->exposure, 1.2), 0.02);
  EXPECT_FALSE(off->pose_update_insignificant);
  EXPECT_NE(off->local_from_cam.translation, s.cand_true.translation);
  cand.local_from_cam = Perturb(s.cand_true, 1.0, 0.01, 51);
  auto moved = RefineView(cand, s.RefPtrs(), gate_on);
  ASSERT_TRUE(moved.ok());
  EXPECT_FALSE(moved->pose_update_insignificant);
  EXPECT_LT(RotErrDeg(moved->local_from_cam, s.cand_true), 0.2);
  EXPECT_LT(TransErrM(moved->local_from_cam, s.cand_true), 0.005);
}

// Exposure gate (guard: min_exposure_gain_over_disagreement): a candidate with the references'
// exposure, noisy references: the estimate differs from 1 by less than the references'
// disagreement explains, so prior_exposure (1) is returned exactly; with the gate off it is
// not (fails if the gate is removed). A real 1.2x exposure change is still estimated.
TEST(ViewRefinerTest, InsignificantExposureUpdateKeepsThePrior) {
  RoomSetup s = MakeSetup(0);
  const glm::dvec3 target{0.3, 0.3, 2.5};
  const glm::dvec3 eyes[4] = {{-0.35, -0.2, -1.6}, {0.4, 0.0, -1.5}, {0.1, -0.35, -1.2},
                              {-0.2, 0.15, -1.8}};
  for (int i = 0; i < 4; ++i) {
    StoredView v = RenderRoom(s.scene, s.cam, LookAt(eyes[i], target), 1.0, 3.0, 60 + i);
    v.id = i + 1;
    s.refs.push_back(std::move(v));
  }
  StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 1.0, 3.0, 70);
  cand.local_from_cam = Perturb(s.cand_true, 0.5, 0.005, 71);
  RefinementOptions gate_on, gate_off;  // gate_on: the default (2)
  gate_off.min_exposure_gain_over_disagreement = 0.0;
  auto on = RefineView(cand, s.RefPtrs(), gate_on);
  auto off = RefineView(cand, s.RefPtrs(), gate_off);
  ASSERT_TRUE(on.ok() && off.ok());
  EXPECT_TRUE(on->exposure_update_insignificant);
  EXPECT_EQ(on->exposure, 1.0);
  EXPECT_FALSE(off->exposure_update_insignificant);
  EXPECT_NE(off->exposure, 1.0);
  EXPECT_LT(ExposureRelErr(off->exposure, 1.0), 0.02);
  StoredView brighter = RenderRoom(s.scene, s.cam, s.cand_true, 1.2, 3.0, 72);
  brighter.local_from_cam = cand.local_from_cam;
  auto b = RefineView(brighter, s.RefPtrs(), gate_on);
  ASSERT_TRUE(b.ok());
  EXPECT_FALSE(b->exposure_update_insignificant);
  EXPECT_LT(ExposureRelErr(b->exposure, 1.2), 0.02) << b->exposure;
  RefinementOptions bad;
  bad.prior_exposure = 0.0;
  EXPECT_FALSE(bad.Validate().ok());
}

TEST(ViewRefinerTest, PoseUpTo2Deg2CmConvergesIn95PercentOfTrials) {
  const RoomSetup s = MakeSetup(4);
  const auto refs = s.RefPtrs();
  RefinementStats stats;
  int converged = 0;
  const int trials = 20;
  for (int t = 0; t < trials; ++t) {
    const double k = 0.6 + 0.05 * t;  // exposure changes too
    StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, k, 1.0, 100 + t);
    cand.local_from_cam = Perturb(s.cand_true, 2.0 * (t % 4 + 1) / 4.0, 0.02 * ((t + 2) % 4 + 1) / 4.0, t);
    auto r = RefineView(cand, refs, RefinementOptions{});
    ASSERT_TRUE(r.ok()) << r.status();
    stats.Add(*r);
    const double rot = RotErrDeg(r->local_from_cam, s.cand_true);
    const double tr = TransErrM(r->local_from_cam, s.cand_true);
    if (rot < 0.2 && tr < 0.005 && !r->rejected_outlier)
      ++converged;
    else
      std::printf("trial %d not converged: rot %.3f deg trans %.4f m refused %d outlier %d rel %.4f "
                  "reverted %d\n", t, rot, tr, r->pose_refused_rank_deficient, r->rejected_outlier,
                  r->relative_residual, r->step_reverted);
    // Guard "never accept a step that raises the cost".
    EXPECT_LE(r->cost_after, r->cost_before + 1e-12) << "trial " << t;
    EXPECT_LT(ExposureRelErr(r->exposure, k), 0.02) << "trial " << t;
  }
  EXPECT_GE(converged, 19) << "converged " << converged << " of " << trials;
  EXPECT_EQ(stats.refined, trials);
  EXPECT_EQ(stats.pose_refused, 0);
}

TEST(ViewRefinerTest, TexturelessPlaneRefusesPoseKeepsExposure) {
  // Guard: rank check of the pose block. A uniform room gives (almost) no pose information; the
  // sensor noise would let Levenberg-Marquardt wander. Without the guard the flag stays false
  // and the pose moves.
  RoomScene flat;
  flat.textureless = true;
  flat.occluder = false;
  const RoomSetup s = MakeSetup(3, 160, 120, flat);
  const auto refs = s.RefPtrs();
  StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 0.6, 1.0, 9);
  cand.local_from_cam = Perturb(s.cand_true, 1.5, 0.015, 2);
  // Photometric information only: with the depth term a uniform ROOM is not featureless (its
  // walls fix the pose geometrically; checked below), so the rank guard is tested without it.
  RefinementOptions photometric;
  photometric.depth_weight = 0.0;
  auto r = RefineView(cand, refs, photometric);
  ASSERT_TRUE(r.ok()) << r.status();
  std::printf("textureless: pose information lmin %.3g cond %.3g\n", r->pose_min_eigenvalue,
              r->pose_condition);
  EXPECT_TRUE(r->pose_refused_rank_deficient) << "lmin " << r->pose_min_eigenvalue << " cond "
                                              << r->pose_condition;
  EXPECT_EQ(r->local_from_cam.rotation, cand.local_from_cam.rotation);
  EXPECT_EQ(r->local_from_cam.translation, cand.local_from_cam.translation);
  EXPECT_LT(ExposureRelErr(r->exposure, 0.6), 0.02) << r->exposure;
  // With the depth term (default), the pose may move but must not get worse.
  auto d = RefineView(cand, refs, RefinementOptions{});
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_LE(RotErrDeg(d->local_from_cam, s.cand_true), RotErrDeg(cand.local_from_cam, s.cand_true) + 0.05);
  EXPECT_LT(ExposureRelErr(d->exposure, 0.6), 0.02) << d->exposure;
}

// Refines exposure only from E = 1 when the truth is 10 (candidate 10x darker) on a texture with
// albedo >= 0.15: every initial residual is far beyond a fixed Tukey scale of 0.05.
double ExposureFromFlatStart(bool scale_from_mad, bool warm_start) {
  RoomScene bright;
  bright.albedo_min = 0.15;
  const RoomSetup s = MakeSetup(2, 160, 120, bright);
  const auto refs = s.RefPtrs();
  StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 0.1, 0.0);
  RefinementOptions o;
  o.refine_pose = false;
  o.init_exposure_from_ratio = false;
  o.initial_exposure = 1.0;
  o.fixed_scale = 0.05;
  o.scale_from_mad = scale_from_mad;
  o.warm_start = warm_start;
  auto r = RefineView(cand, refs, o);
  EXO_CHECK(r.ok());
  return r->exposure;
}

TEST(ViewRefinerTest, AllResidualsBeyondTukeyScale) {
  // The trap itself: fixed scale, no warm start -> Tukey is flat, E does not move.
  EXPECT_LT(ExposureFromFlatStart(false, false), 1.5);
  // Guard "scale from the MAD": the scale grows with the residuals, E converges.
  EXPECT_LT(ExposureRelErr(ExposureFromFlatStart(true, false), 0.1), 0.02);
  // Guard "Cauchy warm start": Cauchy has a gradient everywhere, E converges.
  EXPECT_LT(ExposureRelErr(ExposureFromFlatStart(false, true), 0.1), 0.02);
}

TEST(ViewRefinerTest, ExposureTenthAndTenTimesAndSaturatedFrames) {
  // Guard: saturated (>= 250) and black (<= 5) pixels are excluded. At 10x most of the candidate
  // clips to 255; counting those pixels biases E towards the clip level.
  RoomScene dark;  // darker texture so that part of it stays below the clip level at 10x
  dark.albedo_min = 0.005;
  dark.albedo_max = 0.3;
  const RoomSetup s = MakeSetup(4, 160, 120, dark);
  const auto refs = s.RefPtrs();
  for (double k : {0.1, 10.0}) {
    StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, k, 1.0, 4);
    cand.local_from_cam = Perturb(s.cand_true, 1.0, 0.01, 8);
    auto r = RefineView(cand, refs, RefinementOptions{});
    ASSERT_TRUE(r.ok()) << r.status();
    EXPECT_LT(ExposureRelErr(r->exposure, k), 0.02)
        << "k=" << k << " E=" << r->exposure << " rot " << RotErrDeg(r->local_from_cam, s.cand_true)
        << " refused " << r->pose_refused_rank_deficient << " reverted " << r->step_reverted
        << " n " << r->num_samples << " valid " << r->num_valid_final << " lmin "
        << r->pose_min_eigenvalue << " cond " << r->pose_condition;
    EXPECT_LE(RotErrDeg(r->local_from_cam, s.cand_true), 1.0 + 1e-9) << "k=" << k;
  }
  // Demonstrates the trap: with the guard disabled the 10x estimate is far off.
  StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 10.0, 1.0, 4);
  RefinementOptions off;
  off.saturated_u8 = 256;
  off.refine_pose = false;
  auto r = RefineView(cand, refs, off);
  ASSERT_TRUE(r.ok());
  EXPECT_GT(ExposureRelErr(r->exposure, 10.0), 0.1) << r->exposure;
}

TEST(ViewRefinerTest, OneReferenceView) {
  const RoomSetup s = MakeSetup(1);
  const auto refs = s.RefPtrs();
  for (int t = 0; t < 3; ++t) {
    StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 1.3, 1.0, t);
    cand.local_from_cam = Perturb(s.cand_true, 2.0, 0.02, 40 + t);
    auto r = RefineView(cand, refs, RefinementOptions{});
    ASSERT_TRUE(r.ok()) << r.status();
    EXPECT_LT(ExposureRelErr(r->exposure, 1.3), 0.02);
    EXPECT_LT(RotErrDeg(r->local_from_cam, s.cand_true), 0.2) << t;
    EXPECT_LT(TransErrM(r->local_from_cam, s.cand_true), 0.005) << t;
  }
}

TEST(ViewRefinerTest, TwoReferenceViewsUseTheMeanAsMedian) {
  // Guard: the median of two values is their mean. The two references disagree (rendered at 1.0
  // and 1.2, both stored with E = 1), so the candidate's E must be 1.1 / k; taking either
  // middle element instead gives 1.0 / k or 1.2 / k (9 % off).
  RoomSetup s = MakeSetup(2);
  s.refs[1] = RenderRoom(s.scene, s.cam, s.refs[1].local_from_cam, 1.2);
  const auto refs = s.RefPtrs();
  StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 0.8, 0.0);
  RefinementOptions o;
  o.refine_pose = false;
  auto r = RefineView(cand, refs, o);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NEAR(r->exposure, 1.1 / 0.8, 0.02 * 1.1 / 0.8);
  // And with pose noise, two consistent references still converge.
  const RoomSetup s2 = MakeSetup(2);
  StoredView cand2 = RenderRoom(s2.scene, s2.cam, s2.cand_true, 0.8, 1.0, 2);
  cand2.local_from_cam = Perturb(s2.cand_true, 2.0, 0.02, 77);
  auto r2 = RefineView(cand2, s2.RefPtrs(), RefinementOptions{});
  ASSERT_TRUE(r2.ok());
  EXPECT_LT(RotErrDeg(r2->local_from_cam, s2.cand_true), 0.2);
  EXPECT_LT(TransErrM(r2->local_from_cam, s2.cand_true), 0.005);
}

TEST(ViewRefinerTest, GaugeFixedStoredExposureIsRespected) {
  // References rendered at 0.5 but stored with E = 2: their corrected intensities are the
  // albedo, so a candidate rendered at 1 needs E = 1.
  RoomSetup s = MakeSetup(3);
  for (auto& v : s.refs) {
    v = RenderRoom(s.scene, s.cam, v.local_from_cam, 0.5);
    v.exposure = 2.0f;
  }
  StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 1.0, 1.0, 1);
  auto r = RefineView(cand, s.RefPtrs(), RefinementOptions{});
  ASSERT_TRUE(r.ok());
  EXPECT_LT(ExposureRelErr(r->exposure, 1.0), 0.02) << r->exposure;
  for (const auto& v : s.refs) EXPECT_EQ(v.exposure, 2.0f);
}

TEST(ViewRefinerTest, PoseOutlierIsRejectedAndCounted) {
  // Guard: final residual threshold. A 25 degree / 30 cm pose error is outside the convergence
  // basin (12 degrees used to be; the decoupled chart, the depth term and the Cauchy coarse
  // levels now converge from there).
  const RoomSetup s = MakeSetup(4);
  const auto refs = s.RefPtrs();
  RefinementStats stats;
  StoredView bad = RenderRoom(s.scene, s.cam, s.cand_true, 1.0, 1.0, 1);
  bad.local_from_cam = Perturb(s.cand_true, 25.0, 0.30, 3);
  auto r = RefineView(bad, refs, RefinementOptions{});
  ASSERT_TRUE(r.ok()) << r.status();
  stats.Add(*r);
  EXPECT_TRUE(r->rejected_outlier) << "relative residual " << r->relative_residual;
  EXPECT_LE(r->cost_after, r->cost_before + 1e-12);
  StoredView good = RenderRoom(s.scene, s.cam, s.cand_true, 1.0, 1.0, 2);
  auto g = RefineView(good, refs, RefinementOptions{});
  ASSERT_TRUE(g.ok());
  stats.Add(*g);
  EXPECT_FALSE(g->rejected_outlier) << "relative residual " << g->relative_residual;
  EXPECT_EQ(stats.refined, 2);
  EXPECT_EQ(stats.rejected_outlier, 1);
}

TEST(ViewRefinerTest, BadInputsGiveClearErrors) {
  const RoomSetup s = MakeSetup(1, 64, 48);
  StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 1.0);
  RefinementOptions o;
  EXPECT_EQ(RefineView(cand, {}, o).status().code(), absl::StatusCode::kInvalidArgument);
  o.max_samples = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.pyramid_levels = 0;
  EXPECT_FALSE(o.Validate().ok());
  EXPECT_TRUE(RefinementOptions{}.Validate().ok());
  StoredView nan_pose = cand;
  nan_pose.local_from_cam.rotation.w = std::nan("");
  const auto refs = s.RefPtrs();
  EXPECT_FALSE(RefineView(nan_pose, refs, RefinementOptions{}).ok());
  StoredView bad_size = cand;
  bad_size.depth_m = ImageF(10, 10);
  EXPECT_FALSE(RefineView(bad_size, refs, RefinementOptions{}).ok());
  // No overlap: the candidate looks the other way.
  StoredView away = cand;
  away.local_from_cam = LookAt({0, 0, -1.4}, {0, 0, -2.5});
  auto r = RefineView(away, refs, RefinementOptions{});
  EXPECT_EQ(r.status().code(), absl::StatusCode::kFailedPrecondition) << r.status();
}

}  // namespace
}  // namespace exo

namespace exo {
namespace {

TEST(ViewRefinerTest, LargePoseErrorsNeverRaiseTheCost) {
  // Guard "never accept a step that raises the cost": perturbations of 4-8 degrees / 5-15 cm
  // leave the convergence basin, and stages (mostly at a finer level after a coarse one moved
  // the samples) raise their energy; the guard undoes them. Without the guard the accepted-stage
  // check below fails (measured: stages raising J were kept in 11 of 12 trials).
  const RoomSetup s = MakeSetup(4);
  const auto refs = s.RefPtrs();
  int reverted = 0, undone_stages = 0;
  for (int t = 0; t < 12; ++t) {
    StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 0.9, 1.0, 300 + t);
    cand.local_from_cam = Perturb(s.cand_true, 4.0 + 0.35 * t, 0.05 + 0.01 * t, 500 + t);
    auto r = RefineView(cand, refs, RefinementOptions{});
    ASSERT_TRUE(r.ok()) << r.status();
    EXPECT_LE(r->cost_after, r->cost_before + 1e-12) << "trial " << t;
    for (const RefinementStage& st : r->stages) {
      // Every stage that was kept lowered (or kept) its energy.
      if (st.accepted) {
        EXPECT_LE(st.after, st.before) << "trial " << t << " level " << st.level;
      }
      undone_stages += !st.accepted;
    }
    reverted += r->step_reverted;
  }
  // The scenario does exercise the guard: some stages raised their energy and were undone.
  EXPECT_GT(undone_stages, 0);
  std::printf("large errors: %d of 12 calls reverted a stage (%d stages undone)\n", reverted,
              undone_stages);
}

}  // namespace
}  // namespace exo
