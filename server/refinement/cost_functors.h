// Ceres cost functors of view refinement (SPEC §5, thesis eq. 3.17). One residual per surface
// sample p_j: E_I * C_I(pi(p_j, I)) - m_j (pose stage; the exposure stage uses its log form), where C_I is the candidate's LINEAR luma (bicubic
// over a pyramid level), E_I its exposure factor and m_j the median of the stored views'
// exposure-corrected linear intensities at p_j. The pose is cam_from_local as an Eigen
// quaternion (x, y, z, w; use ceres::EigenQuaternionManifold) and a translation.
#pragma once

#include <ceres/ceres.h>
#include <ceres/cubic_interpolation.h>

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

}  // namespace exo::refinement
