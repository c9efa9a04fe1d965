#include "common/frame.h"

#include <cmath>

namespace exo {

absl::Status Frame::Validate() const {
  if (auto s = color_camera.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("colour camera: ", s.message()));
  if (auto s = depth_camera.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("depth camera: ", s.message()));
  if (color.channels() != 3 || color.width() != color_camera.width ||
      color.height() != color_camera.height)
    return absl::InvalidArgumentError(absl::StrCat(
        "colour image is ", color.width(), "x", color.height(), "x", color.channels(),
        ", intrinsics say ", color_camera.width, "x", color_camera.height, "x3"));
  if (!depth_m.empty() &&
      (depth_m.width() != depth_camera.width || depth_m.height() != depth_camera.height ||
       depth_m.channels() != 1))
    return absl::InvalidArgumentError(absl::StrCat(
        "depth image is ", depth_m.width(), "x", depth_m.height(), ", depth intrinsics say ",
        depth_camera.width, "x", depth_camera.height));
  EXO_RETURN_IF_ERROR(ValidateQuaternion(world_from_cam.rotation));
  const auto& t = world_from_cam.translation;
  if (!std::isfinite(t.x) || !std::isfinite(t.y) || !std::isfinite(t.z))
    return absl::InvalidArgumentError("pose translation has NaN or Inf");
  return absl::OkStatus();
}

}  // namespace exo
