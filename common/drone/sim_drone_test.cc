#include "common/drone/sim_drone.h"

#include <gtest/gtest.h>

#include "common/drone/test_util.h"

namespace exo::control {
namespace {

struct StepResponse {
  double overshoot = 0;  // fraction of the step
  double settle_s = 0;   // last time |error| > 2 cm
  double max_speed = 0;
  double max_accel = 0;
};

StepResponse Step(const SimDroneOptions& o, double step_m, double seconds = 8.0) {
  SimDrone d(o);
  d.Reset({0, 0, 1}, 0);
  StepResponse r;
  glm::dvec3 prev_v(0.0);
  for (int i = 0; i < static_cast<int>(seconds * o.rate_hz); ++i) {
    d.Receive({{step_m, 0, 1}, 0}, d.state().timestamp_s);  // setpoints keep coming
    const DroneState& s = d.Step();
    r.overshoot = std::max(r.overshoot, (s.position.x - step_m) / step_m);
    if (std::abs(s.position.x - step_m) > 0.02) r.settle_s = s.timestamp_s;
    r.max_speed = std::max(r.max_speed, glm::length(s.velocity));
    r.max_accel = std::max(r.max_accel, glm::length(s.velocity - prev_v) * o.rate_hz);
    prev_v = s.velocity;
  }
  return r;
}

TEST(SimDrone, StepResponseOvershootsAboutFivePercent) {
  const SimDroneOptions o;
  const StepResponse r = Step(o, 1.0);
  EXPECT_GT(r.overshoot, 0.03);
  EXPECT_LT(r.overshoot, 0.07);
  EXPECT_LT(r.settle_s, 4.0);
  EXPECT_GT(r.settle_s, 0.5);
}

TEST(SimDrone, SpeedAndAccelerationLimits) {
  SimDroneOptions o;
  o.max_speed_mps = 1.0;
  o.max_accel_mps2 = 2.0;
  const StepResponse r = Step(o, 10.0, 15.0);
  EXPECT_LE(r.max_speed, 1.0 * 1.06);  // the lag lets it overshoot the limit a little
  EXPECT_GT(r.max_speed, 0.95);
  EXPECT_LE(r.max_accel, 2.0 + 1e-9);
  EXPECT_LT(r.settle_s, 15.0);
}

TEST(SimDrone, StateAt120HzAndYawRateLimited) {
  SimDroneOptions o;
  o.max_yaw_rate_rad_s = 0.5;
  SimDrone d(o);
  d.Reset({0, 0, 1}, 0);
  d.Receive({{0, 0, 1}, 3.0}, 0);
  double prev_t = 0, prev_yaw = 0;
  for (int i = 0; i < 120; ++i) {
    d.Receive({{0, 0, 1}, 3.0}, d.state().timestamp_s);
    const DroneState& s = d.Step();
    EXPECT_NEAR(s.timestamp_s - prev_t, 1.0 / 120, 1e-9);
    EXPECT_LE(std::abs(WrapAngle(s.yaw - prev_yaw)), 0.5 / 120 + 1e-9);
    prev_t = s.timestamp_s;
    prev_yaw = s.yaw;
  }
  EXPECT_NEAR(d.state().yaw, 0.5, 1e-6);  // one second at the rate limit
}

// The ground station sends the target at 30 Hz through a link with delay, loss and stalls; the
// drone's state goes back the other way. Returns the drone.
struct LinkRun {
  glm::dvec3 final_position{0.0};
  uint64_t hold_events = 0;
  double drift_in_stall_m = 0;  // how far the drone moved in the stall once it had stopped
  uint64_t lost = 0, sent = 0;
};

LinkRun FlyThroughLink(const LinkOptions& lo, double seconds, double stall_start = -1,
                       double stall_len = 0) {
  SimDroneOptions o;
  SimDrone d(o);
  d.Reset({0, 0, 1}, 0);
  Link<Setpoint> up(lo);
  const Setpoint target{{4, 0, 1}, 0};
  LinkRun r;
  glm::dvec3 braked(0.0);
  bool have_braked = false;
  int steps_since_send = 4;
  for (int i = 0; i < static_cast<int>(seconds * o.rate_hz); ++i) {
    const double now = d.state().timestamp_s;
    if (++steps_since_send >= 4) {  // 30 Hz
      up.Send(target, now);
      steps_since_send = 0;
    }
    for (const Setpoint& sp : up.Receive(now)) d.Receive(sp, now);
    const DroneState& s = d.Step();
    if (stall_start >= 0 && s.timestamp_s > stall_start + o.hold_timeout_s + 2.0 &&
        s.timestamp_s < stall_start + stall_len) {
      if (!have_braked) {
        braked = s.position;
        have_braked = true;
      }
      r.drift_in_stall_m = std::max(r.drift_in_stall_m, glm::length(s.position - braked));
    }
  }
  r.final_position = d.state().position;
  r.hold_events = d.hold_events();
  r.lost = up.lost();
  r.sent = up.sent();
  return r;
}

TEST(SimDrone, TenPercentLossAndDelayStillReachTheTarget) {
  LinkOptions lo;
  lo.delay_s = 0.025;
  lo.loss = 0.1;
  lo.seed = 3;
  const LinkRun r = FlyThroughLink(lo, 8.0);
  EXPECT_NEAR(static_cast<double>(r.lost) / r.sent, 0.1, 0.04);
  EXPECT_LT(glm::length(r.final_position - glm::dvec3(4, 0, 1)), 0.02);
  EXPECT_EQ(r.hold_events, 0u);
}

TEST(SimDrone, HoldsPositionWhenSetpointsStop) {
  LinkOptions lo;
  lo.delay_s = 0.025;
  lo.stalls = {{0.8, 4.0}};  // in mid-flight, towards x = 4
  const LinkRun r = FlyThroughLink(lo, 12.0, 0.8, 4.0);
  EXPECT_EQ(r.hold_events, 1u);
  EXPECT_LT(r.drift_in_stall_m, 0.01);  // braked and held
  // Setpoints came back after the stall: the flight finished.
  EXPECT_LT(glm::length(r.final_position - glm::dvec3(4, 0, 1)), 0.02);
  // Without setpoints after the stall it would stay short of the target.
  LinkOptions cut = lo;
  cut.stalls = {{0.8, 100}};
  const LinkRun stopped = FlyThroughLink(cut, 10.0);
  EXPECT_LT(stopped.final_position.x, 3.0);
  EXPECT_GT(stopped.final_position.x, 0.2);
}

// The camera gimbal follows the setpoint's pitch at its rate limit, stops at its limits, and
// keeps its pitch when the link is lost (HOLD).
TEST(SimDrone, GimbalFollowsTheSetpointPitchWithinItsRateAndLimits) {
  const SimDroneOptions o;
  SimDrone d(o);
  d.Reset({0, 0, 1}, 0);
  EXPECT_EQ(d.state().camera_pitch, 0.0);
  const Setpoint down{{0, 0, 1}, 0, -0.9};
  double at_half_second = 0;
  for (int i = 0; i < 120; ++i) {
    d.Receive(down, d.state().timestamp_s);
    d.Step();
    if (i == 59) at_half_second = d.state().camera_pitch;
  }
  // 1.5 rad/s: -0.75 after 0.5 s, at -0.9 by 0.6 s.
  EXPECT_NEAR(at_half_second, -0.75, 0.01);
  EXPECT_NEAR(d.state().camera_pitch, -0.9, 1e-9);
  // Beyond the gimbal's range: clamped (30° up at most, straight down at least).
  for (int i = 0; i < 240; ++i) {
    d.Receive({{0, 0, 1}, 0, 2.0}, d.state().timestamp_s);
    d.Step();
  }
  EXPECT_NEAR(d.state().camera_pitch, o.max_camera_pitch_rad, 1e-9);
  for (int i = 0; i < 360; ++i) {
    d.Receive({{0, 0, 1}, 0, -3.0}, d.state().timestamp_s);
    d.Step();
  }
  EXPECT_NEAR(d.state().camera_pitch, o.min_camera_pitch_rad, 1e-9);
  // Setpoints stop: HOLD keeps the camera where it looks.
  for (int i = 0; i < 240; ++i) d.Step();
  EXPECT_EQ(d.mode(), FlightMode::kHold);
  EXPECT_NEAR(d.state().camera_pitch, o.min_camera_pitch_rad, 1e-9);
}

TEST(CollisionMonitor, CountsContactsWithTheMesh) {
  TriangleMesh wall;
  testing::AddQuad(&wall, {3, -5, 0}, {3, 5, 0}, {3, 5, 3}, {3, -5, 3});
  CollisionMonitor m(wall, 0.15);
  EXPECT_FALSE(m.Update({2.0, 0, 1}));
  EXPECT_TRUE(m.Update({2.9, 0, 1}));
  EXPECT_TRUE(m.Update({2.95, 0, 1}));  // the same contact
  EXPECT_FALSE(m.Update({2.5, 0, 1}));
  EXPECT_TRUE(m.Update({3.1, 4.9, 2.9}));
  EXPECT_EQ(m.collisions(), 2u);
  EXPECT_NEAR(m.min_clearance_m(), -0.1, 1e-9);
  MeshDistance d(wall);
  EXPECT_NEAR(d.Distance({1, 0, 1}, 5), 2.0, 1e-9);
  EXPECT_NEAR(d.Distance({3, 7, 1}, 5), 2.0, 1e-9);  // to the edge
  EXPECT_EQ(d.Distance({-10, 0, 1}, 5), 5.0);
}

}  // namespace
}  // namespace exo::control
