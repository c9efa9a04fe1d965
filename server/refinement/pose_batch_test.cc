// The batched pose stage (pose_batch.h): PoseBatchCost and RobustBatchCost against
// GradientChecker and against the one-residual analytic functors / Ceres' losses, and
// SolvePoseCeres (one block) against ceres::Solve on one block per residual.
#include "server/refinement/pose_batch.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include <ceres/gradient_checker.h>
#include <gtest/gtest.h>

namespace exo::refinement {
namespace {

struct SmoothScene {
  static constexpr int kW = 128, kH = 96;
  std::vector<float> img, depth;
  std::unique_ptr<LumaGrid> grid;
  std::unique_ptr<LumaInterpolator> interp;
  std::unique_ptr<DepthGrid> dgrid;
  std::unique_ptr<DepthInterpolator> dinterp;
  FastBicubic fast, dfast;  // what PoseBatchCost samples with
  LevelIntrinsics k{100.0, 102.0, 63.5, 47.5};
  SmoothScene() : img(kW * kH), depth(kW * kH) {
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x) {
        img[y * kW + x] = 0.5f + 0.25f * std::sin(0.19 * x + 0.07 * y) * std::cos(0.13 * y - 0.05 * x);
        depth[y * kW + x] = 2.0f + 0.008f * x + 0.012f * y + 0.1f * std::sin(0.05 * x);
      }
    grid = std::make_unique<LumaGrid>(img.data(), 0, kH, 0, kW);
    interp = std::make_unique<LumaInterpolator>(*grid);
    dgrid = std::make_unique<DepthGrid>(depth.data(), 0, kH, 0, kW);
    dinterp = std::make_unique<DepthInterpolator>(*dgrid);
    fast = FastBicubic(img.data(), kH, kW);
    dfast = FastBicubic(depth.data(), kH, kW);
  }
};

// FastBicubic is ceres::BiCubicInterpolator's spline: same value and derivatives inside, at
// the border (clamped support) and outside the grid, value-only path included.
TEST(PoseBatchTest, FastBicubicMatchesCeresBiCubicInterpolator) {
  SmoothScene sc;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> ur(-3.0, SmoothScene::kH + 2.0), uc(-3.0, SmoothScene::kW + 2.0);
  for (int i = 0; i < 2000; ++i) {
    const double r = i == 0 ? 10.0 : ur(rng), c = i == 0 ? 20.0 : uc(rng);  // integer knot
    double f0, dr0, dc0, f1, dr1, dc1, fv;
    sc.interp->Evaluate(r, c, &f0, &dr0, &dc0);
    sc.fast.Evaluate(r, c, &f1, &dr1, &dc1);
    sc.fast.Evaluate(r, c, &fv);
    EXPECT_NEAR(f1, f0, 1e-12) << r << " " << c;
    EXPECT_NEAR(fv, f0, 1e-12) << r << " " << c;
    EXPECT_NEAR(dr1, dr0, 1e-12) << r << " " << c;
    EXPECT_NEAR(dc1, dc0, 1e-12) << r << " " << c;
  }
}

// Multi-residual block: GradientChecker (numeric) and, row by row, the same residual and
// Jacobian as PoseDeltaAnalytic / DepthDeltaAnalytic (the functors with their own checks).
TEST(PoseBatchTest, BatchCostMatchesGradientCheckerAndSingleResidualFunctors) {
  SmoothScene sc;
  const double unit = 2.5, e = 1.2, wd = 3.0;
  PoseBatchCost batch(&sc.fast, sc.k, e, &sc.dfast, sc.k, wd, unit);
  std::vector<Eigen::Vector3d> pts;
  std::vector<double> ms;
  for (int i = 0; i < 12; ++i) {
    pts.emplace_back(0.05 * i - 0.3, 0.03 * i - 0.15, 2.0 + 0.07 * i);
    ms.push_back(0.3 + 0.02 * i);
    batch.AddPhotometric(pts.back(), ms.back());
  }
  for (int i = 0; i < 6; ++i) batch.AddDepth(pts[i]);
  ASSERT_EQ(batch.num_residuals(), 18);
  ceres::NumericDiffOptions nd;
  nd.ridders_relative_initial_step_size = 1e-5;  // stay inside one bicubic cell
  for (int trial = 0; trial < 4; ++trial) {
    const double a = trial == 0 ? 0.0 : 0.04 * trial;  // up to ~7 deg (J_l(w) != I)
    double xi[6] = {a, -0.5 * a, 0.3 * a, 0.002 * trial, -0.003, 0.004};
    double* params[1] = {xi};
    const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
    ceres::GradientChecker checker(&batch, no_manifolds, nd);
    ceres::GradientChecker::ProbeResults results;
    // 1e-4: one of the 18 points lies near a bicubic knot in trial 2, where the C1 spline's
    // numeric derivative is off by ~1e-5 relative; a wrong Jacobian term is off by O(1).
    EXPECT_TRUE(checker.Probe(params, 1e-4, &results)) << "trial " << trial << results.error_log;
    std::vector<double> r(18), j(18 * 6);
    double* jp[1] = {j.data()};
    ASSERT_TRUE(batch.Evaluate(params, r.data(), jp));
    for (int i = 0; i < 18; ++i) {
      std::unique_ptr<ceres::CostFunction> single(
          i < 12 ? static_cast<ceres::CostFunction*>(
                       new PoseDeltaAnalytic(sc.interp.get(), sc.k, pts[i], unit, e, ms[i]))
                 : new DepthDeltaAnalytic(sc.dinterp.get(), sc.k, pts[i - 12], unit, wd));
      double rs, js[6];
      double* jsp[1] = {js};
      ASSERT_TRUE(single->Evaluate(params, &rs, jsp));
      EXPECT_NEAR(r[i], rs, 1e-12);
      double jmax = 1e-12;
      for (double v : js) jmax = std::max(jmax, std::abs(v));
      for (int c = 0; c < 6; ++c) EXPECT_NEAR(j[6 * i + c], js[c], 1e-10 * jmax) << i << " " << c;
    }
  }
  // Behind the camera: the evaluation fails (the solver then rejects the step).
  PoseBatchCost behind(&sc.fast, sc.k, 1.0, nullptr, sc.k, 0.0, 1.0);
  behind.AddPhotometric(Eigen::Vector3d(0, 0, -1), 0.5);
  double xi0[6] = {0, 0, 0, 0, 0, 0}, r0;
  const double* p0[1] = {xi0};
  EXPECT_FALSE(behind.Evaluate(p0, &r0, nullptr));
}

// RobustLoss is Ceres' TukeyLoss / CauchyLoss (rho(s) = q s, rho'(s) = d) away from s = 0, and
// stays exact near 0 where Ceres' Tukey expression cancels.
TEST(PoseBatchTest, RobustLossMatchesCeresLosses) {
  const double a = 0.07;
  ceres::TukeyLoss tukey(a);
  ceres::CauchyLoss cauchy(a);
  RobustLoss rt{RobustLoss::Kind::kTukey, a}, rc{RobustLoss::Kind::kCauchy, a};
  for (double s : {1e-6 * a * a, 0.01 * a * a, 0.5 * a * a, a * a, 1.5 * a * a, 40 * a * a}) {
    double rho[3], q, d;
    tukey.Evaluate(s, rho);
    rt.Evaluate(s, &q, &d);
    EXPECT_NEAR(q * s, rho[0], 1e-9 * rho[0]) << s;
    EXPECT_NEAR(d, rho[1], 1e-9) << s;
    cauchy.Evaluate(s, rho);
    rc.Evaluate(s, &q, &d);
    EXPECT_NEAR(q * s, rho[0], 1e-9 * rho[0]) << s;
    EXPECT_NEAR(d, rho[1], 1e-9) << s;
  }
  double q, d;
  rt.Evaluate(0.0, &q, &d);
  EXPECT_EQ(q, 1.0);
  EXPECT_EQ(d, 1.0);
  rc.Evaluate(0.0, &q, &d);
  EXPECT_EQ(q, 1.0);
  EXPECT_EQ(d, 1.0);
  // Tiny s: q must stay 1 - s/a^2 + ..., not the cancelled (1 - (1 - x)^3) / (3 x).
  rt.Evaluate(1e-20 * a * a, &q, &d);
  EXPECT_NEAR(q, 1.0, 1e-15);
}

// RobustBatchCost: GradientChecker on rows with r_j = 0, |r_j| ~ 1e-9, inside and beyond the
// Tukey scale (and with Cauchy); the zero-residual row is sqrt(rho'(0)) J = J, rows beyond the
// Tukey scale are exactly zero with |rhat| = a / sqrt(3); and 0.5 sum rhat^2 equals
// 0.5 sum rho(r^2) of ceres::TukeyLoss / CauchyLoss on the inner residuals (fails if the
// per-residual transform is removed: then 0.5 sum r^2 is returned, ~3x larger here).
TEST(PoseBatchTest, RobustBatchCostGradientCheckerAndExactRobustCost) {
  SmoothScene sc;
  const double unit = 2.5, e = 1.1, a = 0.05;
  const double xi[6] = {0.01, -0.02, 0.015, 0.003, -0.002, 0.004};
  const double* cparams[1] = {xi};
  std::vector<Eigen::Vector3d> pts;
  PoseBatchCost probe(&sc.fast, sc.k, e, nullptr, sc.k, 0.0, unit);
  for (int i = 0; i < 9; ++i) {
    pts.emplace_back(0.06 * i - 0.25, 0.04 * i - 0.12, 2.1 + 0.06 * i);
    probe.AddPhotometric(pts.back(), 0.0);
  }
  std::vector<double> f(9);
  ASSERT_TRUE(probe.Evaluate(cparams, f.data(), nullptr));  // E C(pi(p)) at xi
  // Wanted residuals at xi: zero, tiny, inside the Tukey scale, beyond it.
  const double want[9] = {0.0, 1e-9, -1e-7, 0.3 * a, -0.6 * a, 0.95 * a, 1.5 * a, -3 * a, 8 * a};
  PoseBatchCost batch(&sc.fast, sc.k, e, nullptr, sc.k, 0.0, unit);
  for (int i = 0; i < 9; ++i) batch.AddPhotometric(pts[i], f[i] - want[i]);
  std::vector<double> r(9), j(9 * 6);
  double* jp[1] = {j.data()};
  ASSERT_TRUE(batch.Evaluate(cparams, r.data(), jp));
  for (int i = 0; i < 9; ++i) ASSERT_NEAR(r[i], want[i], 1e-12);
  ceres::TukeyLoss ceres_tukey(a);
  ceres::CauchyLoss ceres_cauchy(a);
  for (int kind = 0; kind < 2; ++kind) {
    const RobustLoss loss{kind == 0 ? RobustLoss::Kind::kTukey : RobustLoss::Kind::kCauchy, a};
    const ceres::LossFunction& cl = kind == 0 ? static_cast<const ceres::LossFunction&>(ceres_tukey)
                                              : ceres_cauchy;
    RobustBatchCost robust(batch, loss);
    ASSERT_EQ(robust.num_residuals(), 9);
    ceres::NumericDiffOptions nd;
    nd.ridders_relative_initial_step_size = 1e-5;
    double xv[6];
    std::copy(xi, xi + 6, xv);
    double* params[1] = {xv};
    const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
    ceres::GradientChecker checker(&robust, no_manifolds, nd);
    ceres::GradientChecker::ProbeResults results;
    EXPECT_TRUE(checker.Probe(params, 1e-5, &results)) << "kind " << kind << results.error_log;
    std::vector<double> rh(9), jh(9 * 6);
    double* jhp[1] = {jh.data()};
    ASSERT_TRUE(robust.Evaluate(cparams, rh.data(), jhp));
    double half_sum_rhat2 = 0, half_sum_rho = 0, half_sum_r2 = 0;
    for (int i = 0; i < 9; ++i) {
      double rho[3];
      cl.Evaluate(r[i] * r[i], rho);
      half_sum_rho += 0.5 * rho[0];
      half_sum_rhat2 += 0.5 * rh[i] * rh[i];
      half_sum_r2 += 0.5 * r[i] * r[i];
      EXPECT_TRUE(rh[i] == 0.0 ? r[i] == 0.0 : std::signbit(rh[i]) == std::signbit(r[i])) << i;
    }
    EXPECT_NEAR(half_sum_rhat2, half_sum_rho, 1e-12 * half_sum_rho) << kind;
    EXPECT_GT(half_sum_r2, 2.0 * half_sum_rho) << kind;  // the loss does matter here
    double rc = 0;
    ASSERT_TRUE(robust.RobustCost(xi, &rc));
    EXPECT_NEAR(rc, half_sum_rho, 1e-12 * half_sum_rho);
    for (int c = 0; c < 6; ++c) EXPECT_NEAR(jh[c], j[c], 1e-12 * (1 + std::abs(j[c])));  // r = 0
    if (kind == 0) {
      for (int i = 6; i < 9; ++i) {
        EXPECT_NEAR(std::abs(rh[i]), a / std::sqrt(3.0), 1e-15) << i;
        for (int c = 0; c < 6; ++c) EXPECT_EQ(jh[6 * i + c], 0.0) << i << " " << c;
      }
    }
  }
}

struct Problem {
  std::vector<Eigen::Vector3d> pts;
  std::vector<double> ms;
  std::vector<bool> outlier;
};

// Targets rendered at a known chart pose xi_true, 15 % of them replaced by gross outliers.
Problem MakeProblem(const SmoothScene& sc, const double xi_true[6], double unit, double e,
                    int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> ux(-0.35, 0.35), uz(2.0, 3.0), u01(0, 1);
  Problem p;
  PoseBatchCost truth(&sc.fast, sc.k, e, nullptr, sc.k, 0.0, unit);
  for (int i = 0; i < n; ++i) {
    const double z = uz(rng);
    p.pts.emplace_back(ux(rng) * z, 0.75 * ux(rng) * z, z);
    truth.AddPhotometric(p.pts.back(), 0.0);
  }
  std::vector<double> r(n);
  const double* params[1] = {xi_true};
  EXPECT_TRUE(truth.Evaluate(params, r.data(), nullptr));
  for (int i = 0; i < n; ++i) {
    const bool out = u01(rng) < 0.15;
    p.ms.push_back(r[i] + (out ? 0.4 + 0.2 * u01(rng) : 0.0));  // r = E C - 0 at the truth
    p.outlier.push_back(out);
  }
  return p;
}

// SolvePoseCeres (ceres::Solve on ONE block, robust loss per residual inside it) reaches the
// true pose despite 15 % outliers with Tukey (fails if the per-residual loss were dropped: the
// outliers then bias the pose far beyond 1e-6) and Cauchy-then-free subspace handling, and its
// final cost equals the per-residual ceres::Problem's (same robust cost, same minimum).
TEST(PoseBatchTest, SolvePoseCeresSingleBlockMatchesPerResidualProblem) {
  SmoothScene sc;
  const double unit = 2.5, e = 0.9;
  const double xi_true[6] = {0.012, -0.008, 0.005, 0.004, -0.003, 0.002};
  const Problem pr = MakeProblem(sc, xi_true, unit, e, 400, 7);
  for (int variant = 0; variant < 3; ++variant) {
    // 0: all 6 directions, Tukey; 1: rotation only (3 columns), Cauchy; 2: no loss, inliers only.
    Eigen::Matrix<double, 6, Eigen::Dynamic> basis = Eigen::Matrix<double, 6, 6>::Identity();
    if (variant == 1) basis = Eigen::Matrix<double, 6, 6>::Identity().leftCols(3);
    std::unique_ptr<ceres::LossFunction> loss;
    RobustLoss rl;
    if (variant == 0) {
      loss = std::make_unique<ceres::TukeyLoss>(0.1);
      rl = {RobustLoss::Kind::kTukey, 0.1};
    }
    if (variant == 1) {
      loss = std::make_unique<ceres::CauchyLoss>(0.02);
      rl = {RobustLoss::Kind::kCauchy, 0.02};
    }
    PoseBatchCost batch(&sc.fast, sc.k, e, nullptr, sc.k, 0.0, unit);
    ceres::Problem::Options po;
    po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    ceres::Problem problem(po);
    double xi_ref[6] = {0, 0, 0, 0, 0, 0};
    for (size_t i = 0; i < pr.pts.size(); ++i) {
      if (variant == 2 && pr.outlier[i]) continue;
      batch.AddPhotometric(pr.pts[i], pr.ms[i]);
      problem.AddResidualBlock(new PoseDeltaAnalytic(sc.interp.get(), sc.k, pr.pts[i], unit, e, pr.ms[i]),
                               loss.get(), xi_ref);
    }
    SubspaceManifold manifold(basis);
    if (basis.cols() < 6) problem.SetManifold(xi_ref, &manifold);
    ceres::Solver::Options so;
    so.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
    so.max_num_iterations = 30;
    so.function_tolerance = 1e-10;
    so.logging_type = ceres::SILENT;
    ceres::Solver::Summary cs;
    ceres::Solve(so, &problem, &cs);
    PoseSolveOptions lo;
    lo.max_iterations = 30;
    lo.function_tolerance = 1e-10;
    double xi[6] = {0, 0, 0, 0, 0, 0};
    const PoseSolveSummary s = SolvePoseCeres(batch, rl, basis, lo, xi);
    ASSERT_TRUE(s.solved);
    EXPECT_LT(s.final_cost, s.initial_cost);
    EXPECT_NEAR(s.initial_cost, cs.initial_cost, 1e-9 * cs.initial_cost) << variant;
    EXPECT_NEAR(s.final_cost, cs.final_cost, 1e-6 * cs.initial_cost + 1e-14) << variant;
    EXPECT_LE(s.iterations, lo.max_iterations + 1);
    for (int c = 0; c < 6; ++c) {
      EXPECT_NEAR(xi[c], xi_ref[c], 1e-6) << "variant " << variant << " xi" << c;
      if (variant != 1) {
        EXPECT_NEAR(xi[c], xi_true[c], 1e-6) << "variant " << variant << " xi" << c;
      }
    }
    if (variant == 1) {
      for (int c = 3; c < 6; ++c) EXPECT_EQ(xi[c], 0.0);  // frozen translation untouched
    }
  }
  // A point behind the camera at the start: not solved, xi unchanged.
  PoseBatchCost behind(&sc.fast, sc.k, 1.0, nullptr, sc.k, 0.0, 1.0);
  behind.AddPhotometric(Eigen::Vector3d(0, 0, -1), 0.5);
  double xi0[6] = {0.001, 0, 0, 0, 0, 0};
  const PoseSolveSummary sb = SolvePoseCeres(behind, RobustLoss{RobustLoss::Kind::kTukey, 0.1},
                                             Eigen::Matrix<double, 6, 6>::Identity(), PoseSolveOptions{}, xi0);
  EXPECT_FALSE(sb.solved);
  EXPECT_EQ(xi0[0], 0.001);
}

}  // namespace
}  // namespace exo::refinement
