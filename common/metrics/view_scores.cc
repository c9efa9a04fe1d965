#include "common/metrics/view_scores.h"

#include <algorithm>

#include "common/metrics/metrics.h"
#include "common/metrics/perceptual.h"

namespace exo {

absl::StatusOr<ViewScores> ScoreView(const ImageU8& filled, const ImageU8& rendered,
                                     const ImageU8& truth, const ImageU8& mask) {
  ViewScores s;
  EXO_ASSIGN_OR_RETURN(s.ssim, Ssim(filled, truth));
  EXO_ASSIGN_OR_RETURN(const double mse, Mse(filled, truth));
  EXO_ASSIGN_OR_RETURN(s.ssim_unfilled, Ssim(rendered, truth));
  EXO_ASSIGN_OR_RETURN(const double mse_raw, Mse(rendered, truth));
  EXO_ASSIGN_OR_RETURN(s.coverage, CoveredFraction(mask));
  s.psnr = std::min(99.0, PsnrFromMse(mse));
  s.psnr_unfilled = std::min(99.0, PsnrFromMse(mse_raw));
  if (MsSsimFits(truth.width(), truth.height())) {
    EXO_ASSIGN_OR_RETURN(const double m, MsSsim(filled, truth));
    s.ms_ssim = m;
  }
  EXO_ASSIGN_OR_RETURN(s.gmsd, Gmsd(truth, filled));
  if (s.coverage > 0) {
    auto m = MaskedSsim(rendered, truth, mask);
    if (m.ok()) s.ssim_covered = *m;
  }
  return s;
}

}  // namespace exo
