#include "server/inpainting/keyframe_policy.h"

#include <cmath>

namespace exo::inpainting {

absl::Status KeyframePolicyOptions::Validate() const {
  if (!(max_pose_distance > 0.0) || !std::isfinite(max_pose_distance))
    return absl::InvalidArgumentError("max_pose_distance must be > 0");
  if (!(max_unlabelled_fraction >= 0.0 && max_unlabelled_fraction <= 1.0))
    return absl::InvalidArgumentError("max_unlabelled_fraction must be in [0, 1]");
  if (splat_px < 0 || splat_px > 8) return absl::InvalidArgumentError("splat_px in [0, 8]");
  return absl::OkStatus();
}

double PoseDistance(const Rigid3d& a, const Rigid3d& b) {
  const glm::dmat4 m = (a.Inverse() * b).ToMatrix();
  double s = 0.0;
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r) {
      const double d = (r == c ? 1.0 : 0.0) - m[c][r];
      s += d * d;
    }
  return std::sqrt(s);
}

double UnlabelledFraction(const ImageU8& roi, const PinholeCamera& camera,
                          const Rigid3d& local_from_cam, const KeyframeView& kf,
                          const KeyframePolicyOptions& options) {
  const int w = roi.width(), h = roi.height();
  int total = 0;
  for (size_t i = 0; i < roi.size(); ++i) total += roi.data()[i] != 0;
  if (total == 0) return 0.0;
  if (!kf.mask || !kf.depth_m) return 1.0;
  ImageU8 covered(w, h, 1, 0);
  const Rigid3d cam_from_kf = local_from_cam.Inverse() * kf.local_from_cam;
  const int s = options.splat_px;
  for (int y = 0; y < kf.mask->height(); ++y)
    for (int x = 0; x < kf.mask->width(); ++x) {
      if (!kf.mask->at(x, y)) continue;
      const float z = kf.depth_m->at(x, y);
      if (!(std::isfinite(z) && z > 0.f)) continue;
      glm::dvec2 uv;
      if (!camera.Project(cam_from_kf * kf.camera.Unproject({x, y}, z), &uv)) continue;
      const int u = static_cast<int>(std::lround(uv.x)), v = static_cast<int>(std::lround(uv.y));
      for (int dy = -s; dy <= s; ++dy)
        for (int dx = -s; dx <= s; ++dx)
          if (covered.Contains(u + dx, v + dy)) covered.at(u + dx, v + dy) = 1;
    }
  int missing = 0;
  for (size_t i = 0; i < roi.size(); ++i) missing += roi.data()[i] != 0 && !covered.data()[i];
  return static_cast<double>(missing) / total;
}

KeyframeDecision DecideKeyframe(const ImageU8& roi, const PinholeCamera& camera,
                                const Rigid3d& local_from_cam,
                                const std::vector<KeyframeView>& keyframes,
                                const KeyframePolicyOptions& options) {
  KeyframeDecision d;
  if (keyframes.empty()) {
    d.insert = true;
    d.reason = "first";
    return d;
  }
  double best = 1e300;
  for (size_t i = 0; i < keyframes.size(); ++i) {
    const double dist = PoseDistance(keyframes[i].local_from_cam, local_from_cam);
    if (dist < best) {
      best = dist;
      d.nearest = static_cast<int>(i);
    }
  }
  d.pose_distance = best;
  if (best > options.max_pose_distance) {
    d.insert = true;
    d.reason = "pose";
    return d;
  }
  d.unlabelled_fraction =
      UnlabelledFraction(roi, camera, local_from_cam, keyframes[d.nearest], options);
  if (d.unlabelled_fraction > options.max_unlabelled_fraction) {
    d.insert = true;
    d.reason = "unlabelled";
  }
  return d;
}

}  // namespace exo::inpainting
