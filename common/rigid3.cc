#include "common/rigid3.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace exo {

Rigid3d Rigid3d::FromMatrix(const glm::dmat4& m) {
  Rigid3d t;
  t.rotation = glm::normalize(glm::quat_cast(glm::dmat3(m)));
  t.translation = glm::dvec3(m[3]);
  return t;
}

glm::dmat4 Rigid3d::ToMatrix() const {
  glm::dmat4 m(glm::mat3_cast(rotation));
  m[3] = glm::dvec4(translation, 1.0);
  return m;
}

absl::Status ValidateRotation(const glm::dmat3& r) {
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k < 3; ++k)
      if (!std::isfinite(r[c][k]))
        return absl::InvalidArgumentError("rotation has a non-finite entry (NaN or Inf)");
  const glm::dmat3 rtr = glm::transpose(r) * r;
  double err = 0.0;
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k < 3; ++k) err = std::max(err, std::abs(rtr[c][k] - (c == k ? 1.0 : 0.0)));
  if (err > kRotationTolerance)
    return absl::InvalidArgumentError(
        absl::StrCat("rotation is not orthonormal: max|R^T R - I| = ", err, " > ", kRotationTolerance));
  const double det = glm::determinant(r);
  if (std::abs(det - 1.0) > kRotationTolerance)
    return absl::InvalidArgumentError(absl::StrCat("rotation has determinant ", det, " (reflection?)"));
  return absl::OkStatus();
}

double OrthonormalityError(const glm::dmat3& r) {
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k < 3; ++k)
      if (!std::isfinite(r[c][k])) return std::numeric_limits<double>::infinity();
  const glm::dmat3 rtr = glm::transpose(r) * r;
  double err = 0.0;
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k < 3; ++k) err = std::max(err, std::abs(rtr[c][k] - (c == k ? 1.0 : 0.0)));
  return err;
}

absl::StatusOr<glm::dmat3> ProjectToRotation(const glm::dmat3& r) {
  const double err = OrthonormalityError(r);
  if (!std::isfinite(err))
    return absl::InvalidArgumentError("rotation has a non-finite entry (NaN or Inf)");
  if (err > kRotationRepairTolerance)
    return absl::InvalidArgumentError(absl::StrCat(
        "rotation is not orthonormal: max|R^T R - I| = ", err, " > ", kRotationRepairTolerance,
        " (rotations within ", kRotationRepairTolerance, " are projected to SO(3))"));
  const double det = glm::determinant(r);
  if (!(det > 0.0))
    return absl::InvalidArgumentError(absl::StrCat("rotation has determinant ", det, " (reflection?)"));
  // Newton iteration for the orthogonal polar factor, Q <- (Q + Q^-T) / 2: quadratic convergence
  // from a near-orthonormal start (err <= 1e-2 reaches double precision in ~4 steps).
  glm::dmat3 q = r;
  for (int it = 0; it < 20; ++it) {
    const glm::dmat3 next = 0.5 * (q + glm::transpose(glm::inverse(q)));
    double change = 0.0;
    for (int c = 0; c < 3; ++c)
      for (int k = 0; k < 3; ++k) change = std::max(change, std::abs(next[c][k] - q[c][k]));
    q = next;
    if (change < 1e-15) break;
  }
  return q;
}

absl::StatusOr<glm::dmat3> ProjectToRotation(const std::array<double, 9>& r) {
  glm::dmat3 m;  // glm is column-major: m[col][row]
  for (int row = 0; row < 3; ++row)
    for (int col = 0; col < 3; ++col) m[col][row] = r[row * 3 + col];
  return ProjectToRotation(m);
}

absl::Status ValidateRotation(const std::array<double, 9>& r) {
  glm::dmat3 m;  // glm is column-major: m[col][row]
  for (int row = 0; row < 3; ++row)
    for (int col = 0; col < 3; ++col) m[col][row] = r[row * 3 + col];
  return ValidateRotation(m);
}

absl::Status ValidateQuaternion(const glm::dquat& q) {
  if (!std::isfinite(q.w) || !std::isfinite(q.x) || !std::isfinite(q.y) || !std::isfinite(q.z))
    return absl::InvalidArgumentError("quaternion has a non-finite component (NaN or Inf)");
  const double n = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  if (std::abs(n - 1.0) > kRotationTolerance)
    return absl::InvalidArgumentError(absl::StrCat("quaternion is not unit: |q| = ", n));
  return absl::OkStatus();
}

absl::StatusOr<Rigid3d> RigidFromRowMajor4x4(const std::array<double, 16>& m) {
  for (double v : m)
    if (!std::isfinite(v)) return absl::InvalidArgumentError("pose matrix has NaN or Inf");
  if (std::abs(m[12]) > 1e-9 || std::abs(m[13]) > 1e-9 || std::abs(m[14]) > 1e-9 ||
      std::abs(m[15] - 1.0) > 1e-9)
    return absl::InvalidArgumentError("pose matrix last row is not [0 0 0 1]");
  std::array<double, 9> r{m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]};
  EXO_RETURN_IF_ERROR(ValidateRotation(r));
  glm::dmat3 rm;
  for (int row = 0; row < 3; ++row)
    for (int col = 0; col < 3; ++col) rm[col][row] = r[row * 3 + col];
  Rigid3d t;
  t.rotation = glm::normalize(glm::quat_cast(rm));
  t.translation = {m[3], m[7], m[11]};
  return t;
}

double RotationAngleRad(const glm::dquat& a, const glm::dquat& b) {
  const glm::dquat d = glm::conjugate(a) * b;
  const double w = std::min(1.0, std::abs(d.w));
  const double v = std::sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
  return 2.0 * std::atan2(v, w);
}

}  // namespace exo
