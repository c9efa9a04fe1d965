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

// The rotation of 7-Scenes redkitchen seq-01 frame-000000.pose.txt as printed (KinectFusion):
// max|R^T R - I| = 1.12e-4, above kRotationTolerance, far below kRotationRepairTolerance.
constexpr std::array<double, 9> kSevenScenesFrame0{
    9.093128999999999795e-01,  2.726222899999999894e-01, -3.142243299999999961e-01,
    -2.724861800000000223e-01, 9.610497999999999541e-01, 4.527962600000000337e-02,
    3.143392500000000145e-01,  4.444964600000000238e-02, 9.482093499999999509e-01};

glm::dmat3 FromRowMajor(const std::array<double, 9>& r) {
  glm::dmat3 m;
  for (int row = 0; row < 3; ++row)
    for (int col = 0; col < 3; ++col) m[col][row] = r[row * 3 + col];
  return m;
}

TEST(ProjectToRotation, NearRotationFromARealTrackerIsProjected) {
  const glm::dmat3 r = FromRowMajor(kSevenScenesFrame0);
  const double err = OrthonormalityError(r);
  EXPECT_GT(err, kRotationTolerance);  // the old strict check rejected it
  EXPECT_NEAR(err, 1.12e-4, 0.01e-4);
  EXPECT_FALSE(ValidateRotation(kSevenScenesFrame0).ok());
  auto q = ProjectToRotation(kSevenScenesFrame0);
  ASSERT_TRUE(q.ok()) << q.status();
  EXPECT_LT(OrthonormalityError(*q), 1e-14);
  EXPECT_NEAR(glm::determinant(*q), 1.0, 1e-14);
  EXPECT_TRUE(ValidateRotation(*q).ok());
  // The nearest rotation moves each entry by about the error, not more.
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k < 3; ++k) EXPECT_NEAR((*q)[c][k], r[c][k], 1e-4);
  // An exact rotation is a fixed point.
  const glm::dmat3 exact = glm::mat3_cast(glm::normalize(glm::dquat(0.9, 0.1, -0.2, 0.3)));
  auto same = ProjectToRotation(exact);
  ASSERT_TRUE(same.ok());
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k < 3; ++k) EXPECT_NEAR((*same)[c][k], exact[c][k], 1e-15);
}

TEST(ProjectToRotation, FarFromOrthonormalOrReflectionIsRejectedWithTheError) {
  auto off = kSevenScenesFrame0;
  off[1] += 0.05;  // one entry off by 0.05: max|R^T R - I| ~ 0.05
  const double err = OrthonormalityError(FromRowMajor(off));
  EXPECT_GT(err, 0.04);
  auto q = ProjectToRotation(off);
  ASSERT_FALSE(q.ok());
  EXPECT_EQ(q.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(q.status().message().find(absl::StrCat("max|R^T R - I| = ", err)), std::string::npos)
      << q.status();
  std::array<double, 9> reflection{1, 0, 0, 0, 1, 0, 0, 0, -1};
  auto r = ProjectToRotation(reflection);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("determinant"), std::string::npos) << r.status();
  auto nan = kSevenScenesFrame0;
  nan[3] = std::nan("");
  EXPECT_FALSE(ProjectToRotation(nan).ok());
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
