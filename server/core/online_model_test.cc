#include "server/core/online_model.h"

#include <gtest/gtest.h>

#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace exo::core {
namespace {

// 24 frames of the synthetic apartment walk at 160x120 (world poses: the scene's origin added).
std::vector<Frame> ApartmentFrames(int n = 24) {
  auto scene = synth::MakeScene(synth::SceneKind::kApartment, {});
  EXPECT_TRUE(scene.ok());
  synth::TrajectoryOptions to;
  to.num_frames = n;
  auto traj = synth::MakeTrajectory(*scene, synth::TrajectoryKind::kWalk, to);
  EXPECT_TRUE(traj.ok());
  synth::RenderOptions ro;
  ro.width = 160;
  ro.height = 120;
  std::vector<Frame> frames;
  for (int i = 0; i < n; ++i) {
    auto f =
        synth::RenderFrame(*scene, (*traj)[i].local_from_cam, ro, {}, i, (*traj)[i].timestamp_s);
    EXPECT_TRUE(f.ok());
    frames.push_back(std::move(f->frame));
  }
  return frames;
}

OnlineModelOptions SmallOptions() {
  OnlineModelOptions o;
  o.max_views = 6;
  o.max_depth_m = 8.0;
  o.voxel_m = 0.08;  // fast: the tests check equality, not quality
  return o;
}

TEST(OnlineModelOptions, ValidateNamesTheBadOption) {
  OnlineModelOptions o;
  EXPECT_TRUE(o.IsValid());
  o.voxel_m = -1;
  EXPECT_FALSE(o.IsValid());
  o = {};
  o.fuse_depth_downscale = 0;
  EXPECT_NE(o.Validate().message().find("fuse_depth_downscale"), std::string::npos);
  o = {};
  o.lambda = 2;
  EXPECT_NE(o.Validate().message().find("lambda"), std::string::npos);
}

TEST(ChooseSceneSetup, OriginIsFirstCameraAndScalesFollowTheRule) {
  const auto frames = ApartmentFrames(2);
  OnlineModelOptions o = SmallOptions();
  auto s = ChooseSceneSetup(frames[0], o);
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_EQ(s->origin.origin_in_world, frames[0].world_from_cam.translation);
  EXPECT_GT(s->diameter_m, 1.0);
  o.voxel_m = 0;
  s = ChooseSceneSetup(frames[0], o);
  EXPECT_DOUBLE_EQ(s->voxel_m, std::clamp(s->diameter_m / 600.0, 0.02, 0.15));
  EXPECT_GE(s->cell_m, 0.3);
  EXPECT_LE(s->cell_m, 1.0);
  EXPECT_GT(s->view_depth_m, 0.0);
  o.voxel_m = 0.05;
  o.cell_m = 0.7;
  o.d_max_m = 3;
  auto e = ChooseSceneSetup(frames[0], o, LocalOrigin{{1, 2, 3}});
  ASSERT_TRUE(e.ok());
  EXPECT_EQ(e->voxel_m, 0.05);
  EXPECT_EQ(e->cell_m, 0.7);
  EXPECT_EQ(e->d_max_m, 3.0);
  EXPECT_EQ(e->origin.origin_in_world, glm::dvec3(1, 2, 3));
}

// The server runs the two halves on two threads: geometry ahead, the planner applying exactly the
// updates of frames <= the frame it plans. That must equal the one-thread Step, view for view.
TEST(OnlineModel, SplitHalvesEqualStepAndRunsRepeatExactly) {
  const auto frames = ApartmentFrames();
  const OnlineModelOptions o = SmallOptions();
  auto setup = ChooseSceneSetup(frames[0], o);
  ASSERT_TRUE(setup.ok());
  auto a = OnlineModel::Create(o, *setup);
  auto b = OnlineModel::Create(o, *setup);
  ASSERT_TRUE(a.ok() && b.ok());
  std::vector<ViewId> accepted;
  size_t removed = 0;
  for (const Frame& f : frames) {
    auto h = (*a)->Step(f);
    ASSERT_TRUE(h.ok()) << h.status();
    if (h->accepted) accepted.push_back(h->id);
    removed += h->removed.size();
    ASSERT_TRUE((*b)->Step(f).ok());
  }
  EXPECT_GT(accepted.size(), 6u);  // more accepted than the store holds:
  EXPECT_GT(removed, 0u);          // victims left the store
  EXPECT_EQ((*a)->planner().planner().num_views(), 6u);
  EXPECT_EQ((*a)->Digest(), (*b)->Digest());

  auto geo = OnlineGeometry::Create(o, *setup);
  auto plan = OnlinePlanner::Create(o, *setup);
  ASSERT_TRUE(geo.ok() && plan.ok());
  std::vector<GeometryUpdate> updates;
  for (const Frame& f : frames) {
    auto u = (*geo)->Integrate(f);
    ASSERT_TRUE(u.ok());
    updates.push_back(*std::move(u));
  }
  for (size_t i = 0; i < frames.size(); ++i) {
    ASSERT_TRUE((*plan)->Apply(updates[i]).ok());
    ASSERT_TRUE((*plan)->Plan(PlanFrame::Of(frames[i], setup->origin)).ok());
  }
  EXPECT_EQ((*plan)->planner().ViewIds(), (*a)->planner().planner().ViewIds());
  EXPECT_EQ((*plan)->Digest(), (*a)->planner().Digest());
  EXPECT_EQ((*geo)->Digest(), (*a)->geometry().Digest());
  EXPECT_EQ(ModelDigest((*geo)->Digest(), (*plan)->Digest()), (*a)->Digest());
  EXPECT_EQ(DigestHex((*a)->Digest()).size(), 12u);
}

TEST(OnlineModel, ViewIdsCountEveryPlannedFrameAndRemoveRefillsRefs) {
  const auto frames = ApartmentFrames(10);
  OnlineModelOptions o = SmallOptions();
  auto setup = ChooseSceneSetup(frames[0], o);
  auto m = OnlineModel::Create(o, *setup);
  ASSERT_TRUE(m.ok());
  Frame no_depth = frames[1];
  no_depth.depth_m = ImageF();
  auto h0 = (*m)->Step(frames[0]);
  ASSERT_TRUE(h0.ok());
  EXPECT_TRUE(h0->accepted);
  EXPECT_EQ(h0->id, 1u);
  EXPECT_FALSE(h0->cell_refs.empty());
  // A frame without depth (and no proxy cell ids) is no candidate but still takes its number.
  auto h1 = (*m)->planner().Plan(PlanFrame::Of(no_depth, setup->origin));
  ASSERT_TRUE(h1.ok());
  EXPECT_FALSE(h1->candidate);
  EXPECT_EQ(h1->id, 2u);
  auto h2 = (*m)->Step(frames[2]);
  ASSERT_TRUE(h2.ok());
  EXPECT_EQ(h2->id, 3u);
  // Removing the first view: its cells' R(b_k) no longer name it, the digest changes.
  const uint64_t before = (*m)->planner().Digest();
  auto changed = (*m)->planner().Remove(1);
  ASSERT_TRUE(changed.ok());
  EXPECT_FALSE(changed->empty());
  for (const auto& [cell, refs] : *changed)
    EXPECT_EQ(std::count(refs.begin(), refs.end(), ViewId{1}), 0);
  EXPECT_NE((*m)->planner().Digest(), before);
  EXPECT_FALSE((*m)->planner().Remove(1).ok());
}

TEST(OnlineModel, GovernorSkipsCandidatesWhenFull) {
  const auto frames = ApartmentFrames(12);
  OnlineModelOptions o = SmallOptions();
  o.max_views = 1;
  o.max_candidates_per_s_when_full = 0.001;  // one candidate per 1000 s once full
  auto setup = ChooseSceneSetup(frames[0], o);
  auto m = OnlineModel::Create(o, *setup);
  ASSERT_TRUE(m.ok());
  for (const Frame& f : frames) ASSERT_TRUE((*m)->Step(f).ok());
  EXPECT_EQ((*m)->planner().counters().frames, 12u);
  EXPECT_GE((*m)->planner().counters().governed, 9u);
}

TEST(RegisterDepthToColor, IdentityKeepsDepthAndAShiftMovesIt) {
  Frame f = ApartmentFrames(1)[0];
  const ImageF same = RegisterDepthToColor(f);
  EXPECT_EQ(same.width(), f.depth_m.width());
  EXPECT_EQ(same.at(80, 60), f.depth_m.at(80, 60));
  f.color_from_depth.translation = {0.05, 0, 0};
  const ImageF moved = RegisterDepthToColor(f);
  int differ = 0;
  for (int y = 0; y < moved.height(); ++y)
    for (int x = 0; x < moved.width(); ++x) differ += moved.at(x, y) != f.depth_m.at(x, y);
  EXPECT_GT(differ, 100);
  const StoredView v = StoredViewOf(f, 7, LocalOrigin{});
  EXPECT_EQ(v.id, 7u);
  EXPECT_EQ(v.depth_m.at(10, 10), moved.at(10, 10));
}

// The checkpoint of a restarted server (issue 20): geometry and planner saved after 12 frames
// and loaded into new ones continue exactly as the ones that were never stopped (same hand-off
// for every later frame, same digests); a truncated or corrupt state is an error, never a crash.
TEST(OnlineModelState, SavedAndLoadedHalvesContinueExactlyAsUninterrupted) {
  const auto frames = ApartmentFrames(24);
  const OnlineModelOptions o = SmallOptions();
  auto setup = ChooseSceneSetup(frames[0], o);
  ASSERT_TRUE(setup.ok()) << setup.status();
  auto g = OnlineGeometry::Create(o, *setup);
  auto p = OnlinePlanner::Create(o, *setup);
  ASSERT_TRUE(g.ok() && p.ok());
  auto step = [&](OnlineGeometry& geo, OnlinePlanner& plan, const Frame& f) {
    auto u = geo.Integrate(f);
    EXPECT_TRUE(u.ok()) << u.status();
    EXPECT_TRUE(plan.Apply(*u).ok());
    auto h = plan.Plan(PlanFrame::Of(f, setup->origin));
    EXPECT_TRUE(h.ok()) << h.status();
    return *h;
  };
  for (int i = 0; i < 12; ++i) step(**g, **p, frames[i]);
  StateWriter gw, pw;
  (*g)->SaveState(&gw);
  ASSERT_TRUE((*p)->SaveState(&pw).ok());
  auto g2 = OnlineGeometry::Create(o, *setup);
  auto p2 = OnlinePlanner::Create(o, *setup);
  ASSERT_TRUE(g2.ok() && p2.ok());
  StateReader gr(gw.str()), pr(pw.str());
  ASSERT_TRUE((*g2)->LoadState(&gr).ok());
  ASSERT_TRUE((*p2)->LoadState(&pr).ok());
  EXPECT_TRUE(gr.done() && pr.done());
  EXPECT_EQ((*g2)->Digest(), (*g)->Digest());
  EXPECT_EQ((*p2)->Digest(), (*p)->Digest());
  int accepted = 0;
  for (int i = 12; i < 24; ++i) {
    const HandOff a = step(**g, **p, frames[i]);
    const HandOff b = step(**g2, **p2, frames[i]);
    EXPECT_EQ(a.accepted, b.accepted) << "frame " << i;
    EXPECT_EQ(a.id, b.id) << "frame " << i;
    EXPECT_EQ(a.removed, b.removed) << "frame " << i;
    EXPECT_EQ(a.tau_sum, b.tau_sum) << "frame " << i;
    accepted += a.accepted;
  }
  EXPECT_GT(accepted, 0) << "no frame after the restart changed the store: nothing compared";
  EXPECT_EQ((*g2)->Digest(), (*g)->Digest());
  EXPECT_EQ((*p2)->Digest(), (*p)->Digest());
  EXPECT_EQ((*g2)->volume().ExtractAll().positions, (*g)->volume().ExtractAll().positions);

  // Every truncation of the states, and a flipped count, is refused with an error.
  for (const std::string* state : {&gw.str(), &pw.str()})
    for (size_t n = 0; n < state->size(); n += 1 + state->size() / 97) {
      StateReader r(std::string_view(*state).substr(0, n));
      auto g3 = OnlineGeometry::Create(o, *setup);
      auto p3 = OnlinePlanner::Create(o, *setup);
      const absl::Status s = state == &gw.str() ? (*g3)->LoadState(&r) : (*p3)->LoadState(&r);
      EXPECT_FALSE(s.ok() && r.done()) << "a state cut at " << n << " bytes was accepted";
    }
  std::string bad = pw.str();
  for (size_t i = 32; i < 40; ++i) bad[i] = '\xff';  // the number of views
  StateReader r(bad);
  auto p4 = OnlinePlanner::Create(o, *setup);
  EXPECT_FALSE((*p4)->LoadState(&r).ok());
}

}  // namespace
}  // namespace exo::core
