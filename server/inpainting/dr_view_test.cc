// dr_view.h (issue 18): the diminished-reality look-up prefers views that observed the
// background, falls back on inpainted samples, skips a view where the point is occluded; the
// background depth warped from a keyframe; the gradient-domain blend meets the border.
#include "server/inpainting/dr_view.h"

#include <gtest/gtest.h>

#include <cstring>
#include <random>

#include <glm/gtc/quaternion.hpp>

#include "common/image_fill.h"

namespace exo::inpainting {
namespace {

PinholeCamera SmallCamera(int w = 32, int h = 24, double f = 30.0) {
  PinholeCamera c;
  c.width = w;
  c.height = h;
  c.fx = c.fy = f;
  c.cx = 0.5 * (w - 1);
  c.cy = 0.5 * (h - 1);
  return c;
}

DrView FlatView(const PinholeCamera& cam, double x, uint8_t grey, float depth, bool inpainted) {
  DrView v;
  v.cam = cam;
  v.world_from_cam = Rigid3d::Identity();
  v.world_from_cam.translation = {x, 0, 0};
  v.cam_from_world = v.world_from_cam.Inverse();
  v.color = ImageU8(cam.width, cam.height, 3, grey);
  v.depth = ImageF(cam.width, cam.height, 1, depth);
  if (inpainted) v.hallucinated = ImageU8(cam.width, cam.height, 1, 255);
  return v;
}

ImageU8 CentreBlock(const PinholeCamera& cam) {
  ImageU8 m(cam.width, cam.height, 1, 0);
  for (int y = 8; y < 16; ++y)
    for (int x = 12; x < 20; ++x) m.at(x, y) = 255;
  return m;
}

TEST(DrView, ObservedViewWinsOverInpaintedAndOccludedFallsBack) {
  const PinholeCamera cam = SmallCamera();
  const DrView keyframe = FlatView(cam, 0.0, 100, 2.f, /*inpainted=*/true);
  DrView observation = FlatView(cam, 0.1, 200, 2.f, /*inpainted=*/false);
  const ImageU8 region = CentreBlock(cam);
  const ImageF depth(cam.width, cam.height, 1, 2.f);
  ImageU8 color(cam.width, cam.height, 3, 0), observed(cam.width, cam.height, 1, 0),
      filled(cam.width, cam.height, 1, 0);
  // The keyframe comes first (nearer), but its samples are inpainted: the observation wins.
  LookUpInViews({&keyframe, &observation}, cam, Rigid3d::Identity(), region, depth, &color,
                &observed, &filled);
  EXPECT_EQ(color.at(15, 12, 0), 200);
  EXPECT_EQ(observed.at(15, 12), 255);
  EXPECT_EQ(filled.at(15, 12), 255);
  EXPECT_EQ(filled.at(2, 2), 0);  // outside the region: untouched
  // An occluder 1 m in front in the observation: the point is not visible there.
  observation.depth = ImageF(cam.width, cam.height, 1, 1.f);
  LookUpInViews({&keyframe, &observation}, cam, Rigid3d::Identity(), region, depth, &color,
                &observed, &filled);
  EXPECT_EQ(color.at(15, 12, 0), 100);
  EXPECT_EQ(observed.at(15, 12), 0);
  EXPECT_EQ(filled.at(15, 12), 255);
  // No view at all: nothing filled.
  LookUpInViews({}, cam, Rigid3d::Identity(), region, depth, &color, &observed, &filled);
  EXPECT_EQ(filled.at(15, 12), 0);
}

TEST(DrView, BackgroundDepthFromAMovedKeyframe) {
  const PinholeCamera cam = SmallCamera();
  // A fronto-parallel wall at z = 2 seen by a keyframe 10 cm to the side; the frame's own depth
  // in the ROI is an object at 1 m (to be replaced).
  const DrView keyframe = FlatView(cam, 0.1, 100, 2.f, true);
  const ImageU8 roi = CentreBlock(cam);
  ImageF frame_depth(cam.width, cam.height, 1, 2.f);
  for (size_t i = 0; i < roi.size(); ++i)
    if (roi.data()[i]) frame_depth.data()[i] = 1.f;
  const ImageF d = WarpBackgroundDepth(keyframe, cam, Rigid3d::Identity(), roi, frame_depth);
  for (int y = 8; y < 16; ++y)
    for (int x = 12; x < 20; ++x) EXPECT_NEAR(d.at(x, y), 2.f, 1e-3) << x << "," << y;
  EXPECT_FLOAT_EQ(d.at(0, 0), 2.f);
}

// The reference of WarpBackgroundDepth: every keyframe pixel splatted (full-frame z-buffer), the
// dense push-pull over the whole frame, the two fixed-point steps over the whole frame. The
// function warps only the pixels that can land on the ROI's box and fills the gaps sparsely:
// the same depth bit for bit, frame holes outside the ROI included.
ImageF WarpReference(const DrView& kf, const PinholeCamera& cam, const Rigid3d& pose,
                     const ImageU8& roi, const ImageF& frame_depth) {
  const int w = cam.width, h = cam.height;
  ImageF d(w, h, 1, 0.f), zbuf(w, h, 1, 1e30f);
  for (size_t i = 0; i < d.size(); ++i) d.data()[i] = roi.data()[i] ? 0.f : frame_depth.data()[i];
  const Rigid3d cam_from_kf = pose.Inverse() * kf.world_from_cam;
  for (int y = 0; y < kf.cam.height; ++y)
    for (int x = 0; x < kf.cam.width; ++x) {
      const float z = kf.depth.at(x, y);
      glm::dvec2 uv;
      const glm::dvec3 p = cam_from_kf * kf.cam.Unproject({x, y}, z);
      if (!(z > 0.f) || !cam.Project(p, &uv)) continue;
      const int u = static_cast<int>(std::lround(uv.x)), v = static_cast<int>(std::lround(uv.y));
      if (!d.Contains(u, v) || !roi.at(u, v) || p.z >= zbuf.at(u, v)) continue;
      zbuf.at(u, v) = d.at(u, v) = static_cast<float>(p.z);
    }
  std::vector<uint8_t> known(d.size());
  for (size_t i = 0; i < d.size(); ++i) known[i] = d.data()[i] > 0.f;
  PushPullFill(std::span<float>(d.data(), d.size()), 1, known, w, h, PullFilter::kBilinear);
  const Rigid3d kf_from_cam = cam_from_kf.Inverse();
  for (int it = 0; it < 2; ++it)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        glm::dvec2 uv;
        if (!roi.at(x, y) || !(d.at(x, y) > 0.f) ||
            !kf.cam.Project(kf_from_cam * cam.Unproject({x, y}, d.at(x, y)), &uv) ||
            !kf.cam.InImage(uv, 1.0))
          continue;
        const int x0 = static_cast<int>(uv.x), y0 = static_cast<int>(uv.y);
        const float z00 = kf.depth.at(x0, y0), z10 = kf.depth.at(x0 + 1, y0),
                    z01 = kf.depth.at(x0, y0 + 1), z11 = kf.depth.at(x0 + 1, y0 + 1);
        if (!(z00 > 0.f && z10 > 0.f && z01 > 0.f && z11 > 0.f)) continue;
        if (std::max({z00, z10, z01, z11}) - std::min({z00, z10, z01, z11}) >
            0.05f * std::min({z00, z10, z01, z11}))
          continue;
        const double ax = uv.x - x0, ay = uv.y - y0;
        const double z = (1 - ay) * ((1 - ax) * z00 + ax * z10) + ay * ((1 - ax) * z01 + ax * z11);
        const glm::dvec3 q = cam_from_kf * kf.cam.Unproject(uv, z);
        if (q.z > 0) d.at(x, y) = static_cast<float>(q.z);
      }
  return d;
}

TEST(DrView, BackgroundDepthEqualsTheWholeFrameWarp) {
  const PinholeCamera cam = SmallCamera(96, 72, 80.0);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int sparse = 0, dense = 0;
  for (int trial = 0; trial < 40; ++trial) {
    DrView kf = FlatView(cam, 0.0, 100, 2.f, true);
    // A bumpy surface with a step (depth edges) and a few holes.
    for (int y = 0; y < cam.height; ++y)
      for (int x = 0; x < cam.width; ++x) {
        float z = 2.f + 0.3f * std::sin(0.2f * x + trial) + 0.2f * std::cos(0.15f * y);
        if (x > 60 && y < 30) z -= 0.6f;
        if ((x * 7 + y * 13 + trial) % 97 == 0) z = 0.f;
        kf.depth.at(x, y) = z;
      }
    const glm::dvec3 axis = glm::normalize(glm::dvec3(u(rng), u(rng), u(rng)));
    Rigid3d pose;
    pose.rotation = glm::angleAxis(0.25 * u(rng), axis);
    pose.translation = {0.3 * u(rng), 0.2 * u(rng), 0.3 * u(rng)};
    ImageU8 roi(cam.width, cam.height, 1, 0);
    for (int b = 0; b < 3; ++b) {
      const int cx = 10 + static_cast<int>(38 * (1 + u(rng))), cy = 8 + static_cast<int>(28 * (1 + u(rng)));
      const int rx = 3 + trial % 11, ry = 2 + (trial * 3) % 9;
      for (int y = std::max(0, cy - ry); y < std::min(cam.height, cy + ry); ++y)
        for (int x = std::max(0, cx - rx); x < std::min(cam.width, cx + rx); ++x) roi.at(x, y) = 255;
    }
    // The frame's depth outside the ROI: a wall with sensor holes (every 3rd trial: many, which
    // takes the dense push-pull).
    ImageF frame_depth(cam.width, cam.height, 1, 2.5f);
    int holes = 0;
    for (int y = 0; y < cam.height; ++y)
      for (int x = 0; x < cam.width; ++x)
        if (trial % 3 == 0 ? (x + y) % 5 == 0 : (x * 31 + y * 17 + trial) % 211 == 0) {
          frame_depth.at(x, y) = 0.f;
          ++holes;
        }
    const ImageF want = WarpReference(kf, cam, pose, roi, frame_depth);
    const ImageF got = WarpBackgroundDepth(kf, cam, pose, roi, frame_depth);
    ASSERT_EQ(want.size(), got.size());
    int differ = 0;
    for (size_t i = 0; i < want.size(); ++i)
      differ += std::memcmp(&want.data()[i], &got.data()[i], sizeof(float)) != 0;
    EXPECT_EQ(differ, 0) << "trial " << trial;
    (trial % 3 == 0 ? dense : sparse) += holes > 0;
  }
  EXPECT_GT(sparse, 0);
  EXPECT_GT(dense, 0);
}

TEST(DrView, PoissonBlendMeetsTheBorder) {
  const PinholeCamera cam = SmallCamera();
  const ImageU8 roi = CentreBlock(cam);
  // A guide 50 grey levels darker than the frame everywhere: the blend removes the offset.
  ImageU8 guide(cam.width, cam.height, 3, 100), frame(cam.width, cam.height, 3, 150);
  for (int x = 12; x < 20; ++x) guide.at(x, 12, 1) = 140;  // a stripe keeps its gradient
  ASSERT_TRUE(PoissonBlendColor(guide, roi, &frame).ok());
  EXPECT_NEAR(frame.at(15, 9, 0), 150, 1);
  EXPECT_GT(frame.at(15, 12, 1), frame.at(15, 10, 1) + 20);
  EXPECT_EQ(frame.at(2, 2, 0), 150);
  ImageU8 wrong(8, 8, 3, 0);
  EXPECT_EQ(PoissonBlendColor(guide, roi, &wrong).code(), absl::StatusCode::kInvalidArgument);
}

// The live view's rounding is std::lround's: halves away from zero, every representable
// neighbour of a half, negatives, and the library's own fallback beyond 2^52.
TEST(DrView, RoundHalfAwayIsLround) {
  std::vector<double> xs = {0.0, -0.0, 0.5, -0.5, 1.5, -1.5, 2.5, 254.5, 255.49999999999997,
                            0.49999999999999994, -0.49999999999999994, 1e15 + 0.5, 4503599627370497.0,
                            -4503599627370497.0, 1e300, -1e300};
  for (int i = -2000; i <= 2000; ++i) {
    const double h = i + 0.5;
    xs.push_back(h);
    xs.push_back(std::nextafter(h, -1e9));
    xs.push_back(std::nextafter(h, 1e9));
    xs.push_back(i * 0.37);
  }
  for (double x : xs) EXPECT_EQ(RoundHalfAway(x), std::lround(x)) << x;
  // Floats widened to double round as lroundf does.
  for (float f : {0.5f, 2.5f, 127.49999f, 127.5f, -3.5f, std::nextafter(0.5f, 0.f)})
    EXPECT_EQ(RoundHalfAway(f), std::lroundf(f)) << f;
}

}  // namespace
}  // namespace exo::inpainting
