// Online view-selection baselines of the evaluation (issue 22): policies that see the stream one
// frame at a time, never know its length and never hold more than `capacity` views, so they can
// run on a server that streams for an unknown time (unlike the length-aware every-N of eval.h,
// kept there as an oracle). Each decides on poses only; the eval gives the views it keeps the same
// per-cell pre-selection R(b_k) as the planner (eval.h, "fair" references).
#pragma once

#include <cstddef>
#include <cstdint>
#include <random>
#include <vector>

#include "common/rigid3.h"

namespace exo::eval {

class OnlineSelector {
 public:
  virtual ~OnlineSelector() = default;
  // The next frame of the stream (stream index, local_from_cam).
  virtual void Offer(int idx, const Rigid3d& pose) = 0;
  // The kept frames, ascending stream indices (at most the capacity).
  virtual std::vector<int> Selected() const = 0;
  virtual size_t size() const = 0;
};

// Every-N with progressive decimation: N = 1 at the start, the k-th offered frame is kept when
// k mod N == 0; when such a frame arrives and the store is full, every other kept frame is
// dropped (those with k mod 2N != 0) and N doubles. The kept frames are always every N-th frame
// of the stream so far (an even spread), with between capacity/2 and capacity of them.
class ProgressiveEveryN : public OnlineSelector {
 public:
  explicit ProgressiveEveryN(size_t capacity) : cap_(capacity < 1 ? 1 : capacity) {}
  void Offer(int idx, const Rigid3d& pose) override;
  std::vector<int> Selected() const override;
  size_t size() const override { return kept_.size(); }
  int64_t step() const { return n_; }

 private:
  size_t cap_;
  int64_t n_ = 1, offered_ = 0;
  std::vector<std::pair<int64_t, int>> kept_;  // (offer count, stream index)
};

// Reservoir sampling (Vitter's algorithm R), seeded: after k frames every frame so far is kept
// with probability capacity / k.
class ReservoirSampler : public OnlineSelector {
 public:
  ReservoirSampler(size_t capacity, uint64_t seed)
      : cap_(capacity < 1 ? 1 : capacity), rng_(seed * 0x9E3779B97F4A7C15ull + 0x632BE59BD9B4E019ull) {}
  void Offer(int idx, const Rigid3d& pose) override;
  std::vector<int> Selected() const override;
  size_t size() const override { return kept_.size(); }

 private:
  size_t cap_;
  std::mt19937_64 rng_;
  int64_t offered_ = 0;
  std::vector<int> kept_;
};

// The InpaintFusion keyframe distance ||I - M_i^-1 M_k||_F of two 4x4 poses, the translation in
// units of `unit_m` (unit 1 m = the rule as written). Rotation alone: 2 sqrt(2) sin(theta / 2),
// so 0.7 = 28.7 deg; translation alone: |t| / unit_m.
double KeyframeDistance(const Rigid3d& a, const Rigid3d& b, double unit_m);

// SLAM-style keyframes: a frame becomes a keyframe when its KeyframeDistance to the last keyframe
// exceeds the threshold (InpaintFusion: 0.7). When a new keyframe finds the store full, the
// threshold is multiplied by `growth` and the kept keyframes are thinned in stream order with it
// (the first kept; then each keyframe farther than the threshold from the last one kept), until a
// slot is free; the new frame is then a keyframe if it is farther than the new threshold from the
// last kept one. The store thus always spans the whole stream so far, at a coarser spacing.
class KeyframeSelector : public OnlineSelector {
 public:
  KeyframeSelector(size_t capacity, double threshold, double unit_m, double growth = 1.5)
      : cap_(capacity < 1 ? 1 : capacity), threshold_(threshold), unit_m_(unit_m),
        growth_(growth) {}
  void Offer(int idx, const Rigid3d& pose) override;
  std::vector<int> Selected() const override;
  size_t size() const override { return kept_.size(); }
  double threshold() const { return threshold_; }

 private:
  struct Kf {
    int idx;
    Rigid3d pose;
  };
  size_t cap_;
  double threshold_, unit_m_, growth_;
  std::vector<Kf> kept_;
};

}  // namespace exo::eval
