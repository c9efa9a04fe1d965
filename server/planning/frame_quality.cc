#include "server/planning/frame_quality.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace exo::planning {

double LaplacianVariance(const ImageU8& image) {
  const int w = image.width() / 2, h = image.height() / 2;
  if (w < 3 || h < 3) return 0.0;
  const int ch = image.channels();
  std::vector<float> g(static_cast<size_t>(w) * h);
  for (int y = 0; y < h; ++y) {
    const uint8_t* r0 = image.row(2 * y);
    const uint8_t* r1 = image.row(2 * y + 1);
    for (int x = 0; x < w; ++x) {
      float sum = 0.0f;
      for (const uint8_t* r : {r0, r1})
        for (int dx = 0; dx < 2; ++dx) {
          const uint8_t* p = r + static_cast<size_t>(2 * x + dx) * ch;
          sum += ch >= 3 ? 0.25f * (float(p[0]) + 2.0f * float(p[1]) + float(p[2])) : float(p[0]);
        }
      g[static_cast<size_t>(y) * w + x] = 0.25f * sum;
    }
  }
  double sum = 0.0, sum2 = 0.0;
  size_t n = 0;
  for (int y = 1; y + 1 < h; ++y)
    for (int x = 1; x + 1 < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      const double l = double(g[i - 1]) + g[i + 1] + g[i - w] + g[i + w] - 4.0 * g[i];
      sum += l;
      sum2 += l * l;
      ++n;
    }
  const double mean = sum / double(n);
  return std::max(0.0, sum2 / double(n) - mean * mean);
}

absl::Status FrameQualityOptions::Validate() const {
  if (!std::isfinite(gamma) || gamma < 0.0 || gamma > 8.0)
    return absl::InvalidArgumentError(absl::StrCat("frame quality gamma must be in [0, 8], got ", gamma));
  if (window < 1 || window > 1000)
    return absl::InvalidArgumentError(
        absl::StrCat("frame quality window must be in [1, 1000] frames, got ", window));
  if (!std::isfinite(floor) || floor <= 0.0 || floor > 1.0)
    return absl::InvalidArgumentError(absl::StrCat("frame quality floor must be in (0, 1], got ", floor));
  return absl::OkStatus();
}

double FrameQuality::Next(double s) {
  if (!(options_.gamma > 0.0) || !std::isfinite(s) || !(s > 0.0)) return 1.0;
  double ref = s;
  for (double r : recent_) ref = std::max(ref, r);
  recent_.push_back(s);
  while (recent_.size() > static_cast<size_t>(options_.window)) recent_.pop_front();
  const double q = std::pow(s / ref, options_.gamma);
  return std::clamp(q, options_.floor, 1.0);
}

}  // namespace exo::planning
