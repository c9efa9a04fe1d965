#include "server/control/interactions.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"
#include "server/control/safe_flight.h"

namespace exo::control {
namespace {

bool Finite(const glm::dvec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

double Deadzone(double v, double dz) {
  v = std::clamp(v, -1.0, 1.0);
  if (std::abs(v) <= dz) return 0.0;
  return (v - std::copysign(dz, v)) / (1.0 - dz);
}

}  // namespace

std::optional<RayHit> MeshRaycaster::Cast(const glm::dvec3& origin, const glm::dvec3& dir_in,
                                          double max_t) const {
  const glm::dvec3 dir = glm::normalize(dir_in);
  // In the mesh's frame (float positions near the local origin).
  const glm::dvec3 o = origin - offset_;
  std::optional<RayHit> best;
  for (size_t t = 0; t + 2 < mesh_.indices.size(); t += 3) {
    const glm::dvec3 a(mesh_.positions[mesh_.indices[t]]);
    const glm::dvec3 b(mesh_.positions[mesh_.indices[t + 1]]);
    const glm::dvec3 c(mesh_.positions[mesh_.indices[t + 2]]);
    const glm::dvec3 e1 = b - a, e2 = c - a;
    const glm::dvec3 p = glm::cross(dir, e2);
    const double det = glm::dot(e1, p);
    if (std::abs(det) < 1e-12) continue;
    const double inv = 1.0 / det;
    const glm::dvec3 s = o - a;
    const double u = glm::dot(s, p) * inv;
    if (u < 0 || u > 1) continue;
    const glm::dvec3 q = glm::cross(s, e1);
    const double v = glm::dot(dir, q) * inv;
    if (v < 0 || u + v > 1) continue;
    const double dist = glm::dot(e2, q) * inv;
    if (dist <= 1e-6 || dist > max_t || (best && dist >= best->t)) continue;
    glm::dvec3 n = glm::cross(e1, e2);
    const double nl = glm::length(n);
    if (!(nl > 0)) continue;
    n /= nl;
    if (glm::dot(n, dir) > 0) n = -n;
    best = RayHit{dist, origin + dist * dir, n, t / 3};
  }
  return best;
}

absl::StatusOr<PickAndPlaceResult> PickAndPlace(const glm::dvec3& drone, const glm::dvec3& eye,
                                                const glm::dvec3& hand,
                                                const glm::dvec3& hand_displacement,
                                                const PickAndPlaceOptions& options) {
  if (!Finite(drone) || !Finite(eye) || !Finite(hand) || !Finite(hand_displacement))
    return absl::InvalidArgumentError("pick-and-place: non-finite position or displacement");
  PickAndPlaceResult r;
  const double hand_eye = glm::length(hand - eye);
  const double denom = std::max(hand_eye, options.min_hand_eye_m);
  r.guarded = hand_eye < options.min_hand_eye_m;
  r.scale = glm::length(drone - eye) / denom;
  if (r.scale > options.max_scale) {
    r.scale = options.max_scale;
    r.guarded = true;
  }
  r.target = drone + r.scale * hand_displacement;
  return r;
}

absl::StatusOr<GazeResult> GazeToSee(const MeshRaycaster& model, const glm::dvec3& eye,
                                     const glm::dvec3& gaze_dir, const SceneFrame& frame,
                                     const GazeOptions& options) {
  if (!Finite(eye) || !Finite(gaze_dir) || !(glm::length(gaze_dir) > 1e-9))
    return absl::InvalidArgumentError("gaze-to-see: the gaze ray needs a finite eye and direction");
  auto hit = model.Cast(eye, gaze_dir, options.max_range_m);
  if (!hit)
    return absl::NotFoundError(absl::StrFormat(
        "gaze-to-see: the gaze ray hits no modelled surface within %.0f m", options.max_range_m));
  GazeResult r;
  r.hit = *hit;
  const glm::dvec3 n = hit->normal;
  const glm::dvec3 nh = frame.Horizontal(n);
  glm::dvec3 pos;
  if (std::abs(glm::dot(n, frame.up)) < options.horizontal_cos * glm::length(n) &&
      glm::length(nh) > 1e-9) {
    pos = hit->point + glm::normalize(nh) * options.offset_m;
  } else {
    r.horizontal_surface = true;
    pos = hit->point - glm::normalize(gaze_dir) * options.offset_m;
  }
  r.target.position = pos;
  r.target.yaw = frame.YawOf(hit->point - pos);
  r.camera_pitch = CameraPitchToward(pos, hit->point, frame);
  return r;
}

double CameraPitchToward(const glm::dvec3& from, const glm::dvec3& point, const SceneFrame& frame,
                         const GimbalLimits& limits) {
  const glm::dvec3 d = point - from;
  const double h = glm::length(frame.Horizontal(d)), v = glm::dot(d, frame.up);
  if (!(h > 0) && v == 0) return 0.0;
  return std::clamp(std::atan2(v, h), limits.min_pitch_rad, limits.max_pitch_rad);
}

JoypadResult IntegrateJoypad(const Setpoint& current, const JoypadInput& in, double dt_s,
                             const SceneFrame& frame, const JoypadOptions& options,
                             const SafeFlight* safe, const glm::dvec3* drone) {
  JoypadResult r;
  r.setpoint = current;
  dt_s = std::clamp(std::isfinite(dt_s) ? dt_s : 0.0, 0.0, 1.0);
  const double yaw_rate = Deadzone(in.left_x, options.deadzone) * options.max_yaw_rate_rad_s;
  const double climb = Deadzone(in.left_y, options.deadzone) * options.max_climb_mps;
  const double lateral = Deadzone(in.right_x, options.deadzone) * options.max_speed_mps;
  const double forward = Deadzone(in.right_y, options.deadzone) * options.max_speed_mps;
  r.setpoint.yaw = WrapAngle(current.yaw + yaw_rate * dt_s);
  const glm::dvec3 fwd = frame.Heading(current.yaw);
  const glm::dvec3 right = -frame.Heading(current.yaw + kPi / 2);  // left is +90°
  const glm::dvec3 full = (fwd * forward + right * lateral + frame.up * climb) * dt_s;
  // Sliding drops components along the scene's axes (e1, e2, up): a wall or zone face aligned
  // with them keeps the motion along it.
  const glm::dvec3 parts[3] = {glm::dot(full, frame.e1) * frame.e1,
                               glm::dot(full, frame.e2) * frame.e2,
                               glm::dot(full, frame.up) * frame.up};
  if (glm::length(full) == 0) return r;
  auto ok = [&](const glm::dvec3& p) {
    if (drone && glm::length(p - *drone) > options.max_lead_m &&
        glm::length(p - *drone) > glm::length(current.position - *drone))
      return false;
    return safe == nullptr || safe->SegmentPermitted(current.position, p);
  };
  // Full motion, then drop one component, then keep one: the largest permitted one.
  static const int kMasks[] = {7, 3, 5, 6, 1, 2, 4};
  double best = -1;
  for (int m : kMasks) {
    glm::dvec3 d(0.0);
    for (int k = 0; k < 3; ++k)
      if (m & (1 << k)) d += parts[k];
    const double len = glm::length(d);
    if (len == 0 || len <= best) continue;
    if (!ok(current.position + d)) continue;
    best = len;
    r.setpoint.position = current.position + d;
    r.slid = m != 7;
    if (m == 7) break;
  }
  r.blocked = best < 0;
  return r;
}

}  // namespace exo::control
