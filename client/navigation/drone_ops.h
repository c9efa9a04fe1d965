// The operator's actions in the viewer (issue 19, item 5), as plain geometry: pure (no SDL, no
// Vulkan, no gRPC), shared by the window and the browser page. What the control service is sent
// (world frame) is computed here from what the person did with the mouse and the keys:
//   - gaze-to-see on click: the ray through the clicked pixel (thesis 5.2: the eye's gaze ray);
//     in X-ray mode it starts where it crosses the cut-away plane, so the server's ray cast
//     looks through the "virtual hole in the wall" the person sees through;
//   - pick-and-place by drag: the mouse stands in for the hand (thesis 5.1, eq. 5.1): the eye is
//     the viewer camera's centre, the hand a point `hand_m` along the cursor's ray (arm's reach;
//     the wheel during the drag moves it along the ray), so
//       D_drone = |P_drone − P_eye| / |P_hand − P_eye| · D_hand
//     moves the drone with the cursor at its own distance; the denominator is floored (hand at
//     the eye) and the scale capped exactly as the server does (server/control/interactions.h);
//   - joypad by keys: held keys as full stick deflections, Mode 2 (left stick: yaw rate, climb;
//     right stick: lateral, forward), the signs the server's IntegrateJoypad uses;
//   - X-ray: the cut-away plane facing the viewer at a distance along the optical axis.
#pragma once

#include <glm/glm.hpp>
#include <optional>

#include "common/camera.h"
#include "common/rigid3.h"

namespace exo::nav {

struct Ray3 {
  glm::dvec3 origin{0.0};
  glm::dvec3 dir{0.0, 0.0, 1.0};  // unit
};

// The ray from the camera centre through pixel `uv` (pixel centres at integers); scene-local.
Ray3 PixelRay(const PinholeCamera& camera, const Rigid3d& local_from_cam, const glm::dvec2& uv);

// The gaze ray of a click: PixelRay, moved forward to where it crosses the plane z = clip_m of
// the camera (X-ray on: clip_m > 0), so that the cast ignores what the cut-away removed.
Ray3 GazeRay(const PinholeCamera& camera, const Rigid3d& local_from_cam, const glm::dvec2& uv,
             double clip_m = 0.0);

// A mouse drag as the hand's motion: eye = the camera centre, the hand at `hand_m0` along the
// ray through `uv0` when the drag starts and at `hand_m1` along the ray through `uv1` when it
// ends (hand_m >= 0; 0 = the hand at the eye).
struct MouseHand {
  glm::dvec3 eye{0.0}, hand{0.0}, displacement{0.0};  // scene-local
};
MouseHand HandFromDrag(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                       const glm::dvec2& uv0, double hand_m0, const glm::dvec2& uv1,
                       double hand_m1);

// Eq. (5.1) with the server's guard (PickAndPlaceOptions: floor 0.1 m, cap 50): the target the
// server will set, drawn while the drag is in progress. Non-finite input: the drone's position.
struct PickPlacePreview {
  glm::dvec3 target{0.0};
  double scale = 0.0;
  bool guarded = false;  // the floor or the cap applied
};
PickPlacePreview PreviewPickAndPlace(const glm::dvec3& drone, const glm::dvec3& eye,
                                     const glm::dvec3& hand, const glm::dvec3& displacement,
                                     double min_hand_eye_m = 0.1, double max_scale = 50.0);

// Held keys of the joypad-by-keys mapping (docs/viewer.md: I K forward/back, J L left/right,
// U O turn left/right, Y H up/down).
struct JoypadKeys {
  bool forward = false, back = false, left = false, right = false;
  bool turn_left = false, turn_right = false, up = false, down = false;
  bool any() const {
    return forward || back || left || right || turn_left || turn_right || up || down;
  }
};
// Mode-2 sticks in [-1, 1] as exoview.control.v1.JoypadRequest carries them: left_x = yaw rate
// (+ = turn left: yaw grows counter-clockwise about up), left_y = climb, right_x = lateral
// (+ = right), right_y = forward.
struct Sticks {
  double left_x = 0, left_y = 0, right_x = 0, right_y = 0;
  bool zero() const { return left_x == 0 && left_y == 0 && right_x == 0 && right_y == 0; }
};
Sticks SticksFromKeys(const JoypadKeys& keys, double deflection = 1.0);
// A game controller's axes (SDL: x right, y down, in [-1, 1]) as Mode-2 sticks: left stick
// right = turn right, left stick up = climb, right stick right = right, right stick up = forward.
Sticks SticksFromGamepad(double left_x, double left_y, double right_x, double right_y,
                         double deadzone = 0.1);

// The X-ray cut-away plane's distance along the optical axis: through the picked point (its
// z-depth) plus `margin_m` (a wall's thickness), else `default_m` in front of the camera.
double XrayClipDistance(std::optional<double> picked_z_depth_m, double margin_m, double default_m);

// The X-ray hole ("a virtual hole in the wall", thesis 5.2.7): only inside a disc on the picture
// is the proxy nearer than the clip cut away (VulkanRenderer::SetXrayHole draws it; picking and
// the gaze ray use these). The disc is resolution-independent: its centre as a fraction of the
// picture, pixel `uv` (centres at integers) of a w x h picture at ((uv + 0.5) / (w, h)), its
// radius as a fraction of the picture's height.
glm::dvec2 XrayHoleCentre(const glm::dvec2& uv, int w, int h);
bool InsideXrayHole(const glm::dvec2& uv, int w, int h, const glm::dvec2& centre, double radius);

}  // namespace exo::nav
