#include "common/metrics/perceptual.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <random>
#include <vector>

#include "common/io/cv_adapter.h"

namespace exo {
namespace {

// Random rectangles of flat colour over a mild sinusoidal texture: edges as in a real scene.
ImageU8 Scene(int w, int h, uint32_t seed) {
  std::mt19937 rng(seed);
  ImageU8 img(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c)
        img.at(x, y, c) = uint8_t(110 + 30 * std::sin(0.21 * x + c) * std::cos(0.17 * y));
  for (int r = 0; r < 40; ++r) {
    const int x0 = int(rng() % w), y0 = int(rng() % h);
    const int x1 = std::min(w, x0 + 8 + int(rng() % 60)), y1 = std::min(h, y0 + 8 + int(rng() % 60));
    const uint8_t col[3] = {uint8_t(rng() % 256), uint8_t(rng() % 256), uint8_t(rng() % 256)};
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x)
        for (int c = 0; c < 3; ++c) img.at(x, y, c) = col[c];
  }
  return img;
}

ImageU8 Noisy(const ImageU8& img, double sigma, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, sigma);
  ImageU8 out = img;
  for (auto& v : out.span()) v = uint8_t(std::clamp(std::lround(v + n(rng)), 0L, 255L));
  return out;
}

ImageU8 ShiftedX(const ImageU8& img, int dx) {
  ImageU8 out = img;
  for (int y = 0; y < img.height(); ++y)
    for (int x = 0; x < img.width(); ++x)
      for (int c = 0; c < 3; ++c)
        out.at(x, y, c) = img.at(std::clamp(x + dx, 0, img.width() - 1), y, c);
  return out;
}

ImageU8 Blurred(const ImageU8& img, double sigma) {
  ImageU8 out = img;
  cv::GaussianBlur(CvView(img), CvView(out), cv::Size(0, 0), sigma, sigma, cv::BORDER_REPLICATE);
  return out;
}

TEST(PerceptualTest, IdenticalImages) {
  const ImageU8 a = Scene(200, 180, 1);
  EXPECT_DOUBLE_EQ(*MsSsim(a, a), 1.0);
  EXPECT_DOUBLE_EQ(*Gmsd(a, a), 0.0);
}

// Constant images: cs = 1 at every scale (no variance), the coarsest scale's SSIM is the
// luminance term l = (2pq + C1) / (p^2 + q^2 + C1), so MS-SSIM = l^0.1333 (weights sum to 1).
TEST(PerceptualTest, MsSsimConstantImagesByHand) {
  const ImageU8 a(176, 176, 1, 100), b(176, 176, 1, 120);
  const double c1 = 2.55 * 2.55;
  const double l = (2.0 * 100 * 120 + c1) / (100.0 * 100 + 120.0 * 120 + c1);
  EXPECT_NEAR(*MsSsim(a, b), std::pow(l, 0.1333), 1e-12);  // weights as published (sum 1.0001)
  EXPECT_NEAR(*MsSsim(a, b), 0.9977997, 1e-6);  // (24006.5025 / 24406.5025) ^ 0.1333
}

// A zero image against a constant 90 (8x8 -> 4x4 after the 2x2 average). Prewitt with zero
// padding: interior 0, edge pixels |g| = 90, corners |g| = sqrt(2) * 60. GMS with m_r = 0 is
// T / (m_d^2 + T): 4 interior 1, 8 edges 170/8270, 4 corners 170/7370.
TEST(PerceptualTest, GmsdSmallCaseByHand) {
  const ImageU8 ref(8, 8, 1, 0), dist(8, 8, 1, 90);
  auto map = GmsMap(ref, dist);
  ASSERT_TRUE(map.ok());
  ASSERT_EQ(map->width(), 4);
  EXPECT_DOUBLE_EQ(map->at(1, 1), 1.0);
  EXPECT_NEAR(map->at(0, 1), 170.0 / 8270.0, 1e-12);
  EXPECT_NEAR(map->at(3, 3), 170.0 / 7370.0, 1e-12);
  std::vector<double> v(4, 1.0);
  v.insert(v.end(), 8, 170.0 / 8270.0);
  v.insert(v.end(), 4, 170.0 / 7370.0);
  double mean = 0, var = 0;
  for (double x : v) mean += x / 16;
  for (double x : v) var += (x - mean) * (x - mean) / 16;
  EXPECT_NEAR(*Gmsd(ref, dist), std::sqrt(var), 1e-12);
  EXPECT_NEAR(*Gmsd(ref, dist), 0.42375, 1e-5);
}

TEST(PerceptualTest, MonotonicInNoise) {
  const ImageU8 a = Scene(256, 192, 2);
  double prev_ms = 1.0, prev_g = 0.0;
  for (double sigma : {2.0, 5.0, 10.0, 20.0, 40.0}) {
    const ImageU8 n = Noisy(a, sigma, 3);
    const double ms = *MsSsim(a, n), g = *Gmsd(a, n);
    EXPECT_LT(ms, prev_ms) << sigma;
    EXPECT_GT(g, prev_g) << sigma;
    prev_ms = ms;
    prev_g = g;
  }
}

// SSIM prefers blur to a one-pixel misalignment. Find the Gaussian blur whose SSIM equals that of
// a 1 px shift. On an image with fine texture (noise-like detail over flat regions and edges)
// GMSD and MS-SSIM both rate that blur clearly worse than the shift: they do not share SSIM's
// preference for blur. (Measured, not asserted: on the same scene without the fine texture
// GMSD rates shift and blur within 5 % of each other, 0.133 vs 0.139; a 1 px shift is NOT
// generally penalised more than an equal-SSIM blur by GMSD.)
double BlurSigmaOfEqualSsim(const ImageU8& a, double target) {
  double lo = 0.3, hi = 6.0;  // SSIM falls as the blur grows
  for (int it = 0; it < 40; ++it) {
    const double mid = 0.5 * (lo + hi);
    (*Ssim(a, Blurred(a, mid)) > target ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

TEST(PerceptualTest, AtEqualSsimBlurOfFineTextureIsWorseThanShift) {
  const ImageU8 a = Noisy(Scene(320, 240, 5), 8, 1);
  const ImageU8 shifted = ShiftedX(a, 1);
  const double s_shift = *Ssim(a, shifted);
  const ImageU8 blurred = Blurred(a, BlurSigmaOfEqualSsim(a, s_shift));
  ASSERT_NEAR(*Ssim(a, blurred), s_shift, 0.005);
  EXPECT_GT(*Gmsd(a, blurred), 1.3 * *Gmsd(a, shifted));       // measured 0.153 vs 0.096
  EXPECT_LT(*MsSsim(a, blurred), *MsSsim(a, shifted) - 0.05);  // measured 0.829 vs 0.948
}

// A 2 px shift of the clean scene costs more GMSD than the blur of equal SSIM.
TEST(PerceptualTest, GmsdPenalisesTwoPixelShiftMoreThanBlurOfEqualSsim) {
  const ImageU8 a = Scene(320, 240, 8);
  const ImageU8 shifted = ShiftedX(a, 2);
  const double s_shift = *Ssim(a, shifted);
  const ImageU8 blurred = Blurred(a, BlurSigmaOfEqualSsim(a, s_shift));
  ASSERT_NEAR(*Ssim(a, blurred), s_shift, 0.005);
  EXPECT_GT(*Gmsd(a, shifted), 1.1 * *Gmsd(a, blurred));  // measured 0.173 vs 0.152
}

TEST(PerceptualTest, BadInput) {
  const ImageU8 a = Scene(200, 200, 1);
  EXPECT_FALSE(MsSsim(a, Scene(201, 200, 1)).ok());
  EXPECT_FALSE(MsSsim(Scene(160, 200, 1), Scene(160, 200, 1)).ok());  // coarsest scale < 11
  EXPECT_TRUE(MsSsim(Scene(160, 200, 1), Scene(160, 200, 1), {.scales = 4}).ok());
  EXPECT_FALSE(MsSsim(a, a, {.scales = 6}).ok());
  EXPECT_FALSE(Gmsd(a, Scene(200, 199, 1)).ok());
  EXPECT_FALSE(Gmsd(ImageU8(1, 1, 1, 0), ImageU8(1, 1, 1, 0)).ok());
  EXPECT_FALSE(Gmsd(a, a, {.t = 0}).ok());
  EXPECT_TRUE(MsSsimFits(640, 480));
  EXPECT_FALSE(MsSsimFits(160, 120));
}

}  // namespace
}  // namespace exo
