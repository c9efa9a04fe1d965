// The 2D Hilbert curve (a space-filling path whose consecutive points are one grid step apart):
// the synthetic fly-over (common/synth) and the drone's exploration sweep (server/control) both
// walk it.
#pragma once

#include <vector>

#include <glm/vec2.hpp>

namespace exo {

// The curve of the given order as points in [0,1]^2, in curve order (4^order points; order 0:
// the centre).
std::vector<glm::dvec2> HilbertCurve(int order);

}  // namespace exo
