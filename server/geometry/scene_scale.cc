#include "server/geometry/scene_scale.h"

#include <algorithm>
#include <cmath>

namespace exo {
namespace {

bool PositiveFinite(double v) { return v > 0 && std::isfinite(v); }

}  // namespace

absl::Status SceneScaleOptions::Validate() const {
  if (!PositiveFinite(cells_per_diameter) || !PositiveFinite(d_max_per_diameter) ||
      !PositiveFinite(sigma_per_diameter))
    return absl::InvalidArgumentError("SceneScaleOptions: per-diameter factors must be > 0");
  if (!PositiveFinite(min_cell_m) || !(max_cell_m >= min_cell_m) || !std::isfinite(max_cell_m))
    return absl::InvalidArgumentError("SceneScaleOptions: need 0 < min_cell_m <= max_cell_m");
  if (!PositiveFinite(min_d_max_m) || !(max_d_max_m >= min_d_max_m) || !std::isfinite(max_d_max_m))
    return absl::InvalidArgumentError("SceneScaleOptions: need 0 < min_d_max_m <= max_d_max_m");
  if (!PositiveFinite(min_sigma_m) || !(max_sigma_m >= min_sigma_m) || !std::isfinite(max_sigma_m))
    return absl::InvalidArgumentError("SceneScaleOptions: need 0 < min_sigma_m <= max_sigma_m");
  if ((cell_size_m && !PositiveFinite(*cell_size_m)) || (d_max_m && !(*d_max_m >= 0) ) ||
      (d_max_m && !std::isfinite(*d_max_m)) || (sigma_m && !PositiveFinite(*sigma_m)))
    return absl::InvalidArgumentError(
        "SceneScaleOptions: overrides must be finite, cell size and sigma > 0, d_max >= 0");
  return absl::OkStatus();
}

SceneScale DeriveSceneScale(const glm::dvec3& lo, const glm::dvec3& hi,
                            const SceneScaleOptions& o) {
  SceneScale s;
  const glm::dvec3 ext = hi - lo;
  const double d = glm::length(ext);
  s.diameter_m = (std::isfinite(d) && ext.x >= 0 && ext.y >= 0 && ext.z >= 0) ? d : 0.0;
  s.cell_size_m = o.cell_size_m.value_or(
      std::clamp(s.diameter_m / o.cells_per_diameter, o.min_cell_m, o.max_cell_m));
  s.d_max_m = o.d_max_m.value_or(
      std::clamp(o.d_max_per_diameter * s.diameter_m, o.min_d_max_m, o.max_d_max_m));
  s.sigma_m = o.sigma_m.value_or(
      std::clamp(o.sigma_per_diameter * s.diameter_m, o.min_sigma_m, o.max_sigma_m));
  return s;
}

}  // namespace exo
