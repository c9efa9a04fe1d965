// Ceres cost functors of view refinement (SPEC §5, thesis eq. 3.17). One residual per surface
// sample p_j: E_I * C_I(pi(p_j, I)) - m_j (pose stage; the exposure stage uses its log form), where C_I is the candidate's LINEAR luma (bicubic
// over a pyramid level), E_I its exposure factor and m_j the median of the stored views'
// exposure-corrected linear intensities at p_j. The pose is cam_from_local as an Eigen
// quaternion (x, y, z, w; use ceres::EigenQuaternionManifold) and a translation.
#pragma once

#include <ceres/ceres.h>
#include <ceres/cubic_interpolation.h>
#include <ceres/rotation.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace exo::refinement {

using LumaGrid = ceres::Grid2D<float, 1>;
using LumaInterpolator = ceres::BiCubicInterpolator<LumaGrid>;

// Pinhole intrinsics of one pyramid level (pixel centres at integer coordinates).
struct LevelIntrinsics {
  double fx = 0, fy = 0, cx = 0, cy = 0;
};

// Residual of the exposure stage, in log intensity: log(E) + log(c_j) - log(m_j), with the
// candidate value c_j fixed (pose held constant). The exposure model is multiplicative; in the
// log domain the fit is symmetric in c_j and m_j, so it is not attenuated when samples are
// still misaligned (a linear fit of m = E c is biased towards 0 by the errors in c: regression
// dilution), and 0.1x and 10x are equally well conditioned. Parameter block: exposure[1] (> 0).
struct ExposureResidual {
  ExposureResidual(double log_candidate, double log_target) : log_c(log_candidate), log_m(log_target) {}
  template <typename T>
  bool operator()(const T* exposure, T* residual) const {
    using std::log;
    if (!(exposure[0] > T(0))) return false;
    residual[0] = log(exposure[0]) + T(log_c) - T(log_m);
    return true;
  }
  static ceres::CostFunction* Create(double log_candidate, double log_target) {
    return new ceres::AutoDiffCostFunction<ExposureResidual, 1, 1>(
        new ExposureResidual(log_candidate, log_target));
  }
  double log_c, log_m;
};

// Residual of the pose stage: the exposure is held constant. Parameter blocks:
// cam_from_local rotation as Eigen quaternion [x, y, z, w] and translation [3].
struct PoseResidual {
  PoseResidual(const LumaInterpolator* candidate, const LevelIntrinsics& k,
               const Eigen::Vector3d& p_in_local, double exposure, double target)
      : interp(candidate), k(k), p(p_in_local), e(exposure), m(target) {}

  template <typename T>
  bool operator()(const T* q_xyzw, const T* t, T* residual) const {
    const Eigen::Map<const Eigen::Quaternion<T>> q(q_xyzw);
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> trans(t);
    const Eigen::Matrix<T, 3, 1> p_in_cam = q * p.cast<T>() + trans;
    if (!(p_in_cam.z() > T(1e-6))) return false;  // behind the camera: reject the step
    const T u = T(k.fx) * p_in_cam.x() / p_in_cam.z() + T(k.cx);
    const T v = T(k.fy) * p_in_cam.y() / p_in_cam.z() + T(k.cy);
    T value;
    interp->Evaluate(v, u, &value);  // (row, col)
    residual[0] = T(e) * value - T(m);
    return true;
  }
  static ceres::CostFunction* Create(const LumaInterpolator* candidate, const LevelIntrinsics& k,
                                     const Eigen::Vector3d& p_in_local, double exposure,
                                     double target) {
    return new ceres::AutoDiffCostFunction<PoseResidual, 1, 4, 3>(
        new PoseResidual(candidate, k, p_in_local, exposure, target));
  }

  const LumaInterpolator* interp;
  LevelIntrinsics k;
  Eigen::Vector3d p;
  double e, m;
};

// Residual of the pose stage in a LOCAL chart around the current estimate (what the refiner
// optimises): xi = (w, s), w an angle-axis rotation about the CAMERA CENTRE (radians, camera
// frame) and s a camera-frame translation in units of `trans_unit_m` (the median sample depth,
// so both halves move the image by about the same amount per unit and the 6x6 information is
// well scaled). p_cam = R(w) * p_cam0 + trans_unit_m * s, where p_cam0 is the sample in the
// camera frame of the current estimate. Unlike a quaternion of cam_from_local (which rotates
// about the scene origin and so couples rotation with metres of camera motion when the origin
// is far away), rotation and translation are nearly decoupled here. The chart is re-centred
// (xi = 0) at every stage; SubspaceManifold restricts xi to well-conditioned directions.
struct PoseDeltaResidual {
  PoseDeltaResidual(const LumaInterpolator* candidate, const LevelIntrinsics& k,
                    const Eigen::Vector3d& p_in_cam0, double trans_unit_m, double exposure,
                    double target)
      : interp(candidate), k(k), p(p_in_cam0), unit(trans_unit_m), e(exposure), m(target) {}

  template <typename T>
  bool operator()(const T* xi, T* residual) const {
    const T p0[3] = {T(p.x()), T(p.y()), T(p.z())};
    T pc[3];
    ceres::AngleAxisRotatePoint(xi, p0, pc);
    for (int i = 0; i < 3; ++i) pc[i] += T(unit) * xi[3 + i];
    if (!(pc[2] > T(1e-6))) return false;  // behind the camera: reject the step
    const T u = T(k.fx) * pc[0] / pc[2] + T(k.cx);
    const T v = T(k.fy) * pc[1] / pc[2] + T(k.cy);
    T value;
    interp->Evaluate(v, u, &value);  // (row, col)
    residual[0] = T(e) * value - T(m);
    return true;
  }
  static ceres::CostFunction* Create(const LumaInterpolator* candidate, const LevelIntrinsics& k,
                                     const Eigen::Vector3d& p_in_cam0, double trans_unit_m,
                                     double exposure, double target) {
    return new ceres::AutoDiffCostFunction<PoseDeltaResidual, 1, 6>(
        new PoseDeltaResidual(candidate, k, p_in_cam0, trans_unit_m, exposure, target));
  }

  const LumaInterpolator* interp;
  LevelIntrinsics k;
  Eigen::Vector3d p;
  double unit, e, m;
};

using DepthGrid = ceres::Grid2D<float, 1>;
using DepthInterpolator = ceres::BiCubicInterpolator<DepthGrid>;

// Geometric residual of the pose stage (RGB-D candidates): the candidate's own z-depth at the
// projection of p_j against the z of p_j in the candidate frame, relative to z and multiplied
// by `weight` (the ratio of the photometric to the depth robust scale, so both terms share one
// Tukey scale). Same chart as PoseDeltaResidual. A photometric energy alone cannot tell a small
// rotation from a camera translation of depth x angle when the visible depth range is narrow
// (a wall); the depth of a plane changes differently under the two, so the term removes that
// ambiguity. Parameter block: xi[6].
struct DepthDeltaResidual {
  DepthDeltaResidual(const DepthInterpolator* depth, const LevelIntrinsics& k,
                     const Eigen::Vector3d& p_in_cam0, double trans_unit_m, double weight)
      : depth(depth), k(k), p(p_in_cam0), unit(trans_unit_m), w(weight) {}

  template <typename T>
  bool operator()(const T* xi, T* residual) const {
    const T p0[3] = {T(p.x()), T(p.y()), T(p.z())};
    T pc[3];
    ceres::AngleAxisRotatePoint(xi, p0, pc);
    for (int i = 0; i < 3; ++i) pc[i] += T(unit) * xi[3 + i];
    if (!(pc[2] > T(1e-6))) return false;
    const T u = T(k.fx) * pc[0] / pc[2] + T(k.cx);
    const T v = T(k.fy) * pc[1] / pc[2] + T(k.cy);
    T d;
    depth->Evaluate(v, u, &d);
    residual[0] = T(w) * (d - pc[2]) / pc[2];
    return true;
  }
  static ceres::CostFunction* Create(const DepthInterpolator* depth, const LevelIntrinsics& k,
                                     const Eigen::Vector3d& p_in_cam0, double trans_unit_m,
                                     double weight) {
    return new ceres::AutoDiffCostFunction<DepthDeltaResidual, 1, 6>(
        new DepthDeltaResidual(depth, k, p_in_cam0, trans_unit_m, weight));
  }

  const DepthInterpolator* depth;
  LevelIntrinsics k;
  Eigen::Vector3d p;
  double unit, w;
};

// Euclidean 6-vector restricted to the span of the orthonormal columns of `basis` (6 x k):
// Plus(x, d) = x + B d. Used to update only the well-conditioned directions of the pose.
class SubspaceManifold : public ceres::Manifold {
 public:
  explicit SubspaceManifold(const Eigen::Matrix<double, 6, Eigen::Dynamic>& basis) : b_(basis) {}
  int AmbientSize() const override { return 6; }
  int TangentSize() const override { return static_cast<int>(b_.cols()); }
  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override {
    Eigen::Map<const Eigen::Matrix<double, 6, 1>> xv(x);
    Eigen::Map<const Eigen::VectorXd> d(delta, b_.cols());
    Eigen::Map<Eigen::Matrix<double, 6, 1>> out(x_plus_delta);
    out = xv + b_ * d;
    return true;
  }
  bool PlusJacobian(const double* /*x*/, double* jacobian) const override {
    Eigen::Map<Eigen::Matrix<double, 6, Eigen::Dynamic, Eigen::RowMajor>> j(jacobian, 6, b_.cols());
    j = b_;
    return true;
  }
  bool Minus(const double* y, const double* x, double* y_minus_x) const override {
    Eigen::Map<const Eigen::Matrix<double, 6, 1>> yv(y), xv(x);
    Eigen::Map<Eigen::VectorXd> out(y_minus_x, b_.cols());
    out = b_.transpose() * (yv - xv);
    return true;
  }
  bool MinusJacobian(const double* /*x*/, double* jacobian) const override {
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor>> j(jacobian, b_.cols(), 6);
    j = b_.transpose();
    return true;
  }

 private:
  Eigen::Matrix<double, 6, Eigen::Dynamic> b_;
};

}  // namespace exo::refinement
