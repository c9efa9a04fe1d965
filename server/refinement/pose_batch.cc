#include "server/refinement/pose_batch.h"

#include <cmath>

#include <Eigen/Geometry>

namespace exo::refinement {

PoseBatchCost::PoseBatchCost(const FastBicubic* luma, const LevelIntrinsics& k_luma,
                             double exposure, const FastBicubic* depth,
                             const LevelIntrinsics& k_depth, double depth_weight, double unit_m)
    : luma_(luma), k_luma_(k_luma), e_(exposure), depth_(depth), k_depth_(k_depth),
      w_depth_(depth_weight), unit_(unit_m) {
  mutable_parameter_block_sizes()->push_back(6);
  set_num_residuals(0);
}

void PoseBatchCost::AddPhotometric(const Eigen::Vector3d& p_in_cam0, double target) {
  photo_.push_back({p_in_cam0, target});
  set_num_residuals(num_photometric() + num_depth());
}

void PoseBatchCost::AddDepth(const Eigen::Vector3d& p_in_cam0) {
  depth_pts_.push_back(p_in_cam0);
  set_num_residuals(num_photometric() + num_depth());
}

bool PoseBatchCost::Evaluate(double const* const* parameters, double* residuals,
                             double** jacobians) const {
  const double* xi = parameters[0];
  const bool want_j = jacobians != nullptr && jacobians[0] != nullptr;
  // Once per evaluation (ChartPoint does this per residual): R(w), and for the Jacobian
  // d p / d w = -[R p0]_x J_l(w).
  const Eigen::Vector3d w(xi[0], xi[1], xi[2]);
  const double t = w.norm();
  const Eigen::Matrix3d r = t > 0 ? Eigen::AngleAxisd(t, w / t).toRotationMatrix()
                                  : Eigen::Matrix3d::Identity();
  const Eigen::Matrix3d jl = want_j ? So3LeftJacobian(w) : Eigen::Matrix3d::Identity();
  const Eigen::Vector3d s = unit_ * Eigen::Vector3d(xi[3], xi[4], xi[5]);
  // Fills the 1x6 Jacobian row from the gradient g of the residual w.r.t. p_cam.
  const auto jac_row = [&](const Eigen::Vector3d& rp, const Eigen::RowVector3d& g, double* row) {
    // Row of g * (-[rp]_x J_l): g [a]_x = (g x a)^T, so -g [rp]_x = (rp x g)^T.
    const Eigen::Vector3d gr = rp.cross(g.transpose());
    const Eigen::RowVector3d jw = gr.transpose() * jl;
    row[0] = jw[0];
    row[1] = jw[1];
    row[2] = jw[2];
    row[3] = unit_ * g[0];
    row[4] = unit_ * g[1];
    row[5] = unit_ * g[2];
  };
  const int np = num_photometric();
  for (int i = 0; i < np; ++i) {
    const Eigen::Vector3d rp = r * photo_[i].p;
    const Eigen::Vector3d pc = rp + s;
    if (!(pc.z() > 1e-6)) return false;  // behind the camera: reject the step
    Eigen::RowVector3d g;
    residuals[i] = PhotometricAt(*luma_, k_luma_, pc, e_, photo_[i].m, want_j ? &g : nullptr);
    if (want_j) jac_row(rp, g, jacobians[0] + 6 * i);
  }
  for (int i = 0; i < num_depth(); ++i) {
    const Eigen::Vector3d rp = r * depth_pts_[i];
    const Eigen::Vector3d pc = rp + s;
    if (!(pc.z() > 1e-6)) return false;
    Eigen::RowVector3d g;
    residuals[np + i] = DepthAt(*depth_, k_depth_, pc, w_depth_, want_j ? &g : nullptr);
    if (want_j) jac_row(rp, g, jacobians[0] + 6 * (np + i));
  }
  return true;
}

void RobustLoss::Evaluate(double s, double* q, double* d) const {
  switch (kind) {
    case Kind::kNone:
      *q = *d = 1.0;
      return;
    case Kind::kTukey: {
      const double a2 = scale * scale, x = s / a2;
      if (x > 1.0) {
        *q = a2 / (3.0 * s);
        *d = 0.0;
      } else {
        *q = 1.0 - x + x * x / 3.0;  // (1 - (1 - x)^3) / (3 x)
        *d = (1.0 - x) * (1.0 - x);
      }
      return;
    }
    case Kind::kCauchy: {
      const double x = s / (scale * scale);
      *q = x > 0.0 ? std::log1p(x) / x : 1.0;
      *d = 1.0 / (1.0 + x);
      return;
    }
  }
}

RobustBatchCost::RobustBatchCost(const PoseBatchCost& cost, const RobustLoss& loss)
    : cost_(cost), loss_(loss) {
  mutable_parameter_block_sizes()->push_back(6);
  set_num_residuals(cost.num_residuals());
}

bool RobustBatchCost::Evaluate(double const* const* parameters, double* residuals,
                               double** jacobians) const {
  if (!cost_.Evaluate(parameters, residuals, jacobians)) return false;
  const bool want_j = jacobians != nullptr && jacobians[0] != nullptr;
  if (loss_.kind == RobustLoss::Kind::kNone) return true;
  for (int i = 0; i < num_residuals(); ++i) {
    const double r = residuals[i];
    if (!std::isfinite(r)) return false;
    double q, d;
    loss_.Evaluate(r * r, &q, &d);
    const double sq = std::sqrt(q);
    residuals[i] = r * sq;  // sign(r) sqrt(rho(r^2))
    if (want_j) {
      // rho'(s) r / rhat = rho'(s) / sqrt(q); at r = 0: rho'(0) / sqrt(rho'(0)).
      const double f = d / sq;
      double* row = jacobians[0] + 6 * i;
      for (int c = 0; c < 6; ++c) row[c] *= f;
    }
  }
  return true;
}

bool RobustBatchCost::RobustCost(const double xi[6], double* cost) const {
  std::vector<double> r(num_residuals());
  const double* params[1] = {xi};
  if (!cost_.Evaluate(params, r.data(), nullptr)) return false;
  double sum = 0.0;
  for (double ri : r) {
    double q, d;
    loss_.Evaluate(ri * ri, &q, &d);
    sum += q * ri * ri;
  }
  *cost = 0.5 * sum;
  return std::isfinite(*cost);
}

PoseSolveSummary SolvePoseCeres(const PoseBatchCost& cost, const RobustLoss& loss,
                                const Eigen::Matrix<double, 6, Eigen::Dynamic>& basis,
                                const PoseSolveOptions& o, double xi[6]) {
  PoseSolveSummary sum;
  if (basis.cols() == 0 || cost.num_residuals() == 0) return sum;
  ceres::Problem::Options po;
  po.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  RobustBatchCost robust(cost, loss);
  problem.AddResidualBlock(&robust, nullptr, xi);
  SubspaceManifold manifold(basis);
  if (basis.cols() < 6) problem.SetManifold(xi, &manifold);
  ceres::Solver::Options so;
  so.minimizer_type = ceres::TRUST_REGION;
  so.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  so.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
  so.max_num_iterations = o.max_iterations;
  so.num_threads = 1;
  so.use_nonmonotonic_steps = false;
  so.minimizer_progress_to_stdout = false;
  so.logging_type = ceres::SILENT;
  so.function_tolerance = o.function_tolerance;
  so.parameter_tolerance = o.parameter_tolerance;
  so.gradient_tolerance = o.gradient_tolerance;
  ceres::Solver::Summary cs;
  ceres::Solve(so, &problem, &cs);
  sum.iterations = static_cast<int>(cs.iterations.size());
  sum.solved = cs.initial_cost >= 0.0 && !cs.iterations.empty();
  sum.initial_cost = cs.initial_cost;
  sum.final_cost = cs.final_cost;
  return sum;
}

}  // namespace exo::refinement
