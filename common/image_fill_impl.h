// Internal: the push-pull core behind PushPullFill and FillHoles (lumigraph), templated on how
// level 0 is read and written so that callers with another pixel format (RGB8 frames) do not
// convert the whole image first. Level 0 is never materialised: level 1 is summed straight from
// the input, and only the unknown pixels of level 0 are pulled. Not a public header.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
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

// The same fill as PushPull with PullFilter::kBilinear, bit for bit, computing only what the
// unknown pixels read: a pixel's value is the bilinear pull of level 1 around it; a cell with
// alpha 1 is its own (normalised) push, which needs only its own block of pixels; only a cell
// with alpha 0 reads the next coarser level. (Every alpha is 0 or 1 here: level 1 counts known
// pixels clipped to 1, and every coarser level sums clipped 0/1 alphas and clips again, so
// rest = 1 - alpha is 0 or 1 and the pull of an alpha-0 cell is exactly its parent's bilinear
// value.) Cells are evaluated lazily, each at most once per level, with the additions in the
// same order as PushPull, so the values are identical; the cost follows the holes, not the
// frame. `unknown` lists the pixels with !known, in any order; known(i) must hold for at least
// one pixel (else PushPull's "nothing known" case).
template <int kMaxChannels, typename Known, typename Value, typename Write>
void PushPullSparseBilinear(int width, int height, int channels, Known known, Value value,
                            Write write, const std::vector<size_t>& unknown) {
  if (width == 1 && height == 1) return;
  using Px = std::array<float, kMaxChannels>;
  using PxA = std::array<float, kMaxChannels + 1>;  // channels, then alpha
  // The evaluated cells in one open-addressing table keyed by (level, cell index): its size
  // follows the holes (a dense array per level would be touched page by page).
  struct Cell {
    uint64_t key = ~uint64_t{0};
    uint8_t state = 0;  // bit 0: push evaluated, bit 1: pull evaluated
    PxA pushed{};
    Px pulled{};
  };
  struct Sparse {
    int width, height, channels;
    Known& known;
    Value& value;
    std::vector<std::pair<int, int>> dims;  // dims[li]: level li + 1
    int top = 0;
    std::vector<Cell> table;
    size_t used = 0;

    static uint64_t Hash(uint64_t k) {
      k ^= k >> 33;
      k *= 0xff51afd7ed558ccdULL;
      k ^= k >> 33;
      return k;
    }
    Cell& Find(int li, int x, int y) {
      const uint64_t key =
          (uint64_t(li) << 56) | (uint64_t(y) * uint64_t(dims[li].first) + uint64_t(x));
      if (2 * (used + 1) > table.size()) {  // grow: load <= 1/2
        std::vector<Cell> old(table.size() * 2);
        old.swap(table);
        used = 0;
        for (const Cell& c : old)
          if (c.key != ~uint64_t{0}) Place(c);
      }
      const size_t mask = table.size() - 1;
      for (size_t h = Hash(key) & mask;; h = (h + 1) & mask) {
        if (table[h].key == key) return table[h];
        if (table[h].key == ~uint64_t{0}) {
          table[h].key = key;
          ++used;
          return table[h];
        }
      }
    }
    void Place(const Cell& c) {
      const size_t mask = table.size() - 1;
      size_t h = Hash(c.key) & mask;
      while (table[h].key != ~uint64_t{0}) h = (h + 1) & mask;
      table[h] = c;
      ++used;
    }
    void Normalise(PxA& p) const {
      float& wt = p[channels];
      if (wt > 0.f) {
        const float s = std::min(1.f, wt) / wt;
        for (int k = 0; k < channels; ++k) p[k] *= s;
        wt = std::min(1.f, wt);
      }
    }
    // Push of cell (x, y) of level 1 from its pixels (not memoised: 4 reads).
    PxA Pushed0(int x, int y) const {
      PxA p{};
      for (int fy = 2 * y; fy <= 2 * y + 1 && fy < height; ++fy) {
        for (int fx = 2 * x; fx <= 2 * x + 1 && fx < width; ++fx) {
          const size_t fi = static_cast<size_t>(fy) * width + fx;
          if (!known(fi)) continue;
          p[channels] += 1.f;
          for (int k = 0; k < channels; ++k) p[k] += value(fi, k);
        }
      }
      Normalise(p);
      return p;
    }
    // Push of cell (x, y) of level li + 1: the 2x2 children in row order, as PushPull adds them.
    PxA Pushed(int li, int x, int y) {
      if (li == 0) return Pushed0(x, y);
      {
        const Cell& c = Find(li, x, y);
        if (c.state & 1) return c.pushed;
      }
      PxA p{};
      for (int fy = 2 * y; fy <= 2 * y + 1; ++fy) {
        for (int fx = 2 * x; fx <= 2 * x + 1; ++fx) {
          if (fx >= dims[li - 1].first || fy >= dims[li - 1].second) continue;
          const PxA c = Pushed(li - 1, fx, fy);
          p[channels] += c[channels];
          for (int k = 0; k < channels; ++k) p[k] += c[k];
        }
      }
      Normalise(p);
      Cell& c = Find(li, x, y);  // again: the recursion may have grown the table
      c.pushed = p;
      c.state |= 1;
      return p;
    }
    // Value of cell (x, y) of level li + 1 after the pull (the top: its push over its alpha).
    Px Pulled(int li, int x, int y) {
      if (li == 0 && li != top) {  // the usual case, a level-1 cell with a known pixel: no memo
        const PxA p = Pushed0(x, y);
        if (1.f - std::min(1.f, p[channels]) <= 0.f) {
          Px out{};
          for (int k = 0; k < channels; ++k) out[k] = p[k];
          return out;
        }
      }
      {
        const Cell& c = Find(li, x, y);
        if (c.state & 2) return c.pulled;
      }
      const PxA p = Pushed(li, x, y);
      Px out{};
      for (int k = 0; k < channels; ++k) out[k] = p[k];
      if (li == top) {
        if (p[channels] > 0.f)
          for (int k = 0; k < channels; ++k) out[k] /= p[channels];
      } else {
        const float rest = 1.f - std::min(1.f, p[channels]);
        if (rest > 0.f) {
          const Px parent = ReadParent(li + 1, x, y);
          for (int k = 0; k < channels; ++k) out[k] += rest * parent[k];
        }
      }
      Cell& c = Find(li, x, y);
      c.pulled = out;
      c.state |= 2;
      return out;
    }
    // ReadParent (bilinear) of the pulled level cli + 1 for (x, y) of the level below it.
    Px ReadParent(int cli, int x, int y) {
      const int cw = dims[cli].first, ch = dims[cli].second;
      const float cx = std::clamp((x + 0.5f) * 0.5f - 0.5f, 0.f, float(cw - 1));
      const float cy = std::clamp((y + 0.5f) * 0.5f - 0.5f, 0.f, float(ch - 1));
      const int x0 = static_cast<int>(cx), y0 = static_cast<int>(cy);
      const int x1 = std::min(x0 + 1, cw - 1), y1 = std::min(y0 + 1, ch - 1);
      const float ax = cx - x0, ay = cy - y0;
      const float w00 = (1 - ax) * (1 - ay), w01 = ax * (1 - ay), w10 = (1 - ax) * ay,
                  w11 = ax * ay;
      const Px s00 = Pulled(cli, x0, y0);
      const Px s01 = Pulled(cli, x1, y0);
      const Px s10 = Pulled(cli, x0, y1);
      const Px s11 = Pulled(cli, x1, y1);
      Px out{};
      for (int k = 0; k < channels; ++k)
        out[k] = w00 * s00[k] + w01 * s01[k] + w10 * s10[k] + w11 * s11[k];
      return out;
    }
  };
  Sparse sp{width, height, channels, known, value, {}, 0, {}, 0};
  for (int w = (width + 1) / 2, h = (height + 1) / 2;; w = (w + 1) / 2, h = (h + 1) / 2) {
    sp.dims.emplace_back(w, h);
    if (w == 1 && h == 1) break;
  }
  sp.top = static_cast<int>(sp.dims.size()) - 1;
  sp.table.resize(1024);  // grows with the cells that need a coarser level
  for (size_t i : unknown) {
    const Px px = sp.ReadParent(0, static_cast<int>(i % width), static_cast<int>(i / width));
    for (int k = 0; k < channels; ++k) write(i, k, px[k]);
  }
}

}  // namespace exo::image_fill_internal
