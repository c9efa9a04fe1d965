#include "common/image_fill.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#include <gtest/gtest.h>

#include <random>

#include "common/image_fill_impl.h"

namespace exo {
namespace {

// A hole in a constant 2-channel image is filled with that constant by either pull filter, and
// known samples are never touched.
TEST(PushPullFill, ConstantIsReproducedAndKnownSamplesKept) {
  const int w = 37, h = 23;  // odd sizes: partial 2x2 blocks at every level
  for (PullFilter f : {PullFilter::kNearest, PullFilter::kBilinear}) {
    std::vector<float> data(size_t(w) * h * 2);
    std::vector<uint8_t> known(size_t(w) * h, 1);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(y) * w + x;
        const bool hole = (x > 5 && x < 30 && y > 4 && y < 15) || (x == 0 && y == 0);
        known[i] = !hole;
        data[2 * i] = hole ? -99.f : 0.25f;
        data[2 * i + 1] = hole ? -99.f : 3.0f;
      }
    ASSERT_TRUE(PushPullFill(data, 2, known, w, h, f));
    for (size_t i = 0; i < known.size(); ++i) {
      EXPECT_NEAR(data[2 * i], 0.25f, 1e-6f) << i;
      EXPECT_NEAR(data[2 * i + 1], 3.0f, 1e-5f) << i;
    }
  }
}

// The sparse evaluation (FillHoles' path for few holes) gives the dense bilinear push-pull's
// values bit for bit: isolated holes, 2x2 and larger blocks (pulls through several levels), a
// frame almost all unknown, odd sizes and single rows / columns. Guard: a pull that skipped a
// level, summed in another order or used another parent would differ in some float bits.
TEST(PushPullFill, SparseEvaluationEqualsDensePushPullBitForBit) {
  std::mt19937 rng(7);
  struct Case {
    int w, h;
    double p_hole;   // isolated unknown pixels
    int blocks;      // unknown rectangles of up to 1/3 of the frame
  };
  const Case cases[] = {{64, 48, 0.01, 0},  {64, 48, 0.2, 0},  {61, 37, 0.05, 3}, {128, 72, 0.0, 1},
                        {33, 1, 0.3, 0},    {1, 29, 0.3, 0},   {2, 2, 0.5, 0},    {97, 55, 0.9, 0},
                        {320, 180, 0.003, 6}, {40, 30, 0.0, 12}};
  int compared = 0;
  for (const Case& c : cases) {
    SCOPED_TRACE(testing::Message() << c.w << "x" << c.h << " p=" << c.p_hole << " b=" << c.blocks);
    const size_t n = size_t(c.w) * c.h;
    std::vector<float> v(n * 3);
    for (float& f : v) f = std::uniform_real_distribution<float>(0.f, 1.f)(rng);
    std::vector<uint8_t> known(n, 1);
    for (size_t i = 0; i < n; ++i) known[i] = std::bernoulli_distribution(c.p_hole)(rng) ? 0 : 1;
    for (int b = 0; b < c.blocks; ++b) {
      const int bw = 1 + int(rng() % (c.w / 3 + 1)), bh = 1 + int(rng() % (c.h / 3 + 1));
      const int x0 = int(rng() % c.w), y0 = int(rng() % c.h);
      for (int y = y0; y < std::min(c.h, y0 + bh); ++y)
        for (int x = x0; x < std::min(c.w, x0 + bw); ++x) known[size_t(y) * c.w + x] = 0;
    }
    known[n / 2] = 1;  // at least one known pixel
    std::vector<size_t> holes;
    for (size_t i = 0; i < n; ++i)
      if (!known[i]) holes.push_back(i);
    std::vector<float> dense(n * 3, -1.f), sparse(n * 3, -1.f);
    auto is_known = [&](size_t i) { return known[i] != 0; };
    auto value = [&](size_t i, int k) { return v[i * 3 + k]; };
    ASSERT_TRUE(image_fill_internal::PushPull<3>(
        c.w, c.h, 3, PullFilter::kBilinear, is_known, value,
        [&](size_t i, int k, float x) { dense[i * 3 + k] = x; }));
    image_fill_internal::PushPullSparseBilinear<3>(
        c.w, c.h, 3, is_known, value, [&](size_t i, int k, float x) { sparse[i * 3 + k] = x; },
        holes);
    for (size_t i = 0; i < n * 3; ++i) {
      ASSERT_EQ(std::memcmp(&dense[i], &sparse[i], sizeof(float)), 0)
          << "pixel " << i / 3 << " channel " << i % 3 << ": " << dense[i] << " vs " << sparse[i];
    }
    compared += int(holes.size());
  }
  EXPECT_GT(compared, 10000);
}

TEST(PushPullFill, NothingKnownChangesNothing) {
  std::vector<float> data(12, 7.f);
  std::vector<uint8_t> known(12, 0);
  EXPECT_FALSE(PushPullFill(data, 1, known, 4, 3));
  for (float v : data) EXPECT_EQ(v, 7.f);
}

// A hole between a dark left and a bright right part is filled with values between the two,
// rising from left to right; the bilinear pull has no block steps: its largest jump between
// horizontal neighbours inside the hole is smaller than the nearest-parent pull's.
TEST(PushPullFill, FillsBetweenTheBordersAndBilinearIsSmoother) {
  const int w = 64, h = 32;
  auto run = [&](PullFilter f) {
    std::vector<float> data(size_t(w) * h);
    std::vector<uint8_t> known(size_t(w) * h);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(y) * w + x;
        known[i] = x < 16 || x >= 48;
        data[i] = x < 16 ? 0.f : x >= 48 ? 1.f : -1.f;
      }
    EXPECT_TRUE(PushPullFill(data, 1, known, w, h, f));
    return data;
  };
  const std::vector<float> bil = run(PullFilter::kBilinear), nea = run(PullFilter::kNearest);
  float max_jump_bil = 0, max_jump_nea = 0;
  for (int y = 0; y < h; ++y) {
    const float* rb = &bil[size_t(y) * w];
    const float* rn = &nea[size_t(y) * w];
    EXPECT_LT(rb[20], rb[32]);
    EXPECT_LT(rb[32], rb[44]);
    for (int x = 16; x < 48; ++x) {
      EXPECT_GE(rb[x], 0.f);
      EXPECT_LE(rb[x], 1.f);
      max_jump_bil = std::max(max_jump_bil, std::abs(rb[x + 1] - rb[x]));
      max_jump_nea = std::max(max_jump_nea, std::abs(rn[x + 1] - rn[x]));
    }
  }
  EXPECT_LT(max_jump_bil, 0.6f * max_jump_nea);
}

}  // namespace
}  // namespace exo
