// Scene-scale defaults for view planning (SPEC §4: "cell size and d_max derived from the
// observed scene, not hard-coded"): the cell size q and the ideal view distance d_max (with the
// Gaussian width sigma of eq. 3.11) from the observed scene's diameter, each overridable.
//
// Rule (documented in docs/geometry.md):
//   D      = diagonal of the axis-aligned bounds of the observed surface (metres)
//   q      = clamp(D / cells_per_diameter, min_cell_m, max_cell_m)      default D/16, [0.3, 1.0]
//   d_max  = clamp(d_max_per_diameter * D, min_d_max_m, max_d_max_m)    default 0.15 D, [1, 50]
//   sigma  = clamp(sigma_per_diameter * D, min_sigma_m, max_sigma_m)    default 0.2 D, [0.5, 50]
// The thesis found 30-100 cm cells best for its scenes, with the optimum growing with the scene
// diameter, and sigma = 20 m for the ~100 m Viking village (0.2 D); d_max of a few metres for a
// room (clamped below at 1 m, about the RGB-D sensors' comfortable range).
#pragma once

#include <optional>

#include <glm/glm.hpp>

#include "common/status.h"

namespace exo {

struct SceneScaleOptions {
  double cells_per_diameter = 16.0;
  double min_cell_m = 0.3, max_cell_m = 1.0;
  double d_max_per_diameter = 0.15;
  double min_d_max_m = 1.0, max_d_max_m = 50.0;
  double sigma_per_diameter = 0.2;
  double min_sigma_m = 0.5, max_sigma_m = 50.0;
  // Explicit values win over the rule.
  std::optional<double> cell_size_m, d_max_m, sigma_m;

  absl::Status Validate() const;
};

struct SceneScale {
  double diameter_m = 0.0;
  double cell_size_m = 0.0;
  double d_max_m = 0.0;
  double sigma_m = 0.0;
};

// Pure function of the observed bounds (any frame; only the extent matters). Empty or
// non-finite bounds count as diameter 0 (every value then sits at its lower clamp).
SceneScale DeriveSceneScale(const glm::dvec3& bounds_min, const glm::dvec3& bounds_max,
                            const SceneScaleOptions& options = {});

}  // namespace exo
