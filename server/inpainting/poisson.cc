#include "server/inpainting/poisson.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

namespace exo::inpainting {

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

// The normal equations of sum (x_p - x_q - g)^2 on a grid: a weighted graph Laplacian over the
// unknowns (4-neighbour couplings) plus a diagonal (Dirichlet pairs, gauge pins). Matrix-free:
// A x = diag * x - sum_k weight_k * x[neighbour_k].
struct StencilLevel {
  int w = 0, h = 0;
  std::vector<int> index;    // per grid cell: unknown or -1
  std::vector<int> cell_of;  // per unknown: grid cell
  std::vector<double> diag;
  std::vector<int> nb;       // 4 per unknown (left, right, up, down): unknown or -1
  std::vector<double> wt;    // 4 per unknown: coupling weight (the matrix entry is -wt)
  std::vector<int> red, black;  // unknowns by (x + y) parity (no same-colour couplings)
  std::vector<int> parent;   // per unknown: unknown of the next coarser level
};

void Apply(const StencilLevel& L, const Eigen::VectorXd& x, Eigen::VectorXd& y) {
  const int m = static_cast<int>(L.diag.size());
  for (int i = 0; i < m; ++i) {
    double v = L.diag[i] * x[i];
    for (int k = 0; k < 4; ++k) {
      const int j = L.nb[4 * i + k];
      if (j >= 0) v -= L.wt[4 * i + k] * x[j];
    }
    y[i] = v;
  }
}

void SplitColours(StencilLevel& L) {
  L.red.clear();
  L.black.clear();
  for (int i = 0; i < static_cast<int>(L.cell_of.size()); ++i) {
    const int c = L.cell_of[i];
    (((c % L.w) + (c / L.w)) % 2 == 0 ? L.red : L.black).push_back(i);
  }
}

// Galerkin coarse level A_c = P^T A P for piecewise-constant aggregation of 2x2 blocks: stays a
// 4-neighbour stencil on the half-size grid, symmetric positive definite when A is.
StencilLevel CoarsenStencil(StencilLevel& f) {
  StencilLevel c;
  c.w = (f.w + 1) / 2;
  c.h = (f.h + 1) / 2;
  c.index.assign(static_cast<size_t>(c.w) * c.h, -1);
  const int mf = static_cast<int>(f.diag.size());
  f.parent.assign(mf, -1);
  for (int i = 0; i < mf; ++i) {
    const int cx = (f.cell_of[i] % f.w) / 2, cy = (f.cell_of[i] / f.w) / 2;
    const size_t cc = static_cast<size_t>(cy) * c.w + cx;
    if (c.index[cc] < 0) {
      c.index[cc] = static_cast<int>(c.cell_of.size());
      c.cell_of.push_back(static_cast<int>(cc));
    }
    f.parent[i] = c.index[cc];
  }
  const int mc = static_cast<int>(c.cell_of.size());
  c.diag.assign(mc, 0.0);
  c.nb.assign(static_cast<size_t>(mc) * 4, -1);
  c.wt.assign(static_cast<size_t>(mc) * 4, 0.0);
  for (int i = 0; i < mc; ++i) {
    const int x = c.cell_of[i] % c.w, y = c.cell_of[i] / c.w;
    const int nx[4] = {x - 1, x + 1, x, x}, ny[4] = {y, y, y - 1, y + 1};
    for (int k = 0; k < 4; ++k) {
      if (nx[k] >= 0 && ny[k] >= 0 && nx[k] < c.w && ny[k] < c.h) {
        c.nb[4 * i + k] = c.index[static_cast<size_t>(ny[k]) * c.w + nx[k]];
      }
    }
  }
  for (int i = 0; i < mf; ++i) {
    const int ci = f.parent[i];
    c.diag[ci] += f.diag[i];
    for (int k = 0; k < 4; ++k) {
      const int j = f.nb[4 * i + k];
      if (j < 0) continue;
      const int cj = f.parent[j];
      if (cj == ci) {
        c.diag[ci] -= f.wt[4 * i + k];  // internal coupling (counted from both ends)
      } else {
        c.wt[4 * ci + k] += f.wt[4 * i + k];  // a fine k-neighbour lies in the coarse k-neighbour
      }
    }
  }
  SplitColours(c);
  return c;
}

// Multigrid V-cycle as the preconditioner of a conjugate gradient: symmetric red-black
// Gauss-Seidel (red then black before, black then red after the coarse correction), Galerkin
// aggregation coarse levels, sparse LDL^T on the coarsest. Symmetric and positive definite, so
// it is a valid CG preconditioner.
class MultigridPreconditioner {
 public:
  explicit MultigridPreconditioner(StencilLevel fine, int coarsest_unknowns = 400) {
    levels_.push_back(std::move(fine));
    SplitColours(levels_[0]);
    while (static_cast<int>(levels_.back().diag.size()) > coarsest_unknowns &&
           std::max(levels_.back().w, levels_.back().h) > 2) {
      StencilLevel c = CoarsenStencil(levels_.back());
      if (c.diag.size() == levels_.back().diag.size()) break;
      levels_.push_back(std::move(c));
    }
    const StencilLevel& top = levels_.back();
    const int m = static_cast<int>(top.diag.size());
    std::vector<Eigen::Triplet<double>> trip;
    for (int i = 0; i < m; ++i) {
      trip.emplace_back(i, i, top.diag[i]);
      for (int k = 0; k < 4; ++k)
        if (top.nb[4 * i + k] >= 0) trip.emplace_back(i, top.nb[4 * i + k], -top.wt[4 * i + k]);
    }
    Eigen::SparseMatrix<double> a(m, m);
    a.setFromTriplets(trip.begin(), trip.end());
    coarse_.compute(a);
    ok_ = coarse_.info() == Eigen::Success;
    rhs_.resize(levels_.size());
    sol_.resize(levels_.size());
    tmp_.resize(levels_.size());
    for (size_t l = 0; l < levels_.size(); ++l) {
      const int n = static_cast<int>(levels_[l].diag.size());
      rhs_[l].resize(n);
      sol_[l].resize(n);
      tmp_[l].resize(n);
    }
  }
  bool ok() const { return ok_; }
  int num_levels() const { return static_cast<int>(levels_.size()); }
  const StencilLevel& fine() const { return levels_[0]; }

  void Precondition(const Eigen::VectorXd& r, Eigen::VectorXd& z) {
    rhs_[0] = r;
    VCycle(0);
    z = sol_[0];
  }

 private:
  static void Relax(const StencilLevel& L, const std::vector<int>& set, const Eigen::VectorXd& b,
                    Eigen::VectorXd& x) {
    for (int i : set) {
      double v = b[i];
      for (int k = 0; k < 4; ++k) {
        const int j = L.nb[4 * i + k];
        if (j >= 0) v += L.wt[4 * i + k] * x[j];
      }
      x[i] = v / L.diag[i];
    }
  }
  void VCycle(int l) {
    const StencilLevel& L = levels_[l];
    Eigen::VectorXd& x = sol_[l];
    if (l + 1 == static_cast<int>(levels_.size())) {
      x = coarse_.solve(rhs_[l]);
      return;
    }
    x.setZero();
    Relax(L, L.red, rhs_[l], x);
    Relax(L, L.black, rhs_[l], x);
    Apply(L, x, tmp_[l]);
    tmp_[l] = rhs_[l] - tmp_[l];
    rhs_[l + 1].setZero();
    for (int i = 0; i < static_cast<int>(L.parent.size()); ++i) rhs_[l + 1][L.parent[i]] += tmp_[l][i];
    VCycle(l + 1);
    for (int i = 0; i < static_cast<int>(L.parent.size()); ++i) x[i] += sol_[l + 1][L.parent[i]];
    Relax(L, L.black, rhs_[l], x);
    Relax(L, L.red, rhs_[l], x);
  }

  std::vector<StencilLevel> levels_;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> coarse_;
  std::vector<Eigen::VectorXd> rhs_, sol_, tmp_;
  bool ok_ = false;
};

}  // namespace

absl::StatusOr<ImageF> SolvePoisson(const PoissonProblem& p, const PoissonOptions& options,
                                    PoissonStats* stats) {
  EXO_RETURN_IF_ERROR(options.Validate());
  PoissonStats local;
  PoissonStats& st = stats ? *stats : local;
  st = PoissonStats{};
  if (!p.region || !p.values || !p.gx || !p.gy) {
    return absl::InvalidArgumentError("SolvePoisson: region, values, gx and gy are required");
  }
  const int w = p.region->width(), h = p.region->height();
  auto same = [&](const ImageF* im) {
    return im == nullptr || (im->width() == w && im->height() == h && im->channels() == 1);
  };
  if (p.region->channels() != 1 || !same(p.values) || !same(p.gx) || !same(p.gy) ||
      !same(p.gauge) || !same(p.initial) || !same(p.wx) || !same(p.wy) || !same(p.prior) ||
      !same(p.prior_weight)) {
    return absl::InvalidArgumentError("SolvePoisson: all images must be 1-channel, same size");
  }
  const size_t n = static_cast<size_t>(w) * h;
  StencilLevel S;
  S.w = w;
  S.h = h;
  S.index.assign(n, -1);
  for (size_t i = 0; i < n; ++i) {
    if (p.region->data()[i]) {
      S.index[i] = static_cast<int>(S.cell_of.size());
      S.cell_of.push_back(static_cast<int>(i));
    }
  }
  st.unknowns = static_cast<int>(S.cell_of.size());
  ImageF out = *p.values;
  if (S.cell_of.empty()) return out;
  const int m = st.unknowns;

  auto known = [&](int x, int y) {
    return std::isfinite(p.values->at(x, y)) && !p.region->at(x, y);
  };
  // Assemble the normal equations of sum (x_p - x_q - g)^2 directly on the stencil (only the
  // pairs with an unknown end are visited).
  Eigen::VectorXd b = Eigen::VectorXd::Zero(m);
  std::vector<uint8_t> has_dirichlet_px(m, 0);
  S.diag.assign(m, 0.0);
  S.nb.assign(static_cast<size_t>(m) * 4, -1);
  S.wt.assign(static_cast<size_t>(m) * 4, 0.0);
  auto add_pair = [&](int xp, int yp, int xq, int yq, float g, float wgt, int kp, int kq) {
    // Residual wgt * (x_p - x_q - g)^2; kp: direction p -> q in (left, right, up, down), kq the
    // reverse.
    if (!std::isfinite(g)) return;
    const double a = std::isfinite(wgt) && wgt > 0.f ? wgt : 1.0;
    const int ip = S.index[static_cast<size_t>(yp) * w + xp];
    const int iq = S.index[static_cast<size_t>(yq) * w + xq];
    if (ip >= 0 && iq >= 0) {
      S.diag[ip] += a;
      S.diag[iq] += a;
      S.nb[4 * ip + kp] = iq;
      S.wt[4 * ip + kp] = a;
      S.nb[4 * iq + kq] = ip;
      S.wt[4 * iq + kq] = a;
      b[ip] += a * g;
      b[iq] -= a * g;
    } else if (ip >= 0) {
      if (!known(xq, yq)) return;  // Neumann
      S.diag[ip] += a;
      b[ip] += a * (g + p.values->at(xq, yq));
      has_dirichlet_px[ip] = 1;
    } else if (iq >= 0) {
      if (!known(xp, yp)) return;
      S.diag[iq] += a;
      b[iq] += a * (p.values->at(xp, yp) - g);
      has_dirichlet_px[iq] = 1;
    }
  };
  const float kOne = 1.f;
  auto wxa = [&](int x, int y) { return p.wx ? p.wx->at(x, y) : kOne; };
  auto wya = [&](int x, int y) { return p.wy ? p.wy->at(x, y) : kOne; };
  for (int i = 0; i < m; ++i) {
    const int x = S.cell_of[i] % w, y = S.cell_of[i] / w;
    // Each pair once: from its unknown end, or from its left/upper end when both are unknown.
    if (x + 1 < w) add_pair(x, y, x + 1, y, p.gx->at(x, y), wxa(x, y), 1, 0);
    if (y + 1 < h) add_pair(x, y, x, y + 1, p.gy->at(x, y), wya(x, y), 3, 2);
    if (x > 0 && S.index[static_cast<size_t>(y) * w + x - 1] < 0)
      add_pair(x - 1, y, x, y, p.gx->at(x - 1, y), wxa(x - 1, y), 1, 0);
    if (y > 0 && S.index[static_cast<size_t>(y - 1) * w + x] < 0)
      add_pair(x, y - 1, x, y, p.gy->at(x, y - 1), wya(x, y - 1), 3, 2);
  }
  if (p.prior && p.prior_weight) {
    for (int i = 0; i < m; ++i) {
      const float v = p.prior->data()[S.cell_of[i]], a = p.prior_weight->data()[S.cell_of[i]];
      if (!std::isfinite(v) || !(a > 0.f) || !std::isfinite(a)) continue;
      S.diag[i] += a;
      b[i] += static_cast<double>(a) * v;
      has_dirichlet_px[i] = 1;
    }
  }
  // Connected components of R through constrained pairs; a component without a Dirichlet pixel
  // gets pinned at one pixel and shifted to the gauge mean afterwards.
  std::vector<int> comp(m, -1);
  std::vector<int> pinned;  // per component: pinned unknown or -1
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
      for (int d = 0; d < 4; ++d) {
        const int j = S.nb[4 * k + d];
        if (j < 0 || comp[j] >= 0) continue;
        comp[j] = c;
        stack.push_back(j);
      }
    }
    pinned.push_back(dirichlet ? -1 : s);
  }
  // Initial guess: the caller's where given, else the gauge value (the copied samples).
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(m);
  for (int i = 0; i < m; ++i) {
    const float v0 = p.initial ? p.initial->data()[S.cell_of[i]] : kNaN;
    const float g0 = p.gauge ? p.gauge->data()[S.cell_of[i]] : kNaN;
    if (std::isfinite(v0)) x0[i] = v0;
    else if (std::isfinite(g0)) x0[i] = g0;
  }
  for (int c = 0; c < st.components; ++c) {
    if (pinned[c] < 0) continue;
    // Gauge guard: pin one unknown (to its initial guess; any value works: the Neumann
    // minimisers differ only by a constant), which is then set from the gauge mean below.
    ++st.neumann_components;
    S.diag[pinned[c]] += 1.0;
    b[pinned[c]] += x0[pinned[c]];
  }

  const std::vector<int> cell_of = S.cell_of;
  Eigen::VectorXd x;
  bool ok = false;
  if (m > options.direct_max_unknowns) {
    // Conjugate gradient preconditioned by a multigrid V-cycle, from the initial guess.
    MultigridPreconditioner mg(std::move(S));
    if (mg.ok()) {
      const StencilLevel& A = mg.fine();
      x = x0;
      Eigen::VectorXd r(m), z(m), q(m), ap(m);
      Apply(A, x, ap);
      r = b - ap;
      const double bnorm = std::max(b.norm(), 1e-300);
      double rnorm = r.norm();
      mg.Precondition(r, z);
      q = z;
      double rz = r.dot(z);
      int it = 0;
      while (rnorm > options.tolerance * bnorm && it < options.max_iterations) {
        Apply(A, q, ap);
        const double qaq = q.dot(ap);
        if (!(qaq > 0.0)) break;
        const double alpha = rz / qaq;
        x += alpha * q;
        r -= alpha * ap;
        rnorm = r.norm();
        ++it;
        if (rnorm <= options.tolerance * bnorm) break;
        mg.Precondition(r, z);
        const double rz_new = r.dot(z);
        q = z + (rz_new / rz) * q;
        rz = rz_new;
      }
      st.iterations = it;
      st.residual = rnorm / bnorm;
      ok = rnorm <= options.tolerance * bnorm && x.allFinite();
      if (!ok) S = mg.fine();  // kept for the direct fallback below
    }
    if (!ok && S.diag.empty()) return absl::InternalError("SolvePoisson: multigrid setup failed");
  }
  if (!ok) {
    std::vector<Eigen::Triplet<double>> trip;
    trip.reserve(static_cast<size_t>(m) * 5);
    for (int i = 0; i < m; ++i) {
      trip.emplace_back(i, i, S.diag[i]);
      for (int k = 0; k < 4; ++k)
        if (S.nb[4 * i + k] >= 0) trip.emplace_back(i, S.nb[4 * i + k], -S.wt[4 * i + k]);
    }
    Eigen::SparseMatrix<double> A(m, m);
    A.setFromTriplets(trip.begin(), trip.end());
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
    const float g = p.gauge ? p.gauge->data()[cell_of[i]] : kNaN;
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
    out.data()[cell_of[i]] = static_cast<float>(v);
  }
  return out;
}

}  // namespace exo::inpainting
