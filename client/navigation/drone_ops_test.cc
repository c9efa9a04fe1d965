#include "client/navigation/drone_ops.h"

#include <gtest/gtest.h>

#include <cmath>

#include "client/navigation/navigation.h"
#include "common/camera.h"

namespace exo::nav {
namespace {

PinholeCamera Cam() { return PinholeCamera::FromFov(640, 480, 60.0 * M_PI / 180.0); }

// A camera at (1, 2, 3) turned 90° about y: its optical axis (+z) along world +x.
Rigid3d Pose() {
  Rigid3d p;
  p.rotation = glm::angleAxis(M_PI / 2, glm::dvec3(0, 1, 0));
  p.translation = {1, 2, 3};
  return p;
}

TEST(DroneOps, PixelRayThroughTheCentreIsTheOpticalAxis) {
  const PinholeCamera c = Cam();
  const Ray3 r = PixelRay(c, Pose(), {c.cx, c.cy});
  EXPECT_NEAR(glm::length(r.origin - glm::dvec3(1, 2, 3)), 0, 1e-12);
  EXPECT_NEAR(r.dir.x, 1, 1e-12);
  EXPECT_NEAR(glm::length(r.dir), 1, 1e-12);
}

TEST(DroneOps, GazeRayStartsOnTheXrayPlane) {
  const PinholeCamera c = Cam();
  const Rigid3d pose = Pose();
  for (glm::dvec2 uv : {glm::dvec2(c.cx, c.cy), glm::dvec2(10, 20), glm::dvec2(600, 470)}) {
    const Ray3 eye = GazeRay(c, pose, uv, 0.0);
    EXPECT_NEAR(glm::length(eye.origin - pose.translation), 0, 1e-12);
    const Ray3 r = GazeRay(c, pose, uv, 2.5);
    // Same direction, origin on the camera's plane z = 2.5, on the pixel's ray.
    EXPECT_NEAR(glm::length(r.dir - eye.dir), 0, 1e-12);
    const glm::dvec3 in_cam = pose.Inverse() * r.origin;
    EXPECT_NEAR(in_cam.z, 2.5, 1e-9);
    glm::dvec2 back;
    ASSERT_TRUE(c.Project(in_cam, &back));
    EXPECT_NEAR(back.x, uv.x, 1e-6);
    EXPECT_NEAR(back.y, uv.y, 1e-6);
  }
}

// Eq. (5.1) with the mouse as the hand: a drone on the cursor's ray at 3 m stays on the
// cursor's ray at 3 m when the cursor moves (|D_drone| / |D_hand| = 3 / 0.5).
TEST(DroneOps, DragMovesTheDroneWithTheCursorAtItsDistance) {
  const PinholeCamera c = Cam();
  const Rigid3d pose = Pose();
  const glm::dvec2 uv0(320, 240), uv1(420, 180);
  const glm::dvec3 drone = pose.translation + 3.0 * PixelRay(c, pose, uv0).dir;
  const MouseHand h = HandFromDrag(c, pose, uv0, 0.5, uv1, 0.5);
  EXPECT_NEAR(glm::length(h.hand - h.eye), 0.5, 1e-12);
  const PickPlacePreview p = PreviewPickAndPlace(drone, h.eye, h.hand, h.displacement);
  EXPECT_FALSE(p.guarded);
  EXPECT_NEAR(p.scale, 6.0, 1e-9);
  const glm::dvec3 expect = pose.translation + 3.0 * PixelRay(c, pose, uv1).dir;
  EXPECT_NEAR(glm::length(p.target - expect), 0, 1e-9);
  // The wheel pushes the hand along the ray: the drone goes 6x as far along it.
  const MouseHand push = HandFromDrag(c, pose, uv0, 0.5, uv0, 0.6);
  const PickPlacePreview q = PreviewPickAndPlace(drone, push.eye, push.hand, push.displacement);
  EXPECT_NEAR(glm::length(q.target - pose.translation), 3.6, 1e-9);
}

// The hard case: the hand at the eye (hand_m = 0) would divide by zero; the floor (0.1 m)
// guards it, and a huge ratio is capped (the server's PickAndPlaceOptions).
TEST(DroneOps, HandAtTheEyeIsGuarded) {
  const PinholeCamera c = Cam();
  const Rigid3d pose = Pose();
  const glm::dvec3 drone = pose.translation + glm::dvec3(2, 0, 0);
  const MouseHand h = HandFromDrag(c, pose, {320, 240}, 0.0, {320, 240}, 0.05);
  EXPECT_EQ(glm::length(h.hand - h.eye), 0.0);
  const PickPlacePreview p = PreviewPickAndPlace(drone, h.eye, h.hand, h.displacement);
  EXPECT_TRUE(p.guarded);
  EXPECT_NEAR(p.scale, 20.0, 1e-9);  // |drone - eye| / 0.1
  EXPECT_TRUE(std::isfinite(p.target.x) && std::isfinite(p.target.y) && std::isfinite(p.target.z));
  EXPECT_NEAR(glm::length(p.target - drone), 20.0 * 0.05, 1e-9);
  const glm::dvec3 far = pose.translation + glm::dvec3(1000, 0, 0);
  const PickPlacePreview capped =
      PreviewPickAndPlace(far, h.eye, h.eye + glm::dvec3(0.5, 0, 0), glm::dvec3(0, 1, 0));
  EXPECT_TRUE(capped.guarded);
  EXPECT_EQ(capped.scale, 50.0);
  const PickPlacePreview bad = PreviewPickAndPlace(drone, h.eye, glm::dvec3(NAN, 0, 0), {});
  EXPECT_EQ(bad.target, drone);
}

TEST(DroneOps, KeysAndGamepadAsModeTwoSticks) {
  JoypadKeys k;
  EXPECT_FALSE(k.any());
  EXPECT_TRUE(SticksFromKeys(k).zero());
  k.forward = true;
  k.turn_left = true;
  Sticks s = SticksFromKeys(k);
  EXPECT_EQ(s.right_y, 1.0);
  EXPECT_EQ(s.left_x, 1.0);  // + yaw rate = turn left
  EXPECT_EQ(s.right_x, 0.0);
  k.back = true;  // opposite keys cancel
  k.right = k.up = true;
  s = SticksFromKeys(k, 0.5);
  EXPECT_EQ(s.right_y, 0.0);
  EXPECT_EQ(s.right_x, 0.5);
  EXPECT_EQ(s.left_y, 0.5);
  // SDL axes: y down. Left stick right = turn right, up = climb; right stick up = forward.
  s = SticksFromGamepad(1.0, -1.0, 0.05, -0.5);
  EXPECT_EQ(s.left_x, -1.0);
  EXPECT_EQ(s.left_y, 1.0);
  EXPECT_EQ(s.right_x, 0.0);  // within the deadzone
  EXPECT_EQ(s.right_y, 0.5);
  EXPECT_TRUE(SticksFromGamepad(NAN, 0, 0, 0).zero());
}

TEST(DroneOps, XrayPlaneThroughThePickedPointOrInFront) {
  EXPECT_DOUBLE_EQ(XrayClipDistance(2.0, 0.3, 1.5), 2.3);
  EXPECT_DOUBLE_EQ(XrayClipDistance(std::nullopt, 0.3, 1.5), 1.5);
  EXPECT_DOUBLE_EQ(XrayClipDistance(-1.0, 0.3, 1.5), 1.5);
  EXPECT_DOUBLE_EQ(XrayClipDistance(std::nullopt, 0.3, 0.0), 0.05);
}

TEST(DroneOps, XrayHoleIsADiscAroundTheCursorInPictureFractions) {
  const glm::dvec2 c = XrayHoleCentre({479.5, 269.5}, 960, 540);  // the picture's centre
  EXPECT_DOUBLE_EQ(c.x, 0.5);
  EXPECT_DOUBLE_EQ(c.y, 0.5);
  const double r = 0.2;  // 108 px of 540
  EXPECT_TRUE(InsideXrayHole({479.5, 269.5}, 960, 540, c, r));
  EXPECT_TRUE(InsideXrayHole({479.5 + 107, 269.5}, 960, 540, c, r));
  EXPECT_FALSE(InsideXrayHole({479.5 + 109, 269.5}, 960, 540, c, r));
  EXPECT_FALSE(InsideXrayHole({479.5 + 80, 269.5 + 80}, 960, 540, c, r));  // 113 px away
  // The same disc at half the resolution (a moving frame): the same part of the picture.
  EXPECT_TRUE(InsideXrayHole({239.5 + 53, 134.5}, 480, 270, c, r));
  EXPECT_FALSE(InsideXrayHole({239.5 + 55, 134.5}, 480, 270, c, r));
  // A corner cursor: the disc is cut by the border, the far corner is outside.
  const glm::dvec2 k = XrayHoleCentre({0, 0}, 960, 540);
  EXPECT_TRUE(InsideXrayHole({0, 0}, 960, 540, k, r));
  EXPECT_FALSE(InsideXrayHole({959, 539}, 960, 540, k, r));
}

// Picking in X-ray mode skips the surfaces in front of the cut-away plane.
TEST(DroneOps, PickBeyondTheXrayPlane) {
  LumigraphModel m;
  m.grid.cell_size_m = 0.5;
  for (int k = 0; k < 2; ++k) {
    MeshChunk& c = m.chunks[k + 1];
    c.id = k + 1;
    const float z = k == 0 ? 2.0f : 4.0f;
    c.mesh.positions = {{-5, -5, z}, {5, -5, z}, {5, 5, z}, {-5, 5, z}};
    c.mesh.indices = {0, 1, 2, 0, 2, 3};
  }
  const PinholeCamera c = Cam();
  auto front = Pick(m, c, Rigid3d{}, {100, 100});
  ASSERT_TRUE(front);
  EXPECT_NEAR(front->z_depth_m, 2.0, 1e-9);
  auto behind = Pick(m, c, Rigid3d{}, {100, 100}, 2.3);
  ASSERT_TRUE(behind);
  EXPECT_NEAR(behind->z_depth_m, 4.0, 1e-9);
  EXPECT_EQ(behind->chunk_id, 2u);
  EXPECT_FALSE(Pick(m, c, Rigid3d{}, {100, 100}, 4.5));
}

}  // namespace
}  // namespace exo::nav
