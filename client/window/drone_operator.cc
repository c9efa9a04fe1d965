#include "client/window/drone_operator.h"

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>

namespace exo {
namespace {

namespace cv1 = exoview::control::v1;

cv1::Vec3 ToProto(const glm::dvec3& v) {
  cv1::Vec3 p;
  p.set_x(v.x);
  p.set_y(v.y);
  p.set_z(v.z);
  return p;
}
glm::dvec3 FromProto(const cv1::Vec3& v) { return {v.x(), v.y(), v.z()}; }
nlohmann::json J(const glm::dvec3& v) { return {v.x, v.y, v.z}; }

const char* CodeName(grpc::StatusCode c) {
  switch (c) {
    case grpc::StatusCode::OK:
      return "OK";
    case grpc::StatusCode::CANCELLED:
      return "CANCELLED";
    case grpc::StatusCode::INVALID_ARGUMENT:
      return "INVALID_ARGUMENT";
    case grpc::StatusCode::DEADLINE_EXCEEDED:
      return "DEADLINE_EXCEEDED";
    case grpc::StatusCode::NOT_FOUND:
      return "NOT_FOUND";
    case grpc::StatusCode::PERMISSION_DENIED:
      return "PERMISSION_DENIED";
    case grpc::StatusCode::FAILED_PRECONDITION:
      return "FAILED_PRECONDITION";
    case grpc::StatusCode::ABORTED:
      return "ABORTED";
    case grpc::StatusCode::UNIMPLEMENTED:
      return "UNIMPLEMENTED";
    case grpc::StatusCode::UNAVAILABLE:
      return "UNAVAILABLE";
    case grpc::StatusCode::UNAUTHENTICATED:
      return "UNAUTHENTICATED";
    default:
      return "ERROR";
  }
}

}  // namespace

std::string OperatorReply::Summary() const {
  char buf[256];
  if (!ok) {
    std::snprintf(buf, sizeof(buf), "%s: %s: %s", action.c_str(), code.c_str(), message.c_str());
    return buf;
  }
  std::snprintf(buf, sizeof(buf), "%s #%llu: target (%.2f %.2f %.2f) %zu waypoint%s%s%s%s",
                action.c_str(), (unsigned long long)command_sequence, target.x, target.y, target.z,
                waypoints.size(), waypoints.size() == 1 ? "" : "s", clamped ? " clamped" : "",
                note.empty() ? "" : "; ", note.c_str());
  return buf;
}

nlohmann::json OperatorReply::ToJson() const {
  nlohmann::json j = {{"action", action},    {"ok", ok},
                      {"code", code},        {"message", message},
                      {"rtt_ms", rtt_ms},    {"operator_sequence", operator_sequence},
                      {"summary", Summary()}};
  if (ok) {
    j["command_sequence"] = command_sequence;
    j["target"] = J(target);
    j["target_yaw"] = target_yaw;
    nlohmann::json w = nlohmann::json::array();
    for (const auto& p : waypoints) w.push_back(J(p));
    j["waypoints"] = std::move(w);
    j["clamped"] = clamped;
    j["note"] = note;
    if (has_gaze) {
      j["gaze_point"] = J(gaze_point);
      j["gaze_normal"] = J(gaze_normal);
    }
  }
  return j;
}

DroneOperator::DroneOperator(std::shared_ptr<grpc::Channel> channel, std::string drone_id,
                             std::string operator_id, double joypad_period_s)
    : drone_id_(std::move(drone_id)),
      operator_id_(std::move(operator_id)),
      joypad_period_s_(joypad_period_s),
      stub_(cv1::Control::NewStub(std::move(channel))) {
  sequence_ = uint64_t(std::chrono::duration_cast<std::chrono::microseconds>(
                           std::chrono::system_clock::now().time_since_epoch())
                           .count());
  thread_ = std::thread([this] { Run(); });
}

DroneOperator::~DroneOperator() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

void DroneOperator::GazeToSee(const glm::dvec3& eye, const glm::dvec3& direction) {
  {
    std::lock_guard lock(mu_);
    if (jobs_.size() >= 8) {
      jobs_.pop_front();
      ++dropped_;
    }
    jobs_.push_back({Job::kGaze, eye, direction, {}});
  }
  cv_.notify_all();
}

void DroneOperator::PickAndPlace(const glm::dvec3& eye, const glm::dvec3& hand,
                                 const glm::dvec3& disp) {
  {
    std::lock_guard lock(mu_);
    if (jobs_.size() >= 8) {
      jobs_.pop_front();
      ++dropped_;
    }
    jobs_.push_back({Job::kPick, eye, hand, disp});
  }
  cv_.notify_all();
}

void DroneOperator::Joypad(const nav::Sticks& sticks, double dt_s) {
  if (!(dt_s > 0)) return;
  {
    std::lock_guard lock(mu_);
    joy_ = sticks;
    joy_dt_ = std::min(1.0, joy_dt_ + dt_s);  // the server integrates at most 1 s per request
  }
  cv_.notify_all();
}

std::optional<OperatorReply> DroneOperator::last() {
  std::lock_guard lock(mu_);
  return last_;
}
uint64_t DroneOperator::sent() const {
  std::lock_guard lock(mu_);
  return sent_;
}
uint64_t DroneOperator::dropped() const {
  std::lock_guard lock(mu_);
  return dropped_;
}

nlohmann::json DroneOperator::StatusJson() {
  std::lock_guard lock(mu_);
  nlohmann::json j = {{"operator_id", operator_id_},
                      {"sent", sent_},
                      {"joypad_sent", joypad_sent_},
                      {"dropped", dropped_}};
  if (last_) j["last"] = last_->ToJson();
  for (const auto& [k, r] : last_by_action_) j["last_" + k] = r.ToJson();
  return j;
}

cv1::OperatorHeader DroneOperator::Header() {
  cv1::OperatorHeader h;
  h.set_operator_id(operator_id_);
  h.set_operator_sequence(++sequence_);
  h.set_drone_id(drone_id_);
  return h;
}

void DroneOperator::Run() {
  using Clock = std::chrono::steady_clock;
  auto t_joy = Clock::now() - std::chrono::seconds(1);
  std::unique_lock lock(mu_);
  while (!stop_) {
    const bool joy_due =
        joy_dt_ > 0 &&
        std::chrono::duration<double>(Clock::now() - t_joy).count() >= joypad_period_s_;
    if (jobs_.empty() && !joy_due) {
      if (joy_dt_ > 0)
        cv_.wait_for(lock, std::chrono::milliseconds(int(joypad_period_s_ * 1000) + 1));
      else
        cv_.wait(lock);
      continue;
    }
    OperatorReply r;
    cv1::InteractionReply reply;
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
    grpc::Status gs;
    const auto t0 = Clock::now();
    if (!jobs_.empty()) {
      const Job job = jobs_.front();
      jobs_.pop_front();
      const cv1::OperatorHeader h = Header();
      r.operator_sequence = h.operator_sequence();
      ++sent_;
      lock.unlock();
      if (job.kind == Job::kGaze) {
        r.action = "gaze";
        cv1::GazeToSeeRequest req;
        *req.mutable_header() = h;
        *req.mutable_eye() = ToProto(job.a);
        *req.mutable_direction() = ToProto(job.b);
        gs = stub_->GazeToSee(&ctx, req, &reply);
      } else {
        r.action = "pick";
        cv1::PickAndPlaceRequest req;
        *req.mutable_header() = h;
        *req.mutable_eye() = ToProto(job.a);
        *req.mutable_hand() = ToProto(job.b);
        *req.mutable_hand_displacement() = ToProto(job.c);
        gs = stub_->PickAndPlace(&ctx, req, &reply);
      }
    } else {
      const nav::Sticks s = joy_;
      const double dt = std::exchange(joy_dt_, 0.0);
      t_joy = Clock::now();
      const cv1::OperatorHeader h = Header();
      r.operator_sequence = h.operator_sequence();
      ++sent_;
      ++joypad_sent_;
      lock.unlock();
      r.action = "joypad";
      cv1::JoypadRequest req;
      *req.mutable_header() = h;
      req.set_left_x(s.left_x);
      req.set_left_y(s.left_y);
      req.set_right_x(s.right_x);
      req.set_right_y(s.right_y);
      req.set_dt_s(dt);
      gs = stub_->Joypad(&ctx, req, &reply);
    }
    r.rtt_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    r.ok = gs.ok();
    r.code = CodeName(gs.error_code());
    r.message = gs.error_message();
    if (gs.ok()) {
      r.command_sequence = reply.command_sequence();
      r.target = FromProto(reply.target());
      r.target_yaw = reply.target_yaw();
      for (const auto& w : reply.waypoints()) r.waypoints.push_back(FromProto(w));
      r.has_gaze = reply.has_gaze();
      r.gaze_point = FromProto(reply.gaze_point());
      r.gaze_normal = FromProto(reply.gaze_normal());
      r.clamped = reply.clamped();
      r.note = reply.note();
    }
    lock.lock();
    last_ = r;
    last_by_action_[r.action] = r;
  }
}

// ---- DroneControls ----

void DroneControls::Click(const PinholeCamera& cam, const Rigid3d& pose, const LocalOrigin& origin,
                          const glm::dvec2& px, std::optional<glm::dvec3> local_hit) {
  const double clip = ClipAt(cam, px);
  const nav::Ray3 r = nav::GazeRay(cam, pose, px, clip);
  const glm::dvec3 eye = r.origin + origin.origin_in_world;
  ++clicks_;
  last_gesture_ = {{"gesture", "click"},
                   {"px", {px.x, px.y}},
                   {"eye", J(eye)},
                   {"direction", J(r.dir)},
                   {"from_xray_plane", clip > 0}};
  // What the viewer's own proxy says is under the cursor (the server casts into its copy).
  if (local_hit)
    last_gesture_["local_hit"] = J(*local_hit + origin.origin_in_world);
  else
    last_gesture_["local_hit"] = nullptr;
  if (op_) op_->GazeToSee(eye, r.dir);
}

bool DroneControls::BeginDrag(const glm::dvec2& px, std::optional<glm::dvec2> drone_px,
                              std::optional<glm::dvec3> drone_world) {
  drag_.reset();
  if (!drone_px || !drone_world || glm::length(*drone_px - px) > o_.pick_radius_px) return false;
  drag_ = DragState{px, px, o_.hand_m, o_.hand_m, *drone_world};
  return true;
}

std::optional<nav::PickPlacePreview> DroneControls::Preview(const PinholeCamera& cam,
                                                            const Rigid3d& pose,
                                                            const LocalOrigin& origin) const {
  if (!drag_) return std::nullopt;
  const nav::MouseHand h =
      nav::HandFromDrag(cam, pose, drag_->px0, drag_->hand0, drag_->px1, drag_->hand1);
  return nav::PreviewPickAndPlace(drag_->drone_world, h.eye + origin.origin_in_world,
                                  h.hand + origin.origin_in_world, h.displacement);
}

void DroneControls::SendPick(const PinholeCamera& cam, const Rigid3d& pose,
                             const LocalOrigin& origin, const DragState& d) {
  const nav::MouseHand h = nav::HandFromDrag(cam, pose, d.px0, d.hand0, d.px1, d.hand1);
  const glm::dvec3 eye = h.eye + origin.origin_in_world, hand = h.hand + origin.origin_in_world;
  const nav::PickPlacePreview p =
      nav::PreviewPickAndPlace(d.drone_world, eye, hand, h.displacement);
  ++drags_;
  last_gesture_ = {{"gesture", "drag"},         {"px0", {d.px0.x, d.px0.y}},
                   {"px1", {d.px1.x, d.px1.y}}, {"hand0_m", d.hand0},
                   {"hand1_m", d.hand1},        {"eye", J(eye)},
                   {"hand", J(hand)},           {"hand_displacement", J(h.displacement)},
                   {"drone", J(d.drone_world)}, {"preview_target", J(p.target)},
                   {"preview_scale", p.scale},  {"preview_guarded", p.guarded}};
  if (op_) op_->PickAndPlace(eye, hand, h.displacement);
}

bool DroneControls::EndDrag(const PinholeCamera& cam, const Rigid3d& pose,
                            const LocalOrigin& origin) {
  if (!drag_) return false;
  const DragState d = *drag_;
  drag_.reset();
  if (glm::length(d.px1 - d.px0) < 1.0 && d.hand1 == d.hand0) return true;  // not moved
  SendPick(cam, pose, origin, d);
  return true;
}

void DroneControls::Drag(const PinholeCamera& cam, const Rigid3d& pose, const LocalOrigin& origin,
                         const glm::dvec2& px0, const glm::dvec2& px1, double hand0, double hand1,
                         const glm::dvec3& drone_world) {
  SendPick(cam, pose, origin,
           DragState{px0, px1, hand0 < 0 ? o_.hand_m : hand0, hand1 < 0 ? o_.hand_m : hand1,
                     drone_world});
}

void DroneControls::Joypad(const nav::JoypadKeys& keys, double dt_s) {
  Gamepad(nav::SticksFromKeys(keys), dt_s);
}

void DroneControls::Gamepad(const nav::Sticks& s, double dt_s) {
  if (s.zero()) {
    joy_was_active_ = false;
    return;
  }
  joy_was_active_ = true;
  joypad_s_ms_ += uint64_t(std::max(0.0, dt_s) * 1000);
  if (op_) op_->Joypad(s, dt_s);
}

void DroneControls::ToggleXray(std::optional<double> z_under_cursor, const glm::dvec2& centre) {
  xray_ = !xray_;
  if (xray_) {
    xray_clip_m_ = nav::XrayClipDistance(z_under_cursor, o_.xray_margin_m, o_.xray_default_m);
    xray_centre_ = centre;
  }
}

double DroneControls::ClipAt(const PinholeCamera& cam, const glm::dvec2& px) const {
  if (!xray_ || !nav::InsideXrayHole(px, cam.width, cam.height, xray_centre_, o_.xray_radius))
    return 0.0;
  return xray_clip_m_;
}

void DroneControls::MoveXray(int steps) {
  if (xray_) xray_clip_m_ = std::max(0.05, xray_clip_m_ + steps * o_.xray_step_m);
}

std::string DroneControls::HudLine() const {
  char buf[200];
  std::snprintf(buf, sizeof(buf), "%s  ctrl/M: click gaze, drag drone  IJKL UO YH joypad  X x-ray",
                drone_mode_ ? "DRONE MODE" : "operator");
  std::string s = buf;
  if (xray_) {
    std::snprintf(buf, sizeof(buf), "  |  X-RAY: a hole at the cursor cut at %.2f m ([ ])",
                  xray_clip_m_);
    s += buf;
  }
  if (drag_) {
    std::snprintf(buf, sizeof(buf), "  |  dragging the drone, hand %.2f m (wheel)", drag_->hand1);
    s += buf;
  }
  return s;
}

nlohmann::json DroneControls::StatusJson() const {
  nlohmann::json j = {
      {"drone_mode", drone_mode_},
      {"xray", xray_},
      {"xray_clip_m", xray_ ? nlohmann::json(xray_clip_m_) : nlohmann::json(nullptr)},
      {"xray_centre", xray_ ? nlohmann::json({xray_centre_.x, xray_centre_.y})
                            : nlohmann::json(nullptr)},
      {"xray_radius", o_.xray_radius},
      {"dragging", drag_.has_value()},
      {"clicks", clicks_},
      {"drags", drags_},
      {"joypad_held_ms", joypad_s_ms_},
      {"last_gesture", last_gesture_}};
  if (op_) j["operator"] = op_->StatusJson();
  return j;
}

}  // namespace exo
