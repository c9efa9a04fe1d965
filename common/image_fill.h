// Push-pull hole filling (Gortler et al. 1996, "The Lumigraph", §3.3 pull-push): fills the unknown
// samples of an image from the known ones through a pyramid of valid-weighted 2x2 averages. Used
// by RGB-D inpainting (depth pre-fill, initial colours) and by the lumigraph renderers for the
// pixels of a novel view that no stored view and no background sample covers.
#pragma once

#include <cstdint>
#include <span>

#include "common/status.h"

namespace exo {

// How a coarser pyramid level is read back on the way up.
enum class PullFilter {
  kNearest,   // the parent pixel (blocky; what the inpainting tables were measured with)
  kBilinear,  // bilinear between the four nearest parents (smooth fills)
};

inline constexpr int kPushPullMaxChannels = 4;

// Fills unknown samples of a float image with `channels` interleaved channels: valid-weighted
// 2x2 averaging down a pyramid (weights saturate at 1, so dense data is not outvoted by a
// single sample), then unknowns take the coarser level's value on the way up. `known[i]` != 0
// marks known pixels; they are never changed. Returns false when no pixel is known (nothing is
// changed). Sizes: data = width*height*channels, known = width*height; 1 <= channels <= 4.
// Level 0 is not copied: the cost is one pass over the input plus the coarser levels.
bool PushPullFill(std::span<float> data, int channels, std::span<const uint8_t> known, int width,
                  int height, PullFilter filter = PullFilter::kNearest);

}  // namespace exo
