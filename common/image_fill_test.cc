#include "common/image_fill.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

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
