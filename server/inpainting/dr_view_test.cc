// dr_view.h (issue 18): the diminished-reality look-up prefers views that observed the
// background, falls back on inpainted samples, skips a view where the point is occluded; the
// background depth warped from a keyframe; the gradient-domain blend meets the border.
#include "server/inpainting/dr_view.h"

#include <gtest/gtest.h>

namespace exo::inpainting {
namespace {

PinholeCamera SmallCamera() {
  PinholeCamera c;
  c.width = 32;
  c.height = 24;
  c.fx = c.fy = 30.0;
  c.cx = 15.5;
  c.cy = 11.5;
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
