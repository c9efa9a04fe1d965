// What the viewer draws over the rendered frame besides the HUD (issues 17 and 19), as plain
// geometry: pure (no SDL, no Vulkan, no gRPC), shared by the window (Dear ImGui lines) and the
// browser page (/overlay.json, drawn on a canvas).
//   - cells coloured by the server's coverage τ (CellCoverage: τ/τ_max in whole percent);
//   - the drone (issue 19, item 5): its body (a quadrotor X with rotor rings and a nose), its
//     camera frustum (heading + gimbal pitch), its target (cross + heading), the planned route
//     (from the drone through the waypoints still to fly) and the flight zones (boxes, prisms),
//     from what the control service's GetControlState says (world frame -> scene-local).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "common/camera.h"
#include "common/rigid3.h"

namespace exo::nav {

// RGBA8 (r in the lowest byte, as ImGui's IM_COL32).
inline constexpr uint32_t Rgba(int r, int g, int b, int a = 255) {
  return uint32_t(r) | uint32_t(g) << 8 | uint32_t(b) << 16 | uint32_t(a) << 24;
}

// Coverage colour: red (τ = 0) -> yellow (τ_max / 2) -> green (τ >= τ_max).
uint32_t CoverageColor(int tau_percent, int alpha = 220);
// Reference-count colour (models without coverage): red (1 reference) -> green (the fullest cell).
uint32_t RefCountColor(size_t refs, size_t max_refs, int alpha = 200);

// A flight zone as GetControlState sends it (world frame).
struct ZoneView {
  std::string name;
  glm::dvec3 min{0.0}, max{0.0};
  int prism_axis = -1;                // -1: a box; 0/1/2: a prism standing along x/y/z
  std::vector<glm::dvec2> polygon;    // prism: (u, v) along axes prism_axis+1, prism_axis+2
};

// The control service's state (exoview.control.v1.ControlState), world frame.
struct ControlView {
  bool drone_known = false;
  glm::dvec3 drone{0.0}, velocity{0.0};
  double yaw = 0.0, camera_pitch = 0.0;
  bool has_command = false;           // a command was given (command_sequence > 0)
  glm::dvec3 target{0.0};
  double target_yaw = 0.0, target_pitch = 0.0;
  std::vector<glm::dvec3> waypoints;  // the route, in order
  uint32_t waypoint_index = 0;        // the one being flown
  std::vector<ZoneView> zones;
  glm::dvec3 up{0, 0, 1};
  std::string interaction;            // what produced the command ("GAZE_TO_SEE", ...)
  bool exploring = false;
};

enum class OverlayKind { kDrone, kFrustum, kTarget, kRoute, kZone };
const char* OverlayKindName(OverlayKind k);

struct OverlayLine {
  glm::dvec3 a{0.0}, b{0.0};  // scene-local
  uint32_t rgba = 0;
  float width = 1.f;
  OverlayKind kind = OverlayKind::kDrone;
};

struct DroneOverlayOptions {
  double arm_m = 0.2;        // body: centre to rotor
  double rotor_m = 0.08;     // rotor ring radius
  double frustum_m = 0.6;    // camera frustum depth
  double hfov_rad = 1.05;    // the drone camera's (the newest stored view's when known)
  double aspect = 4.0 / 3.0; // width / height
  double target_m = 0.15;    // target cross half-size
};

// The drone camera's orientation (camera x right, y down, z forward) for a heading `yaw` about
// `up` (SPEC §8 convention: yaw 0 along the scene x axis made horizontal) and gimbal `pitch`
// (+ up); no roll. Columns: the camera axes in the world/scene frame.
glm::dmat3 DroneCameraAxes(const glm::dvec3& up, double yaw, double pitch);

// Every line of the drone overlays in the scene-local frame (world - origin); nothing when the
// drone is not known and no zone is configured. Routes: the drone -> waypoints[index..] (bright),
// waypoints flown already dim.
std::vector<OverlayLine> DroneOverlayLines(const ControlView& c, const LocalOrigin& origin,
                                           const DroneOverlayOptions& options = {});

// A segment in pixels of `camera` at `local_from_cam`, clipped to the near plane (z >= near);
// nullopt when it lies wholly behind it. Pixel centres at integers (+0.5 for screen coordinates
// is the caller's).
struct Segment2 {
  glm::dvec2 a{0.0}, b{0.0};
};
std::optional<Segment2> ProjectSegment(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                       const glm::dvec3& a_local, const glm::dvec3& b_local,
                                       double near_m = 0.05);

}  // namespace exo::nav
