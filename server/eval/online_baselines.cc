#include "server/eval/online_baselines.h"

#include <algorithm>
#include <cmath>

namespace exo::eval {

void ProgressiveEveryN::Offer(int idx, const Rigid3d&) {
  const int64_t k = offered_++;
  if (k % n_ != 0) return;
  while (kept_.size() >= cap_) {
    std::vector<std::pair<int64_t, int>> thinned;
    for (const auto& e : kept_)
      if (e.first % (2 * n_) == 0) thinned.push_back(e);
    kept_ = std::move(thinned);
    n_ *= 2;
    if (k % n_ != 0) return;
  }
  kept_.push_back({k, idx});
}

std::vector<int> ProgressiveEveryN::Selected() const {
  std::vector<int> out;
  for (const auto& e : kept_) out.push_back(e.second);
  std::sort(out.begin(), out.end());
  return out;
}

void ReservoirSampler::Offer(int idx, const Rigid3d&) {
  const int64_t k = offered_++;
  if (kept_.size() < cap_) {
    kept_.push_back(idx);
    return;
  }
  const int64_t j = std::uniform_int_distribution<int64_t>(0, k)(rng_);
  if (j < int64_t(cap_)) kept_[size_t(j)] = idx;
}

std::vector<int> ReservoirSampler::Selected() const {
  std::vector<int> out = kept_;
  std::sort(out.begin(), out.end());
  return out;
}

double KeyframeDistance(const Rigid3d& a, const Rigid3d& b, double unit_m) {
  // M_a^-1 M_b = [Ra^T Rb, Ra^T (tb - ta)]; ||I - R||_F^2 = 2 (3 - trace R); the last row of
  // I - M is zero.
  const glm::dmat3 ra = a.RotationMatrix(), rb = b.RotationMatrix();
  const glm::dmat3 rel = glm::transpose(ra) * rb;
  const double tr = rel[0][0] + rel[1][1] + rel[2][2];
  const glm::dvec3 t = glm::transpose(ra) * (b.translation - a.translation) / unit_m;
  return std::sqrt(std::max(0.0, 2.0 * (3.0 - tr)) + glm::dot(t, t));
}

void KeyframeSelector::Offer(int idx, const Rigid3d& pose) {
  if (kept_.empty()) {
    kept_.push_back({idx, pose});
    return;
  }
  if (KeyframeDistance(kept_.back().pose, pose, unit_m_) <= threshold_) return;
  if (cap_ < 2) return;  // one slot: the first frame stays (thinning always keeps it)
  while (kept_.size() >= cap_) {
    threshold_ *= growth_;
    std::vector<Kf> thinned = {kept_.front()};
    for (size_t i = 1; i < kept_.size(); ++i)
      if (KeyframeDistance(thinned.back().pose, kept_[i].pose, unit_m_) > threshold_)
        thinned.push_back(kept_[i]);
    kept_ = std::move(thinned);
  }
  if (KeyframeDistance(kept_.back().pose, pose, unit_m_) > threshold_) kept_.push_back({idx, pose});
}

std::vector<int> KeyframeSelector::Selected() const {
  std::vector<int> out;
  for (const Kf& k : kept_) out.push_back(k.idx);
  return out;
}

}  // namespace exo::eval
