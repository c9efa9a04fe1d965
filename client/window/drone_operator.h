// The viewer as a drone operator (issue 19, item 5): sends what the person does in the window or
// the browser page to the control service (exoview.control.v1.Control: GazeToSee, PickAndPlace,
// Joypad) on its own thread, so the UI never waits for the network, and keeps the last reply (or
// the server's refusal, e.g. NOT_FOUND for a gaze at the sky) for the HUD and the status file.
// Commands queue (at most 8; the oldest is dropped beyond that, counted); joypad input is merged:
// the newest sticks with the time held summed, sent at most every `joypad_period_s`.
// Operator sequence: the wall clock in µs at start, +1 per command (always increasing, also
// across restarts of the viewer, as exoview_operator does).
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <glm/glm.hpp>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "client/navigation/drone_ops.h"
#include "common/camera.h"
#include "common/lumigraph/model.h"
#include "common/rigid3.h"
#include "proto/control.grpc.pb.h"

namespace exo {

struct OperatorReply {
  std::string action;  // "gaze", "pick", "joypad"
  bool ok = false;
  std::string code;     // gRPC status code name ("OK", "NOT_FOUND", ...)
  std::string message;  // the server's reason when refused
  uint64_t command_sequence = 0;
  glm::dvec3 target{0.0};  // world frame
  double target_yaw = 0;
  std::vector<glm::dvec3> waypoints;
  bool has_gaze = false;
  glm::dvec3 gaze_point{0.0}, gaze_normal{0.0};
  bool clamped = false;
  std::string note;
  double rtt_ms = 0;
  uint64_t operator_sequence = 0;
  std::string Summary() const;  // one line for the HUD
  nlohmann::json ToJson() const;
};

class DroneOperator {
 public:
  DroneOperator(std::shared_ptr<grpc::Channel> channel, std::string drone_id,
                std::string operator_id, double joypad_period_s = 0.05);
  ~DroneOperator();
  DroneOperator(const DroneOperator&) = delete;
  DroneOperator& operator=(const DroneOperator&) = delete;

  // World frame (the uploads'; the viewer adds the model's origin).
  void GazeToSee(const glm::dvec3& eye, const glm::dvec3& direction);
  void PickAndPlace(const glm::dvec3& eye, const glm::dvec3& hand,
                    const glm::dvec3& hand_displacement);
  // `dt_s` of stick input (held keys / a gamepad), merged with what is not sent yet.
  void Joypad(const nav::Sticks& sticks, double dt_s);

  std::optional<OperatorReply> last();
  uint64_t sent() const;
  uint64_t dropped() const;
  const std::string& operator_id() const { return operator_id_; }
  nlohmann::json StatusJson();

 private:
  struct Job {
    enum Kind { kGaze, kPick } kind;
    glm::dvec3 a{0.0}, b{0.0}, c{0.0};
  };
  void Run();
  exoview::control::v1::OperatorHeader Header();

  const std::string drone_id_, operator_id_;
  const double joypad_period_s_;
  std::unique_ptr<exoview::control::v1::Control::Stub> stub_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::deque<Job> jobs_;
  nav::Sticks joy_;
  double joy_dt_ = 0;
  std::optional<OperatorReply> last_;
  std::map<std::string, OperatorReply> last_by_action_;
  uint64_t sequence_ = 0, sent_ = 0, dropped_ = 0, joypad_sent_ = 0;
  std::thread thread_;
};

// The operator's gestures in the viewer, independent of SDL and the browser (the window and the
// page translate their events into these calls; docs/viewer.md "Steering the drone"):
//   - Click(px): gaze-to-see along the ray through the pixel (from the X-ray plane when on);
//   - BeginDrag(px, drone_px) on the drone (within pick_radius_px of its projection) ... Drag(px),
//     Wheel(clicks) (the hand along the ray, hand_step_m per click, not behind the eye) ...
//     EndDrag(): one pick-and-place command with eye = the camera, the mouse as the hand;
//   - Joypad(keys, dt): held keys as Mode-2 sticks; Gamepad(...) the same from a controller;
//   - ToggleXray(z under the cursor): the cut-away plane through that point + margin (else
//     xray_default_m in front of the camera); MoveXray(±): the plane nearer / farther.
// Poses are scene-local (the frame on screen), `origin` turns them into the world frame.
struct DroneControlsOptions {
  double hand_m = 0.5;        // the hand's distance from the eye along the cursor's ray
  double hand_step_m = 0.05;  // per wheel click during a drag
  double pick_radius_px = 40;
  double click_slop_px = 5;    // a press that moves farther is not a click
  double xray_margin_m = 0.3;  // behind the picked point (a wall's thickness)
  double xray_default_m = 1.5;
  double xray_step_m = 0.25;
  // The hole's radius as a fraction of the picture's height (nav::InsideXrayHole): only
  // inside it is the picture cut at the plane; >= the picture's diagonal: the whole picture.
  double xray_radius = 0.22;
};

class DroneControls {
 public:
  DroneControls(DroneOperator* op, const DroneControlsOptions& options) : op_(op), o_(options) {}
  bool drone_mode() const { return drone_mode_; }
  void ToggleDroneMode() { drone_mode_ = !drone_mode_; }
  bool dragging() const { return drag_.has_value(); }

  void Click(const PinholeCamera& cam, const Rigid3d& pose, const LocalOrigin& origin,
             const glm::dvec2& px, std::optional<glm::dvec3> local_hit);
  // True when the press is on the drone (a drag begins).
  bool BeginDrag(const glm::dvec2& px, std::optional<glm::dvec2> drone_px,
                 std::optional<glm::dvec3> drone_world);
  void Drag(const glm::dvec2& px) {
    if (drag_) drag_->px1 = px;
  }
  void Wheel(double clicks) {
    if (drag_) drag_->hand1 = std::max(0.0, drag_->hand1 + clicks * o_.hand_step_m);
  }
  // The target the server will set (world) while dragging.
  std::optional<nav::PickPlacePreview> Preview(const PinholeCamera& cam, const Rigid3d& pose,
                                               const LocalOrigin& origin) const;
  std::optional<glm::dvec3> drag_drone_world() const {
    return drag_ ? std::optional(drag_->drone_world) : std::nullopt;
  }
  // Sends the drag (nothing when it did not move); false when no drag was in progress.
  bool EndDrag(const PinholeCamera& cam, const Rigid3d& pose, const LocalOrigin& origin);
  // A whole drag at once (the browser page): hand distances hand0 / hand1 (< 0: hand_m).
  void Drag(const PinholeCamera& cam, const Rigid3d& pose, const LocalOrigin& origin,
            const glm::dvec2& px0, const glm::dvec2& px1, double hand0, double hand1,
            const glm::dvec3& drone_world);

  void Joypad(const nav::JoypadKeys& keys, double dt_s);
  void Gamepad(const nav::Sticks& sticks, double dt_s);

  bool xray() const { return xray_; }
  double xray_clip_m() const { return xray_clip_m_; }
  // The hole: centre as a fraction of the picture (nav::XrayHoleCentre), radius (of its height).
  glm::dvec2 xray_centre() const { return xray_centre_; }
  double xray_radius() const { return o_.xray_radius; }
  // X: on at the cursor `centre` (a fraction of the picture) with the plane through the point
  // under it + margin (else xray_default_m), or off.
  void ToggleXray(std::optional<double> z_under_cursor, const glm::dvec2& centre = {0.5, 0.5});
  void MoveXray(int steps);
  // The hole follows the cursor (no-op while off).
  void MoveXrayHole(const glm::dvec2& centre) {
    if (xray_) xray_centre_ = centre;
  }
  // The clip at pixel `px` of a picture of `cam`'s size: the plane's distance inside the hole,
  // 0 (nothing cut) outside it or with X-ray off; picking and the gaze ray start there.
  double ClipAt(const PinholeCamera& cam, const glm::dvec2& px) const;

  std::string HudLine() const;
  nlohmann::json StatusJson() const;

 private:
  struct DragState {
    glm::dvec2 px0{0.0}, px1{0.0};
    double hand0 = 0, hand1 = 0;
    glm::dvec3 drone_world{0.0};
  };
  void SendPick(const PinholeCamera& cam, const Rigid3d& pose, const LocalOrigin& origin,
                const DragState& d);

  DroneOperator* op_;
  DroneControlsOptions o_;
  bool drone_mode_ = false;
  std::optional<DragState> drag_;
  bool xray_ = false;
  double xray_clip_m_ = 0;
  glm::dvec2 xray_centre_{0.5, 0.5};
  nlohmann::json last_gesture_ = nullptr;  // what was sent last, with the local geometry
  uint64_t clicks_ = 0, drags_ = 0, joypad_s_ms_ = 0;
  bool joy_was_active_ = false;
};

}  // namespace exo
