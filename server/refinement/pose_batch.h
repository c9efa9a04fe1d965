// Batched pose stage of view refinement: all photometric and depth residuals of one pose solve
// (the PoseDeltaAnalytic / DepthDeltaAnalytic residuals of cost_functors.h, same chart, same
// values and Jacobians) evaluated in one pass (PoseBatchCost), the robust loss applied per
// residual inside that one block (RobustBatchCost), and SolvePoseCeres: ceres::Solve (LM) on
// that ONE residual block.
//
// Why one block: with ~1500-3000 one-residual blocks per stage, Ceres' per-block overhead
// (program evaluation, residual-block preparation, the angle-axis rotation and the SO(3) left
// Jacobian recomputed for every residual) was most of the pose stages' CPU time. Here R(w) and
// J_l(w) are computed once per evaluation. Ceres applies a LossFunction per residual block,
// i.e. to the whole block, so the loss is folded into the residuals instead (exactly: the cost
// Ceres sees is 0.5 * sum rho(r_j^2)).
#pragma once

#include <vector>

#include <ceres/ceres.h>
#include <Eigen/Core>

#include "server/refinement/cost_functors.h"

namespace exo::refinement {

// The residuals of one pose stage (images sampled with FastBicubic, the same spline as the
// functors' ceres::BiCubicInterpolator): photometric ones E * C(pi(p)) - m on a luma level, then
// depth ones w * (D(pi(p)) - z) / z on the candidate's depth. Also a ceres::CostFunction (one
// parameter block xi[6], all residuals in one block); plain least squares: wrap it in
// RobustBatchCost for a robust loss.
class PoseBatchCost final : public ceres::CostFunction {
 public:
  // `unit_m`: chart translation unit (median sample depth). `luma` / `depth` may be null when
  // no residual of that kind is added.
  PoseBatchCost(const FastBicubic* luma, const LevelIntrinsics& k_luma, double exposure,
                const FastBicubic* depth, const LevelIntrinsics& k_depth,
                double depth_weight, double unit_m);

  void AddPhotometric(const Eigen::Vector3d& p_in_cam0, double target);
  void AddDepth(const Eigen::Vector3d& p_in_cam0);  // call after all AddPhotometric
  int num_photometric() const { return static_cast<int>(photo_.size()); }
  int num_depth() const { return static_cast<int>(depth_pts_.size()); }

  // residuals[num_residuals()], jacobians[0] (if non-null): row-major num_residuals() x 6.
  // False when a point is behind the camera at xi (Ceres then rejects the step).
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  struct Photo {
    Eigen::Vector3d p;
    double m;
  };
  const FastBicubic* luma_;
  LevelIntrinsics k_luma_;
  double e_;
  const FastBicubic* depth_;
  LevelIntrinsics k_depth_;
  double w_depth_;
  double unit_;
  std::vector<Photo> photo_;
  std::vector<Eigen::Vector3d> depth_pts_;
};

// Robust loss of a pose stage, applied per residual inside RobustBatchCost. The forms are
// Ceres' (TukeyLoss(a): rho = a^2/3 (1 - (1 - s/a^2)^3) for s <= a^2, a^2/3 beyond;
// CauchyLoss(b): rho = b^2 log(1 + s/b^2)), written through rho(s)/s so that they stay exact
// near s = 0 (Ceres' Tukey expression cancels there).
struct RobustLoss {
  enum class Kind { kNone, kTukey, kCauchy };
  Kind kind = Kind::kNone;
  double scale = 1.0;  // a (Tukey) or b (Cauchy), same units as the residuals
  // q = rho(s) / s (q(0) = rho'(0) = 1) and d = rho'(s), s = r^2 >= 0.
  void Evaluate(double s, double* q, double* d) const;
};

// PoseBatchCost with the robust loss applied per residual, as ONE Ceres residual block:
// rhat_j = r_j * sqrt(rho(r_j^2) / r_j^2) = sign(r_j) sqrt(rho(r_j^2)), Jacobian
// d rhat_j / d xi = rho'(r_j^2) r_j / rhat_j * J_j (limit sqrt(rho'(0)) J_j at r_j = 0), so that
// 0.5 * sum rhat_j^2 = 0.5 * sum rho(r_j^2) exactly: the cost Ceres minimises (and accepts
// steps on) is the robust cost. Tukey beyond its scale: rhat_j constant, zero Jacobian row.
// (The Gauss-Newton model differs from Ceres' per-block Corrector, the cost does not.)
class RobustBatchCost final : public ceres::CostFunction {
 public:
  // `cost` must outlive this object and have all its residuals added already.
  RobustBatchCost(const PoseBatchCost& cost, const RobustLoss& loss);
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;
  // 0.5 * sum rho(r_j^2) at xi from the inner residuals (the cost Ceres sees). False when the
  // inner cost cannot be evaluated.
  bool RobustCost(const double xi[6], double* cost) const;

 private:
  const PoseBatchCost& cost_;
  RobustLoss loss_;
};

struct PoseSolveOptions {
  int max_iterations = 15;          // Ceres' max_num_iterations
  double function_tolerance = 1e-5;
  double parameter_tolerance = 1e-8;
  double gradient_tolerance = 1e-10;
};

struct PoseSolveSummary {
  bool solved = false;   // false: the cost could not be evaluated at the start (xi unchanged)
  int iterations = 0;    // summary.iterations.size() (includes iteration 0)
  double initial_cost = 0.0, final_cost = 0.0;  // 0.5 * sum rho(r^2)
};

// Minimises 0.5 * sum_j rho(r_j(xi)^2) over xi restricted to xi0 + span(basis) (orthonormal
// columns, 6 x k, k >= 1; SubspaceManifold when k < 6), starting at `xi` (updated in place),
// with ceres::Solve on ONE residual block (RobustBatchCost): Levenberg-Marquardt,
// DENSE_NORMAL_CHOLESKY, one thread, monotonic steps.
PoseSolveSummary SolvePoseCeres(const PoseBatchCost& cost, const RobustLoss& loss,
                                const Eigen::Matrix<double, 6, Eigen::Dynamic>& basis,
                                const PoseSolveOptions& options, double xi[6]);

}  // namespace exo::refinement
