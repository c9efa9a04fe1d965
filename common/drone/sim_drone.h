// A simulated drone for the control loop (thesis 5.2.2–5.2.3): a position controller with the
// nested loops of the Pixfalcon autopilot (position P → velocity P → attitude/thrust lag →
// acceleration), limits on speed, acceleration and yaw rate, a state at 120 Hz, and the
// behaviour on link loss: when no setpoint arrived for `hold_timeout_s` it brakes to a stop and
// holds the position where it stopped (flight mode HOLD) until setpoints come back (OFFBOARD).
// Also here: a pose/setpoint link with delay, random loss and stalls (the thesis' ~25 ms mocap
// latency and WiFi stalls), and collision counting of the drone's sphere against a ground-truth
// triangle mesh (the synthetic scene's). Pure library: time is passed in, nothing sleeps.
#pragma once

#include <cstdint>
#include <deque>
#include <glm/glm.hpp>
#include <random>
#include <utility>
#include <vector>

#include "common/drone/drone_types.h"
#include "common/mesh.h"
#include "common/status.h"

namespace exo::control {

struct SimDroneOptions {
  double rate_hz = 120.0;  // state rate; each step is integrated in `substeps`
  int substeps = 4;
  // Cascade gains. With the 0.04 s attitude lag, 1.8 / 3.6 gives ~5 % overshoot on a 1 m step
  // (sim_drone_test measures it).
  double position_gain = 1.8;    // 1/s: velocity setpoint per metre of error
  double velocity_gain = 3.6;    // 1/s: acceleration per m/s of velocity error
  double attitude_tau_s = 0.04;  // first-order lag of the attitude/thrust loop
  double max_speed_mps = 1.5;
  double max_accel_mps2 = 3.0;
  double yaw_gain = 3.0;  // 1/s
  double max_yaw_rate_rad_s = 1.5;
  double hold_timeout_s = 0.5;  // no setpoint for this long: HOLD
  double radius_m = 0.15;       // 25 cm frame + margin
  // Camera gimbal: pitch (+ up) follows the setpoint's camera_pitch at this rate, within
  // [min, max] (straight down to 30° up).
  double gimbal_rate_rad_s = 1.5;
  double min_camera_pitch_rad = -1.5707963267948966;
  double max_camera_pitch_rad = 0.5235987755982988;
  absl::Status Validate() const;
};

enum class FlightMode { kOffboard = 0, kHold = 1 };

class SimDrone {
 public:
  explicit SimDrone(const SimDroneOptions& options, const SceneFrame& frame = SceneFrame::ZUp());
  void Reset(const glm::dvec3& position, double yaw, double time_s = 0.0);
  // A setpoint received at `time_s` (the drone's clock).
  void Receive(const Setpoint& sp, double time_s);
  // Advances one state period (1 / rate_hz) and returns the new state.
  const DroneState& Step();
  const DroneState& state() const { return state_; }
  FlightMode mode() const { return mode_; }
  const Setpoint& active_setpoint() const { return active_; }
  double period_s() const { return 1.0 / options_.rate_hz; }
  const SimDroneOptions& options() const { return options_; }
  uint64_t hold_events() const { return hold_events_; }

 private:
  SimDroneOptions options_;
  SceneFrame frame_;
  DroneState state_;
  glm::dvec3 accel_{0.0};
  Setpoint active_;
  double last_receive_s_ = 0.0;
  bool have_setpoint_ = false;
  bool braking_ = false;
  FlightMode mode_ = FlightMode::kHold;
  uint64_t hold_events_ = 0;
};

struct LinkOptions {
  double delay_s = 0.0;
  double loss = 0.0;  // probability a message is lost
  uint64_t seed = 1;
  // Stalls: [start, start + duration) in which every message is lost.
  std::vector<std::pair<double, double>> stalls;
  absl::Status Validate() const;
};

// A one-way message link with delay, loss and stalls.
template <typename T>
class Link {
 public:
  explicit Link(const LinkOptions& o) : options_(o), rng_(o.seed) {}
  void Send(const T& msg, double now_s) {
    ++sent_;
    for (const auto& [start, dur] : options_.stalls)
      if (now_s >= start && now_s < start + dur) {
        ++lost_;
        return;
      }
    if (options_.loss > 0 && std::uniform_real_distribution<double>(0, 1)(rng_) < options_.loss) {
      ++lost_;
      return;
    }
    queue_.emplace_back(now_s + options_.delay_s, msg);
  }
  // Messages due at `now_s`, in send order.
  std::vector<T> Receive(double now_s) {
    std::vector<T> out;
    while (!queue_.empty() && queue_.front().first <= now_s + 1e-12) {
      out.push_back(std::move(queue_.front().second));
      queue_.pop_front();
    }
    return out;
  }
  uint64_t sent() const { return sent_; }
  uint64_t lost() const { return lost_; }

 private:
  LinkOptions options_;
  std::mt19937_64 rng_;
  std::deque<std::pair<double, T>> queue_;
  uint64_t sent_ = 0, lost_ = 0;
};

// Distance queries against a triangle mesh through a uniform grid of triangle buckets.
class MeshDistance {
 public:
  MeshDistance(const TriangleMesh& mesh, double bucket_m = 1.0);
  // Distance from p to the nearest triangle, or `max_m` when none is closer than max_m.
  double Distance(const glm::dvec3& p, double max_m) const;

 private:
  std::vector<glm::dvec3> tri_;  // 3 per triangle
  glm::dvec3 min_{0.0};
  glm::ivec3 dims_{0};
  double bucket_m_;
  std::vector<std::vector<uint32_t>> buckets_;
};

// Counts collisions: a collision begins when the sphere touches the mesh and ends when it is
// clear again (one event per contact, however long).
class CollisionMonitor {
 public:
  CollisionMonitor(const TriangleMesh& mesh, double radius_m) : dist_(mesh), radius_(radius_m) {}
  // Returns true while in contact.
  bool Update(const glm::dvec3& p);
  uint64_t collisions() const { return collisions_; }
  double min_clearance_m() const { return min_clearance_; }

 private:
  MeshDistance dist_;
  double radius_;
  bool in_contact_ = false;
  uint64_t collisions_ = 0;
  double min_clearance_ = 1e9;
};

}  // namespace exo::control
