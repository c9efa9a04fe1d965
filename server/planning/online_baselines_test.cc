// Issue 22 online baselines: every selector keeps the store bound at every frame; progressive
// every-N keeps an even spread over the stream so far without knowing its length; reservoir
// sampling is seeded and uniform; the keyframe rule fires at the InpaintFusion distance and,
// when full, coarsens its spacing over the whole stream instead of freezing.
#include "server/planning/online_baselines.h"

#include <cmath>
#include <memory>

#include <glm/gtc/constants.hpp>
#include <gtest/gtest.h>

namespace exo::planning {
namespace {

Rigid3d At(double x, double yaw_deg = 0) {
  Rigid3d p;
  p.translation = {x, 0, 0};
  p.rotation = glm::angleAxis(glm::radians(yaw_deg), glm::dvec3(0, 0, 1));
  return p;
}

TEST(OnlineBaselinesTest, StoreBoundHoldsAtEveryFrame) {
  for (size_t cap : {1u, 2u, 7u, 50u}) {
    std::vector<std::unique_ptr<OnlineSelector>> sel;
    sel.push_back(std::make_unique<ProgressiveEveryN>(cap));
    sel.push_back(std::make_unique<ReservoirSampler>(cap, 5));
    sel.push_back(std::make_unique<KeyframeSelector>(cap, 0.7, 1.0));
    for (int i = 0; i < 3000; ++i)
      for (auto& s : sel) {
        s->Offer(i, At(0.3 * i, 3.0 * i));
        ASSERT_LE(s->size(), cap) << "frame " << i;
        ASSERT_EQ(s->Selected().size(), s->size());
      }
    for (auto& s : sel) EXPECT_GE(s->size(), std::min<size_t>(cap, 1 + cap / 2));
  }
}

TEST(OnlineBaselinesTest, ProgressiveEveryNKeepsAnEvenSpreadOfAnyLength) {
  const size_t cap = 100;
  ProgressiveEveryN p(cap);
  for (int i = 0; i < 5000; ++i) {
    p.Offer(i, At(0));
    const int n = i + 1;  // frames so far: the selector never knew this number in advance
    if (n % 37 != 0 && n != 5000) continue;
    const std::vector<int64_t> s = p.Selected();
    const int64_t step = p.step();
    ASSERT_FALSE(s.empty());
    EXPECT_EQ(s.front(), 0);
    for (size_t k = 1; k < s.size(); ++k) EXPECT_EQ(s[k] - s[k - 1], step) << "n " << n;
    EXPECT_GT(s.back() + step, n - 1) << "n " << n;  // the tail is sampled
    EXPECT_LE(s.size(), cap);
    EXPECT_GT(s.size(), n <= int(cap) ? size_t(n - 1) : cap / 2);  // never under half full
    // N is at most twice the length-aware oracle's step n / cap.
    EXPECT_LE(step, std::max<int64_t>(1, 2 * ((n + cap - 1) / cap))) << "n " << n;
  }
  EXPECT_EQ(p.step(), 64);  // 5000 frames into 100 slots: N = 1, 2, ..., 64 (79 kept)
  EXPECT_EQ(p.size(), 79u);
}

TEST(OnlineBaselinesTest, ReservoirIsSeededAndUniform) {
  ReservoirSampler a(200, 1), b(200, 1), c(200, 2);
  for (int i = 0; i < 5000; ++i) {
    a.Offer(i, At(0));
    b.Offer(i, At(0));
    c.Offer(i, At(0));
  }
  EXPECT_EQ(a.Selected(), b.Selected());
  EXPECT_NE(a.Selected(), c.Selected());
  ASSERT_EQ(a.size(), 200u);
  int first_half = 0;
  double mean = 0;
  for (int64_t i : a.Selected()) {
    first_half += i < 2500;
    mean += i / 200.0;
  }
  EXPECT_NEAR(first_half, 100, 25);  // binomial sd ~7
  EXPECT_NEAR(mean, 2500, 300);
}

TEST(OnlineBaselinesTest, KeyframeRuleFiresAtTheInpaintFusionDistance) {
  // Rotation alone: ||I - R||_F = 2 sqrt(2) sin(theta / 2); 0.7 at 28.66 deg.
  EXPECT_NEAR(KeyframeDistance(At(0), At(0, 28.66), 1.0), 0.7, 1e-3);
  EXPECT_NEAR(KeyframeDistance(At(0), At(0.7), 1.0), 0.7, 1e-12);
  EXPECT_NEAR(KeyframeDistance(At(0), At(3.5), 5.0), 0.7, 1e-12);  // translation in units
  KeyframeSelector still(10, 0.7, 1.0);
  for (int i = 0; i < 500; ++i) still.Offer(i, At(2.0, 30));
  EXPECT_EQ(still.Selected(), std::vector<int64_t>{0});  // a hovering camera makes no keyframes
  KeyframeSelector yaw(100, 0.7, 1.0);
  for (int i = 0; i < 100; ++i) yaw.Offer(i, At(0, i));  // 1 deg per frame
  EXPECT_EQ(yaw.Selected(), (std::vector<int64_t>{0, 29, 58, 87}));
  KeyframeSelector line(100, 0.7, 1.0);
  for (int i = 0; i < 80; ++i) line.Offer(i, At(0.09 * i));  // 0.72 m > 0.7 every 8 frames
  EXPECT_EQ(line.Selected(), (std::vector<int64_t>{0, 8, 16, 24, 32, 40, 48, 56, 64, 72}));
}

TEST(OnlineBaselinesTest, FullKeyframeStoreCoarsensOverTheWholeStream) {
  KeyframeSelector kf(20, 0.7, 1.0);
  for (int i = 0; i < 4000; ++i) kf.Offer(i, At(0.1 * i));  // 400 m line
  const std::vector<int64_t> s = kf.Selected();
  ASSERT_GE(s.size(), 10u);
  ASSERT_LE(s.size(), 20u);
  EXPECT_EQ(s.front(), 0);
  // The end of the stream is represented: the last frame is within the threshold of the last
  // keyframe (else it would be one), and the spacing grew from 0.7 m to the 400 m / 20 scale.
  EXPECT_LE(0.1 * (3999 - s.back()), kf.threshold() + 1e-9);
  EXPECT_GT(kf.threshold(), 0.7 * 20);
  for (size_t k = 1; k < s.size(); ++k)
    EXPECT_GT(0.1 * (s[k] - s[k - 1]), kf.threshold() * 0.999) << k;
}

TEST(OnlineBaselinesTest, LengthAwareEveryNIsTheEvalsEvenSpread) {
  for (int64_t len : {1, 7, 50, 270, 1000})
    for (int64_t cap : {1, 25, 48, 95, 200, 2000}) {
      LengthAwareEveryN e(size_t(cap), len);
      for (int64_t k = 0; k < len + 30; ++k) e.Offer(1000 + k, At(0));  // frames past L: ignored
      std::vector<int64_t> want;
      const int64_t m = std::min(len, cap);
      for (int64_t j = 0; j < m; ++j) want.push_back(1000 + (j * len) / m);  // eval.cc's every-N
      EXPECT_EQ(e.Selected(), want) << "len " << len << " cap " << cap;
    }
}

TEST(OnlineBaselinesTest, MinDistanceGrowsTheSmallestSpacing) {
  MinDistanceSelector md(10, 1.0);
  // A line walked back and forth: the kept poses spread over it, the closest pair only widens.
  double closest_before = 0;
  for (int i = 0; i < 400; ++i) {
    const double x = (i / 100) % 2 == 0 ? 0.05 * (i % 100) : 5.0 - 0.05 * (i % 100);
    md.Offer(i, At(x));
    if (md.size() < 10) continue;
    const auto keys = md.Selected();
    ASSERT_EQ(keys.size(), 10u);
    std::vector<double> xs;
    for (int64_t k : keys) {
      const int j = int(k);
      xs.push_back((j / 100) % 2 == 0 ? 0.05 * (j % 100) : 5.0 - 0.05 * (j % 100));
    }
    std::sort(xs.begin(), xs.end());
    double closest = 1e9;
    for (size_t a = 1; a < xs.size(); ++a) closest = std::min(closest, xs[a] - xs[a - 1]);
    EXPECT_GE(closest, closest_before - 1e-12) << "frame " << i;
    closest_before = closest;
  }
  // 10 views over 4.95 m: 0.55 m apart at best; the greedy swaps reach 0.35 (7 frame steps of
  // 0.05 m): spread, not the stream's bunched first frames.
  EXPECT_GT(closest_before, 0.3);
}

// Checkpoints: a selector restored from its state decides the rest of the stream exactly as the
// uninterrupted one; Forget drops a frame; a state over the capacity is refused.
TEST(OnlineBaselinesTest, StateRoundTripContinuesTheSameStream) {
  auto make = [](int which) -> std::unique_ptr<OnlineSelector> {
    switch (which) {
      case 0: return std::make_unique<MinDistanceSelector>(20, 1.0);
      case 1: return std::make_unique<ProgressiveEveryN>(20);
      case 2: return std::make_unique<LengthAwareEveryN>(20, 900);
      case 3: return std::make_unique<ReservoirSampler>(20, 3);
      default: return std::make_unique<KeyframeSelector>(20, 0.7, 1.0);
    }
  };
  for (int which = 0; which < 5; ++which) {
    auto a = make(which), b = make(which);
    for (int i = 0; i < 333; ++i) a->Offer(i, At(0.07 * i, 2.0 * i));
    StateWriter w;
    a->SaveState(&w);
    StateReader r(w.str());
    ASSERT_TRUE(b->LoadState(&r).ok()) << which;
    EXPECT_TRUE(r.done()) << which;
    EXPECT_EQ(a->Selected(), b->Selected()) << which;
    for (int i = 333; i < 900; ++i) {
      a->Offer(i, At(0.07 * i, 2.0 * i));
      b->Offer(i, At(0.07 * i, 2.0 * i));
    }
    EXPECT_EQ(a->Selected(), b->Selected()) << which;
    const int64_t gone = a->Selected().front();
    a->Forget(gone);
    EXPECT_FALSE(std::binary_search(a->Selected().begin(), a->Selected().end(), gone)) << which;
    EXPECT_EQ(a->size(), b->size() - 1) << which;
    // A smaller selector must not accept a state holding more frames than it may keep.
    std::unique_ptr<OnlineSelector> small;
    switch (which) {
      case 0: small = std::make_unique<MinDistanceSelector>(3, 1.0); break;
      case 1: small = std::make_unique<ProgressiveEveryN>(3); break;
      case 2: small = std::make_unique<LengthAwareEveryN>(3, 900); break;
      case 3: small = std::make_unique<ReservoirSampler>(3, 3); break;
      default: small = std::make_unique<KeyframeSelector>(3, 0.7, 1.0);
    }
    StateReader r2(w.str());
    if (b->size() > 3) EXPECT_FALSE(small->LoadState(&r2).ok()) << which;
    StateReader cut(std::string_view(w.str()).substr(0, w.str().size() / 2));
    EXPECT_FALSE(make(which)->LoadState(&cut).ok()) << which;  // truncated: a clear error
  }
}

TEST(OnlineBaselinesTest, AdoptedFramesAreKeptWhileThereIsRoom) {
  LengthAwareEveryN e(5, 100);  // keeps 0, 20, 40, 60, 80
  e.Adopt(7, At(0));
  e.Adopt(8, At(0));            // two views restored from a store: the stream is past frame 20
  for (int k = 21; k < 100; ++k) e.Offer(1000 + k, At(0));
  EXPECT_EQ(e.Selected(), (std::vector<int64_t>{7, 8, 1040, 1060, 1080}));
  MinDistanceSelector md(2, 1.0);
  md.Adopt(1, At(0));
  md.Adopt(2, At(1));
  md.Adopt(3, At(2));  // no room: not kept
  EXPECT_EQ(md.Selected(), (std::vector<int64_t>{1, 2}));
}

}  // namespace
}  // namespace exo::planning
