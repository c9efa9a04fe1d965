#include "server/inpainting/poisson.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

namespace exo::inpaint {

absl::Status PoissonOptions::Validate() const {
  if (!(tolerance > 0.0 && tolerance < 1.0)) {
    return absl::InvalidArgumentError("PoissonOptions.tolerance must be in (0, 1)");
  }
  if (max_iterations < 1) return absl::InvalidArgumentError("PoissonOptions.max_iterations < 1");
  if (direct_max_unknowns < 1) return absl::InvalidArgumentError("PoissonOptions.direct_max_unknowns < 1");
  return absl::OkStatus();
}

namespace {

const float kNaN = std::numeric_limits<float>::quiet_NaN();

// The same problem on a grid half the size (cascadic multigrid): R is any-of-2x2, known values
// and gauge values are 2x2 means, a coarse gradient is the sum of the two fine gradients along
// the way, averaged over the two fine rows (columns).
struct CoarseProblem {
  ImageU8 region;
  ImageF values, gx, gy, gauge;
};

CoarseProblem Coarsen(const PoissonProblem& p) {
  const int w = p.region->width(), h = p.region->height();
  const int cw = (w + 1) / 2, ch = (h + 1) / 2;
  CoarseProblem c{ImageU8(cw, ch, 1, 0), ImageF(cw, ch, 1, kNaN), ImageF(cw, ch, 1, kNaN),
                  ImageF(cw, ch, 1, kNaN), ImageF(cw, ch, 1, kNaN)};
  auto known = [&](int x, int y) { return !p.region->at(x, y) && std::isfinite(p.values->at(x, y)); };
  // Effective fine gradient of pair (x,y)-(x+dx,y+dy): the target, or the known difference.
  auto geff = [&](int x, int y, int dx, int dy) -> float {
    const float g = dx ? p.gx->at(x, y) : p.gy->at(x, y);
    if (std::isfinite(g)) return g;
    if (known(x, y) && known(x + dx, y + dy)) return p.values->at(x, y) - p.values->at(x + dx, y + dy);
    return kNaN;
  };
  for (int y = 0; y < ch; ++y) {
    for (int x = 0; x < cw; ++x) {
      bool reg = false;
      double vs = 0, gs = 0;
      int vn = 0, gn = 0;
      for (int dy = 0; dy < 2; ++dy)
        for (int dx = 0; dx < 2; ++dx) {
          const int fx = 2 * x + dx, fy = 2 * y + dy;
          if (fx >= w || fy >= h) continue;
          if (p.region->at(fx, fy)) reg = true;
          if (known(fx, fy)) {
            vs += p.values->at(fx, fy);
            ++vn;
          }
          if (p.gauge && std::isfinite(p.gauge->at(fx, fy))) {
            gs += p.gauge->at(fx, fy);
            ++gn;
          }
        }
      c.region.at(x, y) = reg;
      if (!reg && vn > 0) c.values.at(x, y) = static_cast<float>(vs / vn);
      if (gn > 0) c.gauge.at(x, y) = static_cast<float>(gs / gn);
      // Horizontal pair (x, y)-(x+1, y): fine 2x -> 2x+2 along rows 2y, 2y+1.
      for (int dir = 0; dir < 2; ++dir) {
        const int dx = dir == 0 ? 1 : 0, dy = 1 - dx;
        if ((dx && x + 1 >= cw) || (dy && y + 1 >= ch)) continue;
        double s = 0;
        int n = 0;
        for (int k = 0; k < 2; ++k) {
          const int fx = 2 * x + (dy ? k : 0), fy = 2 * y + (dx ? k : 0);
          const int mx = fx + dx, my = fy + dy, ex = fx + 2 * dx, ey = fy + 2 * dy;
          if (ex >= w || ey >= h) continue;
          const float a = geff(fx, fy, dx, dy), b = geff(mx, my, dx, dy);
          if (std::isfinite(a) && std::isfinite(b)) {
            s += a + b;
            ++n;
          }
        }
        if (n > 0) (dx ? c.gx : c.gy).at(x, y) = static_cast<float>(s / n);
      }
    }
  }
  return c;
}

absl::StatusOr<ImageF> SolveLevel(const PoissonProblem& p, const PoissonOptions& options,
                                  PoissonStats& st, int depth);

}  // namespace

absl::StatusOr<ImageF> SolvePoisson(const PoissonProblem& p, const PoissonOptions& options,
                                    PoissonStats* stats) {
  EXO_RETURN_IF_ERROR(options.Validate());
  PoissonStats local;
  PoissonStats& st = stats ? *stats : local;
  st = PoissonStats{};
  return SolveLevel(p, options, st, 0);
}

namespace {

absl::StatusOr<ImageF> SolveLevel(const PoissonProblem& p, const PoissonOptions& options,
                                  PoissonStats& top_stats, int depth) {
  if (!p.region || !p.values || !p.gx || !p.gy) {
    return absl::InvalidArgumentError("SolvePoisson: region, values, gx and gy are required");
  }
  const int w = p.region->width(), h = p.region->height();
  auto same = [&](const ImageF* im) {
    return im == nullptr || (im->width() == w && im->height() == h && im->channels() == 1);
  };
  if (p.region->channels() != 1 || !same(p.values) || !same(p.gx) || !same(p.gy) ||
      !same(p.gauge) || !same(p.initial)) {
    return absl::InvalidArgumentError("SolvePoisson: all images must be 1-channel, same size");
  }
  const size_t n = static_cast<size_t>(w) * h;
  std::vector<int> index(n, -1);
  std::vector<int> pixel_of;
  for (size_t i = 0; i < n; ++i) {
    if (p.region->data()[i]) {
      index[i] = static_cast<int>(pixel_of.size());
      pixel_of.push_back(static_cast<int>(i));
    }
  }
  PoissonStats level_stats;
  PoissonStats& st = depth == 0 ? top_stats : level_stats;
  st.unknowns = static_cast<int>(pixel_of.size());
  ImageF out = *p.values;
  if (pixel_of.empty()) return out;
  const int m = st.unknowns;

  auto known = [&](int x, int y) {
    return std::isfinite(p.values->at(x, y)) && !p.region->at(x, y);
  };
  // Assemble the normal equations of sum (x_p - x_q - g)^2.
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(static_cast<size_t>(m) * 5);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(m);
  std::vector<uint8_t> has_dirichlet_px(m, 0);
  std::vector<double> diag(m, 0.0);
  auto add_pair = [&](int xp, int yp, int xq, int yq, float g) {
    // Residual x_p - x_q - g.
    if (!std::isfinite(g)) return;
    const int ip = index[static_cast<size_t>(yp) * w + xp];
    const int iq = index[static_cast<size_t>(yq) * w + xq];
    if (ip < 0 && iq < 0) return;
    if (ip >= 0 && iq >= 0) {
      diag[ip] += 1.0;
      diag[iq] += 1.0;
      trip.emplace_back(ip, iq, -1.0);
      trip.emplace_back(iq, ip, -1.0);
      b[ip] += g;
      b[iq] -= g;
    } else if (ip >= 0) {
      if (!known(xq, yq)) return;  // Neumann
      diag[ip] += 1.0;
      b[ip] += g + p.values->at(xq, yq);
      has_dirichlet_px[ip] = 1;
    } else {
      if (!known(xp, yp)) return;
      diag[iq] += 1.0;
      b[iq] += p.values->at(xp, yp) - g;
      has_dirichlet_px[iq] = 1;
    }
  };
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (x + 1 < w) add_pair(x, y, x + 1, y, p.gx->at(x, y));
      if (y + 1 < h) add_pair(x, y, x, y + 1, p.gy->at(x, y));
    }
  }
  // Connected components of R (4-connected through constrained pairs); a component without a
  // Dirichlet pixel gets pinned at one pixel and shifted to the gauge mean afterwards.
  std::vector<int> comp(m, -1);
  std::vector<int> pinned;        // per component: pinned unknown or -1
  std::vector<int> stack;
  for (int s = 0; s < m; ++s) {
    if (comp[s] >= 0) continue;
    const int c = st.components++;
    comp[s] = c;
    stack.push_back(s);
    bool dirichlet = false;
    while (!stack.empty()) {
      const int k = stack.back();
      stack.pop_back();
      dirichlet |= has_dirichlet_px[k] != 0;
      const int px = pixel_of[k] % w, py = pixel_of[k] / w;
      const int nx[4] = {px - 1, px + 1, px, px};
      const int ny[4] = {py, py, py - 1, py + 1};
      for (int d = 0; d < 4; ++d) {
        if (nx[d] < 0 || ny[d] < 0 || nx[d] >= w || ny[d] >= h) continue;
        const int j = index[static_cast<size_t>(ny[d]) * w + nx[d]];
        if (j < 0 || comp[j] >= 0) continue;
        // Only pairs that carry a constraint connect unknowns.
        const float g = d == 0 ? p.gx->at(nx[d], py) : d == 1 ? p.gx->at(px, py)
                      : d == 2 ? p.gy->at(px, ny[d]) : p.gy->at(px, py);
        if (!std::isfinite(g)) continue;
        comp[j] = c;
        stack.push_back(j);
      }
    }
    pinned.push_back(dirichlet ? -1 : s);
  }
  // Initial guess: the caller's, else (large problems) the solution of the coarser problem.
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(m);
  bool have_guess = false;
  if (p.initial) {
    for (int i = 0; i < m; ++i) {
      const float v = p.initial->data()[pixel_of[i]];
      if (std::isfinite(v)) x0[i] = v;
    }
    have_guess = true;
  }
  if (m > options.direct_max_unknowns && std::min(w, h) >= 8) {
    CoarseProblem c = Coarsen(p);
    PoissonProblem cp{&c.region, &c.values, &c.gx, &c.gy, p.gauge ? &c.gauge : nullptr, nullptr};
    PoissonStats cst;
    auto coarse = SolveLevel(cp, options, cst, depth + 1);
    if (coarse.ok()) {
      // Bilinear prolongation over the finite coarse values (solution inside, known outside);
      // keeps the caller's guess where it exists.
      const int cw = coarse->width(), ch = coarse->height();
      for (int i = 0; i < m; ++i) {
        if (p.initial && std::isfinite(p.initial->data()[pixel_of[i]])) continue;
        const int px = pixel_of[i] % w, py = pixel_of[i] / w;
        const double cx = (px - 0.5) / 2.0, cy = (py - 0.5) / 2.0;
        const int x0i = static_cast<int>(std::floor(cx)), y0i = static_cast<int>(std::floor(cy));
        const double fx = cx - x0i, fy = cy - y0i;
        double s = 0, sw = 0;
        for (int dy = 0; dy < 2; ++dy)
          for (int dx = 0; dx < 2; ++dx) {
            const int qx = std::clamp(x0i + dx, 0, cw - 1), qy = std::clamp(y0i + dy, 0, ch - 1);
            const float v = coarse->at(qx, qy);
            if (!std::isfinite(v)) continue;
            const double wgt = (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy) + 1e-6;
            s += wgt * v;
            sw += wgt;
          }
        if (sw > 0) x0[i] = s / sw;
      }
      have_guess = true;
    }
  }
  for (int c = 0; c < st.components; ++c) {
    if (pinned[c] < 0) continue;
    // Gauge guard: pin one unknown (to its initial guess; any value works: the Neumann
    // minimisers differ only by a constant), which is then set from the gauge mean below.
    ++st.neumann_components;
    diag[pinned[c]] += 1.0;
    b[pinned[c]] += x0[pinned[c]];
  }
  for (int i = 0; i < m; ++i) trip.emplace_back(i, i, diag[i]);
  Eigen::SparseMatrix<double> A(m, m);
  A.setFromTriplets(trip.begin(), trip.end());
  A.makeCompressed();

  Eigen::VectorXd x;
  bool ok = false;
  if (m > options.direct_max_unknowns) {
    // Conjugate gradient (diagonal preconditioner) from the coarse-level guess.
    Eigen::ConjugateGradient<Eigen::SparseMatrix<double>, Eigen::Lower | Eigen::Upper> cg;
    cg.setTolerance(options.tolerance);
    cg.setMaxIterations(options.max_iterations);
    cg.compute(A);
    if (cg.info() == Eigen::Success) {
      if (have_guess) x = cg.solveWithGuess(b, x0);
      else x = cg.solve(b);
      st.iterations = static_cast<int>(cg.iterations());
      st.residual = cg.error();
      ok = cg.info() == Eigen::Success && x.allFinite();
    }
  }
  if (!ok) {
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt(A);
    if (ldlt.info() != Eigen::Success) {
      return absl::InternalError("SolvePoisson: the system is singular (no boundary, no gauge)");
    }
    x = ldlt.solve(b);
    st.used_direct_solver = true;
    if (ldlt.info() != Eigen::Success || !x.allFinite()) {
      return absl::InternalError("SolvePoisson: direct solve failed");
    }
  }
  // Shift pure-Neumann components to their gauge mean.
  std::vector<double> sum_x(st.components, 0.0), sum_g(st.components, 0.0);
  std::vector<int> cnt_g(st.components, 0), cnt_x(st.components, 0);
  for (int i = 0; i < m; ++i) {
    const int c = comp[i];
    if (pinned[c] < 0) continue;
    sum_x[c] += x[i];
    ++cnt_x[c];
    const float g = p.gauge ? p.gauge->data()[pixel_of[i]] : std::numeric_limits<float>::quiet_NaN();
    if (std::isfinite(g)) {
      sum_g[c] += g;
      ++cnt_g[c];
    }
  }
  for (int c = 0; c < st.components; ++c) {
    if (pinned[c] >= 0 && cnt_g[c] == 0) {
      return absl::InvalidArgumentError(
          "SolvePoisson: a region part touches no known value and has no gauge values");
    }
  }
  for (int i = 0; i < m; ++i) {
    const int c = comp[i];
    double v = x[i];
    if (pinned[c] >= 0) v += sum_g[c] / cnt_g[c] - sum_x[c] / cnt_x[c];
    out.data()[pixel_of[i]] = static_cast<float>(v);
  }
  return out;
}

}  // namespace
}  // namespace exo::inpaint
