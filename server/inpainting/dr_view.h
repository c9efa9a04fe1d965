// Diminished reality through 3D (issue 18, SPEC §7): the per-frame pieces that fill a frame's
// ROI from views of the same scene -- inpainted keyframes (observed outside their T, inpainted
// inside) and observed frames -- preferring the views that OBSERVED the background over
// inpainted data: the background depth of the ROI warped from a keyframe, the colour looked up
// in the views, and a gradient-domain blend with the frame's border. Measured in dr_bench
// (docs/inpainting.md "Session 10"). Pure: Eigen-free image loops + SolvePoisson.
#pragma once

#include <cmath>
#include <memory>
#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/rigid3.h"
#include "common/status.h"
#include "server/inpainting/inpaint.h"

namespace exo::inpainting {

// std::lround without the library call (bit-identical: half away from zero) for |x| < 2^52; the
// per-pixel loops of the live DR view call it millions of times per second.
inline long RoundHalfAway(double x) {
  if (!(std::fabs(x) < 4503599627370496.0)) return std::lround(x);  // 2^52, NaN
  const long t = static_cast<long>(x);  // toward zero
  const double frac = x - static_cast<double>(t);  // exact
  // Branch-free: the rounding direction of image data is a coin toss for a branch predictor.
  return t + static_cast<long>(frac >= 0.5) - static_cast<long>(frac <= -0.5);
}

// A view the look-up takes colour from: an inpainted keyframe (observed outside its T,
// inpainted inside: `hallucinated`) or an observed frame (depth 0 inside its ROI: never used).
struct DrView {
  ImageU8 color;
  ImageF depth;
  ImageU8 hallucinated;  // 1 ch, 255 where colour/depth are inpainted; empty = none
  PinholeCamera cam;
  Rigid3d world_from_cam, cam_from_world;
  std::shared_ptr<InpaintResult> result;  // keyframes inpainted by the library (propagation)
  ImageU8 roi;                            // keyframes: their full ROI (keyframe rule)
};

// Background depth of the frame's `roi` pixels (frame `cam` at `pose`): the keyframe's depth
// (observed + inpainted) forward-warped into them (each point to its nearest pixel, nearest point
// wins; a 2x2 splat biases the depth by half a pixel, which adds up on a floor seen at a grazing
// angle), the frame's own depth outside `roi`, the gaps push-pull filled (bilinear), then two
// fixed-point look-ups in the keyframe (bilinear depth there, not across a depth edge).
ImageF WarpBackgroundDepth(const DrView& kf, const PinholeCamera& cam, const Rigid3d& pose,
                           const ImageU8& roi, const ImageF& frame_depth);

// Colour of `region`'s pixels (frame `cam`/`pose`, background depth `depth`) looked up in the
// views (nearest pose first): the first view that observed the point (visible there: depth
// within 2 % + 1 cm, not inpainted) gives it (bilinear); failing that, the nearest view holding
// an inpainted sample of it. `observed` = 255 where an observation gave the colour, `filled` =
// 255 where anything did.
void LookUpInViews(const std::vector<const DrView*>& views, const PinholeCamera& cam,
                   const Rigid3d& pose, const ImageU8& region, const ImageF& depth, ImageU8* color,
                   ImageU8* observed, ImageU8* filled, bool bicubic = false);

// Gradient-domain blend: inside `roi` the result has the gradients of `guide` (defined on roi
// dilated by one pixel) and meets `frame` at the ROI's border (Dirichlet). RGB8 guide and frame
// of the roi's size, else InvalidArgument.
absl::Status PoissonBlendColor(const ImageU8& guide, const ImageU8& roi, ImageU8* frame);

}  // namespace exo::inpainting
