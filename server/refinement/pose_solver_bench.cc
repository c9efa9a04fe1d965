// Micro-benchmark of one pose stage solve: the same batched problem (PoseBatchCost, photometric
// residuals on a smooth synthetic image, 15 % gross outliers, known true pose) solved by
// SolvePoseCeres (ceres::Solve on ONE residual block, robust loss per residual inside it, the
// product's solver) and by a ceres::Problem with one block per residual (the session-2
// reference). Prints one JSON object per configuration: CPU us per solve, iterations,
// final cost and pose error, after a first line with the run's commit, build and machine
// (common/run_info). Usage: pose_solver_bench [--n 1500] [--reps 200]
#include <time.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/cli/cli.h"
#include "common/run_info/run_info.h"
#include "server/refinement/pose_batch.h"

namespace exo::refinement {
namespace {

double CpuUs() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return 1e6 * ts.tv_sec + 1e-3 * ts.tv_nsec;
}

int Main(int argc, char** argv) {
  int n = 1500, reps = 200;
  CLI::App app{"One pose-stage solve, the product's single-block Ceres solve against a "
               "per-residual Ceres problem: CPU us per solve, iterations, cost, error (JSON lines).",
               "pose_solver_bench"};
  cli::Setup(app);
  app.add_option("--n", n, "residuals per problem")->check(CLI::Range(10, 1000000));
  app.add_option("--reps", reps, "solves per configuration")->check(CLI::PositiveNumber);
  if (auto rc = cli::Parse(app, argc, argv)) return *rc;
  std::printf("%s\n", nlohmann::json{{"bench", "pose_solver"}, {"run_info", RunInfo()}}.dump().c_str());
  constexpr int kW = 320, kH = 240;
  std::vector<float> img(kW * kH);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x)
      img[y * kW + x] = 0.5f + 0.25f * std::sin(0.19 * x + 0.07 * y) * std::cos(0.13 * y - 0.05 * x);
  const FastBicubic fast(img.data(), kH, kW);
  ceres::Grid2D<float, 1> grid(img.data(), 0, kH, 0, kW);
  ceres::BiCubicInterpolator<ceres::Grid2D<float, 1>> interp(grid);
  const LevelIntrinsics k{250.0, 252.0, 159.5, 119.5};
  const double unit = 2.5, e = 0.9;
  const double xi_true[6] = {0.006, -0.004, 0.003, 0.004, -0.003, 0.002};  // ~0.45 deg, ~1.3 cm
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> ux(-0.4, 0.4), uz(2.0, 3.0), u01(0, 1);
  std::vector<Eigen::Vector3d> pts;
  PoseBatchCost truth(&fast, k, e, nullptr, k, 0.0, unit);
  for (int i = 0; i < n; ++i) {
    const double z = uz(rng);
    pts.emplace_back(ux(rng) * z, 0.75 * ux(rng) * z, z);
    truth.AddPhotometric(pts.back(), 0.0);
  }
  std::vector<double> r(n);
  const double* tp[1] = {xi_true};
  if (!truth.Evaluate(tp, r.data(), nullptr)) return 1;
  std::vector<double> ms(n);
  for (int i = 0; i < n; ++i) ms[i] = r[i] + (u01(rng) < 0.15 ? 0.4 + 0.2 * u01(rng) : 0.0);
  PoseBatchCost batch(&fast, k, e, nullptr, k, 0.0, unit);
  for (int i = 0; i < n; ++i) batch.AddPhotometric(pts[i], ms[i]);

  for (int variant = 0; variant < 2; ++variant) {
    // 0: Tukey, all 6 directions (finest level); 1: Cauchy, rotation only (coarse levels).
    const double scale = variant == 0 ? 0.1 : 0.02;
    Eigen::Matrix<double, 6, Eigen::Dynamic> basis = Eigen::Matrix<double, 6, 6>::Identity();
    if (variant == 1) basis = Eigen::Matrix<double, 6, 6>::Identity().leftCols(3);
    std::unique_ptr<ceres::LossFunction> loss;
    if (variant == 0) loss = std::make_unique<ceres::TukeyLoss>(scale);
    else loss = std::make_unique<ceres::CauchyLoss>(scale);
    const RobustLoss rl{variant == 0 ? RobustLoss::Kind::kTukey : RobustLoss::Kind::kCauchy, scale};
    for (int solver = 0; solver < 2; ++solver) {
      const int nrep = solver == 1 ? std::max(1, reps / 10) : reps;
      double xi[6] = {0, 0, 0, 0, 0, 0}, final_cost = 0;
      int iterations = 0;
      const double t0 = CpuUs();
      for (int rep = 0; rep < nrep; ++rep) {
        std::fill(xi, xi + 6, 0.0);
        if (solver == 0) {
          PoseSolveOptions o;
          const PoseSolveSummary s = SolvePoseCeres(batch, rl, basis, o, xi);
          iterations = s.iterations;
          final_cost = s.final_cost;
        } else {
          ceres::Problem::Options po;
          po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
          po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
          ceres::Problem problem(po);
          for (int i = 0; i < n; ++i)
            problem.AddResidualBlock(new PoseDeltaAnalytic(&interp, k, pts[i], unit, e, ms[i]),
                                     loss.get(), xi);
          SubspaceManifold manifold(basis);
          if (basis.cols() < 6) problem.SetManifold(xi, &manifold);
          ceres::Solver::Options so;
          so.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
          so.max_num_iterations = 15;
          so.function_tolerance = 1e-5;
          so.logging_type = ceres::SILENT;
          ceres::Solver::Summary cs;
          ceres::Solve(so, &problem, &cs);
          iterations = static_cast<int>(cs.iterations.size());
          final_cost = cs.final_cost;
        }
      }
      const double us = (CpuUs() - t0) / nrep;
      double err = 0;
      for (int c = 0; c < 6; ++c)
        if (variant == 0 || c < 3) err = std::max(err, std::abs(xi[c] - xi_true[c]));
      static const char* kNames[2] = {"ceres_single_block", "ceres_per_residual"};
      const nlohmann::json row = {{"bench", "pose_solver"},
                                  {"loss", variant == 0 ? "tukey" : "cauchy"},
                                  {"free_directions", static_cast<int>(basis.cols())},
                                  {"residuals", n},
                                  {"solver", kNames[solver]},
                                  {"reps", nrep},
                                  {"cpu_us_per_solve", us},
                                  {"iterations", iterations},
                                  {"final_cost", final_cost},
                                  {"max_abs_xi_error", err}};
      std::printf("%s\n", row.dump().c_str());
      std::fflush(stdout);
    }
  }
  return 0;
}

}  // namespace
}  // namespace exo::refinement

int main(int argc, char** argv) { return exo::refinement::Main(argc, argv); }
