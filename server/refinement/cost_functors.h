// Ceres cost functors of view refinement (SPEC §5, thesis eq. 3.17). One residual per surface
// sample p_j: E_I * C_I(pi(p_j, I)) - m_j (pose stage; the exposure stage uses its log form), where C_I is the candidate's LINEAR luma (bicubic
// over a pyramid level), E_I its exposure factor and m_j the median of the stored views'
// exposure-corrected linear intensities at p_j. The pose is cam_from_local as an Eigen
// quaternion (x, y, z, w; use ceres::EigenQuaternionManifold) and a translation.
#pragma once

#include <ceres/ceres.h>
#include <ceres/cubic_interpolation.h>
#include <ceres/rotation.h>

#include <algorithm>
#include <cmath>
#include <cstddef>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace exo::refinement {

using LumaGrid = ceres::Grid2D<float, 1>;
using LumaInterpolator = ceres::BiCubicInterpolator<LumaGrid>;

// The same Catmull-Rom bicubic as LumaInterpolator (ceres::BiCubicInterpolator over a
// Grid2D<float, 1> with rows/cols [0, n), border values repeated), written out for one channel:
// identical operations in the same order (tested to agree to 1e-12), inlined, a clamp-free path
// for points whose 4x4 support is inside the grid, and a value-only path that skips the
// derivative splines (Ceres always computes the horizontal ones). The pose stages evaluate it
// ~10^5 times per view.
class FastBicubic {
 public:
  FastBicubic() = default;
  FastBicubic(const float* data, int rows, int cols) : d_(data), rows_(rows), cols_(cols) {}

  // (row, col) order as ceres::BiCubicInterpolator.
  void Evaluate(double r, double c, double* f, double* dfdr, double* dfdc) const {
    const int row = static_cast<int>(std::floor(r)), col = static_cast<int>(std::floor(c));
    const double x = c - col, y = r - row;
    double p[4][4];
    Fetch(row, col, p);
    double fr[4], dr[4];
    for (int i = 0; i < 4; ++i) Spline(p[i][0], p[i][1], p[i][2], p[i][3], x, &fr[i], &dr[i]);
    Spline(fr[0], fr[1], fr[2], fr[3], y, f, dfdr);
    if (dfdc != nullptr) Spline(dr[0], dr[1], dr[2], dr[3], y, dfdc, nullptr);
  }
  void Evaluate(double r, double c, double* f) const {
    const int row = static_cast<int>(std::floor(r)), col = static_cast<int>(std::floor(c));
    const double x = c - col, y = r - row;
    double p[4][4];
    Fetch(row, col, p);
    double fr[4];
    for (int i = 0; i < 4; ++i) Spline(p[i][0], p[i][1], p[i][2], p[i][3], x, &fr[i], nullptr);
    Spline(fr[0], fr[1], fr[2], fr[3], y, f, nullptr);
  }

 private:
  // ceres::CubicHermiteSpline for one dimension, same expression order.
  static inline void Spline(double p0, double p1, double p2, double p3, double x, double* f,
                            double* dfdx) {
    const double a = 0.5 * (-p0 + 3.0 * p1 - 3.0 * p2 + p3);
    const double b = 0.5 * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3);
    const double c = 0.5 * (-p0 + p2);
    const double d = p1;
    if (f != nullptr) *f = d + x * (c + x * (b + x * a));
    if (dfdx != nullptr) *dfdx = c + x * (2.0 * b + 3.0 * a * x);
  }
  inline void Fetch(int row, int col, double p[4][4]) const {
    if (row >= 1 && col >= 1 && row + 2 < rows_ && col + 2 < cols_) {
      const float* base = d_ + static_cast<size_t>(row - 1) * cols_ + (col - 1);
      for (int i = 0; i < 4; ++i, base += cols_)
        for (int j = 0; j < 4; ++j) p[i][j] = static_cast<double>(base[j]);
      return;
    }
    for (int i = 0; i < 4; ++i) {
      const int rr = std::min(std::max(0, row - 1 + i), rows_ - 1);
      for (int j = 0; j < 4; ++j) {
        const int cc = std::min(std::max(0, col - 1 + j), cols_ - 1);
        p[i][j] = static_cast<double>(d_[static_cast<size_t>(rr) * cols_ + cc]);
      }
    }
  }
  const float* d_ = nullptr;
  int rows_ = 0, cols_ = 0;
};

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

// The exposure stage as the refiner solves it: the same log residual with x = log(E) as the
// parameter, x + log(c_j) - log(m_j), linear in x (Jacobian 1): no positivity bound is needed
// (Ceres' bounded LM does a projected line search per step) and LM converges in 1-3 steps
// under the robust loss. Parameter block: log_exposure[1].
class LogExposureResidual final : public ceres::SizedCostFunction<1, 1> {
 public:
  LogExposureResidual(double log_candidate, double log_target)
      : offset_(log_candidate - log_target) {}
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    residuals[0] = parameters[0][0] + offset_;
    if (jacobians != nullptr && jacobians[0] != nullptr) jacobians[0][0] = 1.0;
    return true;
  }

 private:
  double offset_;
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

// --- Analytic Jacobians (what the refiner uses; the autodiff functors above are the reference
// they are tested against) ---------------------------------------------------------------------
//
// Both residuals below live in the PoseDeltaResidual chart: p_cam = R(w) p_cam0 + unit * s.
// Chain rule: d p_cam / d w = -[R(w) p_cam0]_x J_l(w) (J_l the left Jacobian of SO(3): exact at
// any w, not only at w = 0, which LM needs because it evaluates away from the chart centre),
// d p_cam / d s = unit * I; the projection u = fx x / z + cx, v = fy y / z + cy; the image value
// and its gradient come from the SAME bicubic (Catmull-Rom) kernel (BiCubicInterpolator's
// Evaluate with derivatives), so the Jacobian is the exact derivative of the sampled residual.
// Autodiff Jets through AngleAxisRotatePoint and the interpolator cost ~3x more per residual.

// J_l(w) = I + (1 - cos t)/t^2 [w]_x + (t - sin t)/t^3 [w]_x^2, t = |w| (series near 0).
inline Eigen::Matrix3d SkewSymmetric(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}
inline Eigen::Matrix3d So3LeftJacobian(const Eigen::Vector3d& w) {
  const double t2 = w.squaredNorm();
  const Eigen::Matrix3d wx = SkewSymmetric(w);
  double a, b;
  if (t2 < 1e-10) {
    a = 0.5 - t2 / 24.0;
    b = 1.0 / 6.0 - t2 / 120.0;
  } else {
    const double t = std::sqrt(t2);
    a = (1.0 - std::cos(t)) / t2;
    b = (t - std::sin(t)) / (t2 * t);
  }
  return Eigen::Matrix3d::Identity() + a * wx + b * wx * wx;
}

// Point in the camera frame for chart coordinates xi, and (optionally) d p_cam / d xi (3 x 6).
inline Eigen::Vector3d ChartPoint(const double* xi, const Eigen::Vector3d& p_cam0, double unit,
                                  Eigen::Matrix<double, 3, 6>* d_p_d_xi) {
  const Eigen::Vector3d w(xi[0], xi[1], xi[2]);
  const double t = w.norm();
  const Eigen::Vector3d rp =
      t > 0 ? Eigen::AngleAxisd(t, w / t).toRotationMatrix() * p_cam0 : p_cam0;
  if (d_p_d_xi != nullptr) {
    d_p_d_xi->leftCols<3>() = -SkewSymmetric(rp) * So3LeftJacobian(w);
    d_p_d_xi->rightCols<3>() = unit * Eigen::Matrix3d::Identity();
  }
  return rp + unit * Eigen::Vector3d(xi[3], xi[4], xi[5]);
}

// d f(pi(p)) / d p for an image gradient (df/du, df/dv) at the projection of camera point p
// (iz = 1 / p.z): the chain through the pinhole projection of a level.
inline Eigen::RowVector3d ImageGradientToPoint(const LevelIntrinsics& k, const Eigen::Vector3d& p,
                                               double iz, double dfdu, double dfdv) {
  return {dfdu * k.fx * iz, dfdv * k.fy * iz, -(dfdu * k.fx * p.x() + dfdv * k.fy * p.y()) * iz * iz};
}

// The two pose residuals at camera point pc (pc.z() > 0, checked by the caller) and, when
// `d_r_d_p` is given, their derivative with respect to pc. Shared by the single-residual
// functors below and PoseBatchCost (pose_batch.h); `Interp` is any bicubic interpolator with
// Evaluate(row, col, &f, &df/drow, &df/dcol).
// Photometric: E * C(pi(pc)) - m.
template <typename Interp>
inline double PhotometricAt(const Interp& image, const LevelIntrinsics& k, const Eigen::Vector3d& pc,
                            double exposure, double target, Eigen::RowVector3d* d_r_d_p) {
  const double iz = 1.0 / pc.z();
  double f, dfdv, dfdu;
  image.Evaluate(k.fy * pc.y() * iz + k.cy, k.fx * pc.x() * iz + k.cx, &f, &dfdv, &dfdu);
  if (d_r_d_p != nullptr) *d_r_d_p = exposure * ImageGradientToPoint(k, pc, iz, dfdu, dfdv);
  return exposure * f - target;
}
// Depth: weight * (D(pi(pc)) - z) / z; d(D/z)/dp = (grad D . d(u,v)/dp) / z - D / z^2 e_z.
template <typename Interp>
inline double DepthAt(const Interp& depth, const LevelIntrinsics& k, const Eigen::Vector3d& pc,
                      double weight, Eigen::RowVector3d* d_r_d_p) {
  const double iz = 1.0 / pc.z();
  double d, ddv, ddu;
  depth.Evaluate(k.fy * pc.y() * iz + k.cy, k.fx * pc.x() * iz + k.cx, &d, &ddv, &ddu);
  if (d_r_d_p != nullptr) {
    *d_r_d_p = (weight * iz) * ImageGradientToPoint(k, pc, iz, ddu, ddv);
    (*d_r_d_p)(2) -= weight * d * iz * iz;
  }
  return weight * (d * iz - 1.0);
}

// Photometric residual E * C_I(pi(p_cam)) - m with the analytic Jacobian (same value as
// PoseDeltaResidual). Parameter block: xi[6].
class PoseDeltaAnalytic final : public ceres::SizedCostFunction<1, 6> {
 public:
  PoseDeltaAnalytic(const LumaInterpolator* candidate, const LevelIntrinsics& k,
                    const Eigen::Vector3d& p_in_cam0, double trans_unit_m, double exposure,
                    double target)
      : interp_(candidate), k_(k), p_(p_in_cam0), unit_(trans_unit_m), e_(exposure), m_(target) {}

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const bool want_j = jacobians != nullptr && jacobians[0] != nullptr;
    Eigen::Matrix<double, 3, 6> dp;
    const Eigen::Vector3d pc = ChartPoint(parameters[0], p_, unit_, want_j ? &dp : nullptr);
    if (!(pc.z() > 1e-6)) return false;  // behind the camera: reject the step
    Eigen::RowVector3d g;
    residuals[0] = PhotometricAt(*interp_, k_, pc, e_, m_, want_j ? &g : nullptr);
    if (want_j) Eigen::Map<Eigen::Matrix<double, 1, 6>>{jacobians[0]} = g * dp;
    return true;
  }

 private:
  const LumaInterpolator* interp_;
  LevelIntrinsics k_;
  Eigen::Vector3d p_;
  double unit_, e_, m_;
};

// Depth residual weight * (D_I(pi(p_cam)) - z) / z with the analytic Jacobian (same value as
// DepthDeltaResidual). Parameter block: xi[6].
class DepthDeltaAnalytic final : public ceres::SizedCostFunction<1, 6> {
 public:
  DepthDeltaAnalytic(const DepthInterpolator* depth, const LevelIntrinsics& k,
                     const Eigen::Vector3d& p_in_cam0, double trans_unit_m, double weight)
      : depth_(depth), k_(k), p_(p_in_cam0), unit_(trans_unit_m), w_(weight) {}

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const bool want_j = jacobians != nullptr && jacobians[0] != nullptr;
    Eigen::Matrix<double, 3, 6> dp;
    const Eigen::Vector3d pc = ChartPoint(parameters[0], p_, unit_, want_j ? &dp : nullptr);
    if (!(pc.z() > 1e-6)) return false;
    Eigen::RowVector3d g;
    residuals[0] = DepthAt(*depth_, k_, pc, w_, want_j ? &g : nullptr);
    if (want_j) Eigen::Map<Eigen::Matrix<double, 1, 6>>{jacobians[0]} = g * dp;
    return true;
  }

 private:
  const DepthInterpolator* depth_;
  LevelIntrinsics k_;
  Eigen::Vector3d p_;
  double unit_, w_;
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
