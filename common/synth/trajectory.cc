#include "common/synth/trajectory.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "common/hilbert.h"
#include "common/raster/rasterizer.h"
#include "common/synth/trajectory_path.h"

namespace exo::synth {
using internal::ArcLengthPath;
using internal::Direction;

const char* TrajectoryKindName(TrajectoryKind k) {
  switch (k) {
    case TrajectoryKind::kFlyover: return "flyover";
    case TrajectoryKind::kWalk: return "walk";
    case TrajectoryKind::kDrone: return "drone";
    case TrajectoryKind::kHandheld: return "handheld";
  }
  return "?";
}

const char* MotionName(Motion m) {
  switch (m) {
    case Motion::kMove: return "move";
    case Motion::kHover: return "hover";
    case Motion::kPan: return "pan";
    case Motion::kStop: return "stop";
    case Motion::kLookAround: return "look_around";
  }
  return "?";
}

absl::StatusOr<TrajectoryKind> ParseTrajectoryKind(const std::string& name) {
  if (name == "flyover") return TrajectoryKind::kFlyover;
  if (name == "walk") return TrajectoryKind::kWalk;
  if (name == "drone") return TrajectoryKind::kDrone;
  if (name == "handheld") return TrajectoryKind::kHandheld;
  return absl::InvalidArgumentError(absl::StrCat(
      "unknown trajectory '", name, "' (expected flyover, walk, drone or handheld)"));
}

absl::Status TrajectoryOptions::Validate() const {
  if (num_frames < 1 || num_frames > 1000000)
    return absl::InvalidArgumentError(
        absl::StrCat("num_frames must be in [1, 1e6], got ", num_frames));
  if (hilbert_order < 1 || hilbert_order > 8)
    return absl::InvalidArgumentError("hilbert_order must be in [1, 8]");
  if (!(flyover_pitch_deg > 0 && flyover_pitch_deg < 90))
    return absl::InvalidArgumentError("flyover_pitch_deg must be in (0, 90)");
  // Up to 180: a sweep of +-180 deg turns the walker fully around (looks at every wall of a room).
  if (!(walk_look_around_deg >= 0 && walk_look_around_deg <= 180))
    return absl::InvalidArgumentError("walk_look_around_deg must be in [0, 180]");
  if (!(frame_rate_hz > 0) || !std::isfinite(frame_rate_hz))
    return absl::InvalidArgumentError("frame_rate_hz must be > 0");
  return absl::OkStatus();
}

absl::Status TestPoseOptions::Validate() const {
  if (count < 0 || count > 100000) return absl::InvalidArgumentError("test pose count out of range");
  if (!(min_coverage >= 0 && min_coverage <= 1))
    return absl::InvalidArgumentError("min_coverage must be in [0, 1]");
  if (!(min_depth_m >= 0)) return absl::InvalidArgumentError("min_depth_m must be >= 0");
  return absl::OkStatus();
}

Rigid3d LookAt(const glm::dvec3& eye, const glm::dvec3& target) {
  glm::dvec3 f = target - eye;
  const double len = glm::length(f);
  f = len > 1e-12 ? f / len : glm::dvec3(1, 0, 0);
  glm::dvec3 r = glm::cross(f, glm::dvec3(0, 0, 1));
  if (glm::length(r) < 1e-9) r = glm::dvec3(1, 0, 0);
  r = glm::normalize(r);
  const glm::dvec3 d = glm::cross(f, r);  // image down
  Rigid3d out;
  out.rotation = glm::normalize(glm::quat_cast(glm::dmat3(r, d, f)));
  out.translation = eye;
  return out;
}

std::vector<glm::dvec2> HilbertCurve(int order) { return exo::HilbertCurve(order); }

absl::StatusOr<std::vector<TimedPose>> MakeTrajectory(const SynthScene& scene, TrajectoryKind kind,
                                                      const TrajectoryOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  if (kind == TrajectoryKind::kDrone) return internal::MakeDroneStream(scene, options);
  if (kind == TrajectoryKind::kHandheld) return internal::MakeHandheldStream(scene, options);
  std::vector<glm::dvec3> waypoints;
  double heading_window = 2.5;
  if (kind == TrajectoryKind::kFlyover) {
    if (scene.flyover_altitude_m <= 0)
      return absl::InvalidArgumentError(
          absl::StrCat("scene '", scene.name, "' has no fly-over (indoor); use the walk"));
    const glm::dvec3 lo = scene.navigable.min, hi = scene.navigable.max;
    const double inset = 0.15 * std::min(hi.x - lo.x, hi.y - lo.y);
    for (const glm::dvec2& h : HilbertCurve(options.hilbert_order))
      waypoints.push_back({lo.x + inset + h.x * (hi.x - lo.x - 2 * inset),
                           lo.y + inset + h.y * (hi.y - lo.y - 2 * inset),
                           scene.flyover_altitude_m});
    heading_window = 6.0;
  } else {
    if (scene.walk_waypoints.size() < 2)
      return absl::InvalidArgumentError(absl::StrCat("scene '", scene.name, "' has no walk path"));
    waypoints = scene.walk_waypoints;
  }
  const ArcLengthPath path(waypoints);
  const double L = path.Length();
  std::vector<TimedPose> out;
  out.reserve(options.num_frames);
  for (int i = 0; i < options.num_frames; ++i) {
    const double s = options.num_frames > 1 ? L * i / (options.num_frames - 1) : 0.0;
    const glm::dvec3 eye = path.At(s);
    const glm::dvec3 h = path.Heading(s, heading_window);
    double yaw = std::atan2(h.y, h.x), pitch;
    if (kind == TrajectoryKind::kFlyover) {
      pitch = -glm::radians(options.flyover_pitch_deg);
    } else {
      yaw += glm::radians(options.walk_look_around_deg) * std::sin(2 * glm::pi<double>() * s / 9.0);
      pitch = -glm::radians(8.0) + glm::radians(4.0) * std::sin(2 * glm::pi<double>() * s / 5.0);
    }
    out.push_back({i / options.frame_rate_hz, LookAt(eye, eye + Direction(yaw, pitch))});
  }
  return out;
}

absl::StatusOr<std::vector<Rigid3d>> MakeTestPoses(const SynthScene& scene,
                                                   const PinholeCamera& camera,
                                                   const TestPoseOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(camera.Validate());
  std::mt19937_64 rng(options.seed * 0x2545F4914F6CDD1Dull + 17);
  auto uni = [&](double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); };
  RasterOptions ro;
  ro.z_depth = true;
  ro.width = 64;
  ro.height = std::max(8, static_cast<int>(std::lround(64.0 * camera.height / camera.width)));
  ro.num_threads = 1;
  ro.near_m = 0.05;
  const glm::dvec3 lo = scene.navigable.min, hi = scene.navigable.max;
  std::vector<Rigid3d> poses;
  const int max_attempts = 400 * std::max(1, options.count);
  for (int attempt = 0; attempt < max_attempts && int(poses.size()) < options.count; ++attempt) {
    // Eye-level views everywhere; outdoors also elevated views (up to the fly-over altitude).
    const bool high = scene.flyover_altitude_m > 0 && (rng() & 1);
    glm::dvec3 eye(uni(lo.x, hi.x), uni(lo.y, hi.y), 0);
    double pitch;
    if (high) {
      eye.z = uni(4.0, scene.flyover_altitude_m);
      pitch = -glm::radians(uni(20, 60));
    } else {
      eye.z = uni(1.2, 2.0);
      pitch = -glm::radians(uni(0, 25));
    }
    if (!scene.IsFree(eye, 0.5)) continue;
    const Rigid3d pose = LookAt(eye, eye + Direction(uni(-glm::pi<double>(), glm::pi<double>()),
                                                     pitch));
    EXO_ASSIGN_OR_RETURN(RasterOutput r, Rasterize(scene.mesh, camera, pose, ro));
    int hits = 0;
    float min_z = 1e30f;
    for (float z : r.z_depth_m.span())
      if (z > 0) {
        ++hits;
        min_z = std::min(min_z, z);
      }
    const double coverage = double(hits) / r.z_depth_m.size();
    if (coverage < options.min_coverage || min_z < options.min_depth_m) continue;
    poses.push_back(pose);
  }
  if (int(poses.size()) < options.count)
    return absl::FailedPreconditionError(absl::StrCat(
        "found only ", poses.size(), " of ", options.count, " test poses in scene '", scene.name,
        "' (min_coverage ", options.min_coverage, ")"));
  return poses;
}

absl::StatusOr<std::vector<Rigid3d>> MakeNearTestPoses(const SynthScene& scene,
                                                       const std::vector<Rigid3d>& input,
                                                       const PinholeCamera& camera, int count,
                                                       uint64_t seed, bool flyover) {
  EXO_RETURN_IF_ERROR(camera.Validate());
  if (input.empty()) return absl::InvalidArgumentError("near test poses need input poses");
  if (count < 0) return absl::InvalidArgumentError("near test poses: count < 0");
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ull + 3);
  auto uni = [&](double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); };
  RasterOptions ro;
  ro.z_depth = true;
  ro.width = 64;
  ro.height = std::max(8, static_cast<int>(std::lround(64.0 * camera.height / camera.width)));
  ro.num_threads = 1;
  ro.near_m = 0.05;
  const double r_h = 0.1 * scene.ExtentM(), r_v = flyover ? 2.0 : 0.3;
  std::vector<Rigid3d> out;
  for (int attempt = 0; attempt < 400 * count && static_cast<int>(out.size()) < count; ++attempt) {
    const Rigid3d& base = input[rng() % input.size()];
    const glm::dvec3 eye =
        base.translation + glm::dvec3(uni(-r_h, r_h), uni(-r_h, r_h), uni(-r_v, r_v));
    if (!scene.IsFree(eye, 0.5)) continue;
    const glm::dvec3 fwd = base.RotationMatrix() * glm::dvec3(0, 0, 1);
    const double yaw = std::atan2(fwd.y, fwd.x) + glm::radians(uni(-45, 45));
    const double pitch = std::asin(std::clamp(fwd.z, -1.0, 1.0)) + glm::radians(uni(-10, 10));
    const glm::dvec3 dir(std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw),
                         std::sin(pitch));
    const Rigid3d pose = LookAt(eye, eye + dir);
    EXO_ASSIGN_OR_RETURN(RasterOutput r, Rasterize(scene.mesh, camera, pose, ro));
    int hits = 0;
    float min_z = 1e30f;
    for (float z : r.z_depth_m.span())
      if (z > 0) {
        ++hits;
        min_z = std::min(min_z, z);
      }
    if (static_cast<double>(hits) / r.z_depth_m.size() < 0.9 || min_z < 0.4) continue;
    out.push_back(pose);
  }
  if (static_cast<int>(out.size()) < count)
    return absl::FailedPreconditionError(absl::StrCat("found only ", out.size(), " of ", count,
                                                      " near-trajectory test poses"));
  return out;
}

}  // namespace exo::synth
