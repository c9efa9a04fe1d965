#include "common/pose_stream.h"

#include <algorithm>
#include <cmath>

namespace exo {

glm::dquat SlerpShortest(const glm::dquat& a, const glm::dquat& b_in, double alpha) {
  glm::dquat b = b_in;
  double cos_theta = a.w * b.w + a.x * b.x + a.y * b.y + a.z * b.z;
  if (cos_theta < 0.0) {  // q and -q are the same rotation: take the short arc
    b = -b;
    cos_theta = -cos_theta;
  }
  if (cos_theta > 1.0 - 1e-12) {  // nearly identical: normalised lerp avoids 0/0
    return glm::normalize(a * (1.0 - alpha) + b * alpha);
  }
  const double theta = std::acos(std::min(1.0, cos_theta));
  const double s = std::sin(theta);
  const double wa = std::sin((1.0 - alpha) * theta) / s;
  const double wb = std::sin(alpha * theta) / s;
  return glm::normalize(a * wa + b * wb);
}

Rigid3d InterpolateRigid(const Rigid3d& a, const Rigid3d& b, double alpha) {
  return {SlerpShortest(a.rotation, b.rotation, alpha),
          a.translation + (b.translation - a.translation) * alpha};
}

PoseStream::PoseStream(size_t capacity) : capacity_(capacity) { EXO_CHECK(capacity >= 1); }

absl::Status PoseStream::Add(double timestamp_s, const Rigid3d& world_from_cam) {
  if (!std::isfinite(timestamp_s))
    return absl::InvalidArgumentError("pose sample timestamp is NaN or Inf");
  if (auto s = ValidateQuaternion(world_from_cam.rotation); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("pose sample at t=", timestamp_s, ": ",
                                                   s.message()));
  const glm::dvec3& p = world_from_cam.translation;
  if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
    return absl::InvalidArgumentError(
        absl::StrCat("pose sample at t=", timestamp_s, ": translation has NaN or Inf"));
  auto it = std::lower_bound(
      samples_.begin(), samples_.end(), timestamp_s,
      [](const PoseSample& s, double t) { return s.timestamp_s < t; });
  if (it != samples_.end() && it->timestamp_s == timestamp_s)
    return absl::AlreadyExistsError(
        absl::StrCat("pose sample at t=", timestamp_s, " already in the stream"));
  if (samples_.size() >= capacity_ && it == samples_.begin())
    return absl::OutOfRangeError(absl::StrCat(
        "pose sample at t=", timestamp_s, " is older than the oldest retained sample (t=",
        samples_.front().timestamp_s, ") of a full stream"));
  samples_.insert(it, PoseSample{timestamp_s, world_from_cam});
  while (samples_.size() > capacity_) {
    samples_.pop_front();
    ++dropped_;
  }
  return absl::OkStatus();
}

absl::StatusOr<Rigid3d> PoseStream::Interpolate(double t, double tolerance_s) const {
  if (!std::isfinite(t)) return absl::InvalidArgumentError("query timestamp is NaN or Inf");
  if (!(tolerance_s >= 0.0))
    return absl::InvalidArgumentError(absl::StrCat("tolerance ", tolerance_s, " must be >= 0"));
  if (samples_.empty()) return absl::NotFoundError("no pose: the pose stream is empty");
  const double first = samples_.front().timestamp_s, last = samples_.back().timestamp_s;
  if (t <= first) {
    if (first - t <= tolerance_s) return samples_.front().world_from_cam;
    return absl::NotFoundError(absl::StrCat("no pose for t=", t, ": ", first - t,
                                            " s before the oldest sample (tolerance ",
                                            tolerance_s, " s)"));
  }
  if (t >= last) {
    if (t - last <= tolerance_s) return samples_.back().world_from_cam;
    return absl::NotFoundError(absl::StrCat("no pose for t=", t, ": ", t - last,
                                            " s after the newest sample (tolerance ",
                                            tolerance_s, " s)"));
  }
  // first < t < last: samples_[i-1].t < t <= samples_[i].t.
  const auto it = std::lower_bound(
      samples_.begin(), samples_.end(), t,
      [](const PoseSample& s, double q) { return s.timestamp_s < q; });
  const PoseSample& b = *it;
  if (b.timestamp_s == t) return b.world_from_cam;
  const PoseSample& a = *(it - 1);
  const double da = t - a.timestamp_s, db = b.timestamp_s - t;
  if (std::min(da, db) > tolerance_s)
    return absl::NotFoundError(absl::StrCat("no pose for t=", t, ": inside a gap of ",
                                            b.timestamp_s - a.timestamp_s,
                                            " s in the pose stream, nearest sample ",
                                            std::min(da, db), " s away (tolerance ",
                                            tolerance_s, " s)"));
  const double alpha = da / (b.timestamp_s - a.timestamp_s);
  return InterpolateRigid(a.world_from_cam, b.world_from_cam, alpha);
}

}  // namespace exo
