#include "common/pose_stream.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

namespace exo {
namespace {

Rigid3d RotZ(double angle_rad, glm::dvec3 t = glm::dvec3(0)) {
  return {glm::angleAxis(angle_rad, glm::dvec3(0, 0, 1)), t};
}

TEST(PoseStreamTest, ExactAtSamples) {
  PoseStream s(8);
  ASSERT_TRUE(s.Add(1.0, RotZ(0.1, {1, 2, 3})).ok());
  ASSERT_TRUE(s.Add(2.0, RotZ(0.5, {4, 5, 6})).ok());
  ASSERT_TRUE(s.Add(3.0, RotZ(0.9, {7, 8, 9})).ok());
  for (double t : {1.0, 2.0, 3.0}) {
    auto p = s.Interpolate(t, 0.0);
    ASSERT_TRUE(p.ok()) << p.status();
    const double angle = 0.1 + 0.4 * (t - 1.0);
    EXPECT_NEAR(RotationAngleRad(p->rotation, RotZ(angle).rotation), 0.0, 1e-12);
    EXPECT_NEAR(p->translation.x, 1 + 3 * (t - 1.0), 1e-12);
  }
}

TEST(PoseStreamTest, MidpointSlerpOfKnownRotation) {
  PoseStream s;
  ASSERT_TRUE(s.Add(0.0, RotZ(0.0, {0, 0, 0})).ok());
  ASSERT_TRUE(s.Add(1.0, RotZ(std::numbers::pi / 2, {2, -4, 1e5})).ok());
  auto p = s.Interpolate(0.25, 1.0);
  ASSERT_TRUE(p.ok());
  // SLERP: constant angular speed, 90 deg * 0.25 = 22.5 deg about z (a plain component-wise
  // lerp of the quaternions would give a different angle).
  EXPECT_NEAR(RotationAngleRad(p->rotation, RotZ(std::numbers::pi / 8).rotation), 0.0, 1e-12);
  EXPECT_NEAR(p->translation.x, 0.5, 1e-12);
  EXPECT_NEAR(p->translation.y, -1.0, 1e-12);
  EXPECT_NEAR(p->translation.z, 2.5e4, 1e-9);
  // Rotating x by the interpolated pose gives the analytic direction.
  const glm::dvec3 x = p->rotation * glm::dvec3(1, 0, 0);
  EXPECT_NEAR(x.x, std::cos(std::numbers::pi / 8), 1e-12);
  EXPECT_NEAR(x.y, std::sin(std::numbers::pi / 8), 1e-12);
}

// Guard: the sign flip in SlerpShortest. q and -q are the same rotation; without the flip the
// interpolation would swing the long way round (through ~180 deg) instead of staying near 0.
TEST(PoseStreamTest, ShortestPathAcrossSignFlip) {
  const glm::dquat qa = glm::angleAxis(0.2, glm::dvec3(0, 1, 0));
  const glm::dquat qb = -glm::angleAxis(-0.2, glm::dvec3(0, 1, 0));  // -(rotation of -0.2)
  PoseStream s;
  ASSERT_TRUE(s.Add(10.0, {qa, glm::dvec3(0)}).ok());
  ASSERT_TRUE(s.Add(11.0, {qb, glm::dvec3(0)}).ok());
  auto mid = s.Interpolate(10.5, 0.5);
  ASSERT_TRUE(mid.ok());
  EXPECT_NEAR(RotationAngleRad(mid->rotation, glm::dquat(1, 0, 0, 0)), 0.0, 1e-12);
  auto quarter = s.Interpolate(10.25, 0.5);
  ASSERT_TRUE(quarter.ok());
  EXPECT_NEAR(RotationAngleRad(quarter->rotation, glm::angleAxis(0.1, glm::dvec3(0, 1, 0))), 0.0,
              1e-12);
}

TEST(PoseStreamTest, NearlyIdenticalRotationsAreStable) {
  const glm::dquat q = glm::angleAxis(0.3, glm::normalize(glm::dvec3(1, 2, 3)));
  const glm::dquat r = SlerpShortest(q, q, 0.5);
  EXPECT_FALSE(std::isnan(r.w));
  EXPECT_NEAR(RotationAngleRad(r, q), 0.0, 1e-12);
}

TEST(PoseStreamTest, ToleranceEdges) {
  PoseStream s;
  ASSERT_TRUE(s.Add(1.0, RotZ(0.0, {1, 0, 0})).ok());
  ASSERT_TRUE(s.Add(2.0, RotZ(0.0, {2, 0, 0})).ok());
  ASSERT_TRUE(s.Add(5.0, RotZ(0.0, {5, 0, 0})).ok());  // gap 2..5
  // Before the first sample: exactly at tolerance OK (returns the end sample), beyond -> NotFound.
  auto before = s.Interpolate(0.9, 0.1 + 1e-12);
  ASSERT_TRUE(before.ok());
  EXPECT_EQ(before->translation.x, 1.0);  // clamped, no extrapolation
  auto too_early = s.Interpolate(0.8, 0.1);
  ASSERT_FALSE(too_early.ok());
  EXPECT_EQ(too_early.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(too_early.status().message().find("before the oldest"), std::string::npos);
  auto after = s.Interpolate(5.05, 0.05 + 1e-12);
  ASSERT_TRUE(after.ok());
  EXPECT_EQ(after->translation.x, 5.0);
  auto too_late = s.Interpolate(5.2, 0.1);
  ASSERT_FALSE(too_late.ok());
  EXPECT_NE(too_late.status().message().find("after the newest"), std::string::npos);
  // Inside the 3 s gap: the midpoint is 1.5 s from both samples.
  auto in_gap = s.Interpolate(3.5, 0.5);
  ASSERT_FALSE(in_gap.ok());
  EXPECT_EQ(in_gap.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(in_gap.status().message().find("gap"), std::string::npos);
  // Near one end of the gap it interpolates (lerp between 2 and 5).
  auto near_gap_end = s.Interpolate(2.3, 0.5);
  ASSERT_TRUE(near_gap_end.ok());
  EXPECT_NEAR(near_gap_end->translation.x, 2.3, 1e-12);
  EXPECT_FALSE(s.Interpolate(1.5, -1.0).ok());
  EXPECT_FALSE(s.Interpolate(std::nan(""), 1.0).ok());
  EXPECT_EQ(PoseStream().Interpolate(0.0, 1.0).status().code(), absl::StatusCode::kNotFound);
}

TEST(PoseStreamTest, OutOfOrderInsertIsSorted) {
  PoseStream s(10);
  ASSERT_TRUE(s.Add(3.0, RotZ(0, {3, 0, 0})).ok());
  ASSERT_TRUE(s.Add(1.0, RotZ(0, {1, 0, 0})).ok());
  ASSERT_TRUE(s.Add(2.0, RotZ(0, {2, 0, 0})).ok());
  ASSERT_EQ(s.size(), 3u);
  for (size_t i = 0; i < 3; ++i) EXPECT_EQ(s.sample(i).timestamp_s, 1.0 + i);
  auto p = s.Interpolate(1.5, 0.5);
  ASSERT_TRUE(p.ok());
  EXPECT_NEAR(p->translation.x, 1.5, 1e-12);
  auto dup = s.Add(2.0, RotZ(0));
  EXPECT_EQ(dup.code(), absl::StatusCode::kAlreadyExists);
  EXPECT_EQ(s.size(), 3u);
}

TEST(PoseStreamTest, BoundedDropsOldest) {
  PoseStream s(3);
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(s.Add(i, RotZ(0, {double(i), 0, 0})).ok());
  EXPECT_EQ(s.size(), 3u);
  EXPECT_EQ(s.dropped(), 2u);
  EXPECT_EQ(s.oldest_s(), 2.0);
  EXPECT_EQ(s.newest_s(), 4.0);
  EXPECT_FALSE(s.Interpolate(0.5, 0.1).ok());  // dropped history is gone
  // A late sample older than everything retained in a full stream is rejected, stream unchanged.
  auto late = s.Add(1.0, RotZ(0));
  EXPECT_EQ(late.code(), absl::StatusCode::kOutOfRange);
  EXPECT_EQ(s.size(), 3u);
  EXPECT_EQ(s.oldest_s(), 2.0);
  // A late sample inside the retained range is accepted; the oldest is evicted.
  ASSERT_TRUE(s.Add(2.5, RotZ(0, {2.5, 0, 0})).ok());
  EXPECT_EQ(s.oldest_s(), 2.5);
  EXPECT_EQ(s.size(), 3u);
}

// SPEC §11: NaN / non-orthonormal rotations are rejected with a clear error.
TEST(PoseStreamTest, RejectsInvalidSamples) {
  PoseStream s;
  EXPECT_FALSE(s.Add(std::nan(""), Rigid3d()).ok());
  EXPECT_FALSE(s.Add(0.0, {glm::dquat(std::nan(""), 0, 0, 0), glm::dvec3(0)}).ok());
  EXPECT_FALSE(s.Add(0.0, {glm::dquat(2, 0, 0, 0), glm::dvec3(0)}).ok());  // not unit
  EXPECT_FALSE(s.Add(0.0, {glm::dquat(1, 0, 0, 0), glm::dvec3(INFINITY, 0, 0)}).ok());
  EXPECT_TRUE(s.empty());
}

}  // namespace
}  // namespace exo
