// Pinhole camera model. Convention, everywhere in Exoview: depth images hold **z-depth**
// (distance along the optical axis, metres, 0 = invalid), as RGB-D sensors deliver. Where an
// algorithm needs a **range** (Euclidean distance from the camera centre, SPEC §6 validity), it
// converts here and only here: RangeFromZDepth / ZDepthFromRange.
// Camera frame: x right, y down, z forward (OpenCV convention). Integer pixel coordinates
// (u, v) address pixel centres, as OpenCV and 7-Scenes' K do; pixel (0,0) spans [-0.5, 0.5).
#pragma once

#include <cmath>

#include <glm/glm.hpp>

#include "common/status.h"

namespace exo {

struct PinholeCamera {
  double fx = 0, fy = 0, cx = 0, cy = 0;
  int width = 0, height = 0;

  // Clear error for missing/invalid intrinsics (zero focal length, non-finite, empty size).
  absl::Status Validate() const;

  // Camera-frame point -> pixel. Returns false when z <= 0 (behind the camera).
  bool Project(const glm::dvec3& p_in_cam, glm::dvec2* uv) const {
    if (!(p_in_cam.z > 0.0)) return false;
    *uv = {fx * p_in_cam.x / p_in_cam.z + cx, fy * p_in_cam.y / p_in_cam.z + cy};
    return true;
  }
  bool InImage(const glm::dvec2& uv, double border = 0.0) const {
    return uv.x >= -0.5 + border && uv.y >= -0.5 + border && uv.x < width - 0.5 - border &&
           uv.y < height - 0.5 - border;
  }
  // Pixel + z-depth -> camera-frame point.
  glm::dvec3 Unproject(const glm::dvec2& uv, double z_depth) const {
    return {(uv.x - cx) / fx * z_depth, (uv.y - cy) / fy * z_depth, z_depth};
  }
  // Ray through a pixel with z = 1 (not normalised).
  glm::dvec3 RayZ1(const glm::dvec2& uv) const { return {(uv.x - cx) / fx, (uv.y - cy) / fy, 1.0}; }
  // The one place where z-depth and range convert.
  double RangeFromZDepth(const glm::dvec2& uv, double z_depth) const {
    return z_depth * glm::length(RayZ1(uv));
  }
  double ZDepthFromRange(const glm::dvec2& uv, double range) const {
    return range / glm::length(RayZ1(uv));
  }
  // Solid angle (steradians) of one pixel at the image centre: 1/(fx*fy).
  double PixelSolidAngle() const { return 1.0 / (fx * fy); }
  // Same camera at a different resolution (intrinsics scaled consistently).
  PinholeCamera Scaled(int new_width, int new_height) const;
  double HorizontalFovRad() const { return 2.0 * std::atan(0.5 * width / fx); }

  // A camera with the given horizontal field of view, principal point at the centre.
  static PinholeCamera FromFov(int width, int height, double hfov_rad);
};

}  // namespace exo
