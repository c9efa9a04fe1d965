// PatchMatch search of InpaintKeyframe (thesis 4.7-4.12, SPEC §7): the source map f: T ->
// (image \ T) minimising w * rho_t * rho_g + (1 - w) * rho_s, coarse to fine over an image
// pyramid (onion-peel initialisation at the coarsest level), or at full resolution only from a
// previous keyframe's propagated map (4.3-4.6). Deterministic for a given seed whatever the
// thread count (fixed row bands in two phases, hashed random streams). Internal to the
// inpainting library.
#pragma once

#include <cstdint>
#include <vector>

#include "server/inpainting/inpaint.h"

namespace exo::inpainting {

// One pyramid level of the search.
struct Level {
  int w = 0, h = 0;
  std::vector<uint8_t> color;       // RGB, T holds the current estimate
  std::vector<float> normal;        // xyz, T holds the current estimate
  std::vector<uint8_t> target;      // T
  std::vector<uint8_t> data_ok;     // outside T with a valid normal (and depth at level 0)
  std::vector<uint8_t> source_ok;   // valid 5x5 patch centre
  std::vector<uint8_t> fixed;       // source kept (propagated from the previous keyframe)
  std::vector<int32_t> src;         // 2 per pixel, for T
  std::vector<int32_t> src_list;    // all source_ok pixel indices
  std::vector<int> row_x0, row_x1;  // per row: first/last target column (x0 > x1: none)
  size_t Idx(int x, int y) const { return static_cast<size_t>(y) * w + x; }
};

struct SearchParams {
  float w, one_minus_w, kappa, cap;
  bool geometry;
  bool peel_measured_normals_only;  // onion peel: rho_g over window pixels outside T only
};

// Fills the derived fields of a level (source_ok, src_list, row ranges of T; src and fixed
// sized) from w, h, color, normal, target and data_ok.
void FinishLevel(Level& L);

// Keyframe propagation (4.3-4.6): previous map -> sources of this keyframe's level 0. Marks the
// mapped pixels as fixed; returns their number.
int Propagate(const InpaintResult& prev, const RgbdKeyframe& frame, Level& L);

// Search at full resolution only, from a propagated map (Propagate): the unmapped pixels grow
// from the mapped ones, then `propagated_iterations` sweeps; colour and normals of T copied.
void SearchFromPropagated(Level& L, const SearchParams& p, const InpaintOptions& o);

// Coarse-to-fine search: `levels` holds level 0 on entry and the whole pyramid on return (at
// most pyramid_levels, or down to min_coarse_side). Returns the number of levels; adds the
// sweeps run to *sweeps. Colour and normals of T at level 0 are copied from the sources.
int SearchPyramid(std::vector<Level>* levels, const SearchParams& p, const InpaintOptions& o,
                  int* sweeps);

}  // namespace exo::inpainting
