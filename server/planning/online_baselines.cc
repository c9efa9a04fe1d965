#include "server/planning/online_baselines.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "absl/strings/str_cat.h"

namespace exo::planning {

namespace {

template <typename T, typename Key>
void EraseKey(std::vector<T>* v, int64_t key, Key key_of) {
  v->erase(std::remove_if(v->begin(), v->end(), [&](const T& e) { return key_of(e) == key; }),
           v->end());
}

template <typename T, typename Key>
std::vector<int64_t> SortedKeys(const std::vector<T>& v, Key key_of) {
  std::vector<int64_t> out;
  out.reserve(v.size());
  for (const T& e : v) out.push_back(key_of(e));
  std::sort(out.begin(), out.end());
  return out;
}

// A state's kept list may not exceed the capacity it is loaded into.
absl::Status CheckCapacity(const char* what, StateReader* r, size_t n, size_t cap) {
  EXO_RETURN_IF_ERROR(r->Status(what));
  if (n > cap)
    return absl::DataLossError(
        absl::StrCat(what, " state holds ", n, " frames, more than its capacity ", cap));
  return absl::OkStatus();
}

}  // namespace

double BaselinePoseDistance(const Rigid3d& a, const Rigid3d& b, double metres_per_rad) {
  const double dt = glm::length(a.translation - b.translation);
  const double dot = std::abs(glm::dot(a.rotation, b.rotation));
  const double ang = 2.0 * std::acos(std::min(1.0, dot));
  return dt + metres_per_rad * ang;
}

// ---- minimum distance ----

void MinDistanceSelector::Offer(int64_t key, const Rigid3d& pose) {
  if (sel_.size() < cap_) {
    sel_.push_back({key, pose});
    pair_dirty_ = true;
    return;
  }
  // Closest pair in the store (O(n^2) but n <= a few hundred and only when full).
  if (pair_dirty_) {
    pair_d_ = 1e300;
    for (size_t i = 0; i < sel_.size(); ++i)
      for (size_t j = i + 1; j < sel_.size(); ++j) {
        const double d = BaselinePoseDistance(sel_[i].pose, sel_[j].pose, mpr_);
        if (d < pair_d_) {
          pair_d_ = d;
          pair_i_ = i;
          pair_j_ = j;
        }
      }
    pair_dirty_ = false;
  }
  double nearest = 1e300;
  size_t nearest_k = 0;
  for (size_t k = 0; k < sel_.size(); ++k) {
    const double d = BaselinePoseDistance(pose, sel_[k].pose, mpr_);
    if (d < nearest) {
      nearest = d;
      nearest_k = k;
    }
  }
  if (sel_.size() < 2 || nearest <= pair_d_) return;
  // Replace the member of the closest pair that is not the candidate's nearest neighbour's
  // twin: drop pair_j_ unless that is the candidate's nearest (then drop pair_i_).
  const size_t drop = nearest_k == pair_j_ ? pair_i_ : pair_j_;
  sel_[drop] = {key, pose};
  pair_dirty_ = true;
}

std::vector<int64_t> MinDistanceSelector::Selected() const {
  return SortedKeys(sel_, [](const Sel& s) { return s.key; });
}

void MinDistanceSelector::Forget(int64_t key) {
  EraseKey(&sel_, key, [](const Sel& s) { return s.key; });
  pair_dirty_ = true;
}

void MinDistanceSelector::Adopt(int64_t key, const Rigid3d& pose) {
  if (sel_.size() >= cap_) return;
  sel_.push_back({key, pose});
  pair_dirty_ = true;
}

void MinDistanceSelector::SaveState(StateWriter* w) const { w->PutVec(sel_); }

absl::Status MinDistanceSelector::LoadState(StateReader* r) {
  r->GetVec(&sel_);
  pair_dirty_ = true;
  return CheckCapacity("min-distance selector", r, sel_.size(), cap_);
}

// ---- progressive every-N ----

void ProgressiveEveryN::Offer(int64_t key, const Rigid3d&) {
  const int64_t k = offered_++;
  if (k % n_ != 0) return;
  while (kept_.size() >= cap_) {
    std::vector<Kept> thinned;
    for (const Kept& e : kept_)
      if (e.offer % (2 * n_) == 0) thinned.push_back(e);
    kept_ = std::move(thinned);
    n_ *= 2;
    if (k % n_ != 0) return;
  }
  kept_.push_back({k, key});
}

std::vector<int64_t> ProgressiveEveryN::Selected() const {
  return SortedKeys(kept_, [](const Kept& e) { return e.key; });
}

void ProgressiveEveryN::Forget(int64_t key) {
  EraseKey(&kept_, key, [](const Kept& e) { return e.key; });
}

void ProgressiveEveryN::Adopt(int64_t key, const Rigid3d&) {
  if (kept_.size() >= cap_) return;
  const int64_t k = (offered_ + n_ - 1) / n_ * n_;  // the next offer count that N keeps
  kept_.push_back({k, key});
  offered_ = k + 1;
}

void ProgressiveEveryN::SaveState(StateWriter* w) const {
  w->Put(n_);
  w->Put(offered_);
  w->PutVec(kept_);
}

absl::Status ProgressiveEveryN::LoadState(StateReader* r) {
  r->Get(&n_) && r->Get(&offered_) && r->GetVec(&kept_);
  EXO_RETURN_IF_ERROR(CheckCapacity("progressive every-N selector", r, kept_.size(), cap_));
  if (n_ < 1) return absl::DataLossError("progressive every-N selector state: step < 1");
  return absl::OkStatus();
}

// ---- length-aware every-N ----

bool LengthAwareEveryN::Keeps(int64_t k, int64_t len, int64_t cap) {
  const int64_t m = std::min(len, cap);
  if (k < 0 || k >= len || m < 1) return false;
  // The smallest j with floor(j len / m) >= k is ceil(k m / len); k is kept iff it hits k.
  const int64_t j = (k * m + len - 1) / len;
  return j < m && (j * len) / m == k;
}

void LengthAwareEveryN::Offer(int64_t key, const Rigid3d&) {
  const int64_t k = offered_++;
  if (Keeps(k, len_, int64_t(cap_)) && kept_.size() < cap_) kept_.push_back(key);
}

std::vector<int64_t> LengthAwareEveryN::Selected() const {
  return SortedKeys(kept_, [](int64_t k) { return k; });
}

void LengthAwareEveryN::Forget(int64_t key) {
  EraseKey(&kept_, key, [](int64_t k) { return k; });
}

void LengthAwareEveryN::Adopt(int64_t key, const Rigid3d&) {
  if (kept_.size() >= cap_) return;
  kept_.push_back(key);
  // The stream continues after the position of the last kept frame (the j-th: floor(j L / m)).
  const int64_t m = std::min<int64_t>(len_, int64_t(cap_));
  offered_ = std::max(offered_, (int64_t(kept_.size()) - 1) * len_ / m + 1);
}

void LengthAwareEveryN::SaveState(StateWriter* w) const {
  w->Put(offered_);
  w->PutVec(kept_);
}

absl::Status LengthAwareEveryN::LoadState(StateReader* r) {
  r->Get(&offered_) && r->GetVec(&kept_);
  return CheckCapacity("every-N selector", r, kept_.size(), cap_);
}

// ---- reservoir ----

void ReservoirSampler::Offer(int64_t key, const Rigid3d&) {
  const int64_t k = offered_++;
  if (kept_.size() < cap_) {
    kept_.push_back(key);
    return;
  }
  const int64_t j = std::uniform_int_distribution<int64_t>(0, k)(rng_);
  if (j < int64_t(cap_)) kept_[size_t(j)] = key;
}

std::vector<int64_t> ReservoirSampler::Selected() const {
  return SortedKeys(kept_, [](int64_t k) { return k; });
}

void ReservoirSampler::Forget(int64_t key) {
  EraseKey(&kept_, key, [](int64_t k) { return k; });
}

void ReservoirSampler::Adopt(int64_t key, const Rigid3d&) {
  if (kept_.size() >= cap_) return;
  kept_.push_back(key);
  ++offered_;
}

void ReservoirSampler::SaveState(StateWriter* w) const {
  std::ostringstream rng;
  rng << rng_;
  w->PutBytes(rng.str());
  w->Put(offered_);
  w->PutVec(kept_);
}

absl::Status ReservoirSampler::LoadState(StateReader* r) {
  std::string rng;
  r->GetBytes(&rng) && r->Get(&offered_) && r->GetVec(&kept_);
  EXO_RETURN_IF_ERROR(CheckCapacity("reservoir selector", r, kept_.size(), cap_));
  std::istringstream in(rng);
  in >> rng_;
  if (!in) return absl::DataLossError("reservoir selector state: unreadable generator");
  return absl::OkStatus();
}

// ---- keyframes ----

double KeyframeDistance(const Rigid3d& a, const Rigid3d& b, double unit_m) {
  // M_a^-1 M_b = [Ra^T Rb, Ra^T (tb - ta)]; ||I - R||_F^2 = 2 (3 - trace R); the last row of
  // I - M is zero.
  const glm::dmat3 ra = a.RotationMatrix(), rb = b.RotationMatrix();
  const glm::dmat3 rel = glm::transpose(ra) * rb;
  const double tr = rel[0][0] + rel[1][1] + rel[2][2];
  const glm::dvec3 t = glm::transpose(ra) * (b.translation - a.translation) / unit_m;
  return std::sqrt(std::max(0.0, 2.0 * (3.0 - tr)) + glm::dot(t, t));
}

void KeyframeSelector::Offer(int64_t key, const Rigid3d& pose) {
  if (kept_.empty()) {
    kept_.push_back({key, pose});
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
  if (KeyframeDistance(kept_.back().pose, pose, unit_m_) > threshold_) kept_.push_back({key, pose});
}

std::vector<int64_t> KeyframeSelector::Selected() const {
  return SortedKeys(kept_, [](const Kf& k) { return k.key; });
}

void KeyframeSelector::Forget(int64_t key) {
  EraseKey(&kept_, key, [](const Kf& k) { return k.key; });
}

void KeyframeSelector::Adopt(int64_t key, const Rigid3d& pose) {
  if (kept_.size() >= cap_) return;
  kept_.push_back({key, pose});
}

void KeyframeSelector::SaveState(StateWriter* w) const {
  w->Put(threshold_);
  w->PutVec(kept_);
}

absl::Status KeyframeSelector::LoadState(StateReader* r) {
  r->Get(&threshold_) && r->GetVec(&kept_);
  return CheckCapacity("keyframe selector", r, kept_.size(), cap_);
}

}  // namespace exo::planning
