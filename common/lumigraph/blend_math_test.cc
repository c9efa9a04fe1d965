#include "common/lumigraph/blend_math.h"

#include <cmath>
#include <limits>
#include <vector>

#include <gtest/gtest.h>

#include "common/camera.h"

namespace exo::blend {
namespace {

TEST(BlendMath, SrgbRoundTripAndKnownValues) {
  EXPECT_NEAR(SrgbToLinear(0.5f), 0.21404f, 1e-4f);
  EXPECT_NEAR(LinearToSrgb(0.21404f), 0.5f, 1e-4f);
  EXPECT_FLOAT_EQ(SrgbToLinear(0.0f), 0.0f);
  EXPECT_FLOAT_EQ(SrgbToLinear(1.0f), 1.0f);
  for (int v = 0; v < 256; ++v)
    EXPECT_EQ(UnitToU8(LinearToSrgb(SrgbToLinear(U8ToUnit(uint8_t(v))))), v);
  EXPECT_FLOAT_EQ(LinearToSrgb(10.0f), 1.0f);  // overexposed clamps to white
}

TEST(BlendMath, DirectionalWeightIsClampedCosine) {
  const glm::vec3 x(0, 0, 0);
  EXPECT_NEAR(DirectionalWeight(x, {0, 0, 2}, {0, 0, 5}), 1.0f, 1e-6f);
  EXPECT_NEAR(DirectionalWeight(x, {0, 0, 2}, {3, 0, 3}), std::cos(M_PI / 4), 1e-6f);
  EXPECT_EQ(DirectionalWeight(x, {0, 0, 2}, {0, 0, -2}), 0.0f);  // opposite: clamped
  // Guard: camera on the surface point gives 0, not NaN.
  EXPECT_EQ(DirectionalWeight(x, x, {0, 0, 1}), 0.0f);
}

TEST(BlendMath, PositionalWeightPrintedAndUlr) {
  const glm::vec3 x(0), c_o(0, 0, 2);
  // As printed (3.3): 1 - d_i/d_o.
  EXPECT_NEAR(PositionalWeight(x, c_o, {0, 0, 1}, PositionalMode::kPrinted), 0.5f, 1e-6f);
  EXPECT_EQ(PositionalWeight(x, c_o, {0, 0, 2}, PositionalMode::kPrinted), 0.0f);
  EXPECT_EQ(PositionalWeight(x, c_o, {0, 0, 3}, PositionalMode::kPrinted), 0.0f);
  // ULR: closer views are full weight, farther ones lose linearly, 0 at twice the distance.
  EXPECT_EQ(PositionalWeight(x, c_o, {0, 0, 1}, PositionalMode::kUlrResolution), 1.0f);
  EXPECT_EQ(PositionalWeight(x, c_o, {0, 0, 2}, PositionalMode::kUlrResolution), 1.0f);
  EXPECT_NEAR(PositionalWeight(x, c_o, {0, 0, 3}, PositionalMode::kUlrResolution), 0.5f, 1e-6f);
  EXPECT_EQ(PositionalWeight(x, c_o, {0, 0, 5}, PositionalMode::kUlrResolution), 0.0f);
  // Guard d_o -> 0: finite result.
  EXPECT_TRUE(std::isfinite(PositionalWeight(x, x, {0, 0, 1}, PositionalMode::kPrinted)));
}

TEST(BlendMath, CombinedWeight) {
  EXPECT_NEAR(CombinedWeight(1.0f, 0.8f, 0.4f, 0.5f, 0.0f), 0.6f, 1e-6f);
  EXPECT_EQ(CombinedWeight(0.0f, 0.8f, 0.4f, 0.5f, 1e-4f), 0.0f);
  EXPECT_EQ(CombinedWeight(1.0f, 0.0f, 0.0f, 0.5f, 1e-4f), 1e-4f);
}

TEST(BlendMath, RangeConversionMatchesCamera) {
  PinholeCamera cam = PinholeCamera::FromFov(64, 48, 1.2);
  for (glm::dvec2 uv : {glm::dvec2(0, 0), glm::dvec2(63, 47), glm::dvec2(20.3, 7.9)}) {
    const float r = RangeFromZDepth(glm::vec2(uv), 2.5f,
                                    glm::vec4(cam.fx, cam.fy, cam.cx, cam.cy));
    EXPECT_NEAR(r, cam.RangeFromZDepth(uv, 2.5), 1e-5);
  }
}

// A 32x24 view at the origin looking down +z at a fronto-parallel wall at z = 2 (z-depth 2).
struct WallView {
  BlendView view;
  std::vector<float> depth;
  PinholeCamera cam = PinholeCamera::FromFov(32, 24, 1.0);
  WallView() {
    view.intrinsics = glm::vec4(cam.fx, cam.fy, cam.cx, cam.cy);
    view.size = {32, 24};
    depth.assign(32 * 24, 2.0f);
  }
  // The discontinuity test of (3.4) with the thesis' radius (the default is off since issue 15).
  static BlendOptions Thesis() {
    BlendOptions o;
    o.discontinuity_radius_px = 2;
    return o;
  }
  float Valid(const glm::vec3& x, const BlendOptions& opt = Thesis()) const {
    return Validity(x, view, opt, [&](glm::ivec2 p) { return depth[p.y * 32 + p.x]; });
  }
};

TEST(BlendMath, ValidityOcclusionUsesRangeNotZDepth) {
  WallView w;
  BlendOptions opt;
  opt.occlusion_epsilon_m = 0.01f;
  opt.occlusion_epsilon_rel = 0.0f;
  // A point on the wall near the image corner: z = 2 but range > 2 by far more than epsilon.
  const glm::vec2 uv(1.0f, 1.0f);
  const glm::vec3 on_wall(float((uv.x - w.cam.cx) / w.cam.fx * 2), float((uv.y - w.cam.cy) / w.cam.fy * 2), 2.0f);
  ASSERT_GT(glm::length(on_wall) - 2.0f, 0.1f);
  // Guard: the range conversion. Comparing |x - c| with the raw z-depth would reject this point.
  EXPECT_EQ(w.Valid(on_wall, opt), 1.0f);
  // Behind the wall (occluded): invalid.
  EXPECT_EQ(w.Valid(on_wall * 1.1f, opt), 0.0f);
  // Slightly behind, within epsilon: valid.
  EXPECT_EQ(w.Valid(on_wall * (1.0f + 0.004f / glm::length(on_wall)), opt), 1.0f);
}

TEST(BlendMath, ValidityFieldOfViewAndBehind) {
  WallView w;
  EXPECT_EQ(w.Valid({0, 0, 2}), 1.0f);
  EXPECT_EQ(w.Valid({5, 0, 2}), 0.0f);   // outside the image
  EXPECT_EQ(w.Valid({0, 0, -2}), 0.0f);  // behind the camera
  EXPECT_EQ(w.Valid({0, 0, 0}), 0.0f);   // at the camera centre
}

TEST(BlendMath, ValidityInvalidDepthAndDiscontinuity) {
  WallView w;
  const glm::vec3 centre(0.0f, 0.0f, 2.0f);  // projects near pixel (15.5, 11.5) -> (16, 12)
  // NaN / zero / Inf depth at the sample: invalid, never NaN.
  for (float bad : {0.0f, std::numeric_limits<float>::quiet_NaN(),
                    std::numeric_limits<float>::infinity(), -1.0f}) {
    WallView v;
    v.depth[12 * 32 + 16] = bad;
    v.depth[12 * 32 + 15] = bad;
    v.depth[11 * 32 + 16] = bad;
    v.depth[11 * 32 + 15] = bad;
    EXPECT_EQ(v.Valid(centre), 0.0f) << bad;
  }
  // A depth jump 2 px away (beyond Δ_z): invalid; 3 px away: valid.
  WallView j2;
  for (int y = 0; y < 24; ++y)
    for (int x = 18; x < 32; ++x) j2.depth[y * 32 + x] = 5.0f;
  EXPECT_EQ(j2.Valid(centre), 0.0f);
  WallView j3;
  for (int y = 0; y < 24; ++y)
    for (int x = 19; x < 32; ++x) j3.depth[y * 32 + x] = 5.0f;
  EXPECT_EQ(j3.Valid(centre), 1.0f);
  // A small jump (below Δ_z) is fine.
  WallView small;
  for (int y = 0; y < 24; ++y)
    for (int x = 18; x < 32; ++x) small.depth[y * 32 + x] = 2.05f;
  EXPECT_EQ(small.Valid(centre), 1.0f);
}

TEST(BlendMath, BestNKeepsLargest) {
  BestN b = EmptyBestN();
  const float w[] = {0.2f, 0.0f, 0.9f, 0.5f, 0.1f, 0.7f};
  for (int i = 0; i < 6; ++i) InsertBest(b, 3, w[i], i);
  EXPECT_EQ(b.index[0], 2);
  EXPECT_EQ(b.index[1], 5);
  EXPECT_EQ(b.index[2], 3);
  BestN e = EmptyBestN();
  InsertBest(e, 3, 0.0f, 0);
  InsertBest(e, 3, std::numeric_limits<float>::quiet_NaN(), 1);
  EXPECT_EQ(e.index[0], -1);
}

TEST(BlendMath, ResolveAppliesExposureInLinear) {
  BlendAccumulator acc;
  // Two views of the same sRGB 0.5 surface with exposures 0.5 and 1.5, equal weights:
  // the blend is the linear value times the mean exposure 1.0.
  const glm::vec3 lin = SrgbToLinear(glm::vec3(0.5f));
  Accumulate(acc, lin, 0.5f, 1.0f);
  Accumulate(acc, lin, 1.5f, 1.0f);
  glm::vec3 out;
  ASSERT_TRUE(Resolve(acc, glm::vec3(0.0f), &out));
  EXPECT_NEAR(out.x, 0.5f, 1e-5f);
  // Empty: background, not covered.
  BlendAccumulator empty;
  EXPECT_FALSE(Resolve(empty, glm::vec3(0.25f), &out));
  EXPECT_EQ(out, glm::vec3(0.25f));
}

TEST(BlendMath, OptionsValidate) {
  BlendOptions o;
  EXPECT_TRUE(o.Validate().ok());
  o.lambda = 1.5f;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.n_best = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.discontinuity_delta_z_m = 0.0f;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.occlusion_epsilon_m = std::nanf("");
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace exo::blend
