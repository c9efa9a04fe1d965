// dr_compositor.h (issue 18, session 11): the per-frame diminished-reality orchestration as a
// library class. A textured wall with a box 0.7 m in front of it, a sideways walk past the box
// (the wall behind it is seen from the other side of the walk), the ground truth rendered
// without the box: the output is far closer to the truth than the input, later keyframes take
// observed colour (fewer hallucinated pixels), the asynchronous split (Decide / MakeJob /
// ComputeKeyframe on another thread / AddKeyframe) gives the same keyframes as the synchronous
// ProcessFrame, and bad input / bounds.
#include "server/inpainting/dr_compositor.h"

#include <cmath>
#include <thread>

#include <gtest/gtest.h>

#include "server/inpainting/test_scenes.h"

namespace exo::inpainting {
namespace {

using testing::RenderPlanes;
using testing::WorldPlane;

std::vector<WorldPlane> Wall() { return {{glm::dvec3(0, 0, -1), -2.0, nullptr}}; }
std::vector<WorldPlane> WallAndBox() {
  auto p = Wall();
  p.push_back({glm::dvec3(0, 0, -1), -1.3, [](const glm::dvec3& x) {
                 return std::fabs(x.x) < 0.15 && std::fabs(x.y) < 0.15;
               }});
  return p;
}

struct Walk {
  std::vector<RgbdKeyframe> frames, truth;
  std::vector<ImageU8> rois;
};

// Camera at x in [-0.4, 0.4] (n frames), looking +z; ROI = the box's pixels dilated 2 px.
Walk MakeWalk(int n) {
  const PinholeCamera cam = testing::SmallCamera(96, 72);
  Walk w;
  for (int i = 0; i < n; ++i) {
    Rigid3d pose = Rigid3d::Identity();
    pose.translation = {-0.4 + 0.8 * i / (n - 1), 0.0, 0.0};
    w.frames.push_back(RenderPlanes(WallAndBox(), cam, pose));
    w.truth.push_back(RenderPlanes(Wall(), cam, pose));
    ImageU8 box(cam.width, cam.height, 1, 0), roi(cam.width, cam.height, 1, 0);
    for (size_t k = 0; k < box.size(); ++k)
      box.data()[k] = w.frames.back().depth_m.data()[k] + 1e-4f < w.truth.back().depth_m.data()[k];
    for (int y = 0; y < cam.height; ++y)
      for (int x = 0; x < cam.width; ++x)
        for (int dy = -2; dy <= 2; ++dy)
          for (int dx = -2; dx <= 2; ++dx)
            if (box.Contains(x + dx, y + dy) && box.at(x + dx, y + dy)) roi.at(x, y) = 255;
    w.rois.push_back(roi);
  }
  return w;
}

double RoiMeanAbs(const ImageU8& a, const ImageU8& b, const ImageU8& roi) {
  double s = 0;
  long n = 0;
  for (size_t i = 0; i < roi.size(); ++i)
    if (roi.data()[i])
      for (int c = 0; c < 3; ++c) {
        s += std::abs(int(a.data()[3 * i + c]) - int(b.data()[3 * i + c]));
        ++n;
      }
  return n ? s / n : 0.0;
}

int Count(const ImageU8& m) {
  int n = 0;
  for (size_t i = 0; i < m.size(); ++i) n += m.data()[i] != 0;
  return n;
}

DrOptions Options() {
  DrOptions o;
  o.obs_stride = 2;
  o.policy.max_unlabelled_fraction = 0.05;
  return o;
}

TEST(DiminishedReality, RemovesTheBoxAndPrefersObservations) {
  const Walk w = MakeWalk(21);
  DiminishedReality dr(Options());
  ASSERT_TRUE(dr.options().Validate().ok());
  double err_in = 0, err_out = 0;
  long observed = 0, between = 0;
  int keyframes = 0;
  for (size_t t = 0; t < w.frames.size(); ++t) {
    auto r = dr.ProcessFrame(w.frames[t], w.rois[t], static_cast<int64_t>(t));
    ASSERT_TRUE(r.ok()) << r.status();
    ASSERT_GT(r->roi_px, 0);
    EXPECT_EQ(r->roi_px, Count(w.rois[t]));
    keyframes += r->keyframe;
    if (!r->keyframe) {
      observed += r->observed_px;
      between += r->roi_px;
    }
    err_in += RoiMeanAbs(w.frames[t].color, w.truth[t].color, w.rois[t]);
    err_out += RoiMeanAbs(r->color, w.truth[t].color, w.rois[t]);
    // Outside the ROI the frame is untouched, colour and depth.
    for (size_t i = 0; i < w.rois[t].size(); ++i)
      if (!w.rois[t].data()[i]) {
        ASSERT_EQ(r->depth.data()[i], w.frames[t].depth_m.data()[i]);
        ASSERT_EQ(r->color.data()[3 * i], w.frames[t].color.data()[3 * i]);
      }
  }
  err_in /= w.frames.size();
  err_out /= w.frames.size();
  std::printf("ROI mean |error|: input %.1f, output %.1f; keyframes %d (%d inpainted, %d "
              "propagated); observed share between keyframes %.2f\n",
              err_in, err_out, keyframes, dr.stats().keyframes_inpainted,
              dr.stats().keyframes_propagated, between ? double(observed) / between : 0.0);
  EXPECT_LT(err_out, 0.4 * err_in);
  ASSERT_GE(keyframes, 2);
  EXPECT_EQ(static_cast<int>(dr.keyframes().size()), keyframes);
  EXPECT_GE(dr.stats().keyframes_propagated, 1);
  // The first keyframe is inpainted whole; a later one takes what earlier views observed.
  EXPECT_EQ(Count(dr.keyframes().front()->hallucinated), Count(dr.keyframes().front()->roi));
  const auto& last = dr.keyframes().back();
  EXPECT_LT(Count(last->hallucinated), Count(last->roi) * 3 / 4);
  EXPECT_GT(observed, between / 4);
  EXPECT_LE(dr.observations(), static_cast<size_t>(dr.options().obs_views));
}

TEST(DiminishedReality, AsynchronousKeyframesEqualSynchronous) {
  const Walk w = MakeWalk(13);
  DiminishedReality sync(Options()), async(Options());
  for (size_t t = 0; t < w.frames.size(); ++t) {
    ASSERT_TRUE(sync.ProcessFrame(w.frames[t], w.rois[t], static_cast<int64_t>(t)).ok());
    const KeyframeDecision d =
        async.Decide(w.rois[t], w.frames[t].camera, w.frames[t].world_from_cam);
    if (d.insert) {
      const DrKeyframeJob job = async.MakeJob(w.frames[t], w.rois[t], d);
      absl::StatusOr<DrKeyframe> k = absl::UnknownError("not run");
      std::thread worker([&] { k = DiminishedReality::ComputeKeyframe(job, async.options()); });
      worker.join();
      ASSERT_TRUE(k.ok()) << k.status();
      async.AddKeyframe(k->view, &*k);
    }
    async.AddObservation(w.frames[t], w.rois[t], static_cast<int64_t>(t));
  }
  ASSERT_EQ(async.keyframes().size(), sync.keyframes().size());
  ASSERT_GE(sync.keyframes().size(), 2u);
  for (size_t i = 0; i < sync.keyframes().size(); ++i) {
    EXPECT_TRUE(async.keyframes()[i]->color == sync.keyframes()[i]->color) << i;
    EXPECT_TRUE(async.keyframes()[i]->hallucinated == sync.keyframes()[i]->hallucinated) << i;
  }
  EXPECT_EQ(async.stats().keyframes_propagated, sync.stats().keyframes_propagated);
}

TEST(DiminishedReality, LaterObservationsReplaceAKeyframesHoles) {
  // The first keyframe (x = -0.4) is inpainted whole; the walk to x = 0.4 sees the wall that the
  // box hides from there.
  const Walk w = MakeWalk(21);
  DiminishedReality dr(Options());
  for (size_t t = 0; t < w.frames.size(); ++t)
    ASSERT_TRUE(dr.ProcessFrame(w.frames[t], w.rois[t], static_cast<int64_t>(t)).ok());
  const std::shared_ptr<const DrView> first = dr.keyframes().front();
  ASSERT_EQ(first->world_from_cam.translation, w.frames[0].world_from_cam.translation);
  const auto r = DiminishedReality::RefreshKeyframe(*first, dr.ViewsAround(*first));
  ASSERT_NE(r.view, nullptr);
  EXPECT_EQ(r.hallucinated_before, Count(first->roi));
  EXPECT_GT(r.replaced, r.hallucinated_before / 2);
  EXPECT_EQ(Count(r.view->hallucinated), r.hallucinated_before - r.replaced);
  const double before = RoiMeanAbs(first->color, w.truth[0].color, first->roi);
  const double after = RoiMeanAbs(r.view->color, w.truth[0].color, first->roi);
  std::printf("first keyframe: %d of %d hallucinated pixels replaced by observations; ROI mean "
              "|error| %.1f -> %.1f\n", r.replaced, r.hallucinated_before, before, after);
  EXPECT_LT(after, 0.6 * before);
  // Outside what was hallucinated nothing changes.
  for (size_t i = 0; i < first->roi.size(); ++i)
    if (!first->hallucinated.data()[i])
      ASSERT_EQ(r.view->color.data()[3 * i], first->color.data()[3 * i]);
  ASSERT_TRUE(dr.ReplaceKeyframe(first.get(), r.view));
  EXPECT_EQ(dr.keyframes().front(), r.view);
  EXPECT_FALSE(dr.ReplaceKeyframe(first.get(), r.view));  // no longer a keyframe
  // Refreshing again finds (almost) nothing new; no views: nothing.
  const auto again = DiminishedReality::RefreshKeyframe(*r.view, dr.ViewsAround(*r.view));
  EXPECT_LT(again.replaced, r.replaced / 10 + 1);
  EXPECT_EQ(DiminishedReality::RefreshKeyframe(*first, {}).replaced, 0);
}

TEST(DiminishedReality, BadInputEmptyRoiAndBounds) {
  const Walk w = MakeWalk(9);
  DrOptions o = Options();
  o.max_keyframes = 2;
  o.obs_views = 3;
  o.obs_stride = 1;
  o.policy.max_unlabelled_fraction = 0.0;  // a keyframe every frame
  DiminishedReality dr(o);
  // Wrong ROI size: a clear error, nothing kept.
  auto bad = dr.ProcessFrame(w.frames[0], ImageU8(10, 10, 1, 255), 0);
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  // Empty ROI: the frame unchanged, nothing kept.
  const ImageU8 none(96, 72, 1, 0);
  auto same = dr.ProcessFrame(w.frames[0], none, 0);
  ASSERT_TRUE(same.ok());
  EXPECT_TRUE(same->color == w.frames[0].color);
  EXPECT_EQ(dr.keyframes().size(), 0u);
  EXPECT_EQ(dr.observations(), 0u);
  for (size_t t = 0; t < w.frames.size(); ++t)
    ASSERT_TRUE(dr.ProcessFrame(w.frames[t], w.rois[t], static_cast<int64_t>(t)).ok());
  EXPECT_EQ(dr.keyframes().size(), 2u);
  EXPECT_EQ(dr.observations(), 3u);
  dr.Clear();
  EXPECT_EQ(dr.keyframes().size(), 0u);
  EXPECT_EQ(dr.observations(), 0u);
  // An ROI over the whole frame leaves no source patch: the library's status, not a crash.
  auto all = dr.ProcessFrame(w.frames[0], ImageU8(96, 72, 1, 255), 0);
  EXPECT_FALSE(all.ok());
  EXPECT_EQ(dr.keyframes().size(), 0u);
  DrOptions invalid;
  invalid.obs_stride = 0;
  EXPECT_FALSE(invalid.Validate().ok());
  invalid = DrOptions();
  invalid.temporal = 1.0;
  EXPECT_FALSE(invalid.Validate().ok());
}

// The live DR view (ComposeLiveFrame): keyframes computed apart (as the server's worker does, one
// frame late), every frame composited from them. The box is removed nearly as well as by the
// synchronous ProcessFrame; outside the ROI nothing changes; without a keyframe the frame comes
// back unchanged and flagged; bad sizes and options are errors.
TEST(DiminishedReality, LiveFramesRemoveTheBoxFromTheKeyframesSoFar) {
  const Walk w = MakeWalk(21);
  DiminishedReality dr(Options()), sync(Options());
  DrLiveOptions lo;
  DrLiveState state;
  double err_in = 0, err_live = 0, err_sync = 0;
  int composited = 0;
  for (size_t t = 0; t < w.frames.size(); ++t) {
    const RgbdKeyframe& f = w.frames[t];
    auto r = ComposeLiveFrame(f, w.rois[t], dr.LiveSnapshot(f.world_from_cam, lo.max_views), lo,
                              &state);
    ASSERT_TRUE(r.ok()) << r.status();
    EXPECT_EQ(r->roi_px, Count(w.rois[t]));
    if (t == 0) {
      // No keyframe yet: the frame as it is.
      EXPECT_FALSE(r->composited);
      EXPECT_TRUE(r->color == f.color);
    } else {
      ASSERT_TRUE(r->composited);
      ++composited;
      err_in += RoiMeanAbs(f.color, w.truth[t].color, w.rois[t]);
      err_live += RoiMeanAbs(r->color, w.truth[t].color, w.rois[t]);
      for (size_t i = 0; i < w.rois[t].size(); ++i)
        if (!w.rois[t].data()[i]) {
          ASSERT_EQ(r->color.data()[3 * i + 1], f.color.data()[3 * i + 1]);
          ASSERT_EQ(r->depth.data()[i], f.depth_m.data()[i]);
        }
      auto s = sync.ProcessFrame(f, w.rois[t], static_cast<int64_t>(t));
      ASSERT_TRUE(s.ok());
      err_sync += RoiMeanAbs(s->color, w.truth[t].color, w.rois[t]);
    } 
    if (t == 0) ASSERT_TRUE(sync.ProcessFrame(f, w.rois[t], 0).ok());
    // After the frame: the keyframe the rule asks for (ready from the next frame on).
    const KeyframeDecision d = dr.Decide(w.rois[t], f.camera, f.world_from_cam);
    if (d.insert) {
      auto k = DiminishedReality::ComputeKeyframe(dr.MakeJob(f, w.rois[t], d), dr.options());
      ASSERT_TRUE(k.ok()) << k.status();
      dr.AddKeyframe(k->view, &*k);
    }
    dr.AddObservation(f, w.rois[t], static_cast<int64_t>(t));
  }
  err_in /= composited;
  err_live /= composited;
  err_sync /= composited;
  std::printf("live ROI mean |error|: input %.1f, live %.1f, synchronous ProcessFrame %.1f\n",
              err_in, err_live, err_sync);
  EXPECT_LT(err_live, 0.4 * err_in);
  EXPECT_LT(err_live, err_sync + 4.0);
  // No keyframe at all: never composited, whatever the ROI.
  DiminishedReality empty(Options());
  auto none = ComposeLiveFrame(w.frames[3], w.rois[3], empty.LiveSnapshot(w.frames[3].world_from_cam, 4),
                               lo, &state);
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE(none->composited);
  EXPECT_TRUE(state.prev_color.empty());  // the next frame is not smoothed against it
  // Bad input.
  EXPECT_EQ(ComposeLiveFrame(w.frames[3], ImageU8(10, 10, 1, 255),
                             dr.LiveSnapshot(w.frames[3].world_from_cam, 4), lo, &state)
                .status()
                .code(),
            absl::StatusCode::kInvalidArgument);
  DrLiveOptions bad;
  bad.max_views = 0;
  EXPECT_FALSE(bad.Validate().ok());
  bad = DrLiveOptions();
  bad.temporal = 1.0;
  EXPECT_FALSE(bad.Validate().ok());
  // The snapshot: the nearest keyframe always among the views, at most max_views (+ it).
  const DrLiveSnapshot snap = dr.LiveSnapshot(w.frames[10].world_from_cam, 1);
  ASSERT_TRUE(snap.nearest);
  ASSERT_LE(snap.views.size(), 2u);
  EXPECT_TRUE(snap.views.front() == snap.nearest || snap.views.back() == snap.nearest);
}

}  // namespace
}  // namespace exo::inpainting
