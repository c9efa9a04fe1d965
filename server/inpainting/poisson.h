// Gradient-domain (Poisson) reconstruction of a scalar field inside a region, used for the
// inpainted depth (thesis eqs. 4.13-4.16): the unknowns are the pixels of the region R; every
// 4-neighbour pair with at least one end in R contributes (x_p - x_q - g_pq)^2; a neighbour
// outside R with a known value is a Dirichlet boundary, a neighbour outside R without one (or
// outside the image) is a natural (Neumann) boundary. A connected part of R that touches no
// known value is pure Neumann: its solution is fixed up to a constant, which the gauge sets
// (the mean over that part equals the mean of `gauge`). Only the pixels of R are assembled,
// directly as a 4-neighbour stencil. Small problems: Eigen's sparse LDL^T; large ones: a
// conjugate gradient preconditioned by a multigrid V-cycle (Galerkin 2x2-aggregation coarse
// levels, symmetric red-black Gauss-Seidel, LDL^T on the coarsest level; ~10-20 iterations to a
// relative residual of 1e-4 on a 640x480 frame's 17 % region), LDL^T as the fallback when the
// iteration does not converge.
#pragma once

#include <cstdint>

#include "common/image.h"
#include "common/status.h"

namespace exo::inpainting {

struct PoissonOptions {
  double tolerance = 1e-10;  // relative residual of the conjugate gradient
  int max_iterations = 2000;
  // Up to this many unknowns: sparse direct LDL^T. Above: multigrid-preconditioned CG.
  int direct_max_unknowns = 6000;
  absl::Status Validate() const;
};

struct PoissonStats {
  int unknowns = 0;
  int components = 0;
  int neumann_components = 0;  // parts with no Dirichlet boundary (gauge applied)
  int iterations = 0;
  double residual = 0.0;
  bool used_direct_solver = false;
};

struct PoissonProblem {
  const ImageU8* region = nullptr;  // 1 ch, != 0 inside R
  // Known values outside R (NaN = unknown). Size of `region`, 1 channel.
  const ImageF* values = nullptr;
  // gx(x, y): target for x(x, y) - x(x + 1, y); gy(x, y): target for x(x, y) - x(x, y + 1).
  // NaN = no constraint on that pair.
  const ImageF* gx = nullptr;
  const ImageF* gy = nullptr;
  // Per-pixel values whose mean over a pure-Neumann component sets its constant (NaN = not
  // used). May be null when every component has a Dirichlet boundary.
  const ImageF* gauge = nullptr;
  // Optional per-pair weights of the (x_p - x_q - g)^2 terms, same indexing as gx / gy
  // (NaN or absent = 1; must be > 0 where the pair carries a constraint). Robust gradient fusion
  // down-weights pairs whose copied gradient is unreliable.
  const ImageF* wx = nullptr;
  const ImageF* wy = nullptr;
  // Optional screening (data) term prior_weight * (x - prior)^2 per pixel of R (NaN / absent
  // = none). A pixel with a prior anchors its component (no gauge needed).
  const ImageF* prior = nullptr;
  const ImageF* prior_weight = nullptr;
  // Optional initial guess inside R (NaN = none: the gauge value there, else 0).
  const ImageF* initial = nullptr;
};

// Returns `values` with R replaced by the solution. Errors: mismatched sizes, a pure-Neumann
// component without gauge values, solver failure.
absl::StatusOr<ImageF> SolvePoisson(const PoissonProblem& problem, const PoissonOptions& options,
                                    PoissonStats* stats = nullptr);

}  // namespace exo::inpainting
