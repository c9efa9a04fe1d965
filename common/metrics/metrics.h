// Image quality metrics for evaluation (SPEC §9): SSIM exactly per Wang, Bovik, Sheikh,
// Simoncelli 2004 (11x11 Gaussian window, sigma 1.5, K1 0.01, K2 0.03, L 255) on luma,
// MSSIM = mean SSIM over a set of views, PSNR, masked variants, covered-pixel fraction.
//
// Conventions (fixed here, used by every benchmark):
//  - Luma: Y = 0.299 R + 0.587 G + 0.114 B (ITU-R BT.601 weights) on the sRGB-encoded 8-bit
//    values, in double, NOT rounded (MATLAB's rgb2gray rounds to uint8; we do not). A 1-channel
//    image is used as is.
//  - SSIM map: full image size, computed in double with OpenCV's GaussianBlur (kernel 11x11,
//    sigma 1.5) and OpenCV's default border (BORDER_REFLECT_101): the published OpenCV recipe.
//    Ssim() is the mean of the map over all pixels; with SsimOptions::crop_border it is the
//    mean over pixels whose window lies inside the image, which equals Wang's MATLAB
//    ssim_index.m ('valid' filtering) independent of the border rule.
//  - PSNR: 10 log10(255^2 / MSE), MSE over all channels of the (masked) pixels; +infinity when
//    the images are identical (JSON writers must print it as a string or a cap).
//  - Masks: 1-channel ImageU8 of the image size, nonzero = pixel counts.
#pragma once

#include <span>

#include "common/image.h"
#include "common/status.h"

namespace exo {

struct SsimOptions {
  int window = 11;             // odd
  double sigma = 1.5;
  double k1 = 0.01;
  double k2 = 0.03;
  double dynamic_range = 255.0;  // L
  bool crop_border = false;      // mean only over windows fully inside the image (Wang 'valid')
  absl::Status Validate() const;
};

// Y = 0.299 R + 0.587 G + 0.114 B in double (1-channel input copied). Not rounded.
Image<double> LumaFromRgb(const ImageU8& rgb);

// Per-pixel SSIM of the lumas of `a` and `b` (same size, 1 or 3 channels, >= window in each
// dimension). Values in [-1, 1], 1 where the windows are identical.
absl::StatusOr<Image<double>> SsimMap(const ImageU8& a, const ImageU8& b,
                                      const SsimOptions& options = {});
// Mean of the SSIM map (see crop_border).
absl::StatusOr<double> Ssim(const ImageU8& a, const ImageU8& b, const SsimOptions& options = {});
// Mean of the SSIM map over mask pixels (and, with crop_border, inside the valid region).
// Error if no pixel counts.
absl::StatusOr<double> MaskedSsim(const ImageU8& a, const ImageU8& b, const ImageU8& mask,
                                  const SsimOptions& options = {});
// MSSIM over a set of views: mean of the per-view Ssim (masked per view when `masks` is not
// empty; then masks.size() must equal the number of views).
absl::StatusOr<double> MeanSsim(std::span<const ImageU8> a, std::span<const ImageU8> b,
                                std::span<const ImageU8> masks = {},
                                const SsimOptions& options = {});

// Mean squared error over all channels (of the mask pixels). Error if no pixel counts.
// OK when a and b are non-empty 1- or 3-channel images of the same shape (every metric's input
// check); otherwise InvalidArgument naming both shapes.
absl::Status CheckMetricPair(const ImageU8& a, const ImageU8& b);

absl::StatusOr<double> Mse(const ImageU8& a, const ImageU8& b);
absl::StatusOr<double> MaskedMse(const ImageU8& a, const ImageU8& b, const ImageU8& mask);
double PsnrFromMse(double mse, double peak = 255.0);  // +inf for mse == 0
absl::StatusOr<double> Psnr(const ImageU8& a, const ImageU8& b);
absl::StatusOr<double> MaskedPsnr(const ImageU8& a, const ImageU8& b, const ImageU8& mask);

// Fraction of nonzero pixels of a 1-channel mask (e.g. pixels a renderer covered).
absl::StatusOr<double> CoveredFraction(const ImageU8& mask);

}  // namespace exo
