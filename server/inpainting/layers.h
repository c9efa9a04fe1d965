// Layered depth for InpaintKeyframe (InpaintOptions::layered_depth, inverse-depth domain): T may
// hide an occlusion edge (a table in front of a wall) that one Poisson surface cannot carry.
// SetupLayers clusters T's measured border in inverse depth, labels T's pixels with layers
// (Potts labelling by alpha-expansion, graph_cut.h) and rewrites the depth problem so that each
// layer is solved on its own. Internal to the inpainting library.
#pragma once

#include <vector>

#include "common/image.h"
#include "server/inpainting/inpaint.h"

namespace exo::inpainting {

// The depth solve's problem (poisson.h terms) on T's bounding box plus one pixel, a crop at
// (ox, oy) of a frame_w x frame_h frame, in the depth domain (inverse depth by default).
struct DepthCrop {
  int ox = 0, oy = 0, frame_w = 0, frame_h = 0;
  ImageU8 region;  // T (!= 0: solved)
  ImageF q;        // Dirichlet value of a pixel outside T (NaN: none)
  ImageF gx, gy;   // target of the pair (x, x+1) / (y, y+1) (NaN: no constraint)
  ImageF wx, wy;   // weight of that pair (NaN: 1)
  ImageF gauge;    // value at T's source pixels (gauge of Neumann-only components)
  int width() const { return region.width(); }
  int height() const { return region.height(); }
};

struct LayerResult {
  int layers = 1;                 // <= 1: the crop was not changed
  std::vector<int> layer_pixels;  // T pixels per layer
  float seed_dist_px = 0.f;       // largest distance of a T pixel to the nearest seed
  ImageU8 layer_map;              // frame-sized: 1 + layer of T pixels and seeds, 0 elsewhere
  ImageF prior, prior_weight;     // the surface prior per layer region (crop-sized; may be empty)
};

// With two or more layers: pairs between layers and from a T pixel to a border pixel of another
// layer lose their constraint (NaN target = natural boundary), border values that match no layer
// are dropped from crop->q, and the surface prior is built per layer region (BuildSurfacePrior
// on that region and that layer's border values). `measured` (frame-sized) marks pixels with
// sensor depth, `color` is the frame's copied colour.
LayerResult SetupLayers(const std::vector<uint8_t>& measured, const ImageU8& color,
                        const InpaintOptions& options, DepthCrop* crop);

}  // namespace exo::inpainting
