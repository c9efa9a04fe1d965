// The per-view quality figures every evaluation reports (exoview_eval, exoview_product_eval):
// SSIM / PSNR of the frame the product shows (uncovered pixels filled), the same of the frame as
// rendered, coverage, MS-SSIM and GMSD of the shown frame, SSIM over the covered pixels.
#pragma once

#include <optional>

#include "common/image.h"
#include "common/status.h"

namespace exo {

struct ViewScores {
  double ssim = 0, psnr = 0;                    // filled frame (PSNR capped at 99 dB)
  double ssim_unfilled = 0, psnr_unfilled = 0;  // as rendered
  double coverage = 0;                          // covered (blended) fraction of `mask`
  std::optional<double> ms_ssim;                // filled frame; none when the image is too small
  double gmsd = 0;                              // filled frame (0 = identical)
  std::optional<double> ssim_covered;           // as rendered, covered pixels only (coverage > 0)
};

// `filled` = `rendered` with its uncovered pixels filled (the renderers' FillHoles), `truth` the
// ground truth, `mask` the covered pixels (non-zero). Sizes must agree (an error otherwise).
absl::StatusOr<ViewScores> ScoreView(const ImageU8& filled, const ImageU8& rendered,
                                     const ImageU8& truth, const ImageU8& mask);

}  // namespace exo
