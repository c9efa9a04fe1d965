#include "common/image_fill.h"

#include <algorithm>
#include <array>
#include <vector>

namespace exo {
namespace {

struct Level {
  int w = 0, h = 0;
  std::vector<float> sum;  // premultiplied values, channels per pixel
  std::vector<float> wt;   // alpha in [0, 1]
};

}  // namespace

bool PushPullFill(std::span<float> data, int channels, std::span<const uint8_t> known, int width,
                  int height, PullFilter filter) {
  EXO_CHECK(channels > 0 && width > 0 && height > 0);
  const size_t n = static_cast<size_t>(width) * height;
  EXO_CHECK(data.size() == n * channels && known.size() == n);
  std::vector<Level> levels;
  Level l0{width, height, std::vector<float>(n * channels, 0.f), std::vector<float>(n, 0.f)};
  bool any = false;
  for (size_t i = 0; i < n; ++i) {
    if (!known[i]) continue;
    any = true;
    l0.wt[i] = 1.f;
    for (int c = 0; c < channels; ++c) l0.sum[i * channels + c] = data[i * channels + c];
  }
  if (!any) return false;
  levels.push_back(std::move(l0));
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
    // Normalise to averages with weight min(1, w) so that sparse data does not dominate.
    for (size_t i = 0; i < c.wt.size(); ++i) {
      if (c.wt[i] > 0.f) {
        const float s = std::min(1.f, c.wt[i]) / c.wt[i];
        for (int k = 0; k < channels; ++k) c.sum[i * channels + k] *= s;
        c.wt[i] = std::min(1.f, c.wt[i]);
      }
    }
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
  std::vector<float> parent(channels);
  for (int li = static_cast<int>(levels.size()) - 2; li >= 0; --li) {
    Level& f = levels[li];
    const Level& c = levels[li + 1];
    for (int y = 0; y < f.h; ++y) {
      for (int x = 0; x < f.w; ++x) {
        const size_t fi = static_cast<size_t>(y) * f.w + x;
        const float rest = 1.f - std::min(1.f, f.wt[fi]);
        f.wt[fi] = 1.f;
        if (rest <= 0.f) continue;
        if (filter == PullFilter::kNearest) {
          const size_t ci = static_cast<size_t>(y / 2) * c.w + x / 2;
          for (int k = 0; k < channels; ++k) parent[k] = c.sum[ci * channels + k];
        } else {
          // Pixel centres: fine (x + 0.5) sits at coarse (x + 0.5) / 2 - 0.5.
          const float cx = std::clamp((x + 0.5f) * 0.5f - 0.5f, 0.f, float(c.w - 1));
          const float cy = std::clamp((y + 0.5f) * 0.5f - 0.5f, 0.f, float(c.h - 1));
          const int x0 = static_cast<int>(cx), y0 = static_cast<int>(cy);
          const int x1 = std::min(x0 + 1, c.w - 1), y1 = std::min(y0 + 1, c.h - 1);
          const float ax = cx - x0, ay = cy - y0;
          const std::array<size_t, 4> idx{static_cast<size_t>(y0) * c.w + x0,
                                           static_cast<size_t>(y0) * c.w + x1,
                                           static_cast<size_t>(y1) * c.w + x0,
                                           static_cast<size_t>(y1) * c.w + x1};
          const std::array<float, 4> wgt{(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay};
          for (int k = 0; k < channels; ++k) {
            float v = 0.f;
            for (int j = 0; j < 4; ++j) v += wgt[j] * c.sum[idx[j] * channels + k];
            parent[k] = v;
          }
        }
        for (int k = 0; k < channels; ++k) f.sum[fi * channels + k] += rest * parent[k];
      }
    }
  }
  const Level& top = levels[0];
  for (size_t i = 0; i < n; ++i) {
    if (known[i]) continue;
    for (int k = 0; k < channels; ++k) data[i * channels + k] = top.sum[i * channels + k];
  }
  return true;
}

}  // namespace exo
