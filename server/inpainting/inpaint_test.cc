#include "server/inpainting/inpaint.h"

#include <cmath>
#include <cstring>

#include <gtest/gtest.h>

#include "server/inpainting/depth_maps.h"
#include "server/inpainting/poisson.h"
#include "server/inpainting/test_scenes.h"

namespace exo::inpainting {
namespace {

using testing::RectMask;
using testing::RenderPlanes;
using testing::SmallCamera;
using testing::WorldPlane;

// A wall 2 m away, tilted 30 degrees about the vertical axis (world == camera at identity).
std::vector<WorldPlane> TiltedWall() {
  const glm::dvec3 n = glm::normalize(glm::dvec3(std::sin(0.5), 0.0, -std::cos(0.5)));
  return {{n, glm::dot(n, glm::dvec3(0, 0, 2.0)), nullptr}};
}

InpaintOptions FastOptions() {
  InpaintOptions o;
  o.num_threads = 2;
  return o;
}

double MeanAbsDepthErrorInMask(const ImageF& a, const ImageF& b, const ImageU8& mask) {
  double s = 0;
  int n = 0;
  for (int y = 0; y < mask.height(); ++y)
    for (int x = 0; x < mask.width(); ++x)
      if (mask.at(x, y) && b.at(x, y) > 0.f) {
        s += std::fabs(a.at(x, y) - b.at(x, y));
        ++n;
      }
  return n ? s / n : 0.0;
}

TEST(InpaintTest, TiltedPlaneDepthIsExactAndColourIsCopied) {
  const PinholeCamera cam = SmallCamera();
  const RgbdKeyframe truth = RenderPlanes(TiltedWall(), cam, Rigid3d::Identity());
  const ImageU8 mask = RectMask(cam.width, cam.height, 50, 40, 100, 80);
  auto r = InpaintKeyframe(truth, mask, FastOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  // Inverse depth is affine on a plane: the Poisson solve on copied inverse-depth gradients
  // reproduces the plane (up to float rounding).
  EXPECT_LT(MeanAbsDepthErrorInMask(r->depth_m, truth.depth_m, mask), 2e-4);
  for (int y = 40; y < 80; ++y) {
    for (int x = 50; x < 100; ++x) {
      const int sx = r->source.at(x, y, 0), sy = r->source.at(x, y, 1);
      ASSERT_GE(sx, 2);
      ASSERT_FALSE(mask.at(sx, sy));
      for (int k = 0; k < 3; ++k) ASSERT_EQ(r->color.at(x, y, k), truth.color.at(sx, sy, k));  // 4.11
    }
  }
  // The literal thesis domain (raw depth gradients copied from elsewhere on the plane) bends the
  // plane: clearly worse than inverse depth on the same source map.
  InpaintOptions lit = FastOptions();
  lit.depth_domain = DepthDomain::kDepth;
  auto r2 = InpaintKeyframe(truth, mask, lit);
  ASSERT_TRUE(r2.ok());
  EXPECT_GT(MeanAbsDepthErrorInMask(r2->depth_m, truth.depth_m, mask),
            MeanAbsDepthErrorInMask(r->depth_m, truth.depth_m, mask));
}

// Hard case: mask touching the image border. Guards: the target window is clipped to the image
// (Cost), and source patches keep their whole 5x5 window inside the image (source_ok).
TEST(InpaintTest, MaskTouchingTheBorder) {
  const PinholeCamera cam = SmallCamera();
  const RgbdKeyframe truth = RenderPlanes(TiltedWall(), cam, Rigid3d::Identity());
  ImageU8 mask = RectMask(cam.width, cam.height, 0, 0, 40, 30);
  for (int y = 90; y < 120; ++y)
    for (int x = 130; x < 160; ++x) mask.at(x, y) = 255;
  auto r = InpaintKeyframe(truth, mask, FastOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  for (int y = 0; y < cam.height; ++y) {
    for (int x = 0; x < cam.width; ++x) {
      if (!mask.at(x, y)) continue;
      const int sx = r->source.at(x, y, 0), sy = r->source.at(x, y, 1);
      ASSERT_TRUE(sx >= 2 && sy >= 2 && sx < cam.width - 2 && sy < cam.height - 2) << sx << "," << sy;
      ASSERT_GT(r->depth_m.at(x, y), 0.f);
      ASSERT_TRUE(std::isfinite(r->depth_m.at(x, y)));
    }
  }
  EXPECT_LT(MeanAbsDepthErrorInMask(r->depth_m, truth.depth_m, mask), 2e-3);
}

// Hard case (SPEC §11, mask touching the border), depth solve: T touches the frame's right and
// bottom edges, so only its upper-left border is Dirichlet. The known depth is a slanted plane
// (inverse depth affine in x, y), and the copied gradients are those of a fronto-parallel wall
// (0): what a real copy from another surface gives. Without a prior the solve continues the
// border value flat into the free corner (the drift of the f270_m test mask); the Neumann-share
// weighted plane prior (BuildSurfacePrior) keeps it on the plane.
// Guard: InpaintOptions::neumann_prior_weight / BuildSurfacePrior. Measured: mean relative
// depth error 4.0 % with the default prior, 12.3 % with it off (then the first EXPECT fails).
// The prior does not remove the error: at the free edge the natural boundary condition still
// asks for a zero slope, which the weight (0.01 * share^2, tuned on the real training masks)
// only partly overrides.
TEST(InpaintTest, BorderTouchingRegionIsAnchoredBySurfacePrior) {
  const int w = 160, h = 120;
  auto plane_q = [](int x, int y) { return 0.4 + 0.002 * x + 0.004 * y; };  // 1/m
  ImageU8 region(w, h, 1, 0);
  ImageF values(w, h, 1, std::numeric_limits<float>::quiet_NaN());
  ImageF gx(w, h, 1, 0.f), gy(w, h, 1, 0.f);  // copied gradients: a wall's (0)
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const bool t = x >= 60 && y >= 50;
      region.at(x, y) = t ? 255 : 0;
      if (!t) values.at(x, y) = static_cast<float>(plane_q(x, y));
    }
  auto solve = [&](const InpaintOptions& o, int* prior_pixels) {
    ImageF prior, prior_w;
    *prior_pixels = BuildSurfacePrior(region, values, 0, 0, w, h, o, &prior, &prior_w);
    PoissonProblem p;
    p.region = &region;
    p.values = &values;
    p.gx = &gx;
    p.gy = &gy;
    if (*prior_pixels > 0) {
      p.prior = &prior;
      p.prior_weight = &prior_w;
    }
    auto r = SolvePoisson(p, PoissonOptions{});
    EXPECT_TRUE(r.ok()) << r.status();
    double err = 0;  // mean relative depth error over T
    int n = 0;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        if (region.at(x, y)) {
          err += std::fabs(plane_q(x, y) / r->at(x, y) - 1.0);
          ++n;
        }
    return err / n;
  };
  InpaintOptions with;  // defaults: the prior is on
  ASSERT_GT(with.neumann_prior_weight, 0.0);
  int pixels_with = 0, pixels_without = 0;
  const double err_with = solve(with, &pixels_with);
  InpaintOptions without = with;
  without.neumann_prior_weight = 0.0;
  const double err_without = solve(without, &pixels_without);
  EXPECT_LT(err_with, 0.05);  // fails with the prior off
  EXPECT_GT(err_without, 0.1);
  EXPECT_EQ(pixels_without, 0);
  EXPECT_EQ(pixels_with, 100 * 70);  // every pixel of T (the known border lies outside T)
  RecordProperty("err_with", std::to_string(err_with));
  RecordProperty("err_without", std::to_string(err_without));

  // An enclosed region (no Neumann border) gets no term from the Neumann weight: the defaults
  // leave enclosed solves exactly as before.
  ImageU8 enclosed(w, h, 1, 0);
  for (int y = 40; y < 80; ++y)
    for (int x = 50; x < 110; ++x) enclosed.at(x, y) = 255;
  ImageF vals2(w, h, 1, 1.f), prior, prior_w;
  for (int y = 40; y < 80; ++y)
    for (int x = 50; x < 110; ++x) vals2.at(x, y) = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(BuildSurfacePrior(enclosed, vals2, 0, 0, w, h, with, &prior, &prior_w), 0);
}

// Hard case: mask covering the whole frame -> clear error, not a crash.
TEST(InpaintTest, MaskCoveringWholeFrameIsAClearError) {
  const PinholeCamera cam = SmallCamera(40, 30);
  const RgbdKeyframe f = RenderPlanes(TiltedWall(), cam, Rigid3d::Identity());
  auto r = InpaintKeyframe(f, ImageU8(40, 30, 1, 255), FastOptions());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("whole frame"), std::string::npos);
  EXPECT_FALSE(InpaintKeyframe(f, ImageU8(40, 30, 1, 0), FastOptions()).ok());  // empty mask
  EXPECT_FALSE(InpaintKeyframe(f, ImageU8(40, 29, 1, 0), FastOptions()).ok());  // wrong size
}

// Hard case: no valid source pixels. Guard: the empty source list check (without it the random
// initialisation indexes an empty list).
TEST(InpaintTest, NoValidSourceIsAClearError) {
  const PinholeCamera cam = SmallCamera(40, 30);
  RgbdKeyframe f = RenderPlanes(TiltedWall(), cam, Rigid3d::Identity());
  // Everything but a 3-px-wide strip is masked: no 5x5 window fits outside the mask.
  ImageU8 mask = RectMask(40, 30, 0, 0, 40, 30);
  for (int y = 0; y < 30; ++y)
    for (int x = 10; x < 13; ++x) mask.at(x, y) = 0;
  auto r = InpaintKeyframe(f, mask, FastOptions());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(r.status().message().find("no valid source"), std::string::npos);
  // No valid depth anywhere outside the mask: same clear error.
  f.depth_m = ImageF(40, 30, 1, 0.f);
  auto r2 = InpaintKeyframe(f, RectMask(40, 30, 10, 10, 20, 20), FastOptions());
  ASSERT_FALSE(r2.ok());
  EXPECT_EQ(r2.status().code(), absl::StatusCode::kFailedPrecondition);
}

// Hard case: 1-2 px slivers. The texture varies along x only, so a horizontal sliver has an
// exact answer (the pixel above); depth must be the plane. The mask pyramid is any-of-2x2 so
// slivers exist at every level; note that this test was checked to still pass with a
// top-left-only pooling (the full-resolution sweeps repair the random start), so it covers the
// outcome (exact fill, valid sources right next to the sliver), not that pooling rule.
TEST(InpaintTest, OneAndTwoPixelSlivers) {
  const PinholeCamera cam = SmallCamera();
  const std::vector<WorldPlane> wall = {{glm::dvec3(0, 0, -1), -2.0, nullptr}};
  auto stripes = [](const glm::dvec3& p) {
    const double a = std::sin(40.0 * p.x) + 0.5 * std::sin(97.0 * p.x + 1.0);
    return glm::dvec3(128 + 80 * a, 128 - 60 * a, 100 + 40 * std::sin(23.0 * p.x));
  };
  const RgbdKeyframe truth = RenderPlanes(wall, cam, Rigid3d::Identity(), stripes);
  ImageU8 mask(cam.width, cam.height, 1, 0);
  for (int x = 10; x < 150; ++x) mask.at(x, 30) = 255;                 // 1 px, horizontal
  for (int x = 10; x < 150; ++x) mask.at(x, 70) = mask.at(x, 71) = 255;  // 2 px, horizontal
  auto r = InpaintKeyframe(truth, mask, FastOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  double err = 0;
  int n = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x)
      if (mask.at(x, y)) {
        for (int k = 0; k < 3; ++k) err += std::abs(r->color.at(x, y, k) - truth.color.at(x, y, k));
        n += 3;
      }
  EXPECT_LT(err / n, 3.0);
  EXPECT_LT(MeanAbsDepthErrorInMask(r->depth_m, truth.depth_m, mask), 1e-4);
}

// Hard case: degenerate normals. Guard: 1/max(kappa, n . n'): opposite, orthogonal and zero
// normals cost 1/kappa instead of dividing by zero or going negative.
TEST(InpaintTest, GeometryCostKappaGuard) {
  const float up[3] = {0, 0, -1}, down[3] = {0, 0, 1}, side[3] = {1, 0, 0}, zero[3] = {0, 0, 0};
  EXPECT_FLOAT_EQ(GeometryCost(up, up, 1, 0.1f), 1.f);
  EXPECT_FLOAT_EQ(GeometryCost(up, down, 1, 0.1f), 10.f);
  EXPECT_FLOAT_EQ(GeometryCost(up, side, 1, 0.1f), 10.f);
  EXPECT_FLOAT_EQ(GeometryCost(up, zero, 1, 0.25f), 4.f);
  // Whole pipeline on a scene whose normals degenerate (a plane seen nearly edge-on next to a
  // fronto-parallel one): everything stays finite.
  const PinholeCamera cam = SmallCamera();
  const glm::dvec3 graze = glm::normalize(glm::dvec3(0.999, 0.0, -0.045));
  const std::vector<WorldPlane> planes = {
      {glm::dvec3(0, 0, -1), -3.0, nullptr},
      {graze, glm::dot(graze, glm::dvec3(0, 0, 1.5)), [](const glm::dvec3& p) { return p.z < 2.9; }}};
  const RgbdKeyframe f = RenderPlanes(planes, cam, Rigid3d::Identity());
  InpaintOptions o = FastOptions();
  o.kappa = 0.05;
  auto r = InpaintKeyframe(f, RectMask(cam.width, cam.height, 60, 40, 100, 80), o);
  ASSERT_TRUE(r.ok()) << r.status();
  for (float z : r->depth_m.span()) ASSERT_TRUE(std::isfinite(z));
  for (float v : r->normals.span()) ASSERT_TRUE(std::isfinite(v));
}

// The geometry term keeps the search on surfaces whose normals agree: a wall above a floor, both
// painted with the same pattern in image space (so colour alone cannot tell them apart), the
// mask inside the floor. Colour-only search takes matches from both; rho_g keeps it on the floor.
TEST(InpaintTest, GeometryTermPrefersMatchingNormals) {
  const PinholeCamera cam = SmallCamera();
  const glm::dvec3 floor_n = glm::normalize(glm::dvec3(0, -1, -0.15));
  const std::vector<WorldPlane> planes = {
      {glm::dvec3(0, 0, -1), -3.0, [](const glm::dvec3& p) { return p.y < 0.05; }},
      {floor_n, glm::dot(floor_n, glm::dvec3(0, 0.05, 3.0)), nullptr}};
  RgbdKeyframe f = RenderPlanes(planes, cam, Rigid3d::Identity());
  for (int y = 0; y < cam.height; ++y)  // periodic image-space pattern, 7 x 5 px
    for (int x = 0; x < cam.width; ++x) {
      const int u = x % 7, v = y % 5;
      // Plus pixel noise: with exact ties rho_t == 0 and the product rho_t * rho_g could not
      // prefer anything.
      const int noise = static_cast<int>(((static_cast<uint32_t>(x) * 73856093u) ^ (static_cast<uint32_t>(y) * 19349663u)) % 13u) - 6;
      f.color.at(x, y, 0) = static_cast<uint8_t>(30 * u + 20 + noise);
      f.color.at(x, y, 1) = static_cast<uint8_t>(40 * v + 10 - noise);
      f.color.at(x, y, 2) = static_cast<uint8_t>((u * v * 37) % 200 + 20 + noise);
    }
  const ImageU8 mask = RectMask(cam.width, cam.height, 40, 78, 120, 108);
  auto frac_on_floor = [&](const InpaintResult& r) {
    int on = 0, n = 0;
    for (int y = 78; y < 108; ++y)
      for (int x = 40; x < 120; ++x) {
        const int sx = r.source.at(x, y, 0), sy = r.source.at(x, y, 1);
        on += std::fabs(r.normals.at(sx, sy, 1) - static_cast<float>(floor_n.y)) < 0.02f;
        ++n;
      }
    return static_cast<double>(on) / n;
  };
  InpaintOptions geo = FastOptions();
  geo.kappa = 0.1;  // the floor/wall normals differ by 81 deg: penalty 1/max(0.1, 0.15) = 6.7
  auto with = InpaintKeyframe(f, mask, geo);
  ASSERT_TRUE(with.ok());
  EXPECT_GT(frac_on_floor(*with), 0.97);
  InpaintOptions colour_only = geo;
  colour_only.use_geometry = false;
  auto without = InpaintKeyframe(f, mask, colour_only);
  ASSERT_TRUE(without.ok());
  EXPECT_LT(frac_on_floor(*without), 0.8);
  // (Depth is exact either way here: a harmonic fill of a planar surround in inverse depth is
  // the plane itself, whatever gradients the sources give.)
}

// Hard case: depth in mm vs m. Guard 1: the units check (median depth) gives a clear error.
// Guard 2: every threshold is relative to depth, so the same scene 10x larger (still metres)
// gives the same source map and 10x the depth. The scene has a 2 cm (1 %) depth step: an absolute
// 5 cm discontinuity threshold would smooth across it at 1x and cut it at 10x, and the normals
// check below fails (checked by making the thresholds absolute).
TEST(InpaintTest, DepthUnitsAndScaleInvariance) {
  const PinholeCamera cam = SmallCamera();
  const std::vector<WorldPlane> planes = {
      {glm::dvec3(0, 0, -1), -2.0, [](const glm::dvec3& p) { return p.x < 0.0; }},
      {glm::dvec3(0, 0, -1), -2.02, nullptr}};
  const RgbdKeyframe f = RenderPlanes(planes, cam, Rigid3d::Identity());
  const ImageU8 mask = RectMask(cam.width, cam.height, 60, 40, 100, 80);
  RgbdKeyframe mm = f;
  for (float& z : mm.depth_m.span()) z *= 1000.f;
  auto bad = InpaintKeyframe(mm, mask, FastOptions());
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("millimetres"), std::string::npos);

  RgbdKeyframe big = f;
  for (float& z : big.depth_m.span()) z *= 10.f;
  // The normals themselves are scale invariant, step included.
  const ImageF n1 = NormalsFromDepth(f.depth_m, cam), n10 = NormalsFromDepth(big.depth_m, cam);
  for (size_t i = 0; i < n1.size(); ++i) ASSERT_NEAR(n1.data()[i], n10.data()[i], 1e-4) << i;
  auto a = InpaintKeyframe(f, mask, FastOptions());
  auto b = InpaintKeyframe(big, mask, FastOptions());
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_TRUE(a->source == b->source);
  EXPECT_TRUE(a->color == b->color);
  for (int y = 40; y < 80; ++y)
    for (int x = 60; x < 100; ++x) ASSERT_NEAR(b->depth_m.at(x, y), 10.f * a->depth_m.at(x, y), 1e-4 * b->depth_m.at(x, y));
}

// Determinism: same seed -> same output with 1, 2 and 3 threads.
TEST(InpaintTest, SameOutputWithOneAndTwoThreads) {
  const PinholeCamera cam = SmallCamera();
  const RgbdKeyframe f = RenderPlanes(TiltedWall(), cam, Rigid3d::Identity());
  const ImageU8 mask = RectMask(cam.width, cam.height, 30, 20, 110, 90);
  InpaintOptions o = FastOptions();
  o.seed = 1234;
  o.num_threads = 1;
  auto a = InpaintKeyframe(f, mask, o);
  o.num_threads = 2;
  auto b = InpaintKeyframe(f, mask, o);
  o.num_threads = 3;
  auto c = InpaintKeyframe(f, mask, o);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  EXPECT_TRUE(a->source == b->source);
  EXPECT_TRUE(a->color == b->color);
  EXPECT_TRUE(a->depth_m == b->depth_m);
  EXPECT_TRUE(a->source == c->source);
  o.seed = 99;
  auto d = InpaintKeyframe(f, mask, o);
  ASSERT_TRUE(d.ok());
  EXPECT_FALSE(a->source == d->source);  // the seed matters
}

// Keyframe propagation (4.3-4.6).
TEST(InpaintTest, PropagationReusesThePreviousMap) {
  const PinholeCamera cam = SmallCamera();
  const auto planes = TiltedWall();
  const RgbdKeyframe f0 = RenderPlanes(planes, cam, Rigid3d::Identity());
  const ImageU8 mask0 = RectMask(cam.width, cam.height, 50, 40, 100, 80);
  auto r0 = InpaintKeyframe(f0, mask0, FastOptions());
  ASSERT_TRUE(r0.ok());
  // Same pose: every pixel maps to exactly the previous source.
  auto same = InpaintKeyframe(f0, mask0, FastOptions(), &*r0);
  ASSERT_TRUE(same.ok());
  EXPECT_EQ(same->stats.propagated_pixels, same->stats.target_pixels);
  EXPECT_TRUE(same->source == r0->source);

  // Camera moved 5 cm right: the mask is the same 3D region seen from the new pose.
  Rigid3d pose1 = Rigid3d::Identity();
  pose1.translation = glm::dvec3(0.05, 0.0, 0.0);
  const RgbdKeyframe f1 = RenderPlanes(planes, cam, pose1);
  ImageU8 mask1(cam.width, cam.height, 1, 0);
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const glm::dvec3 pw = pose1 * cam.Unproject({x, y}, f1.depth_m.at(x, y));
      glm::dvec2 uv;
      if (cam.Project(pw, &uv) && cam.InImage(uv) && mask0.at(std::lround(uv.x), std::lround(uv.y)))
        mask1.at(x, y) = 255;
    }
  auto r1 = InpaintKeyframe(f1, mask1, FastOptions(), &*r0);
  ASSERT_TRUE(r1.ok()) << r1.status();
  EXPECT_GT(r1->stats.propagated_pixels, 0.9 * r1->stats.target_pixels);
  EXPECT_LT(MeanAbsDepthErrorInMask(r1->depth_m, f1.depth_m, mask1), 2e-3);
  // Consistency: a propagated pixel's source is the previous source's 3D point seen in frame 1.
  int checked = 0;
  for (int y = 0; y < cam.height; y += 3)
    for (int x = 0; x < cam.width; x += 3) {
      if (!mask1.at(x, y)) continue;
      const glm::dvec3 pw = pose1 * cam.Unproject({x, y}, f1.depth_m.at(x, y));
      glm::dvec2 uv0;
      ASSERT_TRUE(cam.Project(pw, &uv0));
      const int u0x = std::lround(uv0.x), u0y = std::lround(uv0.y);
      if (!mask0.at(u0x, u0y)) continue;
      const int s0x = r0->source.at(u0x, u0y, 0), s0y = r0->source.at(u0x, u0y, 1);
      const glm::dvec3 ps = cam.Unproject({s0x, s0y}, f0.depth_m.at(s0x, s0y));
      glm::dvec2 uvs;
      ASSERT_TRUE(cam.Project(pose1.Inverse() * ps, &uvs));
      // Sources that leave the image (or fall into T) in frame 1 are searched afresh.
      if (!cam.InImage(uvs, 3.0) || mask1.at(std::lround(uvs.x), std::lround(uvs.y))) continue;
      EXPECT_NEAR(r1->source.at(x, y, 0), uvs.x, 1.51);
      EXPECT_NEAR(r1->source.at(x, y, 1), uvs.y, 1.51);
      ++checked;
    }
  EXPECT_GT(checked, 50);
}

// Robust gradient fusion (4.13-4.16 with a discontinuity test). Guards: dropping the sample
// that crossed a jump at its source, keeping the smaller of two disagreeing samples, and the
// jump weight; with kMean the first two cases return the (wrong) average instead.
TEST(InpaintTest, RobustGradientFusion) {
  InpaintOptions o;  // kRobust, jump_rel 0.02, jump_weight 0.01
  const float ref = 0.5f;  // inverse depth of a surface at 2 m
  // Agreeing smooth samples: their mean, weight 1.
  FusedGradient a = FuseGradientSamples(true, 0.001f, ref, true, 0.003f, ref, o);
  EXPECT_FLOAT_EQ(a.g, 0.002f);
  EXPECT_FLOAT_EQ(a.weight, 1.f);
  // One sample crossed an occlusion edge (0.2 = 40 % of the value): the other one is kept.
  FusedGradient b = FuseGradientSamples(true, 0.2f, ref, true, 0.001f, ref, o);
  EXPECT_FLOAT_EQ(b.g, 0.001f);
  EXPECT_FLOAT_EQ(b.weight, 1.f);
  // Both jumps, disagreeing: the smaller, down-weighted.
  FusedGradient c = FuseGradientSamples(true, 0.3f, ref, true, -0.1f, ref, o);
  EXPECT_FLOAT_EQ(c.g, -0.1f);
  EXPECT_FLOAT_EQ(c.weight, 0.01f);
  // A single sample that is a jump (pair on T's border): kept, down-weighted.
  FusedGradient d = FuseGradientSamples(false, 0.f, 0.f, true, 0.2f, ref, o);
  EXPECT_FLOAT_EQ(d.g, 0.2f);
  EXPECT_FLOAT_EQ(d.weight, 0.01f);
  // Scale invariance: the same relative step in millimetres-as-metres scale gives the same choice.
  FusedGradient e = FuseGradientSamples(true, 200.f, 500.f, true, 1.f, 500.f, o);
  EXPECT_FLOAT_EQ(e.g, 1.f);
  // The thesis' mean for comparison.
  InpaintOptions m;
  m.gradient_fusion = GradientFusion::kMean;
  EXPECT_FLOAT_EQ(FuseGradientSamples(true, 0.2f, ref, true, 0.f, ref, m).g, 0.1f);
  EXPECT_FLOAT_EQ(FuseGradientSamples(true, 0.2f, ref, true, 0.f, ref, m).weight, 1.f);
}

// The same keyframe inpainted with the layered depth solve on and off (FastOptions otherwise).
std::pair<absl::StatusOr<InpaintResult>, absl::StatusOr<InpaintResult>> LayeredAndSingle(
    const RgbdKeyframe& kf, const ImageU8& mask) {
  InpaintOptions layered = FastOptions(), single = FastOptions();
  layered.layered_depth = true;
  single.layered_depth = false;
  return {InpaintKeyframe(kf, mask, layered), InpaintKeyframe(kf, mask, single)};
}

// Session 5, layered depth: an occlusion edge inside T. A box face 1.5 m away covers the left
// half of the view in front of a wall 3 m away; T straddles the edge, so its measured ring holds
// both surfaces. One surface carried across T (the single solve) blends them; the layered solve
// clusters the ring into two layers, cuts T between them and solves each on its own (guard:
// layered_depth / SetupLayers: with it off the first EXPECT fails).
TEST(InpaintTest, LayeredDepthPlacesAnOcclusionEdgeInsideTheMask) {
  const PinholeCamera cam = SmallCamera();
  std::vector<WorldPlane> planes = {
      {glm::dvec3(0, 0, 1), 1.5, [](const glm::dvec3& p) { return p.x < 0.0; }},
      {glm::dvec3(0, 0, 1), 3.0, nullptr}};
  const RgbdKeyframe truth = RenderPlanes(planes, cam, Rigid3d::Identity());
  const ImageU8 mask = RectMask(cam.width, cam.height, 50, 30, 110, 90);
  auto [rl, rs] = LayeredAndSingle(truth, mask);
  ASSERT_TRUE(rl.ok()) << rl.status();
  ASSERT_TRUE(rs.ok()) << rs.status();
  const double err_layered = MeanAbsDepthErrorInMask(rl->depth_m, truth.depth_m, mask);
  const double err_single = MeanAbsDepthErrorInMask(rs->depth_m, truth.depth_m, mask);
  RecordProperty("err_layered_m", std::to_string(err_layered));
  RecordProperty("err_single_m", std::to_string(err_single));
  EXPECT_LT(err_layered, 0.25 * err_single) << "layered " << err_layered << " single " << err_single;
  EXPECT_LT(err_layered, 0.1);
  EXPECT_EQ(rl->stats.depth_layers, 2);
  ASSERT_EQ(rl->stats.layer_pixels.size(), 2u);
  EXPECT_GT(rl->stats.layer_pixels[0], 1000);  // both layers hold a real part of T (60 x 60)
  EXPECT_GT(rl->stats.layer_pixels[1], 1000);
  EXPECT_EQ(rs->stats.depth_layers, 1);
  // Colour does not depend on the depth solve.
  for (size_t i = 0; i < rl->color.bytes(); ++i) ASSERT_EQ(rl->color.data()[i], rs->color.data()[i]);
  // T's centre lies ~30 px from every seed (the cut is extrapolated that far).
  EXPECT_GT(rl->stats.layer_seed_dist_px, 10.f);
  InpaintOptions layered = FastOptions();
  layered.layered_depth = true;
  // Same output with one and two threads.
  InpaintOptions one = layered;
  one.num_threads = 1;
  auto r1 = InpaintKeyframe(truth, mask, one);
  ASSERT_TRUE(r1.ok());
  for (size_t i = 0; i < rl->depth_m.size(); ++i) ASSERT_EQ(rl->depth_m.data()[i], r1->depth_m.data()[i]);
}

// One surface around T (a tilted wall): the ring forms one layer and the layered option leaves
// the result bit-identical to the single-surface solve.
TEST(InpaintTest, LayeredDepthWithOneLayerIsTheSingleSolve) {
  const PinholeCamera cam = SmallCamera();
  const RgbdKeyframe truth = RenderPlanes(TiltedWall(), cam, Rigid3d::Identity());
  const ImageU8 mask = RectMask(cam.width, cam.height, 40, 30, 100, 80);
  auto [rl, rs] = LayeredAndSingle(truth, mask);
  ASSERT_TRUE(rl.ok()) << rl.status();
  ASSERT_TRUE(rs.ok()) << rs.status();
  EXPECT_EQ(rl->stats.depth_layers, 1);
  EXPECT_TRUE(rl->layers.empty());
  for (size_t i = 0; i < rl->depth_m.size(); ++i) ASSERT_EQ(rl->depth_m.data()[i], rs->depth_m.data()[i]);
}

TEST(InpaintTest, OptionsValidate) {
  InpaintOptions o;
  EXPECT_TRUE(o.Validate().ok());
  o.kappa = 0.0;
  EXPECT_FALSE(o.Validate().ok());
  o = InpaintOptions{};
  o.w = 1.5;
  EXPECT_FALSE(o.Validate().ok());
  o = InpaintOptions{};
  o.num_threads = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = InpaintOptions{};
  o.neumann_prior_weight = -1.0;
  EXPECT_FALSE(o.Validate().ok());
  o = InpaintOptions{};
  o.max_layers = 4;
  EXPECT_FALSE(o.Validate().ok());
  o = InpaintOptions{};
  o.layer_gap_rel = 0.0;
  EXPECT_FALSE(o.Validate().ok());
  o = InpaintOptions{};
  o.layer_jump_factor = 2.0;
  EXPECT_FALSE(o.Validate().ok());
}

TEST(DepthMapsTest, PushPullFillsHolesAndNormalsFacePlane) {
  const PinholeCamera cam = SmallCamera(80, 60);
  RgbdKeyframe f = RenderPlanes(TiltedWall(), cam, Rigid3d::Identity());
  const ImageF truth = f.depth_m;
  for (int y = 20; y < 30; ++y)
    for (int x = 20; x < 30; ++x) f.depth_m.at(x, y) = 0.f;
  std::vector<uint8_t> all(80 * 60, 1);
  EXPECT_EQ(PrefillDepth(f.depth_m, all, all), 100);
  for (int y = 20; y < 30; ++y)
    for (int x = 20; x < 30; ++x) EXPECT_NEAR(f.depth_m.at(x, y), truth.at(x, y), 0.1);  // push-pull is smooth, not planar
  const ImageF n = NormalsFromDepth(truth, cam);
  const glm::dvec3 expect = glm::normalize(glm::dvec3(std::sin(0.5), 0.0, -std::cos(0.5)));
  for (int y = 5; y < 55; y += 5)
    for (int x = 5; x < 75; x += 5)
      EXPECT_GT(n.at(x, y, 0) * expect.x + n.at(x, y, 1) * expect.y + n.at(x, y, 2) * expect.z, 0.999);
}

// The smoothing of NormalsFromDepth runs four columns at a time inside the frame and one at a
// time near its left and right edges. Zero-depth columns added on the left (the principal point
// shifted with them) change neither the sums (a zero neighbour is never averaged) nor the normals
// (a pixel without depth is unusable, as one outside the frame), but move every pixel to another
// lane or to the scalar edge loop: the normals must stay the same bit for bit.
TEST(DepthMapsTest, NormalsDoNotDependOnTheColumnOffset) {
  const PinholeCamera cam = SmallCamera(61, 23);
  ImageF depth(cam.width, cam.height, 1, 0.f);
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      float z = 1.5f + 0.002f * x * x / 7.f + 0.01f * std::sin(0.7f * y + 0.3f * x);
      if (x > 30) z += 0.2f;                           // a depth step
      if ((x * 5 + y * 3) % 23 == 0) z = 0.f;          // holes
      if (x == 40 && y == 7) z = std::nanf("");        // invalid
      depth.at(x, y) = z;
    }
  const ImageF base = NormalsFromDepth(depth, cam);
  for (int pad = 1; pad <= 5; ++pad) {
    PinholeCamera pc = cam;
    pc.width += pad;
    pc.cx += pad;
    ImageF padded(pc.width, pc.height, 1, 0.f);
    for (int y = 0; y < cam.height; ++y)
      for (int x = 0; x < cam.width; ++x) padded.at(x + pad, y) = depth.at(x, y);
    const ImageF n = NormalsFromDepth(padded, pc, 2, 0.05f, 1 + pad % 2);
    int differ = 0;
    for (int y = 0; y < cam.height; ++y)
      for (int x = 0; x < cam.width; ++x)
        for (int k = 0; k < 3; ++k)
          differ += std::memcmp(&base.at(x, y, k), &n.at(x + pad, y, k), sizeof(float)) != 0;
    EXPECT_EQ(differ, 0) << "pad " << pad;
  }
}

// The units check compares the median (the n/2-th smallest valid depth) with the limit.
TEST(DepthMapsTest, DepthUnitsCheckAtTheMedian) {
  auto check = [](std::vector<float> v) {
    ImageF d(static_cast<int>(v.size()), 1, 1, 0.f);
    for (size_t i = 0; i < v.size(); ++i) d.data()[i] = v[i];
    return CheckDepthUnits(d, 100.0).ok();
  };
  EXPECT_TRUE(check({1.f, 1.f, 200.f}));
  EXPECT_FALSE(check({1.f, 200.f}));  // sorted {1, 200}: index 1
  EXPECT_FALSE(check({200.f, 1.f, 200.f}));
  EXPECT_TRUE(check({0.f, 0.f, 200.f, 1.f, 1.f, std::nanf("")}));  // {1, 1, 200}
  EXPECT_TRUE(check({100.f, 100.f}));  // at the limit: not above it
  EXPECT_FALSE(check({100.0001f, 100.0001f, 1.f}));
  EXPECT_TRUE(check({0.f, 0.f}));
  EXPECT_FALSE(check({1.f, -1.f}));
}

}  // namespace
}  // namespace exo::inpainting
