#include "common/metrics/perceptual.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "common/io/cv_adapter.h"

namespace exo {
namespace {

constexpr std::array<double, 5> kMsSsimWeights = {0.0448, 0.2856, 0.3001, 0.2363, 0.1333};


// 2x2 mean, every second sample; pixels beyond the last row/column are `pad(edge)` (msssim.m:
// 'symmetric' = the edge pixel again; GMSD's conv2 'same': zero).
Image<double> Halve(const Image<double>& in, bool zero_pad) {
  const int w = (in.width() + 1) / 2, h = (in.height() + 1) / 2;
  Image<double> out(w, h, 1);
  auto px = [&](int x, int y) -> double {
    if (x >= in.width() || y >= in.height()) {
      if (zero_pad) return 0.0;
      x = std::min(x, in.width() - 1);
      y = std::min(y, in.height() - 1);
    }
    return in.at(x, y);
  };
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      out.at(x, y) = 0.25 * (px(2 * x, 2 * y) + px(2 * x + 1, 2 * y) + px(2 * x, 2 * y + 1) +
                             px(2 * x + 1, 2 * y + 1));
  return out;
}

// Mean contrast-structure term and mean SSIM over the windows fully inside the image.
struct ScaleTerms {
  double cs = 0, ssim = 0;
};
ScaleTerms SsimTerms(const Image<double>& ya, const Image<double>& yb, const SsimOptions& o) {
  const cv::Mat i1 = CvView(ya), i2 = CvView(yb);
  const double c1 = (o.k1 * o.dynamic_range) * (o.k1 * o.dynamic_range);
  const double c2 = (o.k2 * o.dynamic_range) * (o.k2 * o.dynamic_range);
  const cv::Size ksize(o.window, o.window);
  auto blur = [&](const cv::Mat& src) {
    cv::Mat dst;
    cv::GaussianBlur(src, dst, ksize, o.sigma, o.sigma, cv::BORDER_REFLECT_101);
    return dst;
  };
  const cv::Mat mu1 = blur(i1), mu2 = blur(i2);
  const cv::Mat s11 = blur(i1.mul(i1)), s22 = blur(i2.mul(i2)), s12 = blur(i1.mul(i2));
  const int r = o.window / 2;
  double cs_sum = 0, ssim_sum = 0;
  size_t n = 0;
  for (int y = r; y < ya.height() - r; ++y) {
    const double* m1 = mu1.ptr<double>(y);
    const double* m2 = mu2.ptr<double>(y);
    const double* a11 = s11.ptr<double>(y);
    const double* a22 = s22.ptr<double>(y);
    const double* a12 = s12.ptr<double>(y);
    for (int x = r; x < ya.width() - r; ++x) {
      const double v1 = a11[x] - m1[x] * m1[x], v2 = a22[x] - m2[x] * m2[x];
      const double cov = a12[x] - m1[x] * m2[x];
      const double cs = (2.0 * cov + c2) / (v1 + v2 + c2);
      const double l = (2.0 * m1[x] * m2[x] + c1) / (m1[x] * m1[x] + m2[x] * m2[x] + c1);
      cs_sum += cs;
      ssim_sum += l * cs;
      ++n;
    }
  }
  return {cs_sum / double(n), ssim_sum / double(n)};
}

// Prewitt gradient magnitude, zero padding (conv2 'same').
Image<double> GradientMagnitude(const Image<double>& y) {
  const int w = y.width(), h = y.height();
  auto px = [&](int x, int yy) { return (x < 0 || yy < 0 || x >= w || yy >= h) ? 0.0 : y.at(x, yy); };
  Image<double> g(w, h, 1);
  for (int yy = 0; yy < h; ++yy)
    for (int x = 0; x < w; ++x) {
      double gx = 0, gy = 0;
      for (int d = -1; d <= 1; ++d) {
        gx += px(x - 1, yy + d) - px(x + 1, yy + d);
        gy += px(x + d, yy - 1) - px(x + d, yy + 1);
      }
      gx /= 3.0;
      gy /= 3.0;
      g.at(x, yy) = std::sqrt(gx * gx + gy * gy);
    }
  return g;
}

}  // namespace

absl::Status MsSsimOptions::Validate() const {
  EXO_RETURN_IF_ERROR(ssim.Validate());
  if (scales < 1 || scales > int(kMsSsimWeights.size()))
    return absl::InvalidArgumentError(absl::StrCat("MS-SSIM scales ", scales, " not in 1..5"));
  return absl::OkStatus();
}

bool MsSsimFits(int width, int height, const MsSsimOptions& o) {
  if (!o.Validate().ok()) return false;
  for (int s = 1; s < o.scales; ++s) {
    width = (width + 1) / 2;
    height = (height + 1) / 2;
  }
  return width >= o.ssim.window && height >= o.ssim.window;
}

absl::StatusOr<double> MsSsim(const ImageU8& a, const ImageU8& b, const MsSsimOptions& o) {
  EXO_RETURN_IF_ERROR(o.Validate());
  EXO_RETURN_IF_ERROR(CheckMetricPair(a, b));
  if (!MsSsimFits(a.width(), a.height(), o))
    return absl::InvalidArgumentError(absl::StrCat("MS-SSIM with ", o.scales, " scales needs a ",
                                                   o.ssim.window, " px window at the coarsest scale; ",
                                                   a.width(), "x", a.height(), " is too small"));
  // The paper's five weights (sum 1.0001) as published; fewer scales: renormalised to sum 1.
  double wsum = 1.0;
  if (o.scales < int(kMsSsimWeights.size())) {
    wsum = 0;
    for (int s = 0; s < o.scales; ++s) wsum += kMsSsimWeights[s];
  }
  Image<double> ya = LumaFromRgb(a), yb = LumaFromRgb(b);
  double result = 1.0;
  for (int s = 0; s < o.scales; ++s) {
    const ScaleTerms t = SsimTerms(ya, yb, o.ssim);
    const double term = s + 1 < o.scales ? t.cs : t.ssim;
    result *= std::pow(std::max(0.0, term), kMsSsimWeights[s] / wsum);
    if (s + 1 < o.scales) {
      ya = Halve(ya, /*zero_pad=*/false);
      yb = Halve(yb, /*zero_pad=*/false);
    }
  }
  return result;
}

absl::Status GmsdOptions::Validate() const {
  if (!(t > 0)) return absl::InvalidArgumentError("GMSD constant T must be > 0");
  return absl::OkStatus();
}

absl::StatusOr<Image<double>> GmsMap(const ImageU8& reference, const ImageU8& distorted,
                                     const GmsdOptions& o) {
  EXO_RETURN_IF_ERROR(o.Validate());
  EXO_RETURN_IF_ERROR(CheckMetricPair(reference, distorted));
  if (reference.width() < 2 || reference.height() < 2)
    return absl::InvalidArgumentError("GMSD needs at least 2x2 pixels");
  Image<double> yr = LumaFromRgb(reference), yd = LumaFromRgb(distorted);
  if (o.downsample) {
    yr = Halve(yr, /*zero_pad=*/true);
    yd = Halve(yd, /*zero_pad=*/true);
  }
  const Image<double> gr = GradientMagnitude(yr), gd = GradientMagnitude(yd);
  Image<double> gms(gr.width(), gr.height(), 1);
  for (size_t i = 0; i < gms.size(); ++i) {
    const double mr = gr.data()[i], md = gd.data()[i];
    gms.data()[i] = (2.0 * mr * md + o.t) / (mr * mr + md * md + o.t);
  }
  return gms;
}

absl::StatusOr<double> Gmsd(const ImageU8& reference, const ImageU8& distorted,
                            const GmsdOptions& o) {
  EXO_ASSIGN_OR_RETURN(const Image<double> gms, GmsMap(reference, distorted, o));
  double mean = 0;
  for (double v : gms.span()) mean += v;
  mean /= double(gms.size());
  double var = 0;
  for (double v : gms.span()) var += (v - mean) * (v - mean);
  return std::sqrt(var / double(gms.size()));
}

}  // namespace exo
