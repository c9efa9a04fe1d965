// The operator interactions of exocentric drone control (SPEC §8, thesis 5.1): each turns what
// the operator did into a target for the drone, before safe flight clamps and routes it.
//   - Pick-and-place (5.1): D_drone = |P_drone − P_eye| / |P_hand − P_eye| · D_hand; the
//     denominator is floored (hand at the eye) and the scale capped.
//   - Gaze-to-see (5.2): the gaze ray is cast into the proxy mesh → P_gaze, N_g; unless the
//     surface is horizontal (|N_g·up| ≥ 0.9|N_g|) the drone goes x metres off the surface along
//     N_g made horizontal, yaw facing P_gaze; on a horizontal surface it goes x metres back along
//     the gaze ray (between the user and the point, mimicking the user's view). The camera's
//     gimbal pitch faces P_gaze too (floors and table tops are seen from above, centred).
//   - Joypad (Mode 2): left stick = yaw rate (x) and climb rate (y), right stick = lateral (x)
//     and forward (y) speed in the drone's heading frame; integrated into the setpoint, which
//     slides along the permitted space's boundary instead of stopping at it.
// Pure functions plus a brute-force mesh ray caster (Möller–Trumbore over every triangle).
#pragma once

#include <glm/glm.hpp>
#include <optional>

#include "common/drone/drone_types.h"
#include "common/mesh.h"
#include "common/status.h"

namespace exo::control {

class SafeFlight;

struct RayHit {
  double t = 0.0;  // distance along the unit ray
  glm::dvec3 point{0.0};
  glm::dvec3 normal{0.0};  // unit, facing the ray's origin
  size_t triangle = 0;
};

// Ray casting into a triangle mesh held in the control frame (positions + offset).
class MeshRaycaster {
 public:
  MeshRaycaster() = default;
  MeshRaycaster(TriangleMesh mesh, const glm::dvec3& offset = glm::dvec3(0.0))
      : mesh_(std::move(mesh)), offset_(offset) {}
  std::optional<RayHit> Cast(const glm::dvec3& origin, const glm::dvec3& dir,
                             double max_t = 1e9) const;
  const TriangleMesh& mesh() const { return mesh_; }
  const glm::dvec3& offset() const { return offset_; }

 private:
  TriangleMesh mesh_;
  glm::dvec3 offset_{0.0};
};

struct PickAndPlaceOptions {
  double min_hand_eye_m = 0.1;  // floor of |P_hand − P_eye| (division guard)
  double max_scale = 50.0;
};
struct PickAndPlaceResult {
  glm::dvec3 target{0.0};
  double scale = 0.0;
  bool guarded = false;  // the floor or the cap was applied
};
// Errors: non-finite input.
absl::StatusOr<PickAndPlaceResult> PickAndPlace(const glm::dvec3& drone, const glm::dvec3& eye,
                                                const glm::dvec3& hand,
                                                const glm::dvec3& hand_displacement,
                                                const PickAndPlaceOptions& options = {});

struct GazeOptions {
  double offset_m = 0.5;        // x of (5.2)
  double horizontal_cos = 0.9;  // |N·up| >= this·|N|: a horizontal surface
  double max_range_m = 100.0;
};
struct GazeResult {
  RayHit hit;  // P_gaze, N_g
  Setpoint target;
  bool horizontal_surface = false;
  // Camera (gimbal) pitch that centres P_gaze from `target` (CameraPitchToward). A level camera
  // 0.5 m from a floor point sees it ~40° below its axis, outside the central third.
  double camera_pitch = 0.0;
};

// Gimbal pitch range, rad (+ up): a typical drone gimbal looks straight down to 30° up.
struct GimbalLimits {
  double min_pitch_rad = -1.5707963267948966;
  double max_pitch_rad = 0.5235987755982988;
};
// The pitch (+ up, about the camera's horizontal axis, within `limits`) at which a camera at
// `from` with its yaw facing `point` has the point on its optical axis. 0 for from == point.
double CameraPitchToward(const glm::dvec3& from, const glm::dvec3& point, const SceneFrame& frame,
                         const GimbalLimits& limits = {});
// Errors: InvalidArgument for a zero/non-finite ray; NotFound when the ray hits no surface
// ("gaze at the sky").
absl::StatusOr<GazeResult> GazeToSee(const MeshRaycaster& model, const glm::dvec3& eye,
                                     const glm::dvec3& gaze_dir, const SceneFrame& frame,
                                     const GazeOptions& options = {});

struct JoypadInput {
  double left_x = 0, left_y = 0;    // yaw rate (+ = counter-clockwise about up), climb
  double right_x = 0, right_y = 0;  // lateral (+ = right), forward
};
struct JoypadOptions {
  double max_speed_mps = 1.0;  // horizontal
  double max_climb_mps = 0.5;
  double max_yaw_rate_rad_s = 1.0;
  double deadzone = 0.05;
  double max_lead_m = 1.0;  // the setpoint stays this close to the drone
};
struct JoypadResult {
  Setpoint setpoint;
  bool slid = false;     // part of the motion was removed at a boundary
  bool blocked = false;  // no motion was possible
};
// Integrates `dt_s` of stick input from `current`. With `safe` (may be null) the new position
// is permitted: the largest permitted part of the motion (full, then dropping one or two of its
// components along e1, e2 and up) is kept. `drone` (optional) bounds the lead.
JoypadResult IntegrateJoypad(const Setpoint& current, const JoypadInput& in, double dt_s,
                             const SceneFrame& frame, const JoypadOptions& options,
                             const SafeFlight* safe, const glm::dvec3* drone = nullptr);

}  // namespace exo::control
