#include "server/control/interactions.h"

#include <gtest/gtest.h>

#include "common/drone/test_util.h"
#include "server/control/safe_flight.h"

namespace exo::control {
namespace {

using testing::AddQuad;

// z up: a wall at x = 3 (facing -x), a floor at z = 0, a 45° ramp at y in [5, 7].
MeshRaycaster ZUpScene() {
  TriangleMesh m;
  AddQuad(&m, {3, -5, 0}, {3, 5, 0}, {3, 5, 3}, {3, -5, 3});
  AddQuad(&m, {-5, -5, 0}, {3, -5, 0}, {3, 5, 0}, {-5, 5, 0});
  return MeshRaycaster(m);
}

TEST(PickAndPlace, ScalesTheHandDisplacementByTheDistanceRatio) {
  auto r = PickAndPlace({4, 0, 0}, {0, 0, 0}, {0.5, 0, 0}, {0, 0.1, 0});
  ASSERT_TRUE(r.ok());
  EXPECT_DOUBLE_EQ(r->scale, 8.0);
  EXPECT_NEAR(r->target.y, 0.8, 1e-12);
  EXPECT_NEAR(r->target.x, 4.0, 1e-12);
  EXPECT_FALSE(r->guarded);
}

TEST(PickAndPlace, HandAtTheEyeIsGuarded) {
  auto r = PickAndPlace({4, 0, 0}, {1, 1, 1}, {1, 1, 1}, {0, 0.01, 0});
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r->guarded);
  EXPECT_TRUE(std::isfinite(r->scale));
  EXPECT_NEAR(r->scale, glm::length(glm::dvec3(3, -1, -1)) / 0.1, 1e-9);
  EXPECT_NEAR(r->target.y, 0.01 * r->scale, 1e-9);
  // A tiny hand-eye distance hits the scale cap instead of a huge jump.
  auto capped = PickAndPlace({100, 0, 0}, {0, 0, 0}, {0.5, 0, 0}, {0, 1, 0});
  ASSERT_TRUE(capped.ok());
  EXPECT_DOUBLE_EQ(capped->scale, 50.0);
  EXPECT_TRUE(capped->guarded);
  EXPECT_FALSE(PickAndPlace({0, 0, 0}, {0, 0, 0}, {1, 0, 0}, {NAN, 0, 0}).ok());
}

TEST(GazeToSee, WallPlacesTheDroneOffTheSurfaceFacingIt) {
  const auto model = ZUpScene();
  auto r = GazeToSee(model, {0, 0, 1.5}, {1, 0.2, 0.1}, SceneFrame::ZUp());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_FALSE(r->horizontal_surface);
  EXPECT_NEAR(r->hit.point.x, 3.0, 1e-9);
  EXPECT_NEAR(r->hit.normal.x, -1.0, 1e-9);
  // x = 0.5 m along the horizontal normal, same height as P_gaze.
  EXPECT_NEAR(r->target.position.x, 2.5, 1e-9);
  EXPECT_NEAR(r->target.position.y, r->hit.point.y, 1e-9);
  EXPECT_NEAR(r->target.position.z, r->hit.point.z, 1e-9);
  EXPECT_NEAR(r->target.yaw, 0.0, 1e-9);  // facing +x, towards the wall
}

TEST(GazeToSee, SlopedSurfaceUsesTheNormalProjectedToTheHorizontal) {
  TriangleMesh m;
  // A 60° slope (normal 60° from up, |N·up| = 0.5): not horizontal by the 0.9 rule.
  AddQuad(&m, {2, -2, 0}, {2, 2, 0}, {3, 2, 1.7320508f}, {3, -2, 1.7320508f});
  MeshRaycaster model(m);
  auto r = GazeToSee(model, {0, 0, 1.0}, {1, 0, 0}, SceneFrame::ZUp());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_FALSE(r->horizontal_surface);
  const glm::dvec3 d = r->target.position - r->hit.point;
  EXPECT_NEAR(d.z, 0.0, 1e-9);
  EXPECT_NEAR(glm::length(d), 0.5, 1e-9);
  EXPECT_LT(d.x, 0);
}

TEST(GazeToSee, SkyHasNoTarget) {
  const auto model = ZUpScene();
  auto r = GazeToSee(model, {0, 0, 1.5}, {-1, 0, 1}, SceneFrame::ZUp());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(r.status().message().find("hits no modelled surface"), std::string::npos);
  EXPECT_EQ(GazeToSee(model, {0, 0, 1.5}, {0, 0, 0}, SceneFrame::ZUp()).status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(GazeToSee, HorizontalFloorPlacesTheDroneBetweenUserAndPoint) {
  const auto model = ZUpScene();
  const glm::dvec3 eye(0, 0, 1.6), dir = glm::normalize(glm::dvec3(1, 0.5, -1));
  auto r = GazeToSee(model, eye, dir, SceneFrame::ZUp());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(r->horizontal_surface);
  EXPECT_NEAR(r->hit.point.z, 0.0, 1e-9);
  // On the segment eye -> P_gaze, 0.5 m from the point.
  EXPECT_NEAR(glm::length(r->target.position - r->hit.point), 0.5, 1e-9);
  EXPECT_NEAR(glm::length(glm::cross(r->target.position - eye, dir)), 0.0, 1e-9);
  EXPECT_GT(r->target.position.z, 0.0);
  EXPECT_NEAR(r->target.yaw, std::atan2(0.5, 1.0), 1e-9);  // the user's horizontal view
  // The gimbal looks down the gaze ray: the user's view direction, P_gaze on the optical axis.
  const glm::dvec3 axis = std::cos(r->camera_pitch) * SceneFrame::ZUp().Heading(r->target.yaw) +
                          std::sin(r->camera_pitch) * glm::dvec3(0, 0, 1);
  EXPECT_NEAR(glm::dot(axis, dir), 1.0, 1e-9);
  EXPECT_NEAR(r->camera_pitch, std::asin(dir.z), 1e-9);
}

TEST(GazeToSee, CameraPitchTowardIsWithinTheGimbalLimits) {
  const SceneFrame z = SceneFrame::ZUp();
  EXPECT_NEAR(CameraPitchToward({0, 0, 1}, {1, 0, 1}, z), 0.0, 1e-12);     // level
  EXPECT_NEAR(CameraPitchToward({0, 0, 1}, {1, 0, 0}, z), -kPi / 4, 1e-12);  // 45° down
  EXPECT_NEAR(CameraPitchToward({0, 0, 1}, {0, 0, 0}, z), -kPi / 2, 1e-12);  // straight down
  EXPECT_NEAR(CameraPitchToward({0, 0, 0}, {0, 0, 3}, z), kPi / 6, 1e-12);   // capped at +30°
  EXPECT_EQ(CameraPitchToward({1, 2, 3}, {1, 2, 3}, z), 0.0);
  // y down (7-Scenes): "up" is -y.
  auto y_down = SceneFrame::FromUp({0, -1, 0});
  ASSERT_TRUE(y_down.ok());
  EXPECT_NEAR(CameraPitchToward({0, 0, 0}, {0, 1, 1}, *y_down), -kPi / 4, 1e-12);
  // A wall straight ahead: the gaze target faces it level.
  const auto model = ZUpScene();
  auto wall = GazeToSee(model, {0, 0, 1.6}, {1, 0, 0}, z);
  ASSERT_TRUE(wall.ok()) << wall.status();
  EXPECT_FALSE(wall->horizontal_surface);
  EXPECT_NEAR(wall->camera_pitch, 0.0, 1e-9);
}

TEST(GazeToSee, UpAxisIsAParameterSevenScenesIsYDown) {
  // y down: the floor is y = +1 (below an eye at y = -0.6), a wall at z = 3.
  TriangleMesh m;
  AddQuad(&m, {-5, 1, -5}, {5, 1, -5}, {5, 1, 3}, {-5, 1, 3});
  AddQuad(&m, {-5, -2, 3}, {5, -2, 3}, {5, 1, 3}, {-5, 1, 3});
  MeshRaycaster model(m);
  auto frame = SceneFrame::FromUp({0, -1, 0});
  ASSERT_TRUE(frame.ok());
  const glm::dvec3 eye(0, -0.6, 0);
  // At the floor: horizontal for y-down.
  auto floor = GazeToSee(model, eye, {0, 1, 1}, *frame);
  ASSERT_TRUE(floor.ok()) << floor.status();
  EXPECT_TRUE(floor->horizontal_surface);
  // The same ray with z taken as up would treat the floor as a wall and put the drone at floor
  // height: the up axis matters.
  auto wrong = GazeToSee(model, eye, {0, 1, 1}, SceneFrame::ZUp());
  ASSERT_TRUE(wrong.ok());
  EXPECT_FALSE(wrong->horizontal_surface);
  // At the wall: offset along -z (horizontal), no change of height (y).
  auto wall = GazeToSee(model, eye, {0.2, 0.1, 1}, *frame);
  ASSERT_TRUE(wall.ok()) << wall.status();
  EXPECT_FALSE(wall->horizontal_surface);
  EXPECT_NEAR(wall->target.position.y, wall->hit.point.y, 1e-9);
  EXPECT_NEAR(wall->target.position.z, 2.5, 1e-9);
  // The drone's heading points at the wall (+z).
  EXPECT_NEAR(glm::dot(frame->Heading(wall->target.yaw), glm::dvec3(0, 0, 1)), 1.0, 1e-9);
  EXPECT_FALSE(SceneFrame::FromUp({0, 0, 0}).ok());
}

TEST(Joypad, Mode2SticksMoveInTheHeadingFrame) {
  Setpoint sp{{0, 0, 1}, kPi / 2};  // facing +y
  JoypadOptions o;
  o.max_lead_m = 100;
  JoypadInput in;
  in.right_y = 1.0;  // forward
  auto r = IntegrateJoypad(sp, in, 0.5, SceneFrame::ZUp(), o, nullptr);
  EXPECT_NEAR(r.setpoint.position.y, 0.5, 1e-9);
  EXPECT_NEAR(r.setpoint.position.x, 0.0, 1e-9);
  in = {};
  in.right_x = 1.0;  // facing +y (north, z up), the right hand is +x (east)
  r = IntegrateJoypad(sp, in, 0.5, SceneFrame::ZUp(), o, nullptr);
  EXPECT_NEAR(r.setpoint.position.x, 0.5, 1e-9);
  in = {};
  in.left_y = 1.0;
  in.left_x = 0.5;
  r = IntegrateJoypad(sp, in, 1.0, SceneFrame::ZUp(), o, nullptr);
  EXPECT_NEAR(r.setpoint.position.z, 1.5, 1e-9);
  EXPECT_NEAR(r.setpoint.yaw, kPi / 2 + (0.5 - 0.05) / 0.95, 1e-9);
  // Inside the deadzone nothing moves.
  in = {};
  in.right_y = 0.04;
  r = IntegrateJoypad(sp, in, 1.0, SceneFrame::ZUp(), o, nullptr);
  EXPECT_EQ(r.setpoint.position, sp.position);
}

TEST(Joypad, SlidesAlongTheZoneBoundary) {
  SafeFlightOptions so;
  so.zones = {{"room", {0, 0, 0}, {4, 4, 3}}};
  auto safe = SafeFlight::Create(so);
  ASSERT_TRUE(safe.ok());
  ASSERT_TRUE(safe->UsingRegions());   // nothing modelled: zones only
  Setpoint sp{{3.95, 2, 1}, kPi / 4};  // near the x = 4 face, heading diagonally into it
  JoypadInput in;
  in.right_y = 1.0;
  JoypadOptions o;
  o.max_lead_m = 100;
  auto r = IntegrateJoypad(sp, in, 0.2, SceneFrame::ZUp(), o, &*safe);
  EXPECT_TRUE(r.slid);
  EXPECT_FALSE(r.blocked);
  EXPECT_NEAR(r.setpoint.position.x, 3.95, 1e-9);                      // the blocked part removed
  EXPECT_NEAR(r.setpoint.position.y, 2 + 0.2 * std::sqrt(0.5), 1e-9);  // the rest kept
  // Straight into a corner: blocked, the setpoint stays.
  Setpoint corner{{3.99, 3.99, 1}, kPi / 4};
  r = IntegrateJoypad(corner, in, 0.2, SceneFrame::ZUp(), o, &*safe);
  EXPECT_TRUE(r.blocked);
  EXPECT_EQ(r.setpoint.position, corner.position);
  // The lead bound: the setpoint does not run away from the drone.
  o.max_lead_m = 0.5;
  const glm::dvec3 drone(2, 2, 1);
  Setpoint lead{{2.45, 2, 1}, 0};
  r = IntegrateJoypad(lead, in, 0.2, SceneFrame::ZUp(), o, &*safe, &drone);
  EXPECT_TRUE(r.blocked);
}

}  // namespace
}  // namespace exo::control
