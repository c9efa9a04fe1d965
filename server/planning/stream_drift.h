// Time-correlated error of a posed RGB-D stream, measured from the stream itself (issue 15,
// session 16). Each frame's depth is warped into the frame one step later and into the frame
// `lag` steps later by their poses; the median relative depth disagreement |z_warped − z| / z is
// r_1 and r_lag. Both contain the sensor's noise and the resampling error; only errors that grow
// with the time between two frames — pose drift of the tracker, slowly varying depth bias —
// make r_lag larger than r_1. The growth g = mean(r_lag) − mean(r_1) is that time-correlated
// part: 0 on a stream whose poses and depth agree with themselves at every lag (a synthetic
// stream: exact poses), ~0.3 % of the depth on 7-Scenes redkitchen (r_1 0.27 %, r_15 0.54 %).
// The planner's time term (PlannerOptions::dispersion_time_steps) is scaled by
// min(1, g / reference): it spreads the stored views in time only as far as the stream's own
// errors are correlated in time. Pure, no I/O.
#pragma once

#include <cstdint>
#include <deque>
#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo::planning {

struct StreamDriftOptions {
  int lag = 15;              // frames between the far pair (0.5 s at 30 Hz)
  int max_width = 80;        // the depth is subsampled to at most this many columns
  int min_pairs = 8;         // pairs of each kind before Growth() reports
  double min_overlap = 0.2;  // a pair counts when this fraction of the samples warp into the other
  absl::Status Validate() const;
};

// Median of |z_b(u') − z'| / z' over the samples of depth `a` that land in `b` (u' the warped
// pixel, z' the warped depth, z_b bilinear where its four samples agree within 5 %); -1 when fewer
// than `min_overlap` of a's valid samples land. local_from_a / _b: depth camera to scene.
double MedianRelativeDisagreement(const ImageF& a, const PinholeCamera& cam_a,
                                  const Rigid3d& local_from_a, const ImageF& b,
                                  const PinholeCamera& cam_b, const Rigid3d& local_from_b,
                                  double min_overlap = 0.2);

class StreamDrift {
 public:
  explicit StreamDrift(const StreamDriftOptions& options) : options_(options) {}
  // The next frame of the stream, in stream order (its depth in metres, 0 = invalid).
  void Next(const ImageF& depth, const PinholeCamera& camera, const Rigid3d& local_from_depth);
  // g = mean(r_lag) − mean(r_1), clamped at 0; -1 until min_pairs of each were measured.
  double Growth() const;
  double MeanNear() const { return n1_ > 0 ? sum1_ / n1_ : 0.0; }
  double MeanFar() const { return nl_ > 0 ? suml_ / nl_ : 0.0; }
  uint64_t pairs_near() const { return n1_; }
  uint64_t pairs_far() const { return nl_; }
  // The running sums (the server's checkpoint); the frames themselves are not kept.
  std::vector<double> State() const { return {sum1_, double(n1_), suml_, double(nl_)}; }
  void SetState(const std::vector<double>& s);

 private:
  struct Small {
    ImageF depth;
    PinholeCamera camera;
    Rigid3d local_from_depth;
  };
  StreamDriftOptions options_;
  std::deque<Small> recent_;  // the last `lag` frames, oldest first
  double sum1_ = 0, suml_ = 0;
  uint64_t n1_ = 0, nl_ = 0;
};

}  // namespace exo::planning
