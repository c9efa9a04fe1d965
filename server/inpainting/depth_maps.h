// Per-pixel geometry helpers for RGB-D inpainting (thesis §4.1.7 "frame pre-processing"):
// hole pre-fill by push-pull (common/image_fill.h), normals from z-depth, and
// the depth-unit sanity check. Every threshold here is relative to depth, so the results are
// invariant to the unit scale of the scene (a scene 10x larger gives the same normals).
#pragma once

#include <cstdint>
#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/image_fill.h"  // PushPullFill (nearest pull: what the tables were measured with)
#include "common/status.h"

namespace exo::inpainting {

// Fills invalid depth (0 / non-finite) of pixels where `fill_here` != 0 from the valid depth of
// pixels where `use_as_data` != 0 (push-pull). Pixels outside `fill_here` keep their value.
// Returns the number of pixels filled; 0 valid data pixels leaves everything unchanged.
int PrefillDepth(ImageF& depth_m, const std::vector<uint8_t>& fill_here,
                 const std::vector<uint8_t>& use_as_data);

// Camera-frame unit normals (3 channels, facing the camera) from z-depth. The depth is first
// smoothed with a 5x5 valid-weighted filter that ignores neighbours differing by more than
// `rel_discontinuity` * z (Kinect depth is quantised); the normal is the cross product of
// central differences at +-`step` px, falling back to one-sided differences across a relative
// discontinuity. Pixels without a usable neighbourhood get (0,0,0).
// `num_threads` splits the rows; the result does not depend on it.
ImageF NormalsFromDepth(const ImageF& depth_m, const PinholeCamera& camera, int step = 2,
                        float rel_discontinuity = 0.05f, int num_threads = 1);

// Depth-unit check: the median of the valid depth must not exceed `max_median_depth_m`
// (millimetre depth passed as metres is the usual cause). Negative depth is rejected too.
absl::Status CheckDepthUnits(const ImageF& depth_m, double max_median_depth_m);

}  // namespace exo::inpainting
