// Timestamped pose stream for frames whose pose arrives separately (e.g. a 120 Hz UDP stream
// from motion capture, SPEC §2): a bounded buffer of (timestamp, world_from_cam) samples and
// interpolation at a frame's timestamp: SLERP on the rotation (shortest path), linear on the
// translation, between the two samples that bracket the query time.
//
// Policies (decided here, tested in pose_stream_test.cc):
//  - Out-of-order samples are inserted in timestamp order (UDP reorders packets). A sample older
//    than the oldest retained one while the stream is full is rejected (OutOfRange): it would be
//    dropped at once. A sample with the same timestamp as a retained one is rejected
//    (AlreadyExists). NaN/Inf timestamps, non-unit/NaN quaternions, non-finite translations are
//    rejected (InvalidArgument). A rejected sample leaves the stream unchanged.
//  - Capacity N: when full, the oldest sample (smallest timestamp) is dropped.
//  - Interpolate(t, tolerance_s): inside [first, last] the bracketing pair is interpolated if at
//    least one of the two lies within tolerance_s of t (otherwise the gap is too long: NotFound
//    with the gap in the message). Outside [first, last] the end sample is returned (no
//    extrapolation) if it lies within tolerance_s, else NotFound with the distance.
#pragma once

#include <cstddef>
#include <deque>

#include "common/rigid3.h"
#include "common/status.h"

namespace exo {

// SLERP between unit quaternions along the shortest arc (q and -q are the same rotation).
glm::dquat SlerpShortest(const glm::dquat& a, const glm::dquat& b, double alpha);
// Interpolates two rigid transforms: SLERP rotation, lerp translation, alpha in [0, 1].
Rigid3d InterpolateRigid(const Rigid3d& a, const Rigid3d& b, double alpha);

struct PoseSample {
  double timestamp_s = 0.0;
  Rigid3d world_from_cam;
};

class PoseStream {
 public:
  explicit PoseStream(size_t capacity = 1024);

  absl::Status Add(double timestamp_s, const Rigid3d& world_from_cam);
  absl::StatusOr<Rigid3d> Interpolate(double t, double tolerance_s) const;

  size_t size() const { return samples_.size(); }
  size_t capacity() const { return capacity_; }
  bool empty() const { return samples_.empty(); }
  const PoseSample& sample(size_t i) const { return samples_[i]; }  // sorted by time
  double oldest_s() const { return samples_.front().timestamp_s; }
  double newest_s() const { return samples_.back().timestamp_s; }
  size_t dropped() const { return dropped_; }  // samples evicted by the capacity bound

 private:
  size_t capacity_;
  size_t dropped_ = 0;
  std::deque<PoseSample> samples_;  // sorted by timestamp, strictly increasing
};

}  // namespace exo
