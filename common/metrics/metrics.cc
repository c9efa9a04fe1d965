#include "common/metrics/metrics.h"

#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>

#include "common/io/cv_adapter.h"

namespace exo {
namespace {


absl::Status CheckMask(const ImageU8& a, const ImageU8& mask) {
  if (mask.channels() != 1 || mask.width() != a.width() || mask.height() != a.height())
    return absl::InvalidArgumentError(absl::StrCat("mask is ", mask.width(), "x", mask.height(),
                                                   "x", mask.channels(), ", image is ", a.width(),
                                                   "x", a.height(), " (need 1 channel)"));
  return absl::OkStatus();
}

absl::StatusOr<double> MeanOfMap(const Image<double>& map, const ImageU8* mask,
                                 const SsimOptions& o) {
  const int r = o.crop_border ? o.window / 2 : 0;
  double sum = 0.0;
  size_t n = 0;
  for (int y = r; y < map.height() - r; ++y)
    for (int x = r; x < map.width() - r; ++x) {
      if (mask != nullptr && mask->at(x, y) == 0) continue;
      sum += map.at(x, y);
      ++n;
    }
  if (n == 0)
    return absl::InvalidArgumentError("SSIM over zero pixels (empty mask or image too small)");
  return sum / static_cast<double>(n);
}

}  // namespace

absl::Status CheckMetricPair(const ImageU8& a, const ImageU8& b) {
  if (a.empty() || b.empty()) return absl::InvalidArgumentError("metric on an empty image");
  if (!a.SameShape(b))
    return absl::InvalidArgumentError(absl::StrCat("metric on images of different shape: ",
                                                   a.width(), "x", a.height(), "x", a.channels(),
                                                   " vs ", b.width(), "x", b.height(), "x",
                                                   b.channels()));
  if (a.channels() != 1 && a.channels() != 3)
    return absl::InvalidArgumentError(
        absl::StrCat("metric needs 1- or 3-channel images, got ", a.channels()));
  return absl::OkStatus();
}

absl::Status SsimOptions::Validate() const {
  if (window < 3 || window % 2 == 0)
    return absl::InvalidArgumentError(absl::StrCat("SSIM window ", window, " must be odd and >= 3"));
  if (!(sigma > 0.0) || !(k1 > 0.0) || !(k2 > 0.0) || !(dynamic_range > 0.0))
    return absl::InvalidArgumentError("SSIM sigma, K1, K2 and L must be > 0");
  return absl::OkStatus();
}

Image<double> LumaFromRgb(const ImageU8& rgb) {
  Image<double> y(rgb.width(), rgb.height(), 1);
  const size_t n = static_cast<size_t>(rgb.width()) * rgb.height();
  const uint8_t* p = rgb.data();
  if (rgb.channels() == 1) {
    for (size_t i = 0; i < n; ++i) y.data()[i] = p[i];
  } else {
    EXO_CHECK(rgb.channels() == 3);
    for (size_t i = 0; i < n; ++i)
      y.data()[i] = 0.299 * p[3 * i] + 0.587 * p[3 * i + 1] + 0.114 * p[3 * i + 2];
  }
  return y;
}

absl::StatusOr<Image<double>> SsimMap(const ImageU8& a, const ImageU8& b,
                                      const SsimOptions& o) {
  EXO_RETURN_IF_ERROR(o.Validate());
  EXO_RETURN_IF_ERROR(CheckMetricPair(a, b));
  if (a.width() < o.window || a.height() < o.window)
    return absl::InvalidArgumentError(absl::StrCat("SSIM needs images of at least ", o.window,
                                                   "x", o.window, ", got ", a.width(), "x",
                                                   a.height()));
  Image<double> ya = LumaFromRgb(a), yb = LumaFromRgb(b);
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
  const cv::Mat mu1_sq = mu1.mul(mu1), mu2_sq = mu2.mul(mu2), mu1_mu2 = mu1.mul(mu2);
  const cv::Mat sigma1_sq = blur(i1.mul(i1)) - mu1_sq;
  const cv::Mat sigma2_sq = blur(i2.mul(i2)) - mu2_sq;
  const cv::Mat sigma12 = blur(i1.mul(i2)) - mu1_mu2;
  Image<double> map(a.width(), a.height(), 1);
  for (int y = 0; y < a.height(); ++y) {
    const double* m1 = mu1.ptr<double>(y);
    const double* m2 = mu2.ptr<double>(y);
    const double* s1 = sigma1_sq.ptr<double>(y);
    const double* s2 = sigma2_sq.ptr<double>(y);
    const double* s12 = sigma12.ptr<double>(y);
    double* out = map.row(y);
    for (int x = 0; x < a.width(); ++x) {
      const double num = (2.0 * m1[x] * m2[x] + c1) * (2.0 * s12[x] + c2);
      const double den = (m1[x] * m1[x] + m2[x] * m2[x] + c1) * (s1[x] + s2[x] + c2);
      out[x] = num / den;  // den >= c1 * c2 > 0 up to rounding of the variances
    }
  }
  return map;
}

absl::StatusOr<double> Ssim(const ImageU8& a, const ImageU8& b, const SsimOptions& o) {
  EXO_ASSIGN_OR_RETURN(const Image<double> map, SsimMap(a, b, o));
  return MeanOfMap(map, nullptr, o);
}

absl::StatusOr<double> MaskedSsim(const ImageU8& a, const ImageU8& b, const ImageU8& mask,
                                  const SsimOptions& o) {
  EXO_RETURN_IF_ERROR(CheckMask(a, mask));
  EXO_ASSIGN_OR_RETURN(const Image<double> map, SsimMap(a, b, o));
  return MeanOfMap(map, &mask, o);
}

absl::StatusOr<double> MeanSsim(std::span<const ImageU8> a, std::span<const ImageU8> b,
                                std::span<const ImageU8> masks, const SsimOptions& o) {
  if (a.size() != b.size() || a.empty())
    return absl::InvalidArgumentError(absl::StrCat("MSSIM needs equal, non-zero view counts, got ",
                                                   a.size(), " and ", b.size()));
  if (!masks.empty() && masks.size() != a.size())
    return absl::InvalidArgumentError(
        absl::StrCat("MSSIM: ", masks.size(), " masks for ", a.size(), " views"));
  double sum = 0.0;
  for (size_t i = 0; i < a.size(); ++i) {
    auto s = masks.empty() ? Ssim(a[i], b[i], o) : MaskedSsim(a[i], b[i], masks[i], o);
    if (!s.ok())
      return absl::Status(s.status().code(), absl::StrCat("view ", i, ": ", s.status().message()));
    sum += *s;
  }
  return sum / static_cast<double>(a.size());
}

absl::StatusOr<double> MaskedMse(const ImageU8& a, const ImageU8& b, const ImageU8& mask) {
  EXO_RETURN_IF_ERROR(CheckMetricPair(a, b));
  const bool use_mask = !mask.empty();
  if (use_mask) EXO_RETURN_IF_ERROR(CheckMask(a, mask));
  const int c = a.channels();
  double se = 0.0;
  size_t n = 0;
  for (int y = 0; y < a.height(); ++y)
    for (int x = 0; x < a.width(); ++x) {
      if (use_mask && mask.at(x, y) == 0) continue;
      for (int k = 0; k < c; ++k) {
        const double d = static_cast<double>(a.at(x, y, k)) - b.at(x, y, k);
        se += d * d;
      }
      n += c;
    }
  if (n == 0) return absl::InvalidArgumentError("MSE over zero pixels (empty mask)");
  return se / static_cast<double>(n);
}

absl::StatusOr<double> Mse(const ImageU8& a, const ImageU8& b) {
  return MaskedMse(a, b, ImageU8());
}

double PsnrFromMse(double mse, double peak) {
  if (mse <= 0.0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(peak * peak / mse);
}

absl::StatusOr<double> Psnr(const ImageU8& a, const ImageU8& b) {
  EXO_ASSIGN_OR_RETURN(const double mse, Mse(a, b));
  return PsnrFromMse(mse);
}

absl::StatusOr<double> MaskedPsnr(const ImageU8& a, const ImageU8& b, const ImageU8& mask) {
  if (mask.empty()) return absl::InvalidArgumentError("MaskedPsnr: empty mask image");
  EXO_ASSIGN_OR_RETURN(const double mse, MaskedMse(a, b, mask));
  return PsnrFromMse(mse);
}

absl::StatusOr<double> CoveredFraction(const ImageU8& mask) {
  if (mask.empty() || mask.channels() != 1)
    return absl::InvalidArgumentError("CoveredFraction needs a non-empty 1-channel mask");
  size_t n = 0;
  for (uint8_t v : mask.span()) n += (v != 0);
  return static_cast<double>(n) / static_cast<double>(mask.size());
}

}  // namespace exo
