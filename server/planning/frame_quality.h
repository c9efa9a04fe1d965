// Image quality of a candidate frame for view planning (issue 15, "view quality in planning"):
// real frames are motion-blurred to very different degrees (7-Scenes redkitchen: the variance of
// the Laplacian of neighbouring frames differs by up to 5x; the online planner kept runs of the
// blurriest frames where the camera turned fast, because those frames were the most novel).
// A blurred frame should cover less than a sharp one of the same place. Sharpness alone is
// scene-dependent (a white wall is "blurred"), so the quality is RELATIVE: the frame's
// sharpness over the largest sharpness of the previous `window` frames (which saw nearly the
// same content), clamped to [floor, 1] and raised to gamma. Pure, no I/O.
#pragma once

#include <cstddef>
#include <deque>
#include <vector>

#include "common/image.h"
#include "common/status.h"

namespace exo::planning {

// Variance of the 4-neighbour Laplacian of the luma (R + 2G + B) / 4, computed at half
// resolution (2x2 box average first, which also suppresses sensor noise and JPEG blocking).
// RGB8 or grey input; 0 for images smaller than 6x6.
double LaplacianVariance(const ImageU8& image);

struct FrameQualityOptions {
  double gamma = 0.0;   // 0 = off (quality 1 for every frame)
  int window = 15;      // previous frames whose sharpness is the reference (0.5 s at 30 Hz)
  double floor = 0.1;   // smallest quality
  absl::Status Validate() const;
};

// Relative sharpness of a stream of frames, in stream order.
class FrameQuality {
 public:
  explicit FrameQuality(const FrameQualityOptions& options) : options_(options) {}
  // Quality in [floor, 1] of the next frame with sharpness `s` (LaplacianVariance); 1 when off,
  // for the first frame, or when s is not finite / not positive (no information).
  double Next(double s);
  // The window of recent sharpness values (the server's checkpoint).
  std::vector<double> State() const { return {recent_.begin(), recent_.end()}; }
  void SetState(const std::vector<double>& recent) { recent_.assign(recent.begin(), recent.end()); }

 private:
  FrameQualityOptions options_;
  std::deque<double> recent_;
};

}  // namespace exo::planning
