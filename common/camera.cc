#include "common/camera.h"

namespace exo {

absl::Status PinholeCamera::Validate() const {
  if (!std::isfinite(fx) || !std::isfinite(fy) || !std::isfinite(cx) || !std::isfinite(cy))
    return absl::InvalidArgumentError("intrinsics contain NaN or Inf");
  if (fx <= 0 || fy <= 0)
    return absl::InvalidArgumentError(
        absl::StrCat("intrinsics missing or invalid: fx=", fx, " fy=", fy, " (must be > 0)"));
  if (width <= 0 || height <= 0)
    return absl::InvalidArgumentError(
        absl::StrCat("intrinsics have an empty image size ", width, "x", height));
  return absl::OkStatus();
}

PinholeCamera PinholeCamera::Scaled(int new_width, int new_height) const {
  const double sx = static_cast<double>(new_width) / width;
  const double sy = static_cast<double>(new_height) / height;
  PinholeCamera c = *this;
  c.fx = fx * sx;
  c.fy = fy * sy;
  // Pixel centres at integers: the continuous coordinate of a centre is u + 0.5.
  c.cx = (cx + 0.5) * sx - 0.5;
  c.cy = (cy + 0.5) * sy - 0.5;
  c.width = new_width;
  c.height = new_height;
  return c;
}

PinholeCamera PinholeCamera::FromFov(int width, int height, double hfov_rad) {
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.fx = c.fy = 0.5 * width / std::tan(0.5 * hfov_rad);
  c.cx = 0.5 * width - 0.5;
  c.cy = 0.5 * height - 0.5;
  return c;
}

}  // namespace exo
