#include "common/drone/sim_drone.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"

namespace exo::control {
namespace {

// Ericson, Real-Time Collision Detection, 5.1.5.
glm::dvec3 ClosestOnTriangle(const glm::dvec3& p, const glm::dvec3& a, const glm::dvec3& b,
                             const glm::dvec3& c) {
  const glm::dvec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = glm::dot(ab, ap), d2 = glm::dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const glm::dvec3 bp = p - b;
  const double d3 = glm::dot(ab, bp), d4 = glm::dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + ab * (d1 / (d1 - d3));
  const glm::dvec3 cp = p - c;
  const double d5 = glm::dot(ab, cp), d6 = glm::dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + ac * (d2 / (d2 - d6));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
  const double denom = 1.0 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

glm::dvec3 ClampLength(const glm::dvec3& v, double max_len) {
  const double l = glm::length(v);
  return l > max_len && l > 0 ? v * (max_len / l) : v;
}

}  // namespace

absl::Status SimDroneOptions::Validate() const {
  if (!(rate_hz > 0) || substeps < 1)
    return absl::InvalidArgumentError("sim drone: rate_hz > 0 and substeps >= 1 required");
  if (!(position_gain > 0 && velocity_gain > 0 && attitude_tau_s >= 0 && max_speed_mps > 0 &&
        max_accel_mps2 > 0 && yaw_gain > 0 && max_yaw_rate_rad_s > 0 && hold_timeout_s > 0 &&
        radius_m >= 0 && gimbal_rate_rad_s > 0 && min_camera_pitch_rad <= max_camera_pitch_rad))
    return absl::InvalidArgumentError(
        "sim drone: gains, limits and the hold timeout must be positive");
  return absl::OkStatus();
}

absl::Status LinkOptions::Validate() const {
  if (!(delay_s >= 0) || !(loss >= 0 && loss <= 1))
    return absl::InvalidArgumentError("link: delay_s >= 0 and loss in [0, 1] required");
  for (const auto& [s, d] : stalls)
    if (!(d >= 0)) return absl::InvalidArgumentError("link: a stall has a negative duration");
  return absl::OkStatus();
}

SimDrone::SimDrone(const SimDroneOptions& options, const SceneFrame& frame)
    : options_(options), frame_(frame) {
  EXO_CHECK(options_.Validate().ok());
}

void SimDrone::Reset(const glm::dvec3& position, double yaw, double time_s) {
  state_ = DroneState{};
  state_.timestamp_s = time_s;
  state_.position = position;
  state_.yaw = yaw;
  accel_ = glm::dvec3(0.0);
  active_ = Setpoint{position, yaw};
  have_setpoint_ = false;
  braking_ = false;
  mode_ = FlightMode::kHold;
}

void SimDrone::Receive(const Setpoint& sp, double time_s) {
  active_ = sp;
  last_receive_s_ = time_s;
  have_setpoint_ = true;
  braking_ = false;
  mode_ = FlightMode::kOffboard;
}

const DroneState& SimDrone::Step() {
  const double dt = period_s() / options_.substeps;
  for (int i = 0; i < options_.substeps; ++i) {
    const double now = state_.timestamp_s + dt;
    if (mode_ == FlightMode::kOffboard && now - last_receive_s_ > options_.hold_timeout_s) {
      // Link lost: brake and hold where the drone is now.
      mode_ = FlightMode::kHold;
      braking_ = true;
      active_ = Setpoint{state_.position, state_.yaw, state_.camera_pitch};
      ++hold_events_;
    }
    if (braking_ && glm::length(state_.velocity) < 0.05) {
      braking_ = false;  // stopped: hold here
      active_.position = state_.position;
    }
    // Position loop -> velocity setpoint -> velocity loop -> commanded acceleration. Braking
    // (HOLD entered while moving) commands zero velocity until the drone has stopped.
    const glm::dvec3 v_sp =
        braking_ ? glm::dvec3(0.0)
                 : ClampLength(options_.position_gain * (active_.position - state_.position),
                               options_.max_speed_mps);
    const glm::dvec3 a_cmd =
        ClampLength(options_.velocity_gain * (v_sp - state_.velocity), options_.max_accel_mps2);
    // Attitude/thrust loop: the acceleration follows the command with a first-order lag.
    const double k =
        options_.attitude_tau_s > 0 ? std::min(1.0, dt / options_.attitude_tau_s) : 1.0;
    accel_ += k * (a_cmd - accel_);
    state_.velocity += accel_ * dt;
    state_.position += state_.velocity * dt;
    const double yaw_err = WrapAngle(active_.yaw - state_.yaw);
    state_.yaw_rate = std::clamp(options_.yaw_gain * yaw_err, -options_.max_yaw_rate_rad_s,
                                 options_.max_yaw_rate_rad_s);
    state_.yaw = WrapAngle(state_.yaw + state_.yaw_rate * dt);
    const double pitch_goal = std::clamp(active_.camera_pitch, options_.min_camera_pitch_rad,
                                         options_.max_camera_pitch_rad);
    const double pitch_step = options_.gimbal_rate_rad_s * dt;
    state_.camera_pitch += std::clamp(pitch_goal - state_.camera_pitch, -pitch_step, pitch_step);
    state_.timestamp_s = now;
  }
  return state_;
}

MeshDistance::MeshDistance(const TriangleMesh& mesh, double bucket_m) : bucket_m_(bucket_m) {
  const size_t nt = mesh.num_triangles();
  tri_.reserve(nt * 3);
  if (nt == 0) return;
  glm::dvec3 lo(1e300), hi(-1e300);
  for (size_t i = 0; i < mesh.indices.size(); ++i) {
    const glm::dvec3 p(mesh.positions[mesh.indices[i]]);
    tri_.push_back(p);
    lo = glm::min(lo, p);
    hi = glm::max(hi, p);
  }
  min_ = lo;
  dims_ = glm::max(glm::ivec3(glm::floor((hi - lo) / bucket_m_)) + 1, glm::ivec3(1));
  buckets_.resize(static_cast<size_t>(dims_.x) * dims_.y * dims_.z);
  for (size_t t = 0; t < nt; ++t) {
    const glm::dvec3 a = tri_[3 * t], b = tri_[3 * t + 1], c = tri_[3 * t + 2];
    const glm::ivec3 c0 =
        glm::clamp(glm::ivec3(glm::floor((glm::min(a, glm::min(b, c)) - min_) / bucket_m_)),
                   glm::ivec3(0), dims_ - 1);
    const glm::ivec3 c1 =
        glm::clamp(glm::ivec3(glm::floor((glm::max(a, glm::max(b, c)) - min_) / bucket_m_)),
                   glm::ivec3(0), dims_ - 1);
    for (int z = c0.z; z <= c1.z; ++z)
      for (int y = c0.y; y <= c1.y; ++y)
        for (int x = c0.x; x <= c1.x; ++x)
          buckets_[(static_cast<size_t>(z) * dims_.y + y) * dims_.x + x].push_back(
              static_cast<uint32_t>(t));
  }
}

double MeshDistance::Distance(const glm::dvec3& p, double max_m) const {
  if (buckets_.empty()) return max_m;
  const glm::ivec3 c0 =
      glm::clamp(glm::ivec3(glm::floor((p - max_m - min_) / bucket_m_)), glm::ivec3(0), dims_ - 1);
  const glm::ivec3 c1 =
      glm::clamp(glm::ivec3(glm::floor((p + max_m - min_) / bucket_m_)), glm::ivec3(0), dims_ - 1);
  double best = max_m;
  for (int z = c0.z; z <= c1.z; ++z)
    for (int y = c0.y; y <= c1.y; ++y)
      for (int x = c0.x; x <= c1.x; ++x)
        for (uint32_t t : buckets_[(static_cast<size_t>(z) * dims_.y + y) * dims_.x + x]) {
          const double d =
              glm::length(p - ClosestOnTriangle(p, tri_[3 * t], tri_[3 * t + 1], tri_[3 * t + 2]));
          best = std::min(best, d);
        }
  return best;
}

bool CollisionMonitor::Update(const glm::dvec3& p) {
  const double d = dist_.Distance(p, radius_ + 1.0);
  min_clearance_ = std::min(min_clearance_, d - radius_);
  const bool contact = d < radius_;
  if (contact && !in_contact_) ++collisions_;
  in_contact_ = contact;
  return contact;
}

}  // namespace exo::control
