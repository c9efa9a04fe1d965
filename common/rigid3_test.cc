#include "common/rigid3.h"

#include <gtest/gtest.h>

#include <glm/gtc/matrix_transform.hpp>

namespace exo {
namespace {

Rigid3d SomePose(glm::dvec3 t) {
  Rigid3d p;
  p.rotation = glm::angleAxis(0.7, glm::normalize(glm::dvec3(1, 2, 3)));
  p.translation = t;
  return p;
}

TEST(Rigid3d, InverseComposesToIdentity) {
  const Rigid3d a = SomePose({1, -2, 3});
  const Rigid3d id = a * a.Inverse();
  EXPECT_NEAR(RotationAngleRad(id.rotation, glm::dquat(1, 0, 0, 0)), 0.0, 1e-12);
  EXPECT_NEAR(glm::length(id.translation), 0.0, 1e-12);
  const glm::dvec3 p{0.3, 0.2, 5.0};
  const glm::dvec3 q = a.Inverse() * (a * p);
  EXPECT_NEAR(glm::length(q - p), 0.0, 1e-12);
}

TEST(Rigid3d, MatrixRoundTrip) {
  const Rigid3d a = SomePose({4, 5, 6});
  const Rigid3d b = Rigid3d::FromMatrix(a.ToMatrix());
  EXPECT_NEAR(RotationAngleRad(a.rotation, b.rotation), 0.0, 1e-7);
  EXPECT_NEAR(glm::length(a.translation - b.translation), 0.0, 1e-12);
}

// SPEC §11: a scene 1e5 m from the origin must lose no precision. Poses stay in double; the
// local origin turns them into small float coordinates for rendering.
TEST(Rigid3d, SceneFarFromOriginKeepsSubMillimetrePrecision) {
  const glm::dvec3 far{1e5, -1e5, 1e5};
  const Rigid3d world_from_cam = SomePose(far + glm::dvec3(0.1234567, 0.7654321, 1.5));
  const glm::dvec3 p_in_cam{0.0001, -0.0002, 2.0};
  const glm::dvec3 p_world = world_from_cam * p_in_cam;
  const glm::dvec3 back = world_from_cam.Inverse() * p_world;
  EXPECT_NEAR(glm::length(back - p_in_cam), 0.0, 1e-9);

  LocalOrigin origin{far};
  const glm::vec3 local = origin.ToLocal(p_world);
  const glm::dvec3 world_again = origin.ToWorld(local);
  EXPECT_LT(glm::length(world_again - p_world), 1e-6);  // float at ~2 m: ~1e-7 m
  // Doing it naively in float would lose centimetres: show the guard matters.
  const glm::vec3 naive(p_world);
  EXPECT_GT(glm::length(glm::dvec3(naive) - p_world), 1e-4);
}

TEST(ValidateRotation, RejectsNaNAndNonOrthonormal) {
  std::array<double, 9> id{1, 0, 0, 0, 1, 0, 0, 0, 1};
  EXPECT_TRUE(ValidateRotation(id).ok());
  auto nan = id;
  nan[4] = std::nan("");
  EXPECT_EQ(ValidateRotation(nan).code(), absl::StatusCode::kInvalidArgument);
  auto scaled = id;
  scaled[0] = 1.1;
  EXPECT_FALSE(ValidateRotation(scaled).ok());
  auto reflection = id;
  reflection[8] = -1;
  EXPECT_FALSE(ValidateRotation(reflection).ok());
  auto sheared = id;
  sheared[1] = 0.01;
  const auto s = ValidateRotation(sheared);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("orthonormal"), std::string::npos);
}

TEST(ValidateRotation, RowMajor4x4) {
  std::array<double, 16> m{0, -1, 0, 1, 1, 0, 0, 2, 0, 0, 1, 3, 0, 0, 0, 1};
  auto pose = RigidFromRowMajor4x4(m);
  ASSERT_TRUE(pose.ok()) << pose.status();
  const glm::dvec3 x = *pose * glm::dvec3(1, 0, 0);
  EXPECT_NEAR(x.x, 1.0, 1e-12);
  EXPECT_NEAR(x.y, 3.0, 1e-12);
  EXPECT_NEAR(x.z, 3.0, 1e-12);
  m[15] = 2;
  EXPECT_FALSE(RigidFromRowMajor4x4(m).ok());
}

TEST(ValidateQuaternion, RejectsNonUnit) {
  EXPECT_TRUE(ValidateQuaternion(glm::dquat(1, 0, 0, 0)).ok());
  EXPECT_FALSE(ValidateQuaternion(glm::dquat(2, 0, 0, 0)).ok());
  EXPECT_FALSE(ValidateQuaternion(glm::dquat(std::nan(""), 0, 0, 0)).ok());
}

}  // namespace
}  // namespace exo
