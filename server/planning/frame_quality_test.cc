#include "server/planning/frame_quality.h"

#include <random>

#include <gtest/gtest.h>

#include "server/planning/view_planner.h"

namespace exo::planning {
namespace {

// A textured RGB image (uniform noise, fixed seed) and the same image box-blurred along x
// (horizontal motion blur of `len` pixels).
ImageU8 Texture(int w, int h, uint32_t seed) {
  ImageU8 im(w, h, 3);
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> u(0, 255);
  for (auto& v : im.span()) v = static_cast<uint8_t>(u(rng));
  return im;
}
ImageU8 MotionBlur(const ImageU8& in, int len) {
  ImageU8 out(in.width(), in.height(), in.channels());
  for (int y = 0; y < in.height(); ++y)
    for (int x = 0; x < in.width(); ++x)
      for (int c = 0; c < in.channels(); ++c) {
        int sum = 0, n = 0;
        for (int k = 0; k < len; ++k)
          if (x + k < in.width()) sum += in.at(x + k, y, c), ++n;
        out.at(x, y, c) = static_cast<uint8_t>(sum / n);
      }
  return out;
}

TEST(FrameQuality, LaplacianVarianceFallsWithBlur) {
  const ImageU8 sharp = Texture(128, 96, 3);
  const double s0 = LaplacianVariance(sharp);
  const double s4 = LaplacianVariance(MotionBlur(sharp, 4));
  const double s12 = LaplacianVariance(MotionBlur(sharp, 12));
  EXPECT_GT(s0, 2.0 * s4);
  EXPECT_GT(s4, 2.0 * s12);
  EXPECT_EQ(LaplacianVariance(ImageU8(64, 48, 3, 128)), 0.0);  // flat: no detail
  EXPECT_EQ(LaplacianVariance(ImageU8(4, 4, 3, 7)), 0.0);      // too small: no information
  EXPECT_EQ(LaplacianVariance(ImageU8()), 0.0);
  // Grey input works and agrees with an RGB image of equal channels.
  ImageU8 grey(128, 96, 1), rgb(128, 96, 3);
  for (int y = 0; y < 96; ++y)
    for (int x = 0; x < 128; ++x) {
      grey.at(x, y) = sharp.at(x, y, 1);
      for (int c = 0; c < 3; ++c) rgb.at(x, y, c) = sharp.at(x, y, 1);
    }
  EXPECT_NEAR(LaplacianVariance(grey), LaplacianVariance(rgb), 1e-6 * LaplacianVariance(grey));
}

TEST(FrameQuality, RelativeToTheSharpestRecentFrame) {
  FrameQualityOptions o;
  o.gamma = 1.0;
  o.window = 3;
  o.floor = 0.1;
  ASSERT_TRUE(o.Validate().ok());
  FrameQuality q(o);
  EXPECT_EQ(q.Next(100), 1.0);              // first frame: its own reference
  EXPECT_DOUBLE_EQ(q.Next(50), 0.5);        // half as sharp as the last one
  EXPECT_EQ(q.Next(200), 1.0);              // sharper than every recent frame
  EXPECT_DOUBLE_EQ(q.Next(1), 0.1);         // clamped to the floor
  EXPECT_DOUBLE_EQ(q.Next(100), 0.5);       // 200 still in the window of 3
  EXPECT_DOUBLE_EQ(q.Next(100), 0.5);       // window: 1, 100, 100 after this... (200 leaves next)
  EXPECT_EQ(q.Next(100), 1.0);              // 200 has left the window
  EXPECT_EQ(q.Next(std::nan("")), 1.0);     // no information: no penalty, window unchanged
  EXPECT_EQ(q.Next(0.0), 1.0);
  FrameQuality off(FrameQualityOptions{});  // gamma 0: off
  EXPECT_EQ(off.Next(100), 1.0);
  EXPECT_EQ(off.Next(1), 1.0);
}

TEST(FrameQuality, OptionsValidated) {
  FrameQualityOptions o;
  o.gamma = -1;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.window = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.floor = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.floor = std::nan("");
  EXPECT_FALSE(o.Validate().ok());
}

Candidate Cand(ViewId id, double quality) {
  Candidate c;
  c.id = id;
  c.local_from_cam.translation = {0.5, 20.5, 0.5};
  c.id_camera = PinholeCamera::FromFov(40, 30, 1.0);
  c.cells.push_back({PackCell({0, 0, 0}), 10});
  c.bytes = 1;
  c.quality = quality;
  return c;
}

// A blurred frame covers less: with one slot, a sharp frame of the same pose replaces it, and a
// blurred frame never replaces a sharp one.
TEST(FrameQuality, SharpFrameReplacesBlurredOneInThePlanner) {
  PlannerOptions o;
  o.max_views = 1;
  o.lambda = 1.0;
  o.cell_size_m = 1.0;
  o.delta_tau_sum = 0.05;
  auto p = ViewPlanner::Create(o).value();
  ASSERT_TRUE(p.Consider(Cand(1, 0.3)).value().accepted);
  EXPECT_NEAR(p.tau_sum(), 0.3, 1e-6);
  auto d = p.Consider(Cand(2, 1.0)).value();
  ASSERT_TRUE(d.accepted);
  EXPECT_EQ(d.removed, std::vector<ViewId>{1});
  EXPECT_NEAR(p.tau_sum(), 1.0, 1e-6);
  EXPECT_FALSE(p.Consider(Cand(3, 0.5)).value().accepted);
  EXPECT_EQ(p.ViewIds(), std::vector<ViewId>{2});
  EXPECT_NEAR(p.RecomputeTauSum(), p.tau_sum(), 1e-9);
  // Quality outside (0, 1] is bad input: an error, nothing changes.
  EXPECT_FALSE(p.Consider(Cand(4, 0.0)).ok());
  EXPECT_FALSE(p.Consider(Cand(5, 1.5)).ok());
  EXPECT_FALSE(p.Consider(Cand(6, std::nan(""))).ok());
  EXPECT_EQ(p.ViewIds(), std::vector<ViewId>{2});
}

// Soft saturation: τ_sum is S(τ) = τ_max (1 - exp(-τ/τ_max)) per cell; the incremental sum
// equals the recomputed one, and a second view of a saturated cell still has a positive gain.
TEST(ViewPlannerSoftSaturation, StrictlyIncreasingAndExact) {
  PlannerOptions o;
  o.max_views = 8;
  o.lambda = 1.0;
  o.tau_max = 1.0;
  o.cell_size_m = 1.0;
  o.delta_tau_sum = 0.0;
  o.soft_saturation = true;
  auto p = ViewPlanner::Create(o).value();
  ASSERT_TRUE(p.Consider(Cand(1, 1.0)).value().accepted);
  EXPECT_NEAR(p.tau_sum(), 1.0 - std::exp(-1.0), 1e-6);
  Candidate c = Cand(2, 1.0);
  c.local_from_cam.translation = {20.5, 0.5, 0.5};  // another direction: φ_d > 0
  auto d = p.Consider(c).value();
  ASSERT_TRUE(d.accepted);
  EXPECT_GT(d.gain, 0.0);
  EXPECT_LT(p.tau_sum(), 1.0);
  EXPECT_NEAR(p.RecomputeTauSum(), p.tau_sum(), 1e-9);
}

}  // namespace
}  // namespace exo::planning
