// Image quality metrics beyond single-scale SSIM (issue 15, item 3): SSIM prefers blur to a
// one-pixel misalignment, so the evaluation also reports
//  - MS-SSIM, multi-scale SSIM (Wang, Simoncelli, Bovik, "Multi-scale structural similarity for
//    image quality assessment", Asilomar 2003): 5 scales, weights 0.0448 0.2856 0.3001 0.2363
//    0.1333; at scales 1..4 the mean contrast-structure term cs, at scale 5 the mean SSIM
//    (luminance x cs), each raised to its weight and multiplied. Between scales a 2x2 box
//    low-pass and factor-2 subsampling (the authors' msssim.m: imfilter ones(2)/4 'symmetric',
//    then every second sample). SSIM constants and window as common/metrics (11x11 Gaussian,
//    sigma 1.5, K1 0.01, K2 0.03, L 255) on the same luma; means over windows fully inside the
//    image (msssim.m uses ssim_index 'valid'). A negative mean cs is clamped to 0 (the product
//    of fractional powers is undefined there); 1 for identical images, higher is better.
//  - GMSD, gradient magnitude similarity deviation (Xue, Zhang, Mou, Bovik, "Gradient magnitude
//    similarity deviation: a highly efficient perceptual image quality index", IEEE TIP 2014):
//    luma 2x2-averaged and subsampled by 2, Prewitt gradients (1/3 [1 0 -1] x 3 rows, zero
//    padding), GMS = (2 m_r m_d + T) / (m_r^2 + m_d^2 + T) with T = 170 (8-bit range), GMSD =
//    the standard deviation (1/N, Eq. 8 of the paper) of the GMS map. 0 for identical images,
//    higher is worse; it penalises misplaced edges more than a uniform loss of sharpness.
#pragma once

#include "common/image.h"
#include "common/metrics/metrics.h"
#include "common/status.h"

namespace exo {

struct MsSsimOptions {
  SsimOptions ssim;  // crop_border is ignored: every scale averages over 'valid' windows
  int scales = 5;    // 1..5; fewer: the first `scales` of the paper's weights, renormalised
  absl::Status Validate() const;
};

// MS-SSIM of the lumas of `a` and `b` (same size, 1 or 3 channels). Error when the coarsest
// scale is smaller than the window (5 scales of an 11 px window: at least 176 x 176 pixels).
absl::StatusOr<double> MsSsim(const ImageU8& a, const ImageU8& b, const MsSsimOptions& options = {});
// True when MsSsim accepts images of this size.
bool MsSsimFits(int width, int height, const MsSsimOptions& options = {});

struct GmsdOptions {
  double t = 170.0;       // stability constant T of the GMS map (8-bit images)
  bool downsample = true; // the paper's 2x2 average + factor-2 subsampling first
  absl::Status Validate() const;
};

// GMS map (after the optional downsampling): per pixel, in (0, 1].
absl::StatusOr<Image<double>> GmsMap(const ImageU8& reference, const ImageU8& distorted,
                                     const GmsdOptions& options = {});
// GMSD = standard deviation (population) of the GMS map. Images need at least 2 x 2 pixels.
absl::StatusOr<double> Gmsd(const ImageU8& reference, const ImageU8& distorted,
                            const GmsdOptions& options = {});

}  // namespace exo
