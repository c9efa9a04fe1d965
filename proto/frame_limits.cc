#include "proto/frame_limits.h"

#include <algorithm>
#include <cmath>

namespace exo {

absl::Status FrameLimits::Validate() const {
  if (max_pixels < 1) return absl::InvalidArgumentError("max_pixels must be >= 1");
  if (max_side < 1 || max_side > 65535)
    return absl::InvalidArgumentError("max_side must be in [1, 65535]");
  if (!(min_focal_rel > 0.0) || !(max_focal_rel >= min_focal_rel) || !std::isfinite(max_focal_rel))
    return absl::InvalidArgumentError(
        "focal limits must satisfy 0 < min_focal_rel <= max_focal_rel");
  if (!(principal_margin >= 0.0) || !std::isfinite(principal_margin))
    return absl::InvalidArgumentError("principal_margin must be >= 0");
  // Exposure is stored as float: its limits must be normal floats.
  if (!(min_exposure > 1e-30) || !(max_exposure >= min_exposure) || !(max_exposure < 1e30))
    return absl::InvalidArgumentError("exposure limits must satisfy 1e-30 < min <= max < 1e30");
  if (!(min_depth_scale_m > 0.0) || !(max_depth_scale_m >= min_depth_scale_m) ||
      !std::isfinite(max_depth_scale_m))
    return absl::InvalidArgumentError("depth scale limits must satisfy 0 < min <= max");
  if (!(scene_radius_m > 0.0) || !std::isfinite(scene_radius_m))
    return absl::InvalidArgumentError("scene_radius_m must be > 0 and finite");
  if (!std::isfinite(scene_center.x) || !std::isfinite(scene_center.y) ||
      !std::isfinite(scene_center.z))
    return absl::InvalidArgumentError("scene_center must be finite");
  if (!(max_color_from_depth_m > 0.0) || !std::isfinite(max_color_from_depth_m))
    return absl::InvalidArgumentError("max_color_from_depth_m must be > 0 and finite");
  if (!(max_abs_timestamp_s > 0.0) || !std::isfinite(max_abs_timestamp_s))
    return absl::InvalidArgumentError("max_abs_timestamp_s must be > 0 and finite");
  return absl::OkStatus();
}

absl::Status CheckImageSize(int width, int height, const FrameLimits& limits,
                            const std::string& what) {
  if (width <= 0 || height <= 0)
    return absl::InvalidArgumentError(
        absl::StrCat(what, ": image size ", width, "x", height, " is empty"));
  if (width > limits.max_side || height > limits.max_side)
    return absl::InvalidArgumentError(absl::StrCat(what, ": image size ", width, "x", height,
                                                   " exceeds the side limit ", limits.max_side));
  if (int64_t{width} * height > limits.max_pixels)
    return absl::InvalidArgumentError(absl::StrCat(what, ": image ", width, "x", height,
                                                   " exceeds the limit of ", limits.max_pixels,
                                                   " pixels"));
  return absl::OkStatus();
}

absl::Status CheckIntrinsics(const PinholeCamera& c, const FrameLimits& limits,
                             const std::string& what) {
  if (auto s = c.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat(what, ": ", s.message()));
  EXO_RETURN_IF_ERROR(CheckImageSize(c.width, c.height, limits, what));
  const double side = std::max(c.width, c.height);
  const double fmin = limits.min_focal_rel * side, fmax = limits.max_focal_rel * side;
  for (const auto& [name, f] : {std::pair<const char*, double>{"fx", c.fx}, {"fy", c.fy}})
    if (!(f >= fmin && f <= fmax))
      return absl::InvalidArgumentError(
          absl::StrCat(what, ": ", name, " = ", f, " outside the plausible range [", fmin, ", ",
                       fmax, "] (", limits.min_focal_rel, "..", limits.max_focal_rel,
                       " x the larger image side ", side, ")"));
  const double mx = limits.principal_margin * c.width, my = limits.principal_margin * c.height;
  if (!(c.cx >= -mx && c.cx <= c.width + mx) || !(c.cy >= -my && c.cy <= c.height + my))
    return absl::InvalidArgumentError(absl::StrCat(
        what, ": principal point (", c.cx, ", ", c.cy, ") is not inside the ", c.width, "x",
        c.height, " image or within ", limits.principal_margin, " x its size of it"));
  return absl::OkStatus();
}

absl::Status CheckExposure(double exposure, const FrameLimits& limits) {
  const float stored = static_cast<float>(exposure);  // what the view store keeps
  if (!std::isfinite(stored) || !(stored >= limits.min_exposure && stored <= limits.max_exposure))
    return absl::InvalidArgumentError(
        absl::StrCat("exposure ", exposure, " (", stored, " as stored float) is outside [",
                     limits.min_exposure, ", ", limits.max_exposure, "]"));
  return absl::OkStatus();
}

absl::Status CheckDepthScale(double s, const FrameLimits& limits) {
  if (!(s >= limits.min_depth_scale_m && s <= limits.max_depth_scale_m))
    return absl::InvalidArgumentError(absl::StrCat("depth scale ", s, " m/unit is outside [",
                                                   limits.min_depth_scale_m, ", ",
                                                   limits.max_depth_scale_m, "]"));
  return absl::OkStatus();
}

absl::Status CheckTimestamp(double t, const FrameLimits& limits) {
  if (!std::isfinite(t)) return absl::InvalidArgumentError("timestamp is NaN or Inf");
  if (std::abs(t) > limits.max_abs_timestamp_s)
    return absl::InvalidArgumentError(
        absl::StrCat("timestamp ", t, " s is outside +-", limits.max_abs_timestamp_s, " s"));
  return absl::OkStatus();
}

absl::Status CheckCameraPosition(const glm::dvec3& p, const FrameLimits& limits) {
  if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
    return absl::InvalidArgumentError("pose translation has NaN or Inf");
  const double d = glm::length(p - limits.scene_center);
  if (!(d <= limits.scene_radius_m))
    return absl::InvalidArgumentError(absl::StrCat(
        "pose: camera position (", p.x, ", ", p.y, ", ", p.z, ") is ", d,
        " m from the scene centre, outside the scene radius ", limits.scene_radius_m, " m"));
  return absl::OkStatus();
}

absl::Status CheckColorFromDepth(const Rigid3d& color_from_depth, const FrameLimits& limits) {
  const glm::dvec3& t = color_from_depth.translation;
  const double d = glm::length(t);
  if (!std::isfinite(d) || !(d < limits.max_color_from_depth_m))
    return absl::InvalidArgumentError(absl::StrCat("depth-to-colour extrinsic: offset ", d,
                                                   " m is not under the limit ",
                                                   limits.max_color_from_depth_m, " m"));
  return absl::OkStatus();
}

absl::Status CheckFrame(const Frame& f, const FrameLimits& limits) {
  EXO_RETURN_IF_ERROR(CheckTimestamp(f.timestamp_s, limits));
  EXO_RETURN_IF_ERROR(CheckIntrinsics(f.color_camera, limits, "colour intrinsics"));
  EXO_RETURN_IF_ERROR(CheckIntrinsics(f.depth_camera, limits, "depth intrinsics"));
  EXO_RETURN_IF_ERROR(CheckColorFromDepth(f.color_from_depth, limits));
  EXO_RETURN_IF_ERROR(CheckCameraPosition(f.world_from_cam.translation, limits));
  if (f.exposure) EXO_RETURN_IF_ERROR(CheckExposure(*f.exposure, limits));
  return f.Validate();
}

}  // namespace exo
