// Region of interest for inpainting from a 2D user stroke (thesis eq. 4.1): a pixel u is in the
// ROI when, for some stroke point s, |s - u| < r_ROI on screen and its 3D point lies within
// d_ROI of the stroke point's 3D point along u's normal: |(V(s) - V(u)) . N(u)| < d_ROI.
// (The thesis writes the signed product; the absolute value keeps surfaces behind the stroked
// one out of the ROI.) The ROI is then dilated by a safety margin, as the thesis does.
#pragma once

#include <span>

#include <glm/glm.hpp>

#include "common/camera.h"
#include "common/image.h"
#include "common/status.h"

namespace exo::inpainting {

struct RoiOptions {
  double radius_px = 30.0;   // r_ROI
  double depth_tol_m = 0.05; // d_ROI (e.g. the sensor's depth uncertainty)
  int dilate_px = 2;         // safety margin
  // Pixels without valid depth inside the disc: true = part of the ROI (holes get filled too).
  bool include_invalid_depth = true;
  absl::Status Validate() const;
};

// Returns a 1-channel mask (255 = ROI) of the depth image's size. Errors: invalid options or
// camera, an empty stroke, a stroke entirely outside the image.
absl::StatusOr<ImageU8> RoiFromStroke(std::span<const glm::dvec2> stroke_px, const ImageF& depth_m,
                                      const PinholeCamera& camera, const RoiOptions& options);

}  // namespace exo::inpainting
