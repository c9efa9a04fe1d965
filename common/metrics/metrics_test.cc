#include "common/metrics/metrics.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace exo {
namespace {

// ---- Independent reference: naive direct-summation SSIM (no OpenCV) ----
// Gaussian weights built here, window statistics by explicit weighted sums with the variance as
// sum w (x - mu)^2 (not E[x^2] - mu^2), reflect-101 border indexing as OpenCV's default.
int Reflect101(int i, int n) {
  while (i < 0 || i >= n) i = i < 0 ? -i : 2 * (n - 1) - i;
  return i;
}
double RefLuma(const ImageU8& img, int x, int y) {
  if (img.channels() == 1) return img.at(x, y);
  return 0.299 * img.at(x, y, 0) + 0.587 * img.at(x, y, 1) + 0.114 * img.at(x, y, 2);
}
std::vector<double> RefSsimMap(const ImageU8& a, const ImageU8& b) {
  const int r = 5;
  double w[11][11], wsum = 0;
  for (int j = -r; j <= r; ++j)
    for (int i = -r; i <= r; ++i) wsum += (w[j + r][i + r] = std::exp(-(i * i + j * j) / 4.5));
  for (auto& row : w)
    for (double& v : row) v /= wsum;
  const double c1 = std::pow(0.01 * 255, 2), c2 = std::pow(0.03 * 255, 2);
  std::vector<double> map(static_cast<size_t>(a.width()) * a.height());
  for (int y = 0; y < a.height(); ++y)
    for (int x = 0; x < a.width(); ++x) {
      double m1 = 0, m2 = 0;
      for (int j = -r; j <= r; ++j)
        for (int i = -r; i <= r; ++i) {
          const int xx = Reflect101(x + i, a.width()), yy = Reflect101(y + j, a.height());
          m1 += w[j + r][i + r] * RefLuma(a, xx, yy);
          m2 += w[j + r][i + r] * RefLuma(b, xx, yy);
        }
      double v1 = 0, v2 = 0, cov = 0;
      for (int j = -r; j <= r; ++j)
        for (int i = -r; i <= r; ++i) {
          const int xx = Reflect101(x + i, a.width()), yy = Reflect101(y + j, a.height());
          const double d1 = RefLuma(a, xx, yy) - m1, d2 = RefLuma(b, xx, yy) - m2;
          v1 += w[j + r][i + r] * d1 * d1;
          v2 += w[j + r][i + r] * d2 * d2;
          cov += w[j + r][i + r] * d1 * d2;
        }
      map[static_cast<size_t>(y) * a.width() + x] =
          ((2 * m1 * m2 + c1) * (2 * cov + c2)) / ((m1 * m1 + m2 * m2 + c1) * (v1 + v2 + c2));
    }
  return map;
}
double RefMean(const std::vector<double>& map, int w, int h, int crop) {
  double s = 0;
  int n = 0;
  for (int y = crop; y < h - crop; ++y)
    for (int x = crop; x < w - crop; ++x) s += map[static_cast<size_t>(y) * w + x], ++n;
  return s / n;
}

ImageU8 Textured(int w, int h, uint32_t seed) {
  std::mt19937 rng(seed);
  ImageU8 img(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c)
        img.at(x, y, c) = static_cast<uint8_t>(
            std::clamp(120 + 80 * std::sin(0.3 * x + c) * std::cos(0.2 * y) +
                           static_cast<int>(rng() % 31) - 15, 0.0, 255.0));
  return img;
}

ImageU8 AddNoise(const ImageU8& img, int amplitude, uint32_t seed) {
  std::mt19937 rng(seed);
  ImageU8 out = img;
  for (auto& v : out.span())
    v = static_cast<uint8_t>(std::clamp(int(v) + int(rng() % (2 * amplitude + 1)) - amplitude, 0, 255));
  return out;
}

ImageU8 Shifted(const ImageU8& img, int dx) {
  ImageU8 out = img;
  for (int y = 0; y < img.height(); ++y)
    for (int x = 0; x < img.width(); ++x)
      for (int c = 0; c < 3; ++c) out.at(x, y, c) = img.at(std::min(img.width() - 1, x + dx), y, c);
  return out;
}

TEST(MetricsTest, IdenticalIsOne) {
  const ImageU8 a = Textured(40, 30, 1);
  EXPECT_NEAR(*Ssim(a, a), 1.0, 1e-12);
  EXPECT_TRUE(std::isinf(*Psnr(a, a)));
  EXPECT_EQ(*Mse(a, a), 0.0);
}

// Constant images a and b: both variances and the covariance vanish, so per pixel
// SSIM = (2ab + C1) / (a^2 + b^2 + C1) exactly (analytic).
TEST(MetricsTest, ConstantOffsetAnalytic) {
  ImageU8 a(20, 20, 3, 100), b(20, 20, 3, 130);
  const double c1 = std::pow(0.01 * 255, 2);
  const double want = (2.0 * 100 * 130 + c1) / (100.0 * 100 + 130.0 * 130 + c1);
  EXPECT_NEAR(*Ssim(a, b), want, 1e-9);
  // PSNR of a known MSE: every channel off by 30 -> MSE 900.
  EXPECT_NEAR(*Psnr(a, b), 10 * std::log10(255.0 * 255.0 / 900.0), 1e-12);
}

// SSIM vs the independent direct summation on known pairs, map and mean, to 1e-6.
// Guards: Gaussian sigma/window, C1/C2, the luma weights and the border rule.
TEST(MetricsTest, MatchesDirectSummationReference) {
  const ImageU8 a = Textured(37, 29, 2);  // odd sizes
  ImageU8 offset = a;
  for (auto& v : offset.span()) v = static_cast<uint8_t>(std::min(255, v + 20));
  const std::vector<std::pair<const char*, ImageU8>> cases = {
      {"offset", offset}, {"noise", AddNoise(a, 25, 3)}, {"shift", Shifted(a, 2)},
      {"other", Textured(37, 29, 9)}};
  for (const auto& [name, b] : cases) {
    const auto ref = RefSsimMap(a, b);
    auto map = SsimMap(a, b);
    ASSERT_TRUE(map.ok()) << map.status();
    double max_diff = 0;
    for (size_t i = 0; i < ref.size(); ++i) max_diff = std::max(max_diff, std::abs(ref[i] - map->data()[i]));
    EXPECT_LT(max_diff, 1e-6) << name;
    EXPECT_NEAR(*Ssim(a, b), RefMean(ref, 37, 29, 0), 1e-6) << name;
    SsimOptions valid;
    valid.crop_border = true;  // Wang's 'valid' mean: border-rule independent
    EXPECT_NEAR(*Ssim(a, b, valid), RefMean(ref, 37, 29, 5), 1e-6) << name;
    EXPECT_LT(*Ssim(a, b), 1.0) << name;
  }
  // Ordering sanity: mild noise scores higher than strong noise.
  EXPECT_GT(*Ssim(a, AddNoise(a, 5, 4)), *Ssim(a, AddNoise(a, 40, 4)));
}

TEST(MetricsTest, LumaWeights) {
  ImageU8 px(1, 1, 3);
  px.at(0, 0, 0) = 100, px.at(0, 0, 1) = 50, px.at(0, 0, 2) = 200;
  EXPECT_NEAR(LumaFromRgb(px).at(0, 0), 0.299 * 100 + 0.587 * 50 + 0.114 * 200, 1e-12);
  // Luma, not per channel: swapping R and B of a pixel changes SSIM.
  ImageU8 a(16, 16, 3, 0), b(16, 16, 3, 0);
  for (int y = 0; y < 16; ++y) a.at(8, y, 0) = 255, b.at(8, y, 2) = 255;
  EXPECT_LT(*Ssim(a, b), 0.99);
}

TEST(MetricsTest, MaskedVariants) {
  const ImageU8 a = Textured(30, 20, 5);
  ImageU8 b = a;
  ImageU8 mask(30, 20, 1, 0);
  for (int y = 0; y < 20; ++y)
    for (int x = 0; x < 30; ++x) {
      if (x < 15) mask.at(x, y) = 255;
      else b.at(x, y, 1) = static_cast<uint8_t>(255 - b.at(x, y, 1));  // damage the right half
    }
  // Masked PSNR sees only the untouched left half.
  EXPECT_TRUE(std::isinf(*MaskedPsnr(a, b, mask)));
  EXPECT_TRUE(std::isfinite(*Psnr(a, b)));
  // Masked SSIM = mean of the map over the mask (computed from the map here).
  auto map = *SsimMap(a, b);
  double s = 0;
  for (int y = 0; y < 20; ++y)
    for (int x = 0; x < 15; ++x) s += map.at(x, y);
  EXPECT_NEAR(*MaskedSsim(a, b, mask), s / (15 * 20), 1e-12);
  EXPECT_GT(*MaskedSsim(a, b, mask), *Ssim(a, b));
  // Known masked MSE: one channel off by 10 on the masked pixels only.
  ImageU8 c = a;
  for (int y = 0; y < 20; ++y)
    for (int x = 0; x < 15; ++x) c.at(x, y, 0) = static_cast<uint8_t>(a.at(x, y, 0) < 128 ? a.at(x, y, 0) + 10 : a.at(x, y, 0) - 10);
  EXPECT_NEAR(*MaskedMse(a, c, mask), 100.0 / 3.0, 1e-12);
  EXPECT_NEAR(*MaskedPsnr(a, c, mask), 10 * std::log10(255.0 * 255.0 * 3.0 / 100.0), 1e-12);
  EXPECT_NEAR(*CoveredFraction(mask), 0.5, 1e-12);
  // Empty masks are errors, not NaN.
  const ImageU8 none(30, 20, 1, 0);
  EXPECT_FALSE(MaskedSsim(a, b, none).ok());
  EXPECT_FALSE(MaskedPsnr(a, b, none).ok());
  EXPECT_EQ(*CoveredFraction(none), 0.0);
}

TEST(MetricsTest, MeanSsimOverViews) {
  const ImageU8 a = Textured(24, 24, 6), n = AddNoise(a, 20, 7);
  const std::vector<ImageU8> truth = {a, a}, rendered = {a, n};
  EXPECT_NEAR(*MeanSsim(rendered, truth), (1.0 + *Ssim(n, a)) / 2.0, 1e-12);
  const std::vector<ImageU8> one = {a};
  EXPECT_FALSE(MeanSsim(one, truth).ok());
  const std::vector<ImageU8> masks = {ImageU8(24, 24, 1, 1), ImageU8(24, 24, 1, 1)};
  EXPECT_NEAR(*MeanSsim(rendered, truth, masks), *MeanSsim(rendered, truth), 1e-12);
}

TEST(MetricsTest, BadInput) {
  const ImageU8 a = Textured(20, 20, 1);
  EXPECT_FALSE(Ssim(a, Textured(21, 20, 1)).ok());
  EXPECT_FALSE(Ssim(ImageU8(8, 8, 3), ImageU8(8, 8, 3)).ok());  // smaller than the window
  EXPECT_FALSE(Psnr(ImageU8(), ImageU8()).ok());
  EXPECT_FALSE(MaskedSsim(a, a, ImageU8(20, 20, 3)).ok());
  SsimOptions o;
  o.window = 10;
  EXPECT_FALSE(Ssim(a, a, o).ok());
}

}  // namespace
}  // namespace exo
