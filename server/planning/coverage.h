// Coverage metric of the view planner (SPEC §4, thesis §3.1.2, eqs. 3.6-3.14) as pure functions
// in double precision, with both errata of SPEC §4 and the numerical guards of SPEC §11:
//  - erratum 1: an empty reference set gives φ_d = 1 (a first view is maximally novel);
//  - erratum 2: R_max >= 2 (1 - φ_d^max would be 0); checked by PlannerOptions::Validate and
//    guarded here (returns an error value instead of dividing by zero);
//  - φ_p clamped to [0, 1] (ψ_vis may exceed ψ_total when the cell area is underestimated);
//  - d -> 0 (camera inside a cell): the direction p(M_i) - p(b_k) is undefined, the view claims no
//    coverage of that cell (φ = 0) instead of producing NaN.
#pragma once

#include <algorithm>
#include <cmath>
#include <span>

#include <glm/glm.hpp>

namespace exo::planning {

// Cosine of the Tammes angle upper bound for R_max views (3.9): 2(1 - 2/R_max)^2 - 1.
inline double TammesMaxCos(int r_max) {
  const double t = 1.0 - 2.0 / r_max;
  return 2.0 * t * t - 1.0;
}

// φ_d^min of (3.8) AS PRINTED: 1 for an empty R(b_k) (Kronecker delta), else γ of (3.7), the
// largest cosine between the candidate direction and a reference direction.
inline double PhiDMinPrinted(const glm::dvec3& dir_to_cam, std::span<const glm::dvec3> ref_dirs) {
  if (ref_dirs.empty()) return 1.0;
  double gamma = -1.0;
  for (const glm::dvec3& r : ref_dirs) gamma = std::max(gamma, glm::dot(dir_to_cam, r));
  return std::min(gamma, 1.0);
}

// Directional coverage φ_d (3.7-3.9) with both errata. `dir_to_cam` is the unit vector from the
// cell centre to the candidate camera, `ref_dirs` the unit vectors to the cell's references.
inline double DirectionalCoverage(const glm::dvec3& dir_to_cam, std::span<const glm::dvec3> ref_dirs,
                                  int r_max) {
  // Erratum 2: R_max <= 1 gives 1 - φ_d^max = 0 (options reject it; never divide by zero here).
  if (r_max < 2) return 0.0;
  // Erratum 1: (3.8) as printed gives φ_d = 0 for an empty R(b_k); a first view is maximally
  // novel.
  if (ref_dirs.empty()) return 1.0;
  const double phi_max = TammesMaxCos(r_max);
  return std::clamp((1.0 - PhiDMinPrinted(dir_to_cam, ref_dirs)) / (1.0 - phi_max), 0.0, 1.0);
}

// Distance quality g (3.11).
inline double DistanceQuality(double d_m, double d_max_m, double sigma_m) {
  const double e = d_m - d_max_m;
  return std::exp(-(e * e) / (2.0 * sigma_m * sigma_m));
}

// ψ_total (3.13): expected pixel count of the cell's surface in the view. `area_m2` = A(b_k),
// `cell_face_m2` = A_cell, `pixel_sr` = A_px, the solid angle of ONE pixel of the buffer that
// produced ψ_vis (so reduced-resolution cell-id buffers scale consistently). d is guarded.
inline double PsiTotal(double area_m2, double cell_face_m2, double d_m, double pixel_sr,
                       double min_distance_m) {
  const double d = std::max(d_m, min_distance_m);
  const double a = std::max(0.0, std::min(area_m2, cell_face_m2));
  return std::max(a / (d * d), pixel_sr) / pixel_sr;
}

// Positional coverage φ_p (3.14), clamped to [0, 1] (SPEC §4).
inline double PositionalCoverage(double g, double psi_vis, double psi_total) {
  if (!(psi_total > 0.0) || !std::isfinite(psi_vis)) return 0.0;
  return std::clamp(g * psi_vis / psi_total, 0.0, 1.0);
}

// φ (3.6).
inline double Coverage(double lambda, double phi_d, double phi_p) {
  return lambda * phi_d + (1.0 - lambda) * phi_p;
}

}  // namespace exo::planning
