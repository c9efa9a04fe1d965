// Shared vocabulary of drone control (client and server) (SPEC §8, thesis ch. 5): the scene's up
// axis and yaw convention, setpoints and drone states. Pure data + small math, no I/O.
//
// Yaw is the heading about the scene's up axis: yaw 0 faces `e1` (the scene x axis made
// horizontal; the y axis when x is the up axis), yaw +90° faces e2 = up × e1. With z up that is
// the usual x-forward / y-left convention; 7-Scenes (y down) is SceneFrame::FromUp({0,-1,0}).
#pragma once

#include <cmath>
#include <cstdint>
#include <glm/glm.hpp>
#include <string>

#include "common/status.h"

namespace exo::control {

inline constexpr double kPi = 3.14159265358979323846;

// Wraps an angle to (-pi, pi].
inline double WrapAngle(double a) {
  a = std::remainder(a, 2 * kPi);
  return a <= -kPi ? a + 2 * kPi : a;
}

struct SceneFrame {
  glm::dvec3 up{0, 0, 1};  // unit
  glm::dvec3 e1{1, 0, 0};  // horizontal, yaw 0
  glm::dvec3 e2{0, 1, 0};  // horizontal, yaw +90°

  // Errors: a zero or non-finite up vector.
  static absl::StatusOr<SceneFrame> FromUp(const glm::dvec3& up);
  static SceneFrame ZUp() { return {}; }

  double Height(const glm::dvec3& p) const { return glm::dot(p, up); }
  // The horizontal part of a vector.
  glm::dvec3 Horizontal(const glm::dvec3& v) const { return v - glm::dot(v, up) * up; }
  glm::dvec3 Heading(double yaw) const { return std::cos(yaw) * e1 + std::sin(yaw) * e2; }
  // Yaw of a direction's horizontal part (0 when it has none).
  double YawOf(const glm::dvec3& v) const {
    const double a = glm::dot(v, e1), b = glm::dot(v, e2);
    return (a == 0 && b == 0) ? 0.0 : std::atan2(b, a);
  }
};

// Which interaction produced a setpoint (mirrors the wire enum in proto/control.proto).
enum class InteractionKind : int {
  kNone = 0,
  kPickAndPlace = 1,
  kGazeToSee = 2,
  kJoypad = 3,
  kGoToView = 4,
  kHold = 5,
  kExplore = 6,
};
const char* InteractionName(InteractionKind k);

struct Setpoint {
  glm::dvec3 position{0.0};
  double yaw = 0.0;  // rad about SceneFrame::up
  // The camera gimbal's pitch, rad, + up (0: level). Applied by the drone within its gimbal's
  // limits; a setpoint without one (an older server) keeps the camera level.
  double camera_pitch = 0.0;
};

struct DroneState {
  double timestamp_s = 0.0;
  glm::dvec3 position{0.0};
  glm::dvec3 velocity{0.0};
  double yaw = 0.0;
  double yaw_rate = 0.0;
  double camera_pitch = 0.0;  // the gimbal's pitch now, rad, + up
};

}  // namespace exo::control
