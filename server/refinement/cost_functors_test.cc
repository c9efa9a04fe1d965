// GradientChecker tests for every cost functor of refinement (autodiff vs numeric).
#include "server/refinement/cost_functors.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include <ceres/gradient_checker.h>
#include <ceres/manifold.h>
#include <gtest/gtest.h>

namespace exo::refinement {
namespace {

TEST(CostFunctorsTest, ExposureResidualGradient) {
  std::unique_ptr<ceres::CostFunction> cf(ExposureResidual::Create(std::log(0.37), std::log(0.52)));
  ceres::NumericDiffOptions nd;
  const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
  ceres::GradientChecker checker(cf.get(), no_manifolds, nd);
  double e = 1.3;
  double* params[1] = {&e};
  ceres::GradientChecker::ProbeResults results;
  EXPECT_TRUE(checker.Probe(params, 1e-7, &results)) << results.error_log;
  EXPECT_NEAR(results.residuals[0], std::log(1.3 * 0.37 / 0.52), 1e-12);
}

TEST(CostFunctorsTest, LogExposureResidualGradient) {
  LogExposureResidual cf(std::log(0.37), std::log(0.52));
  ceres::NumericDiffOptions nd;
  const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
  ceres::GradientChecker checker(&cf, no_manifolds, nd);
  double x = std::log(1.3);
  double* params[1] = {&x};
  ceres::GradientChecker::ProbeResults results;
  EXPECT_TRUE(checker.Probe(params, 1e-7, &results)) << results.error_log;
  EXPECT_NEAR(results.residuals[0], std::log(1.3 * 0.37 / 0.52), 1e-12);
}

TEST(CostFunctorsTest, PoseResidualGradientWithQuaternionManifold) {
  // A smooth analytic image so the bicubic interpolant is well resolved.
  const int w = 64, h = 48;
  std::vector<float> img(w * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      img[y * w + x] = 0.5f + 0.3f * std::sin(0.21 * x + 0.1 * y) * std::cos(0.17 * y);
  LumaGrid grid(img.data(), 0, h, 0, w);
  LumaInterpolator interp(grid);
  LevelIntrinsics k{50.0, 52.0, 31.5, 23.5};
  ceres::EigenQuaternionManifold q_manifold;
  std::vector<const ceres::Manifold*> manifolds = {&q_manifold, nullptr};
  // GradientChecker differentiates with Ridders' method; its default initial step (1e-2) spans
  // several bicubic cells, where the C1 spline's second derivative jumps and extrapolation
  // breaks. Small steps keep the numeric derivative inside one cell.
  ceres::NumericDiffOptions nd;
  nd.ridders_relative_initial_step_size = 1e-5;
  for (int trial = 0; trial < 5; ++trial) {
    const Eigen::Vector3d p(0.1 * trial - 0.2, 0.05 * trial - 0.1, 2.0 + 0.1 * trial);
    std::unique_ptr<ceres::CostFunction> cf(PoseResidual::Create(&interp, k, p, 1.2, 0.4));
    ceres::GradientChecker checker(cf.get(), &manifolds, nd);
    Eigen::Quaterniond q(Eigen::AngleAxisd(0.05 * trial, Eigen::Vector3d(0.3, 1, 0.2).normalized()));
    double qd[4] = {q.x(), q.y(), q.z(), q.w()};
    double t[3] = {0.01 * trial, -0.02, 0.03};
    double* params[2] = {qd, t};
    ceres::GradientChecker::ProbeResults results;
    EXPECT_TRUE(checker.Probe(params, 1e-5, &results)) << "trial " << trial << results.error_log;
  }
}

TEST(CostFunctorsTest, PoseResidualRejectsPointsBehindCamera) {
  std::vector<float> img(16 * 16, 0.5f);
  LumaGrid grid(img.data(), 0, 16, 0, 16);
  LumaInterpolator interp(grid);
  PoseResidual f(&interp, {10, 10, 7.5, 7.5}, Eigen::Vector3d(0, 0, -1), 1.0, 0.5);
  double q[4] = {0, 0, 0, 1}, t[3] = {0, 0, 0}, r;
  EXPECT_FALSE(f(q, t, &r));
}

// A smooth 64x48 luma image and a slanted, rippled depth map with their bicubic interpolators
// and intrinsics: the input of the pose/depth functor Jacobian tests.
struct SmoothLevel {
  static constexpr int w = 64, h = 48;
  template <typename F>
  static std::vector<float> Fill(F f) {
    std::vector<float> v(w * h);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) v[y * w + x] = f(x, y);
    return v;
  }
  // Filled before the grids below are built on them (members initialise in this order).
  const std::vector<float> img = Fill([](int x, int y) {
    return float(0.5 + 0.3 * std::sin(0.21 * x + 0.1 * y) * std::cos(0.17 * y));
  });
  const std::vector<float> depth = Fill([](int x, int y) {
    return float(2.0 + 0.01 * x + 0.02 * y + 0.05 * std::sin(0.1 * x));
  });
  LumaGrid grid{img.data(), 0, h, 0, w};
  LumaInterpolator interp{grid};
  DepthGrid dgrid{depth.data(), 0, h, 0, w};
  DepthInterpolator dinterp{dgrid};
  LevelIntrinsics k{50.0, 52.0, 31.5, 23.5};
  // Numeric differentiation that stays inside one bicubic cell (see above).
  ceres::NumericDiffOptions nd = [] {
    ceres::NumericDiffOptions o;
    o.ridders_relative_initial_step_size = 1e-5;
    return o;
  }();
};

// The refiner's pose chart: xi = (angle-axis about the camera centre, translation in units of
// the median depth). Checked at xi != 0 (the chart is re-centred per stage, but LM evaluates
// away from 0) for the photometric and the depth residual.
TEST(CostFunctorsTest, PoseDeltaAndDepthDeltaResidualGradients) {
  const SmoothLevel level;
  const auto& interp = level.interp;
  const auto& dinterp = level.dinterp;
  const LevelIntrinsics& k = level.k;
  const ceres::NumericDiffOptions& nd = level.nd;
  for (int trial = 0; trial < 5; ++trial) {
    const Eigen::Vector3d p(0.1 * trial - 0.2, 0.05 * trial - 0.1, 2.0 + 0.1 * trial);
    double xi[6] = {0.01 * trial, -0.02, 0.015, 0.002 * trial, 0.003, -0.004};
    double* params[1] = {xi};
    for (int which = 0; which < 2; ++which) {
      std::unique_ptr<ceres::CostFunction> cf(
          which == 0 ? PoseDeltaResidual::Create(&interp, k, p, 2.5, 1.2, 0.4)
                     : DepthDeltaResidual::Create(&dinterp, k, p, 2.5, 3.0));
      const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
      ceres::GradientChecker checker(cf.get(), no_manifolds, nd);
      ceres::GradientChecker::ProbeResults results;
      EXPECT_TRUE(checker.Probe(params, 1e-5, &results))
          << (which ? "depth" : "photometric") << " trial " << trial << results.error_log;
    }
  }
}

// The analytic-Jacobian functors the refiner uses: GradientChecker (numeric, Ridders) at
// xi != 0 including rotations of up to ~10 degrees (where J_l(w) != I matters), and the same
// residual and Jacobian as the autodiff functors (to 1e-9 relative).
TEST(CostFunctorsTest, AnalyticPoseAndDepthJacobiansMatchNumericAndAutodiff) {
  const SmoothLevel level;
  const auto& interp = level.interp;
  const auto& dinterp = level.dinterp;
  const LevelIntrinsics& k = level.k;
  const ceres::NumericDiffOptions& nd = level.nd;
  for (int trial = 0; trial < 6; ++trial) {
    const Eigen::Vector3d p(0.1 * trial - 0.2, 0.05 * trial - 0.1, 2.0 + 0.1 * trial);
    const double a = trial == 5 ? 0.0 : 0.03 * trial;  // trial 5: the chart centre (series)
    double xi[6] = {a, -0.6 * a, 0.4 * a, 0.002 * trial, 0.003, -0.004};
    double* params[1] = {xi};
    for (int which = 0; which < 2; ++which) {
      std::unique_ptr<ceres::CostFunction> analytic(
          which == 0 ? static_cast<ceres::CostFunction*>(
                           new PoseDeltaAnalytic(&interp, k, p, 2.5, 1.2, 0.4))
                     : new DepthDeltaAnalytic(&dinterp, k, p, 2.5, 3.0));
      std::unique_ptr<ceres::CostFunction> autodiff(
          which == 0 ? PoseDeltaResidual::Create(&interp, k, p, 2.5, 1.2, 0.4)
                     : DepthDeltaResidual::Create(&dinterp, k, p, 2.5, 3.0));
      const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
      ceres::GradientChecker checker(analytic.get(), no_manifolds, nd);
      ceres::GradientChecker::ProbeResults results;
      EXPECT_TRUE(checker.Probe(params, 1e-5, &results))
          << (which ? "depth" : "photometric") << " trial " << trial << results.error_log;
      double r_a, r_b, j_a[6], j_b[6];
      double* ja[1] = {j_a};
      double* jb[1] = {j_b};
      ASSERT_TRUE(analytic->Evaluate(params, &r_a, ja));
      ASSERT_TRUE(autodiff->Evaluate(params, &r_b, jb));
      EXPECT_NEAR(r_a, r_b, 1e-12);
      double jmax = 0;
      for (double v : j_b) jmax = std::max(jmax, std::abs(v));
      for (int i = 0; i < 6; ++i) EXPECT_NEAR(j_a[i], j_b[i], 1e-9 * jmax) << "trial " << trial << " d/dxi" << i;
    }
  }
  // Behind the camera: the step is rejected, as in the autodiff functors.
  PoseDeltaAnalytic behind(&interp, k, Eigen::Vector3d(0, 0, -1), 1.0, 1.0, 0.5);
  double xi0[6] = {0, 0, 0, 0, 0, 0}, r;
  const double* p0[1] = {xi0};
  EXPECT_FALSE(behind.Evaluate(p0, &r, nullptr));
}

TEST(CostFunctorsTest, SubspaceManifoldUpdatesOnlyItsDirections) {
  Eigen::Matrix<double, 6, Eigen::Dynamic> b = Eigen::Matrix<double, 6, 2>::Zero();
  b(0, 0) = 1.0;
  b(3, 1) = std::sqrt(0.5);
  b(4, 1) = std::sqrt(0.5);
  SubspaceManifold m(b);
  EXPECT_EQ(m.TangentSize(), 2);
  const double x[6] = {1, 2, 3, 4, 5, 6}, d[2] = {0.5, 2.0};
  double y[6], back[2];
  ASSERT_TRUE(m.Plus(x, d, y));
  EXPECT_DOUBLE_EQ(y[0], 1.5);
  EXPECT_DOUBLE_EQ(y[1], 2.0);  // frozen direction unchanged
  EXPECT_DOUBLE_EQ(y[2], 3.0);
  EXPECT_NEAR(y[3], 4.0 + std::sqrt(2.0), 1e-12);
  EXPECT_NEAR(y[4], 5.0 + std::sqrt(2.0), 1e-12);
  EXPECT_DOUBLE_EQ(y[5], 6.0);
  ASSERT_TRUE(m.Minus(y, x, back));
  EXPECT_NEAR(back[0], 0.5, 1e-12);
  EXPECT_NEAR(back[1], 2.0, 1e-12);
}

}  // namespace
}  // namespace exo::refinement
