#include "server/inpainting/roi.h"

#include <gtest/gtest.h>

#include "server/inpainting/test_scenes.h"

namespace exo::inpainting {
namespace {

using testing::RenderPlanes;
using testing::SmallCamera;
using testing::WorldPlane;

TEST(RoiTest, StrokeOnABoxExcludesTheWallBehind) {
  const PinholeCamera cam = SmallCamera();
  // A wall at 2 m and a box face at 1.5 m covering x < 0 (left half of the image).
  const std::vector<WorldPlane> planes = {
      {glm::dvec3(0, 0, -1), -2.0, nullptr},
      {glm::dvec3(0, 0, -1), -1.5, [](const glm::dvec3& p) { return p.x < 0.0; }}};
  const RgbdKeyframe f = RenderPlanes(planes, cam, Rigid3d::Identity());
  RoiOptions o;
  o.radius_px = 20;
  o.depth_tol_m = 0.1;
  o.dilate_px = 0;
  const std::vector<glm::dvec2> stroke = {{70.0, 60.0}};  // on the box, 10 px left of its edge
  auto roi = RoiFromStroke(stroke, f.depth_m, cam, o);
  ASSERT_TRUE(roi.ok()) << roi.status();
  int box = 0, wall = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      if (!roi->at(x, y)) continue;
      (f.depth_m.at(x, y) < 1.75f ? box : wall)++;
      EXPECT_LT(std::hypot(x - 70.0, y - 60.0), 20.0);
    }
  EXPECT_EQ(wall, 0);
  EXPECT_GT(box, 800);  // most of the 1257-px disc lies on the box
  // With a generous d_ROI the wall joins.
  o.depth_tol_m = 1.0;
  auto roi2 = RoiFromStroke(stroke, f.depth_m, cam, o);
  ASSERT_TRUE(roi2.ok());
  int all = 0;
  for (uint8_t v : roi2->span()) all += v != 0;
  EXPECT_GT(all, box + 200);
}

TEST(RoiTest, Errors) {
  const PinholeCamera cam = SmallCamera(40, 30);
  ImageF depth(40, 30, 1, 1.f);
  RoiOptions o;
  EXPECT_FALSE(RoiFromStroke({}, depth, cam, o).ok());
  const std::vector<glm::dvec2> outside = {{-50.0, -50.0}};
  EXPECT_FALSE(RoiFromStroke(outside, depth, cam, o).ok());
  o.radius_px = -1;
  const std::vector<glm::dvec2> in = {{10.0, 10.0}};
  EXPECT_FALSE(RoiFromStroke(in, depth, cam, o).ok());
}

}  // namespace
}  // namespace exo::inpainting
