// Time-correlated error of a posed RGB-D stream, measured from the stream itself (issue 15,
// session 16). Each frame's depth is warped into the frame one step later and into the frame
// `lag` steps later by their poses; the median relative depth disagreement |z_warped − z| / z is
// r_1 and r_lag. Both contain the sensor's noise and the resampling error; only errors that grow
// with the time between two frames — pose drift of the tracker, slowly varying depth bias —
// make r_lag larger than r_1. The growth g = median over pairs of r_lag − median of r_1 is that
// time-correlated part (medians over pairs: a pair whose samples are mostly occluded in the other
// frame — a fast pan, a long baseline — does not move it): ~0 on a stream whose poses and depth
// agree with themselves at every lag (a synthetic stream: exact poses; measured < 1e-4), ~0.26 %
// of the depth on 7-Scenes redkitchen (r_1 0.21 %, r_15 0.47 %). The planner's time term
// (PlannerOptions::dispersion_time_steps) is switched on by it (TimeScale): it spreads the
// stored views in time only where the stream's own errors are correlated in time. Pure, no I/O.
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
  double min_overlap = 0.5;  // a pair counts when this fraction of the samples warp into the other
  absl::Status Validate() const;
};

// Median of |z_b(u') − z'| / z' over the samples of depth `a` that land in `b` (u' the warped
// pixel, z' the warped depth, z_b bilinear where its four samples agree within 5 %); -1 when fewer
// than `min_overlap` of a's valid samples land. local_from_a / _b: depth camera to scene.
double MedianRelativeDisagreement(const ImageF& a, const PinholeCamera& cam_a,
                                  const Rigid3d& local_from_a, const ImageF& b,
                                  const PinholeCamera& cam_b, const Rigid3d& local_from_b,
                                  double min_overlap = 0.5);

class StreamDrift {
 public:
  explicit StreamDrift(const StreamDriftOptions& options) : options_(options) {}
  // The next frame of the stream, in stream order (its depth in metres, 0 = invalid).
  void Next(const ImageF& depth, const PinholeCamera& camera, const Rigid3d& local_from_depth);
  // g = median(r_lag) − median(r_1), clamped at 0; -1 until min_pairs of each were measured.
  double Growth() const;
  double Near() const { return Median(near_); }  // median r_1 over pairs (0 when none)
  double Far() const { return Median(far_); }    // median r_lag over pairs
  uint64_t pairs_near() const { return Count(near_); }
  uint64_t pairs_far() const { return Count(far_); }
  // The time term's scale for a reference growth `ref`: 0 while g < ref / 2 (the disagreement
  // does not grow measurably), rising linearly to 1 at g = ref; 0 until measured.
  double TimeScale(double ref) const;
  // The histograms of r_1 and r_lag (the server's checkpoint); the frames themselves are not kept.
  std::vector<double> State() const;
  void SetState(const std::vector<double>& s);
  // r in log-spaced bins: 40 per decade from 1e-6 to 1 (bin 0: below 1e-6, the last: above 1).
  static constexpr int kBins = 242;

 private:
  struct Small {
    ImageF depth;
    PinholeCamera camera;
    Rigid3d local_from_depth;
  };
  StreamDriftOptions options_;
  static int Bin(double r);
  static double Median(const std::vector<uint64_t>& h);
  static uint64_t Count(const std::vector<uint64_t>& h);
  std::deque<Small> recent_;  // the last `lag` frames, oldest first
  std::vector<uint64_t> near_ = std::vector<uint64_t>(kBins, 0), far_ = std::vector<uint64_t>(kBins, 0);
};

}  // namespace exo::planning
