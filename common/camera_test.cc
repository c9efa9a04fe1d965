#include "common/camera.h"

#include <gtest/gtest.h>

namespace exo {
namespace {

PinholeCamera Kinect() { return {585, 585, 320, 240, 640, 480}; }

TEST(PinholeCamera, ProjectUnprojectRoundTrip) {
  const PinholeCamera cam = Kinect();
  for (double z : {0.3, 1.0, 7.5, 120.0}) {
    for (glm::dvec2 uv : {glm::dvec2{0, 0}, glm::dvec2{639, 479}, glm::dvec2{123.25, 400.75}}) {
      const glm::dvec3 p = cam.Unproject(uv, z);
      EXPECT_DOUBLE_EQ(p.z, z);
      glm::dvec2 back;
      ASSERT_TRUE(cam.Project(p, &back));
      EXPECT_NEAR(back.x, uv.x, 1e-9);
      EXPECT_NEAR(back.y, uv.y, 1e-9);
    }
  }
}

TEST(PinholeCamera, BehindCameraDoesNotProject) {
  glm::dvec2 uv;
  EXPECT_FALSE(Kinect().Project({0, 0, -1}, &uv));
  EXPECT_FALSE(Kinect().Project({0, 0, 0}, &uv));
}

TEST(PinholeCamera, RangeAndZDepthConvertConsistently) {
  const PinholeCamera cam = Kinect();
  // At the principal point range == z-depth.
  EXPECT_DOUBLE_EQ(cam.RangeFromZDepth({320, 240}, 2.0), 2.0);
  // At a corner range > z-depth and equals the Euclidean norm of the unprojected point.
  const glm::dvec2 uv{0, 0};
  const double range = cam.RangeFromZDepth(uv, 2.0);
  EXPECT_NEAR(range, glm::length(cam.Unproject(uv, 2.0)), 1e-12);
  EXPECT_GT(range, 2.0);
  EXPECT_NEAR(cam.ZDepthFromRange(uv, range), 2.0, 1e-12);
}

TEST(PinholeCamera, ValidateRejectsMissingIntrinsics) {
  PinholeCamera cam;
  EXPECT_FALSE(cam.Validate().ok());
  cam = Kinect();
  EXPECT_TRUE(cam.Validate().ok());
  cam.fx = std::nan("");
  EXPECT_FALSE(cam.Validate().ok());
}

TEST(PinholeCamera, ScaledKeepsRaysThroughPixelCorners) {
  const PinholeCamera cam = Kinect();
  const PinholeCamera half = cam.Scaled(160, 120);
  // The ray through the image corner (-0.5,-0.5) is the same at both resolutions.
  const glm::dvec3 a = cam.RayZ1({-0.5, -0.5});
  const glm::dvec3 b = half.RayZ1({-0.5, -0.5});
  EXPECT_NEAR(a.x, b.x, 1e-12);
  EXPECT_NEAR(a.y, b.y, 1e-12);
}

}  // namespace
}  // namespace exo
