#include "server/service/refinement_worker.h"

#include <condition_variable>
#include <mutex>

#include <gtest/gtest.h>

namespace exo {
namespace {

StoredView FlatView(int w, int h) {
  StoredView v;
  v.id = 7;
  v.camera = PinholeCamera{200.0, 200.0, w / 2.0 - 0.5, h / 2.0 - 0.5, w, h};
  v.color = ImageU8(w, h, 3, 100);
  v.depth_m = ImageF(w, h, 1, 2.0f);
  return v;
}

// Box-filtered colour and the depth rule: a smooth block is averaged, a block across a depth
// edge keeps its nearest sample (a mixed depth would lie on no surface; removing the edge guard
// gives 2.5 m here).
TEST(DownscaleViewTest, BoxColourAndEdgeSafeDepth) {
  StoredView v = FlatView(4, 2);
  v.color.at(0, 0, 0) = 0;
  v.color.at(1, 0, 0) = 200;
  v.color.at(0, 1, 0) = 100;
  v.color.at(1, 1, 0) = 100;
  v.depth_m.at(2, 0) = 3.0f;   // block (1, 0): edge 2 m / 3 m
  v.depth_m.at(0, 1) = 2.02f;  // block (0, 0): smooth
  v.depth_m.at(1, 1) = 0.0f;   // invalid sample ignored
  const StoredView s = DownscaleView(v, 2);
  ASSERT_EQ(s.color.width(), 2);
  ASSERT_EQ(s.color.height(), 1);
  EXPECT_EQ(s.color.at(0, 0, 0), 100);  // (0 + 200 + 100 + 100) / 4
  EXPECT_EQ(s.color.at(1, 0, 1), 100);
  EXPECT_NEAR(s.depth_m.at(0, 0), (2.0f + 2.0f + 2.02f) / 3.0f, 1e-6);
  EXPECT_FLOAT_EQ(s.depth_m.at(1, 0), 2.0f);
  // Camera scaled with pixel centres kept: continuous centre (cx + 0.5) halves.
  EXPECT_DOUBLE_EQ(s.camera.fx, 100.0);
  EXPECT_DOUBLE_EQ(s.camera.cx + 0.5, (v.camera.cx + 0.5) / 2.0);
}

// Submission never blocks: with the worker busy and its queue full, the next view is skipped
// and counted; every submitted job is applied exactly once by Stop().
TEST(RefinementWorkerTest, SkipsUnderLoadNeverBlocks) {
  RefinementWorkerOptions o;
  o.queue = 1;
  std::mutex mu;
  std::condition_variable cv;
  bool release = false;
  int applied = 0, errors = 0;
  RefinementWorker w(o, [&](const RefinementJob&, const absl::StatusOr<RefinementResult>& r) {
    std::unique_lock lock(mu);
    cv.wait(lock, [&] { return release; });
    ++applied;
    errors += !r.ok();
  });
  auto cand = std::make_shared<const StoredView>(FlatView(32, 24));
  auto job = [&] {
    RefinementJob j;
    j.id = 7;
    j.candidate = cand;  // no references: RefineView reports an error, the view stays as is
    return j;
  };
  EXPECT_TRUE(w.TrySubmit(job()));
  // The first job is being refined (blocked in apply) or queued; fill until one is skipped.
  int accepted = 1, skipped = 0;
  for (int i = 0; i < 4; ++i) (w.TrySubmit(job()) ? accepted : skipped)++;
  EXPECT_GE(skipped, 2);
  EXPECT_LE(accepted, 3);  // at most one running + one queued (+ one popped before the check)
  {
    std::lock_guard lock(mu);
    release = true;
  }
  cv.notify_all();
  w.Stop();
  EXPECT_EQ(applied, accepted);
  EXPECT_EQ(errors, accepted);
  EXPECT_EQ(w.pending(), 0u);
  const RefinementWorkerStats st = w.stats();
  EXPECT_EQ(st.skipped_under_load, static_cast<uint64_t>(skipped));
  EXPECT_EQ(st.submitted, static_cast<uint64_t>(accepted));
}

}  // namespace
}  // namespace exo
