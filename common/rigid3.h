// Rigid transforms in double precision. Names say the frame: `world_from_cam` maps a point in
// camera coordinates to world coordinates. Rotations entering from outside (files, network) go
// through ValidateRotation() (strict) or ProjectToRotation() (near-rotations projected to SO(3)),
// which reject NaN/Inf and non-orthonormal matrices with a clear error. Large world coordinates
// (1e5 m from the origin) are handled by keeping every pose in double and by rendering in a
// scene-local frame (see LocalOrigin below).
#pragma once

#include <array>

#include <glm/glm.hpp>
#include <glm/gtc/quaternion.hpp>

#include "common/status.h"

namespace exo {

struct Rigid3d {
  glm::dquat rotation{1.0, 0.0, 0.0, 0.0};  // w, x, y, z (unit)
  glm::dvec3 translation{0.0};

  static Rigid3d Identity() { return {}; }
  static Rigid3d FromMatrix(const glm::dmat4& m);  // assumes a valid rigid matrix
  glm::dmat4 ToMatrix() const;
  glm::dmat3 RotationMatrix() const { return glm::mat3_cast(rotation); }

  glm::dvec3 operator*(const glm::dvec3& p) const { return rotation * p + translation; }
  Rigid3d operator*(const Rigid3d& o) const {
    return {glm::normalize(rotation * o.rotation), rotation * o.translation + translation};
  }
  Rigid3d Inverse() const {
    const glm::dquat inv = glm::conjugate(rotation);
    return {inv, -(inv * translation)};
  }
  // Camera centre when this is world_from_cam.
  glm::dvec3 Position() const { return translation; }
};

// Tolerance for ||R^T R - I||_max and |det R - 1| of an incoming rotation.
inline constexpr double kRotationTolerance = 1e-4;

// Incoming rotations (network, files) within this distance of orthonormal (max|R^T R - I|) are
// projected to SO(3) and accepted; farther ones are rejected (SPEC §12). Real trackers print
// rotations with 4 to 7 decimals (7-Scenes: max|R^T R - I| ~ 1.1e-4), above kRotationTolerance.
inline constexpr double kRotationRepairTolerance = 1e-2;

// max|R^T R - I| (entrywise), or +inf when an entry is not finite.
double OrthonormalityError(const glm::dmat3& r);
// The nearest rotation (Frobenius norm: the orthogonal polar factor, det +1) of a matrix within
// kRotationRepairTolerance of orthonormal and with det > 0; otherwise InvalidArgument with the
// measured error (non-finite entries, max|R^T R - I| above the limit, or a reflection).
absl::StatusOr<glm::dmat3> ProjectToRotation(const glm::dmat3& r);
absl::StatusOr<glm::dmat3> ProjectToRotation(const std::array<double, 9>& r_row_major);

// Checks a row-major 3x3 rotation: finite, orthonormal within kRotationTolerance, det +1.
absl::Status ValidateRotation(const std::array<double, 9>& r_row_major);
absl::Status ValidateRotation(const glm::dmat3& r);
// Checks a quaternion: finite and of norm 1 within kRotationTolerance.
absl::Status ValidateQuaternion(const glm::dquat& q);
// Builds a validated rigid transform from a 4x4 row-major matrix (last row must be 0 0 0 1).
absl::StatusOr<Rigid3d> RigidFromRowMajor4x4(const std::array<double, 16>& m);

// Angle in radians between two rotations, and the translation distance.
double RotationAngleRad(const glm::dquat& a, const glm::dquat& b);

// A scene-local origin: world coordinates (double, possibly 1e5 m from the world origin) are
// re-expressed relative to `origin_in_world` before they become float for rendering.
struct LocalOrigin {
  glm::dvec3 origin_in_world{0.0};
  glm::vec3 ToLocal(const glm::dvec3& p_in_world) const {
    return glm::vec3(p_in_world - origin_in_world);
  }
  glm::dvec3 ToWorld(const glm::vec3& p_local) const {
    return glm::dvec3(p_local) + origin_in_world;
  }
  // local_from_world * world_from_cam: a camera pose in the local frame (still double).
  Rigid3d ToLocal(const Rigid3d& world_from_cam) const {
    return {world_from_cam.rotation, world_from_cam.translation - origin_in_world};
  }
};

}  // namespace exo
