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
#include "common/rigid3.h"
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

// A pixel rectangle [x0, x1) x [y0, y1) (empty when x1 <= x0).
struct PixelRect {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;
};

// The pixels of a source view (`src_depth`, `src_cam`) whose points can land within 1.5 px of
// `box` (a rectangle of the destination camera `dst_cam`; `dst_from_src` maps source camera
// coordinates to destination ones): the destination's viewing frustum through the box grown by
// 1.5 px, cut to the source's depth range, is a convex body whose corners lie on the box's four
// corner rays (and the frustum's apex); their projections bound it, grown by 2-3 px. The whole
// source image when a corner ray does not cross the depth range in a bounded segment; empty when
// `box` is empty or the source has no valid depth. Forward warps (a nearest-pixel splat or a
// 2x2 footprint) into `box` need only these source pixels.
PixelRect SourcePixelsOnto(const ImageF& src_depth, const PinholeCamera& src_cam,
                           const PinholeCamera& dst_cam, const Rigid3d& dst_from_src,
                           const PixelRect& box);

}  // namespace exo::inpainting
