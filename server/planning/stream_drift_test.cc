#include "server/planning/stream_drift.h"

#include <cmath>

#include <glm/gtc/quaternion.hpp>
#include <gtest/gtest.h>

namespace exo::planning {
namespace {

// z-depth of a room corner (floor z = 0, walls x = 4 and y = 4) seen from `local_from_cam`:
// exact ray casts, as a synthetic stream delivers.
ImageF RoomDepth(const PinholeCamera& cam, const Rigid3d& local_from_cam) {
  ImageF d(cam.width, cam.height);
  const glm::dvec3 o = local_from_cam.translation;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const glm::dvec3 ray_cam = cam.RayZ1({x, y});
      const glm::dvec3 dir = local_from_cam.rotation * ray_cam;
      double t = 1e9;
      if (dir.z < -1e-9) t = std::min(t, -o.z / dir.z);
      if (dir.x > 1e-9) t = std::min(t, (4.0 - o.x) / dir.x);
      if (dir.y > 1e-9) t = std::min(t, (4.0 - o.y) / dir.y);
      d.at(x, y) = t < 50.0 ? static_cast<float>(t) : 0.0f;  // z-depth: ray_cam has z = 1
    }
  return d;
}

Rigid3d Pose(double s, double error) {
  // A camera at 1.5 m walking along x, looking at the corner (down 30°), turning slowly.
  const glm::dvec3 eye(0.5 + 0.02 * s, 0.3 + 0.01 * s, 1.5);
  const double yaw = 0.6 + 0.003 * s + glm::radians(0.05) * error;
  const glm::dvec3 fwd(std::cos(yaw) * std::cos(0.5), std::sin(yaw) * std::cos(0.5), -std::sin(0.5));
  const glm::dvec3 right = glm::normalize(glm::cross(fwd, glm::dvec3(0, 0, 1)));
  const glm::dvec3 down = glm::cross(fwd, right);
  Rigid3d p;
  p.rotation = glm::quat_cast(glm::dmat3(right, down, fwd));
  p.translation = eye + glm::dvec3(0.002, 0.002, 0.002) * error;  // mm of tracker drift
  return p;
}

// The stream's own poses (exact) give no growth; a tracker that drifts 0.05° in yaw and 2 mm
// along each axis per frame (what the stream reports; the depth is the truth) makes the far pair
// disagree more than the near one. Growth is -1 until enough pairs were measured. State round-trips.
TEST(StreamDrift, GrowthIsZeroForExactPosesAndPositiveForDrift) {
  const PinholeCamera cam = PinholeCamera::FromFov(160, 120, glm::radians(60.0));
  auto run = [&](double drift_per_frame) {
    StreamDrift d(StreamDriftOptions{});
    for (int i = 0; i < 60; ++i) {
      if (i == 10) EXPECT_LT(d.Growth(), 0.0) << "not enough far pairs yet";
      const ImageF depth = RoomDepth(cam, Pose(i, 0.0));
      d.Next(depth, cam, Pose(i, drift_per_frame * i));
    }
    return d;
  };
  const StreamDrift exact = run(0.0);
  ASSERT_GE(exact.Growth(), 0.0);
  EXPECT_LT(exact.Near(), 1e-3);
  EXPECT_LT(exact.Growth(), 2e-4) << "near " << exact.Near() << " far " << exact.Far();
  const StreamDrift drifting = run(1.0);
  EXPECT_GT(drifting.Growth(), 2e-3) << "near " << drifting.Near() << " far "
                                     << drifting.Far();
  EXPECT_GT(drifting.pairs_far(), 40u);
  EXPECT_EQ(exact.TimeScale(1e-3), 0.0) << "exact poses: the time term stays off";
  EXPECT_EQ(drifting.TimeScale(1e-3), 1.0) << "a drifting tracker: the time term is on";
  EXPECT_EQ(StreamDrift(StreamDriftOptions{}).TimeScale(1e-3), 0.0) << "unmeasured: off";
  StreamDrift restored(StreamDriftOptions{});
  restored.SetState(drifting.State());
  EXPECT_DOUBLE_EQ(restored.Growth(), drifting.Growth());
  EXPECT_EQ(restored.pairs_far(), drifting.pairs_far());
  StreamDriftOptions bad;
  bad.lag = 1;
  EXPECT_FALSE(bad.Validate().ok());
}

// Depth that is all holes, or frames that do not overlap, yield no reading (not a zero).
TEST(StreamDrift, NoOverlapNoReading) {
  const PinholeCamera cam = PinholeCamera::FromFov(64, 48, glm::radians(60.0));
  ImageF empty(64, 48);
  EXPECT_LT(MedianRelativeDisagreement(empty, cam, Rigid3d{}, empty, cam, Rigid3d{}), 0.0);
  const ImageF depth = RoomDepth(cam, Pose(0, 0));
  Rigid3d away = Pose(0, 0);
  away.rotation = away.rotation * glm::angleAxis(glm::pi<double>(), glm::dvec3(0, 1, 0));
  EXPECT_LT(MedianRelativeDisagreement(depth, cam, Pose(0, 0), depth, cam, away), 0.0);
  EXPECT_NEAR(MedianRelativeDisagreement(depth, cam, Pose(0, 0), depth, cam, Pose(0, 0)), 0.0,
              1e-6);
}

}  // namespace
}  // namespace exo::planning
