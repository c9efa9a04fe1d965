#include "client/navigation/navigation.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <glm/gtc/quaternion.hpp>
#include <limits>
#include <sstream>

namespace exo::nav {

FlyCamera::FlyCamera(const Rigid3d& local_from_cam, const glm::dvec3& up_local,
                     const FlyOptions& options)
    : pose_(local_from_cam), up_(glm::normalize(up_local)), options_(options) {}

bool FlyCamera::Step(const FlyInput& in, double dt_s) {
  bool moved = false;
  if (in.wheel != 0) options_.speed_mps *= std::pow(1.25, in.wheel);
  if (in.look_dx_px != 0 || in.look_dy_px != 0) {
    // Yaw about the scene's up (mouse right = turn right), pitch about the camera x (mouse down =
    // look down), pitch clamped so that forward stays away from +/- up.
    const glm::dvec3 fwd0 = pose_.rotation * glm::dvec3(0, 0, 1);
    // The camera's right (x) is (-up) x forward; turning right rotates forward towards it, which
    // is a negative angle about `up` for this handedness.
    const glm::dquat yaw = glm::angleAxis(-in.look_dx_px * options_.look_rad_per_px, up_);
    glm::dquat r = glm::normalize(yaw * pose_.rotation);
    const double pitch_now = std::asin(std::clamp(glm::dot(fwd0, up_), -1.0, 1.0));
    double dp = -in.look_dy_px * options_.look_rad_per_px;
    dp = std::clamp(pitch_now + dp, -options_.max_pitch_rad, options_.max_pitch_rad) - pitch_now;
    // Pitch up (dp > 0) turns forward towards -y of the camera: x cross z = -y, so a positive
    // rotation about the camera's +x.
    const glm::dquat pitch = glm::angleAxis(dp, glm::dvec3(1, 0, 0));
    pose_.rotation = glm::normalize(r * pitch);
    moved = true;
  }
  const glm::dvec3 fwd = pose_.rotation * glm::dvec3(0, 0, 1);
  const glm::dvec3 right = pose_.rotation * glm::dvec3(1, 0, 0);
  glm::dvec3 v(0.0);
  if (in.forward) v += fwd;
  if (in.back) v -= fwd;
  if (in.right) v += right;
  if (in.left) v -= right;
  if (in.up) v += up_;
  if (in.down) v -= up_;
  if (glm::length(v) > 0 && dt_s > 0) {
    pose_.translation += glm::normalize(v) * options_.speed_mps * dt_s;
    moved = true;
  }
  return moved;
}

glm::dvec3 SceneUp(const LumigraphModel& model) {
  glm::dvec3 s(0.0);
  for (const auto& [id, v] : model.views) s += v.local_from_cam.rotation * glm::dvec3(0, -1, 0);
  if (glm::length(s) < 1e-9) return {0, -1, 0};
  return glm::normalize(s);
}

Bounds ModelBounds(const LumigraphModel& model) {
  Bounds b;
  b.lo = glm::dvec3(std::numeric_limits<double>::max());
  b.hi = -b.lo;
  bool any = false;
  for (const auto& [id, c] : model.chunks)
    for (const glm::vec3& p : c.mesh.positions) {
      b.lo = glm::min(b.lo, glm::dvec3(p));
      b.hi = glm::max(b.hi, glm::dvec3(p));
      any = true;
    }
  if (!any)
    for (const auto& [id, v] : model.views) {
      b.lo = glm::min(b.lo, v.local_from_cam.translation);
      b.hi = glm::max(b.hi, v.local_from_cam.translation);
      any = true;
    }
  if (!any) b = Bounds{};
  return b;
}

std::optional<ViewId> NearestView(const LumigraphModel& model, const glm::dvec3& p_local) {
  std::optional<ViewId> best;
  double best_d = std::numeric_limits<double>::max();
  for (const auto& [id, v] : model.views) {
    const double d = glm::length(v.local_from_cam.translation - p_local);
    if (d < best_d) {
      best_d = d;
      best = id;
    }
  }
  return best;
}

absl::Status AdaptiveOptions::Validate() const {
  auto pow2 = [](int d) { return d == 1 || d == 2 || d == 4 || d == 8; };
  if (!pow2(moving_divisor) || !pow2(min_divisor) || !pow2(max_divisor))
    return absl::InvalidArgumentError("divisors must be 1, 2, 4 or 8");
  if (min_divisor > max_divisor || moving_divisor < min_divisor || moving_divisor > max_divisor)
    return absl::InvalidArgumentError("need min_divisor <= moving_divisor <= max_divisor");
  if (!(target_ms >= 0)) return absl::InvalidArgumentError("target_ms must be >= 0");
  return absl::OkStatus();
}

void AdaptiveResolution::ReportMovingFrame(double frame_ms) {
  if (!options_.enabled || options_.target_ms <= 0 || last_ != moving_) return;
  if (frame_ms > options_.target_ms && moving_ < options_.max_divisor) {
    moving_ *= 2;
  } else if (frame_ms * 4 < 0.8 * options_.target_ms && moving_ > options_.min_divisor) {
    moving_ /= 2;
  }
}

int AdaptiveResolution::Next(bool changed) {
  if (!options_.enabled) {
    if (changed || last_ == 0) return last_ = 1;
    return 0;
  }
  if (changed || last_ == 0) return last_ = moving_;
  if (last_ > 1) return last_ = last_ / 2;
  return 0;
}

std::optional<PickResult> Pick(const LumigraphModel& model, const PinholeCamera& camera,
                               const Rigid3d& local_from_cam, const glm::dvec2& uv,
                               double min_z_depth_m) {
  const glm::dvec3 o = local_from_cam.translation;
  const glm::dvec3 dir_cam = glm::normalize(camera.RayZ1(uv));
  const double min_dist = std::max(1e-9, min_z_depth_m / dir_cam.z);
  const glm::dvec3 d = local_from_cam.rotation * dir_cam;
  std::optional<PickResult> best;
  double best_t = std::numeric_limits<double>::max();
  for (const auto& [chunk_id, chunk] : model.chunks) {
    const TriangleMesh& m = chunk.mesh;
    for (size_t t = 0; t < m.num_triangles(); ++t) {
      // Möller–Trumbore, double precision, both faces.
      const glm::dvec3 a(m.positions[m.indices[3 * t]]), b(m.positions[m.indices[3 * t + 1]]),
          c(m.positions[m.indices[3 * t + 2]]);
      const glm::dvec3 e1 = b - a, e2 = c - a;
      const glm::dvec3 p = glm::cross(d, e2);
      const double det = glm::dot(e1, p);
      if (std::abs(det) < 1e-15) continue;
      const double inv = 1.0 / det;
      const glm::dvec3 s = o - a;
      const double u = glm::dot(s, p) * inv;
      if (u < 0 || u > 1) continue;
      const glm::dvec3 q = glm::cross(s, e1);
      const double v = glm::dot(d, q) * inv;
      if (v < 0 || u + v > 1) continue;
      const double dist = glm::dot(e2, q) * inv;
      if (dist <= min_dist || dist >= best_t) continue;
      best_t = dist;
      PickResult r;
      r.point_local = o + dist * d;
      glm::dvec3 n = glm::normalize(glm::cross(e1, e2));
      if (glm::dot(n, d) > 0) n = -n;
      r.normal_local = n;
      r.range_m = dist;
      r.z_depth_m = dist * dir_cam.z;
      r.cell = model.grid.cell_size_m > 0 ? model.grid.IdOf(r.point_local) : 0;
      r.chunk_id = chunk_id;
      r.triangle = static_cast<uint32_t>(t);
      best = r;
    }
  }
  return best;
}

absl::StatusOr<std::vector<PathPose>> ReadTumPath(const std::string& path) {
  std::ifstream f(path);
  if (!f) return absl::NotFoundError("cannot open camera path " + path);
  std::vector<PathPose> out;
  std::string line;
  for (int n = 1; std::getline(f, line); ++n) {
    const size_t first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream in(line);
    double v[8];
    int k = 0;
    while (k < 8 && in >> v[k]) ++k;
    std::string extra;
    if (k != 8 || (in >> extra))
      return absl::InvalidArgumentError(path + ":" + std::to_string(n) +
                                        ": expected 8 numbers 'timestamp tx ty tz qx qy qz qw'");
    for (double x : v)
      if (!std::isfinite(x))
        return absl::InvalidArgumentError(path + ":" + std::to_string(n) + ": not finite");
    glm::dquat q(v[7], v[4], v[5], v[6]);
    const double len = glm::length(q);
    if (std::abs(len - 1.0) > 1e-2)
      return absl::InvalidArgumentError(path + ":" + std::to_string(n) +
                                        ": quaternion is not unit (|q| = " + std::to_string(len) +
                                        ")");
    PathPose p;
    p.timestamp_s = v[0];
    p.world_from_cam.rotation = q / len;
    p.world_from_cam.translation = {v[1], v[2], v[3]};
    out.push_back(p);
  }
  if (out.empty()) return absl::InvalidArgumentError(path + ": no poses");
  return out;
}

absl::Status WriteTumPath(const std::string& path, const std::vector<PathPose>& poses) {
  std::ofstream f(path);
  if (!f) return absl::PermissionDeniedError("cannot write camera path " + path);
  f << "# exoview camera path (TUM): timestamp tx ty tz qx qy qz qw, world_from_cam\n";
  char buf[256];
  for (const PathPose& p : poses) {
    const glm::dquat& q = p.world_from_cam.rotation;
    const glm::dvec3& t = p.world_from_cam.translation;
    std::snprintf(buf, sizeof(buf), "%.6f %.9g %.9g %.9g %.9g %.9g %.9g %.9g\n", p.timestamp_s, t.x,
                  t.y, t.z, q.x, q.y, q.z, q.w);
    f << buf;
  }
  f.close();
  if (!f) return absl::DataLossError("writing camera path " + path + " failed");
  return absl::OkStatus();
}

}  // namespace exo::nav
