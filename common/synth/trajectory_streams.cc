// Realistic camera streams for issue 22 (see trajectory.h): a drone exploration and a handheld
// walk, generated as a sequence of actions (travel to a place, hover / stop, pan / look around)
// drawn from a seeded RNG. The draws never depend on the requested length, so a stream of N
// frames is the prefix of any longer stream of the same seed.
#include <algorithm>
#include <cmath>
#include <functional>
#include <random>

#include <absl/strings/str_cat.h>
#include <glm/gtc/constants.hpp>

#include "common/synth/trajectory_path.h"

namespace exo::synth::internal {
namespace {

constexpr double kPi = glm::pi<double>();
double Rad(double deg) { return deg * kPi / 180.0; }
double Wrap(double a) { return std::remainder(a, 2 * kPi); }
// `cur` moved towards `target` (angles) by at most `max_step`.
double Approach(double cur, double target, double max_step) {
  return cur + std::clamp(Wrap(target - cur), -max_step, max_step);
}

// Trapezoidal speed profile over a distance D: accelerate at a to the cruise speed v, cruise,
// brake at a (a triangle when D is too short to reach v).
struct Profile {
  double D = 0, v = 1, a = 1, tr = 0, T = 0;
  Profile(double dist, double speed, double accel) : D(dist), v(speed), a(accel) {
    if (D <= 0) return;
    if (D < v * v / a) v = std::sqrt(D * a);
    tr = v / a;
    T = 2 * tr + (D - v * tr) / v;
  }
  double At(double t) const {
    if (t <= 0 || D <= 0) return 0;
    if (t >= T) return D;
    if (t < tr) return 0.5 * a * t * t;
    if (t > T - tr) return D - 0.5 * a * (T - t) * (T - t);
    return 0.5 * a * tr * tr + v * (t - tr);
  }
};

// How the camera moves and what it does at places.
struct Style {
  double v_min, v_max, accel;           // cruise speed range per leg (m/s), acceleration (m/s²)
  double yaw_rate_deg;                  // heading change limit while travelling (deg/s)
  double pitch_min_deg, pitch_max_deg;  // below the horizon, drawn per leg
  double pitch_rate_deg = 20;
  double p_hold, hold_min_s, hold_max_s;  // hover / stop at a place
  Motion hold_motion;
  double p_turn, turn_min_deg, turn_max_deg, turn_rate_min_deg, turn_rate_max_deg;
  Motion turn_motion;
  bool look_around;    // turn there and back (handheld) instead of a one-way pan (drone)
  double p_revisit;    // probability that the next place is an earlier one
  bool shake;          // hand shake and head bob (handheld)
};

Style DroneStyle(bool indoor) {
  Style s;
  s.v_min = indoor ? 0.4 : 1.5;
  s.v_max = indoor ? 2.0 : 8.0;
  s.accel = indoor ? 1.0 : 2.5;
  s.yaw_rate_deg = 90;
  s.pitch_min_deg = indoor ? 5 : 25;
  s.pitch_max_deg = indoor ? 30 : 55;
  s.pitch_rate_deg = 15;
  s.p_hold = 0.6;
  s.hold_min_s = 3;
  s.hold_max_s = 8;
  s.hold_motion = Motion::kHover;
  s.p_turn = 0.5;
  s.turn_min_deg = 90;
  s.turn_max_deg = 360;
  s.turn_rate_min_deg = 90;
  s.turn_rate_max_deg = 180;
  s.turn_motion = Motion::kPan;
  s.look_around = false;
  s.p_revisit = 0.4;
  s.shake = false;
  return s;
}

Style HandheldStyle() {
  Style s;
  s.v_min = 0.5;
  s.v_max = 1.4;
  s.accel = 0.8;
  s.yaw_rate_deg = 120;
  s.pitch_min_deg = 3;
  s.pitch_max_deg = 15;
  s.p_hold = 0.75;
  s.hold_min_s = 1.5;
  s.hold_max_s = 4;
  s.hold_motion = Motion::kStop;
  s.p_turn = 0.6;
  s.turn_min_deg = 45;
  s.turn_max_deg = 160;
  s.turn_rate_min_deg = 40;
  s.turn_rate_max_deg = 80;
  s.turn_motion = Motion::kLookAround;
  s.look_around = true;
  s.p_revisit = 0.35;
  s.shake = true;
  return s;
}

// Appends frames at the frame rate until the requested count; every action draws its random
// numbers whether or not its frames are still wanted (the prefix property).
class Streamer {
 public:
  Streamer(int n, double hz, const Style& style, std::mt19937_64* rng)
      : n_(n), hz_(hz), style_(style), rng_(rng) {
    out_.reserve(n);
    for (double& p : phase_) p = Uni(0, 2 * kPi);
  }
  double Uni(double a, double b) { return std::uniform_real_distribution<double>(a, b)(*rng_); }
  bool Done() const { return int(out_.size()) >= n_; }
  std::vector<TimedPose> Take() { return std::move(out_); }

  glm::dvec3 eye{0.0};
  double yaw = 0, pitch = 0;

  void Emit(Motion m, int place) {
    if (Done()) return;
    const double t = double(out_.size()) / hz_;
    glm::dvec3 e = eye;
    double y = yaw, p = pitch;
    if (style_.shake) {  // ~1 cm / ~0.6 deg of smooth hand shake, 2.5 cm head bob when walking
      e += 0.01 * glm::dvec3(std::sin(2.1 * t + phase_[0]), std::sin(1.7 * t + phase_[1]),
                             std::sin(2.9 * t + phase_[2]));
      y += Rad(0.6) * std::sin(1.3 * t + phase_[3]);
      p += Rad(0.5) * std::sin(1.9 * t + phase_[4]);
      if (m == Motion::kMove) e.z += 0.025 * std::sin(2 * kPi * 1.8 * t + phase_[5]);
    }
    TimedPose tp;
    tp.timestamp_s = t;
    tp.local_from_cam = LookAt(e, e + Direction(y, p));
    tp.motion = m;
    tp.place = place;
    out_.push_back(tp);
  }
  void Hold(double seconds, Motion m, int place) {
    const int k = std::max(1, int(std::lround(seconds * hz_)));
    for (int i = 0; i < k; ++i) Emit(m, place);
  }
  void Turn(double delta, double rate, Motion m, int place) {
    const int k = std::max(1, int(std::ceil(std::abs(delta) / rate * hz_)));
    const double y0 = yaw;
    for (int i = 1; i <= k; ++i) {
      yaw = y0 + delta * i / k;
      Emit(m, place);
    }
    yaw = Wrap(yaw);
  }
  // Travels u = 0..D along `at(u)` with the trapezoidal profile; the heading follows
  // `heading(u)` and the pitch `target_pitch`, both rate limited.
  void Travel(const std::function<glm::dvec3(double)>& at,
              const std::function<double(double)>& heading, double D, double v,
              double target_pitch) {
    const Profile pr(D, v, style_.accel);
    const int k = std::max(1, int(std::ceil(pr.T * hz_)));
    for (int i = 1; i <= k; ++i) {
      const double u = pr.At(pr.T * i / k);
      eye = at(u);
      yaw = Approach(yaw, heading(u), Rad(style_.yaw_rate_deg) / hz_);
      pitch = Approach(pitch, target_pitch, Rad(style_.pitch_rate_deg) / hz_);
      Emit(Motion::kMove, -1);
    }
  }
  // At a place: maybe hover / stop, maybe pan / look around.
  void AtPlace(int place) {
    const bool hold = Uni(0, 1) < style_.p_hold;
    const double hold_s = Uni(style_.hold_min_s, style_.hold_max_s);
    const bool turn = Uni(0, 1) < style_.p_turn;
    const double sign = Uni(0, 1) < 0.5 ? 1.0 : -1.0;
    const double a = Rad(Uni(style_.turn_min_deg, style_.turn_max_deg));
    const double b = Rad(Uni(style_.turn_min_deg, style_.turn_max_deg));
    const double rate = Rad(Uni(style_.turn_rate_min_deg, style_.turn_rate_max_deg));
    const double pause = Uni(0.3, 1.0);
    if (hold) Hold(hold_s, style_.hold_motion, place);
    if (!turn) return;
    Turn(sign * a, rate, style_.turn_motion, place);
    if (!style_.look_around) return;
    Hold(pause, style_.turn_motion, place);
    Turn(-sign * (a + b), rate, style_.turn_motion, place);
    Hold(pause, style_.turn_motion, place);
    Turn(sign * b, rate, style_.turn_motion, place);
  }

 private:
  int n_;
  double hz_;
  Style style_;
  std::mt19937_64* rng_;
  double phase_[6] = {};
  std::vector<TimedPose> out_;
};

// Along the scene's walk path (indoor drone, handheld): places are arc lengths s. Exploring
// moves 6-20 % of the path (of at most 40 m of it) beyond the farthest place so far (anywhere
// once the path is explored); a revisit goes back to an earlier place at least 3 m (and 10 % of
// that length) away along the path.
absl::StatusOr<std::vector<TimedPose>> PathStream(const SynthScene& scene,
                                                  const TrajectoryOptions& o, const Style& style,
                                                  double z_min, double z_max, uint64_t salt) {
  if (scene.walk_waypoints.size() < 2)
    return absl::InvalidArgumentError(absl::StrCat("scene '", scene.name, "' has no walk path"));
  std::mt19937_64 rng(o.seed * 0xA0761D6478BD642Full + salt);
  Streamer st(o.num_frames, o.frame_rate_hz, style, &rng);
  const ArcLengthPath path(scene.walk_waypoints);
  const double L = path.Length();
  const double scale = std::min(L, 40.0);
  const double window = scene.indoor ? 1.5 : 2.5;
  const bool own_z = z_max > 0;
  std::vector<double> place_s = {0.0}, place_z = {own_z ? st.Uni(z_min, z_max) : 0.0};
  double s = 0, hi = 0;
  auto yaw_at = [&](double at_s, double dir) {
    const glm::dvec3 h = path.Heading(at_s, window) * dir;
    return std::atan2(h.y, h.x);
  };
  st.eye = path.At(0);
  if (own_z) st.eye.z = place_z[0];
  st.yaw = yaw_at(0, 1);
  st.pitch = -Rad(st.Uni(style.pitch_min_deg, style.pitch_max_deg));
  st.AtPlace(0);
  while (!st.Done()) {
    const bool want_revisit = place_s.size() >= 3 && st.Uni(0, 1) < style.p_revisit;
    const double r_pick = st.Uni(0, 1), r_explore = st.Uni(0.06, 0.2) * scale;
    const double r_wander = st.Uni(0, L);
    const double v = st.Uni(style.v_min, style.v_max);
    const double pitch = -Rad(st.Uni(style.pitch_min_deg, style.pitch_max_deg));
    const double z_new = own_z ? st.Uni(z_min, z_max) : 0.0;
    int place = -1;
    if (want_revisit) {
      std::vector<int> far;
      for (size_t k = 0; k < place_s.size(); ++k)
        if (std::abs(place_s[k] - s) > std::max(3.0, 0.1 * scale)) far.push_back(int(k));
      if (!far.empty()) place = far[std::min(far.size() - 1, size_t(r_pick * far.size()))];
    }
    if (place < 0) {
      place = int(place_s.size());
      place_s.push_back(hi < L - 1e-6 ? std::min(L, hi + r_explore) : r_wander);
      place_z.push_back(z_new);
    }
    const double target = place_s[place];
    hi = std::max(hi, target);
    const double dir = target >= s ? 1.0 : -1.0, D = std::abs(target - s);
    const double s0 = s, z0 = st.eye.z, z1 = place_z[place];
    auto at = [&](double u) {
      glm::dvec3 p = path.At(s0 + dir * u);
      if (own_z) p.z = D > 0 ? z0 + (z1 - z0) * u / D : z1;
      return p;
    };
    st.Travel(at, [&](double u) { return yaw_at(s0 + dir * u, dir); }, D, v, pitch);
    s = target;
    st.AtPlace(place);
  }
  return st.Take();
}

// Outdoors: free flight between places at 14-24 m. A new place is the best of 8 random free
// points (reachable on a straight free leg) by distance to the places seen so far minus 0.6 x
// the leg length (explores, but not only the far corners); a revisit flies back to an earlier
// place other than the last two.
absl::StatusOr<std::vector<TimedPose>> OutdoorDrone(const SynthScene& scene,
                                                    const TrajectoryOptions& o) {
  const Style style = DroneStyle(false);
  std::mt19937_64 rng(o.seed * 0xA0761D6478BD642Full + 0xE7037ED1A0B428DBull);
  Streamer st(o.num_frames, o.frame_rate_hz, style, &rng);
  const Box3& nav = scene.navigable;
  const double inset = 6.0;
  const double z_lo = std::min(14.0, nav.max.z - 2), z_hi = std::min(24.0, nav.max.z - 1);
  auto leg_free = [&](const glm::dvec3& a, const glm::dvec3& b) {
    const int k = std::max(1, int(std::ceil(glm::length(b - a))));
    for (int i = 0; i <= k; ++i)
      if (!scene.IsFree(a + (b - a) * (double(i) / k), 1.5)) return false;
    return true;
  };
  auto random_point = [&] {
    return glm::dvec3(st.Uni(nav.min.x + inset, nav.max.x - inset),
                      st.Uni(nav.min.y + inset, nav.max.y - inset), st.Uni(z_lo, z_hi));
  };
  std::vector<glm::dvec3> places;
  for (int attempt = 0; attempt < 1000 && places.empty(); ++attempt) {
    const glm::dvec3 p = random_point();
    if (scene.IsFree(p, 1.5)) places.push_back(p);
  }
  if (places.empty())
    return absl::FailedPreconditionError(
        absl::StrCat("scene '", scene.name, "': no free start for the drone"));
  st.eye = places[0];
  st.yaw = st.Uni(-kPi, kPi);
  st.pitch = -Rad(st.Uni(style.pitch_min_deg, style.pitch_max_deg));
  st.AtPlace(0);
  int cur = 0, prev = -1;
  while (!st.Done()) {
    const bool want_revisit = places.size() >= 4 && st.Uni(0, 1) < style.p_revisit;
    const double r_pick = st.Uni(0, 1);
    const double v = st.Uni(style.v_min, style.v_max);
    const double pitch = -Rad(st.Uni(style.pitch_min_deg, style.pitch_max_deg));
    int next = -1;
    if (want_revisit) {
      std::vector<int> cand;
      for (int k = 0; k < int(places.size()); ++k)
        if (k != cur && k != prev && leg_free(places[cur], places[k])) cand.push_back(k);
      if (!cand.empty()) next = cand[std::min(cand.size() - 1, size_t(r_pick * cand.size()))];
    }
    if (next < 0) {
      double best = -1e300;
      glm::dvec3 best_p{0.0};
      for (int tries = 0; tries < 64 && (tries < 8 || best < -1e299); ++tries) {
        const glm::dvec3 p = random_point();
        if (!leg_free(places[cur], p)) continue;
        double dmin = 1e300;
        for (const glm::dvec3& q : places)
          dmin = std::min(dmin, glm::length(glm::dvec2(p - q)));
        const double score = dmin - 0.6 * glm::length(p - places[cur]);
        if (score > best) {
          best = score;
          best_p = p;
        }
      }
      if (best < -1e299)
        return absl::InternalError(absl::StrCat("scene '", scene.name,
                                                "': the drone found no free leg"));
      next = int(places.size());
      places.push_back(best_p);
    }
    const glm::dvec3 a = places[cur], b = places[next];
    const double D = glm::length(b - a);
    const double heading = std::atan2(b.y - a.y, b.x - a.x);
    st.Travel([&](double u) { return D > 0 ? a + (b - a) * (u / D) : b; },
              [&](double) { return heading; }, D, v, pitch);
    prev = cur;
    cur = next;
    st.AtPlace(cur);
  }
  return st.Take();
}

}  // namespace

absl::StatusOr<std::vector<TimedPose>> MakeDroneStream(const SynthScene& scene,
                                                       const TrajectoryOptions& options) {
  if (scene.indoor || scene.flyover_altitude_m <= 0)
    return PathStream(scene, options, DroneStyle(true), 1.2, 2.0, 0x8EBC6AF09C88C6E3ull);
  return OutdoorDrone(scene, options);
}

absl::StatusOr<std::vector<TimedPose>> MakeHandheldStream(const SynthScene& scene,
                                                          const TrajectoryOptions& options) {
  return PathStream(scene, options, HandheldStyle(), 0, 0, 0x589965CC75374CC3ull);
}

}  // namespace exo::synth::internal
