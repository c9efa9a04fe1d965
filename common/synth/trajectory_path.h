// Internal to common/synth's trajectories (not a public API): the arc-length parametrised
// centripetal Catmull-Rom path the walk and the realistic streams follow, the yaw/pitch view
// direction, and the generators of the drone and handheld streams (trajectory_streams.cc).
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include <glm/glm.hpp>

#include "common/status.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace exo::synth::internal {

// Dense polyline along a centripetal Catmull-Rom spline through `pts`, resampled by arc length.
class ArcLengthPath {
 public:
  explicit ArcLengthPath(const std::vector<glm::dvec3>& pts) {
    const size_t n = pts.size();
    auto P = [&](long i) { return pts[std::clamp<long>(i, 0, long(n) - 1)]; };
    for (size_t i = 0; i + 1 < n; ++i) {
      glm::dvec3 p0 = P(long(i) - 1), p1 = P(i), p2 = P(i + 1), p3 = P(i + 2);
      if (i == 0) p0 = 2.0 * p1 - p2;
      if (i + 2 >= n) p3 = 2.0 * p2 - p1;
      auto knot = [](const glm::dvec3& a, const glm::dvec3& b) {
        return std::max(1e-6, std::sqrt(glm::length(b - a)));
      };
      const double t0 = 0, t1 = t0 + knot(p0, p1), t2 = t1 + knot(p1, p2), t3 = t2 + knot(p2, p3);
      constexpr int kSteps = 48;
      for (int k = (i == 0 ? 0 : 1); k <= kSteps; ++k) {
        const double t = t1 + (t2 - t1) * k / kSteps;
        const glm::dvec3 a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1;
        const glm::dvec3 a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2;
        const glm::dvec3 a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3;
        const glm::dvec3 b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2;
        const glm::dvec3 b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3;
        const glm::dvec3 c = (t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2;
        if (!dense_.empty()) cum_.push_back(cum_.back() + glm::length(c - dense_.back()));
        else cum_.push_back(0.0);
        dense_.push_back(c);
      }
    }
    if (n == 1) {
      dense_.push_back(pts[0]);
      cum_.push_back(0);
    }
  }
  double Length() const { return cum_.back(); }
  glm::dvec3 At(double s) const {
    s = std::clamp(s, 0.0, Length());
    const size_t i = std::upper_bound(cum_.begin(), cum_.end(), s) - cum_.begin();
    if (i == 0) return dense_.front();
    if (i >= dense_.size()) return dense_.back();
    const double seg = cum_[i] - cum_[i - 1];
    const double t = seg > 0 ? (s - cum_[i - 1]) / seg : 0;
    return dense_[i - 1] + t * (dense_[i] - dense_[i - 1]);
  }
  // Smoothed horizontal heading: direction between points `window` metres before and after.
  glm::dvec3 Heading(double s, double window) const {
    glm::dvec3 d = At(s + window) - At(s - window);
    d.z = 0;
    const double len = glm::length(d);
    return len > 1e-9 ? d / len : glm::dvec3(1, 0, 0);
  }

 private:
  std::vector<glm::dvec3> dense_;
  std::vector<double> cum_;
};

inline glm::dvec3 Direction(double yaw, double pitch) {
  return {std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw), std::sin(pitch)};
}

absl::StatusOr<std::vector<TimedPose>> MakeDroneStream(const SynthScene& scene,
                                                       const TrajectoryOptions& options);
absl::StatusOr<std::vector<TimedPose>> MakeHandheldStream(const SynthScene& scene,
                                                          const TrajectoryOptions& options);

}  // namespace exo::synth::internal
