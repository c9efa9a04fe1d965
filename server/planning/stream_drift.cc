#include "server/planning/stream_drift.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"

namespace exo::planning {

absl::Status StreamDriftOptions::Validate() const {
  if (lag < 2 || lag > 300) return absl::InvalidArgumentError(absl::StrCat("stream drift lag must be in [2, 300], got ", lag));
  if (max_width < 8) return absl::InvalidArgumentError("stream drift max_width must be >= 8");
  if (min_pairs < 1) return absl::InvalidArgumentError("stream drift min_pairs must be >= 1");
  if (!(min_overlap > 0.0 && min_overlap <= 1.0))
    return absl::InvalidArgumentError("stream drift min_overlap must be in (0, 1]");
  return absl::OkStatus();
}

double MedianRelativeDisagreement(const ImageF& a, const PinholeCamera& cam_a,
                                  const Rigid3d& local_from_a, const ImageF& b,
                                  const PinholeCamera& cam_b, const Rigid3d& local_from_b,
                                  double min_overlap) {
  const Rigid3d b_from_a = local_from_b.Inverse() * local_from_a;
  std::vector<double> rel;
  rel.reserve(static_cast<size_t>(a.width()) * a.height());
  size_t valid = 0;
  for (int y = 0; y < a.height(); ++y)
    for (int x = 0; x < a.width(); ++x) {
      const double z = a.at(x, y);
      if (!(z > 0.0) || !std::isfinite(z)) continue;
      ++valid;
      const glm::dvec3 p = b_from_a * cam_a.Unproject({x, y}, z);
      glm::dvec2 uv;
      if (!cam_b.Project(p, &uv)) continue;
      const int x0 = static_cast<int>(std::floor(uv.x)), y0 = static_cast<int>(std::floor(uv.y));
      if (x0 < 0 || y0 < 0 || x0 + 1 >= b.width() || y0 + 1 >= b.height()) continue;
      const double z00 = b.at(x0, y0), z10 = b.at(x0 + 1, y0), z01 = b.at(x0, y0 + 1),
                   z11 = b.at(x0 + 1, y0 + 1);
      const double lo = std::min({z00, z10, z01, z11}), hi = std::max({z00, z10, z01, z11});
      if (!(lo > 0.0) || hi > 1.05 * lo) continue;  // a hole or a depth edge: no reading
      const double fx = uv.x - x0, fy = uv.y - y0;
      const double zb = (1 - fy) * ((1 - fx) * z00 + fx * z10) + fy * ((1 - fx) * z01 + fx * z11);
      rel.push_back(std::abs(zb - p.z) / p.z);
    }
  if (valid == 0 || static_cast<double>(rel.size()) < min_overlap * static_cast<double>(valid))
    return -1.0;
  auto mid = rel.begin() + static_cast<std::ptrdiff_t>(rel.size() / 2);
  std::nth_element(rel.begin(), mid, rel.end());
  return *mid;
}

void StreamDrift::Next(const ImageF& depth, const PinholeCamera& camera,
                       const Rigid3d& local_from_depth) {
  if (depth.empty() || depth.width() != camera.width || depth.height() != camera.height) return;
  const int step = std::max(1, (depth.width() + options_.max_width - 1) / options_.max_width);
  Small s;
  // Every step-th sample, the camera scaled with the pixel centres kept.
  const int w = depth.width() / step, h = depth.height() / step;
  s.depth = ImageF(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) s.depth.at(x, y) = depth.at(x * step, y * step);
  s.camera = camera;
  s.camera.fx /= step;
  s.camera.fy /= step;
  s.camera.cx /= step;
  s.camera.cy /= step;
  s.camera.width = w;
  s.camera.height = h;
  s.local_from_depth = local_from_depth;
  auto measure = [&](const Small& o, std::vector<uint64_t>* h) {
    const double r = MedianRelativeDisagreement(o.depth, o.camera, o.local_from_depth, s.depth,
                                                s.camera, s.local_from_depth, options_.min_overlap);
    if (r >= 0.0) ++(*h)[Bin(r)];
  };
  if (!recent_.empty()) measure(recent_.back(), &near_);
  if (static_cast<int>(recent_.size()) == options_.lag) measure(recent_.front(), &far_);
  recent_.push_back(std::move(s));
  while (static_cast<int>(recent_.size()) > options_.lag) recent_.pop_front();
}

int StreamDrift::Bin(double r) {
  if (!(r >= 1e-6)) return 0;
  if (r >= 1.0) return kBins - 1;
  return std::clamp(1 + static_cast<int>(std::floor(40.0 * (std::log10(r) + 6.0))), 1, kBins - 2);
}

uint64_t StreamDrift::Count(const std::vector<uint64_t>& h) {
  uint64_t n = 0;
  for (uint64_t c : h) n += c;
  return n;
}

double StreamDrift::Median(const std::vector<uint64_t>& h) {
  const uint64_t n = Count(h);
  if (n == 0) return 0.0;
  uint64_t seen = 0;
  for (int b = 0; b < kBins; ++b) {
    seen += h[b];
    if (2 * seen >= n) {
      if (b == 0) return 0.0;
      if (b == kBins - 1) return 1.0;
      return std::pow(10.0, (b - 0.5) / 40.0 - 6.0);  // the bin's geometric centre
    }
  }
  return 1.0;
}

double StreamDrift::Growth() const {
  if (pairs_near() < static_cast<uint64_t>(options_.min_pairs) ||
      pairs_far() < static_cast<uint64_t>(options_.min_pairs))
    return -1.0;
  return std::max(0.0, Far() - Near());
}

double StreamDrift::TimeScale(double ref) const {
  const double g = Growth();
  if (g < 0.0 || !(ref > 0.0)) return 0.0;
  return std::clamp((g - 0.5 * ref) / (0.5 * ref), 0.0, 1.0);
}

std::vector<double> StreamDrift::State() const {
  std::vector<double> s;
  s.reserve(2 * kBins);
  for (uint64_t c : near_) s.push_back(static_cast<double>(c));
  for (uint64_t c : far_) s.push_back(static_cast<double>(c));
  return s;
}

void StreamDrift::SetState(const std::vector<double>& s) {
  if (s.size() != 2 * static_cast<size_t>(kBins)) return;
  for (int b = 0; b < kBins; ++b) {
    near_[b] = static_cast<uint64_t>(s[b]);
    far_[b] = static_cast<uint64_t>(s[kBins + b]);
  }
}

}  // namespace exo::planning
