// Where a triangle mesh lies inside each scene cell (SPEC §4 grid): per cell, the box of the
// surface pieces in it and a ball around the box centre that holds them. Used by the Vulkan
// client's per-frame reference ranking (client/vulkan/vk_cell_table.cc, issue 16 session 17): an
// upper bound of a reference's weight over the ball of the cell's surface is tighter than one
// over the ball of the whole cube (a flat cell's surface ball has radius q / sqrt 2 instead of
// q sqrt 3 / 2).
//
// What "the surface in cell k" means here is what a renderer can assign to k: every point x of a
// triangle with floor(x / q) == k evaluated in float (so each cell's box is inflated by
// CellSurfaceMarginM before clipping: float division and floor near a cell plane, and the slack),
// plus, through CellSurfaceBallRadius, a slack for a rasterised surface point lying slightly off
// its triangle (interpolation rounding, edge extrapolation to the snapped coverage of a pixel).
#pragma once

#include <cstdint>
#include <span>
#include <unordered_map>
#include <vector>

#include <glm/glm.hpp>

#include "common/cells.h"

namespace exo {

// Splits the convex polygon `poly` at the plane coord[axis] = c into the part with coord <= c
// (`below`) and the part with coord >= c (`above`); vertices on the plane go to both
// (Sutherland-Hodgman, one plane).
void SplitPolygon(const std::vector<glm::dvec3>& poly, int axis, double c,
                  std::vector<glm::dvec3>* below, std::vector<glm::dvec3>* above);

struct CellSurfaceBound {
  glm::dvec3 lo{0.0}, hi{0.0};  // box of the surface pieces in the (inflated) cell
  glm::dvec3 centre{0.0};       // (lo + hi) / 2
  double radius = 0.0;          // largest distance of a piece point from centre (no slack)
};
using CellSurfaceBounds = std::unordered_map<CellId, CellSurfaceBound>;

// Slack for a rasterised surface point (a G-buffer texel) off its triangle, up to |x| = extent_m
// from the origin: 1e-5 relative for the float interpolation, plus 0.2 % of q for a pixel centre
// covered by the snapped triangle (llvmpipe: 1/256-pixel vertex snapping for coverage, attributes
// from the float vertices) whose interpolated point lies up to 1/512 pixel beyond the triangle's
// edge (1 mm at q = 0.5 m: a footprint of 0.5 m per pixel along the surface).
inline double CellSurfaceSlackM(double q, double extent_m) {
  return 2e-3 * q + 1e-5 * (extent_m + q);
}
// Inflation of a cell's box before clipping: the float cell assignment floor(x / q) (0.1 % of q;
// it errs by ~1e-7 |x|) plus the slack, since a point off its triangle by the slack is assigned
// to its own cell.
inline double CellSurfaceMarginM(double q, double extent_m) {
  return 1e-3 * q + CellSurfaceSlackM(q, extent_m);
}

// Per-cell bounds of the triangles of (positions, indices): every triangle is clipped (double)
// against the box of each cell it may reach, inflated by CellSurfaceMarginM; every piece, down to
// a single point, adds to that cell's box and ball. Degenerate triangles count as well.
CellSurfaceBounds SurfaceBoundsPerCell(std::span<const glm::vec3> positions,
                                       std::span<const uint32_t> indices, const CellGrid& grid);

// *into becomes a bound of the union of both surfaces (union box; the ball around its centre is
// the smaller of its half diagonal and the ball enclosing both balls).
void MergeSurfaceBound(const CellSurfaceBound& b, CellSurfaceBound* into);

// The radius of the ball (around b.centre) the ranking may use for cell `b` of a grid with cell
// size q: every surface piece point plus the slack for a rasterised point off its triangle. (A
// point x within the slack s of the surface and in the cell's box B is within s of a surface
// point in B inflated by s, which the clipping kept.)
inline double CellSurfaceBoundSlackM(const CellSurfaceBound& b, double q) {
  return CellSurfaceSlackM(q, glm::length(b.centre) + b.radius);
}
inline double CellSurfaceBallRadius(const CellSurfaceBound& b, double q) {
  return b.radius + CellSurfaceBoundSlackM(b, q);
}
// The box the ranking may use is likewise [lo, hi] inflated by CellSurfaceBoundSlackM.

}  // namespace exo
