// Online view-selection baselines (issues 15 / 22): policies that decide from camera poses alone
// which frames a bounded store keeps. The evaluation runs them beside the planner (server/eval),
// and the server can run them in the product path instead of the coverage planner
// (`planner_policy`, PlannerOptions::policy): the planner then keeps its per-cell bookkeeping
// and reference pre-selection for the views the baseline keeps, so clients render a baseline's
// store exactly as they render the planner's.
//
// Keys are the caller's frame keys (the eval's stream index, the server's view id); Offer sees
// every frame once, in stream order. Except the length-aware every-N (an oracle that is told the
// stream's length), none knows the stream's length, and none ever holds more than `capacity`.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "common/rigid3.h"
#include "common/state_io.h"
#include "common/status.h"

namespace exo::planning {

class OnlineSelector {
 public:
  virtual ~OnlineSelector() = default;
  // The next frame of the stream (its key, local_from_cam).
  virtual void Offer(int64_t key, const Rigid3d& pose) = 0;
  // The kept frames' keys, ascending (at most the capacity).
  virtual std::vector<int64_t> Selected() const = 0;
  virtual size_t size() const = 0;
  // The frame left the store for a reason of the caller's (a byte budget, a deletion): drop it.
  virtual void Forget(int64_t key) = 0;
  // A frame the store already held before a restart (no stream position): kept while there is
  // room, as the newest kept frame.
  virtual void Adopt(int64_t key, const Rigid3d& pose) = 0;
  // Checkpoints (the server's): everything Offer depends on.
  virtual void SaveState(StateWriter* w) const = 0;
  virtual absl::Status LoadState(StateReader* r) = 0;
};

// Pose distance of the minimum-distance policy: metres + metres_per_rad × the rotation angle.
double BaselinePoseDistance(const Rigid3d& a, const Rigid3d& b, double metres_per_rad);

// Minimum distance: while there is room every frame is kept; when full, a frame farther from its
// nearest kept frame than the closest kept pair is apart replaces one member of that pair (the
// one that is not its own nearest neighbour), so the smallest pose distance in the store grows.
class MinDistanceSelector : public OnlineSelector {
 public:
  MinDistanceSelector(size_t capacity, double metres_per_rad)
      : cap_(capacity < 1 ? 1 : capacity), mpr_(metres_per_rad) {}
  void Offer(int64_t key, const Rigid3d& pose) override;
  std::vector<int64_t> Selected() const override;
  size_t size() const override { return sel_.size(); }
  void Forget(int64_t key) override;
  void Adopt(int64_t key, const Rigid3d& pose) override;
  void SaveState(StateWriter* w) const override;
  absl::Status LoadState(StateReader* r) override;

 private:
  struct Sel {
    int64_t key;
    Rigid3d pose;
  };
  size_t cap_;
  double mpr_;
  std::vector<Sel> sel_;
  bool pair_dirty_ = true;
  double pair_d_ = 0;
  size_t pair_i_ = 0, pair_j_ = 1;
};

// Every-N with progressive decimation: N = 1 at the start, the k-th offered frame is kept when
// k mod N == 0; when such a frame arrives and the store is full, every other kept frame is
// dropped (those with k mod 2N != 0) and N doubles. The kept frames are always every N-th frame
// of the stream so far (an even spread), with between capacity/2 and capacity of them.
class ProgressiveEveryN : public OnlineSelector {
 public:
  explicit ProgressiveEveryN(size_t capacity) : cap_(capacity < 1 ? 1 : capacity) {}
  void Offer(int64_t key, const Rigid3d& pose) override;
  std::vector<int64_t> Selected() const override;
  size_t size() const override { return kept_.size(); }
  void Forget(int64_t key) override;
  void Adopt(int64_t key, const Rigid3d& pose) override;
  void SaveState(StateWriter* w) const override;
  absl::Status LoadState(StateReader* r) override;
  int64_t step() const { return n_; }

 private:
  struct Kept {
    int64_t offer;  // the frame's offer count k
    int64_t key;
  };
  size_t cap_;
  int64_t n_ = 1, offered_ = 0;
  std::vector<Kept> kept_;
};

// The length-aware every-N (an oracle: it is told the stream's length L): the k-th offered frame
// (k = 0..L-1) is kept iff k = floor(j L / m) for some j < m = min(L, capacity), i.e. m frames
// evenly over the whole stream (the eval's every-N). Frames beyond L are not kept.
class LengthAwareEveryN : public OnlineSelector {
 public:
  LengthAwareEveryN(size_t capacity, int64_t stream_frames)
      : cap_(capacity < 1 ? 1 : capacity), len_(stream_frames < 1 ? 1 : stream_frames) {}
  // Whether the k-th offered frame of a stream of `len` frames is kept (store `cap`).
  static bool Keeps(int64_t k, int64_t len, int64_t cap);
  void Offer(int64_t key, const Rigid3d& pose) override;
  std::vector<int64_t> Selected() const override;
  size_t size() const override { return kept_.size(); }
  void Forget(int64_t key) override;
  void Adopt(int64_t key, const Rigid3d& pose) override;
  void SaveState(StateWriter* w) const override;
  absl::Status LoadState(StateReader* r) override;

 private:
  size_t cap_;
  int64_t len_, offered_ = 0;
  std::vector<int64_t> kept_;
};

// Reservoir sampling (Vitter's algorithm R), seeded: after k frames every frame so far is kept
// with probability capacity / k.
class ReservoirSampler : public OnlineSelector {
 public:
  ReservoirSampler(size_t capacity, uint64_t seed)
      : cap_(capacity < 1 ? 1 : capacity), rng_(seed * 0x9E3779B97F4A7C15ull + 0x632BE59BD9B4E019ull) {}
  void Offer(int64_t key, const Rigid3d& pose) override;
  std::vector<int64_t> Selected() const override;
  size_t size() const override { return kept_.size(); }
  void Forget(int64_t key) override;
  void Adopt(int64_t key, const Rigid3d& pose) override;
  void SaveState(StateWriter* w) const override;
  absl::Status LoadState(StateReader* r) override;

 private:
  size_t cap_;
  std::mt19937_64 rng_;
  int64_t offered_ = 0;
  std::vector<int64_t> kept_;
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
  void Offer(int64_t key, const Rigid3d& pose) override;
  std::vector<int64_t> Selected() const override;
  size_t size() const override { return kept_.size(); }
  void Forget(int64_t key) override;
  void Adopt(int64_t key, const Rigid3d& pose) override;
  void SaveState(StateWriter* w) const override;
  absl::Status LoadState(StateReader* r) override;
  double threshold() const { return threshold_; }

 private:
  struct Kf {
    int64_t key;
    Rigid3d pose;
  };
  size_t cap_;
  double threshold_, unit_m_, growth_;
  std::vector<Kf> kept_;
};

}  // namespace exo::planning
