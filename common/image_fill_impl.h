// Internal: the push-pull core behind PushPullFill and FillHoles (lumigraph), templated on how
// level 0 is read and written so that callers with another pixel format (RGB8 frames) do not
// convert the whole image first. Level 0 is never materialised: level 1 is summed straight from
// the input, and only the unknown pixels of level 0 are pulled. Not a public header.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <vector>

#include "common/image_fill.h"

namespace exo::image_fill_internal {

struct Level {
  int w = 0, h = 0;
  std::vector<float> sum;  // premultiplied values, channels per pixel
  std::vector<float> wt;   // alpha in [0, 1]
};

// Value of the coarse level `c` (complete, channels interleaved) read for fine pixel (x, y).
template <int kMaxChannels>
inline void ReadParent(const Level& c, int channels, int x, int y, PullFilter filter,
                       std::array<float, kMaxChannels>& out) {
  if (filter == PullFilter::kNearest) {
    const size_t ci = static_cast<size_t>(y / 2) * c.w + x / 2;
    for (int k = 0; k < channels; ++k) out[k] = c.sum[ci * channels + k];
    return;
  }
  // Pixel centres: fine (x + 0.5) sits at coarse (x + 0.5) / 2 - 0.5.
  const float cx = std::clamp((x + 0.5f) * 0.5f - 0.5f, 0.f, float(c.w - 1));
  const float cy = std::clamp((y + 0.5f) * 0.5f - 0.5f, 0.f, float(c.h - 1));
  const int x0 = static_cast<int>(cx), y0 = static_cast<int>(cy);
  const int x1 = std::min(x0 + 1, c.w - 1), y1 = std::min(y0 + 1, c.h - 1);
  const float ax = cx - x0, ay = cy - y0;
  const size_t i00 = static_cast<size_t>(y0) * c.w + x0, i01 = static_cast<size_t>(y0) * c.w + x1;
  const size_t i10 = static_cast<size_t>(y1) * c.w + x0, i11 = static_cast<size_t>(y1) * c.w + x1;
  const float w00 = (1 - ax) * (1 - ay), w01 = ax * (1 - ay), w10 = (1 - ax) * ay, w11 = ax * ay;
  for (int k = 0; k < channels; ++k)
    out[k] = w00 * c.sum[i00 * channels + k] + w01 * c.sum[i01 * channels + k] +
             w10 * c.sum[i10 * channels + k] + w11 * c.sum[i11 * channels + k];
}

// known(i) -> bool, value(i, k) -> float (read only where known), write(i, k, v) (called only
// where !known). Returns false (nothing written) when no pixel is known.
template <int kMaxChannels, typename Known, typename Value, typename Write>
bool PushPull(int width, int height, int channels, PullFilter filter, Known known, Value value,
              Write write) {
  std::vector<Level> levels;
  if (width == 1 && height == 1) {  // nothing to pull from
    return known(0);
  }
  // Level 1 straight from the input: 2x2 sums of the known samples (same order of additions as
  // summing a materialised level 0).
  Level l1{(width + 1) / 2, (height + 1) / 2, {}, {}};
  l1.sum.assign(static_cast<size_t>(l1.w) * l1.h * channels, 0.f);
  l1.wt.assign(static_cast<size_t>(l1.w) * l1.h, 0.f);
  bool any = false;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const size_t fi = static_cast<size_t>(y) * width + x;
      if (!known(fi)) continue;
      any = true;
      const size_t ci = static_cast<size_t>(y / 2) * l1.w + x / 2;
      l1.wt[ci] += 1.f;
      for (int k = 0; k < channels; ++k) l1.sum[ci * channels + k] += value(fi, k);
    }
  }
  if (!any) return false;
  auto normalise = [channels](Level& c) {
    // Averages with weight min(1, w), so that sparse data does not dominate.
    for (size_t i = 0; i < c.wt.size(); ++i) {
      if (c.wt[i] > 0.f) {
        const float s = std::min(1.f, c.wt[i]) / c.wt[i];
        for (int k = 0; k < channels; ++k) c.sum[i * channels + k] *= s;
        c.wt[i] = std::min(1.f, c.wt[i]);
      }
    }
  };
  normalise(l1);
  levels.push_back(std::move(l1));
  // Push: 2x2 sums down to 1x1.
  while (levels.back().w > 1 || levels.back().h > 1) {
    const Level& f = levels.back();
    Level c{(f.w + 1) / 2, (f.h + 1) / 2, {}, {}};
    c.sum.assign(static_cast<size_t>(c.w) * c.h * channels, 0.f);
    c.wt.assign(static_cast<size_t>(c.w) * c.h, 0.f);
    for (int y = 0; y < f.h; ++y) {
      for (int x = 0; x < f.w; ++x) {
        const size_t fi = static_cast<size_t>(y) * f.w + x;
        const size_t ci = static_cast<size_t>(y / 2) * c.w + x / 2;
        c.wt[ci] += f.wt[fi];
        for (int k = 0; k < channels; ++k) c.sum[ci * channels + k] += f.sum[fi * channels + k];
      }
    }
    normalise(c);
    levels.push_back(std::move(c));
  }
  // Pull: every level holds premultiplied values (sum = average * alpha, wt = alpha <= 1); the
  // missing part (1 - alpha) comes from the coarser level, which is already complete.
  {
    Level& top = levels.back();
    for (size_t i = 0; i < top.wt.size(); ++i) {
      if (top.wt[i] > 0.f)
        for (int k = 0; k < channels; ++k) top.sum[i * channels + k] /= top.wt[i];
      top.wt[i] = 1.f;
    }
  }
  std::array<float, kMaxChannels> parent{};
  for (int li = static_cast<int>(levels.size()) - 2; li >= 0; --li) {
    Level& f = levels[li];
    const Level& c = levels[li + 1];
    for (int y = 0; y < f.h; ++y) {
      for (int x = 0; x < f.w; ++x) {
        const size_t fi = static_cast<size_t>(y) * f.w + x;
        const float rest = 1.f - std::min(1.f, f.wt[fi]);
        f.wt[fi] = 1.f;
        if (rest <= 0.f) continue;
        ReadParent<kMaxChannels>(c, channels, x, y, filter, parent);
        for (int k = 0; k < channels; ++k) f.sum[fi * channels + k] += rest * parent[k];
      }
    }
  }
  // Level 0: an unknown pixel takes level 1's value (its own alpha is 0).
  const Level& l1f = levels[0];
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const size_t i = static_cast<size_t>(y) * width + x;
      if (known(i)) continue;
      ReadParent<kMaxChannels>(l1f, channels, x, y, filter, parent);
      for (int k = 0; k < channels; ++k) write(i, k, parent[k]);
    }
  }
  return true;
}

}  // namespace exo::image_fill_internal
