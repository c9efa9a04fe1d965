#include "server/inpainting/inpaint.h"

#include "server/inpainting/parallel_rows.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <limits>
#include <thread>
#include <vector>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "server/inpainting/depth_maps.h"
#include "server/inpainting/graph_cut.h"
#include "server/inpainting/poisson.h"

namespace exo::inpaint {
namespace {

using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}
double CpuMs() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

// splitmix64: the per-(seed, level, iteration, pixel) random stream.
inline uint64_t Mix(uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}
struct Rng {
  uint64_t s;
  Rng(uint64_t seed, int level, int iter, int pixel)
      : s(Mix(seed ^ Mix((static_cast<uint64_t>(level + 1) << 48) ^
                         (static_cast<uint64_t>(iter + 7) << 32) ^
                         static_cast<uint32_t>(pixel)))) {}
  uint32_t Next() {
    s = Mix(s);
    return static_cast<uint32_t>(s >> 32);
  }
  int Uniform(int n) { return static_cast<int>((static_cast<uint64_t>(Next()) * n) >> 32); }
};

// One pyramid level of the search.
struct Level {
  int w = 0, h = 0;
  std::vector<uint8_t> color;   // RGB, T holds the current estimate
  std::vector<float> normal;    // xyz, T holds the current estimate
  std::vector<uint8_t> target;  // T
  std::vector<uint8_t> data_ok; // outside T with a valid normal (and depth at level 0)
  std::vector<uint8_t> source_ok;  // valid 5x5 patch centre
  std::vector<uint8_t> fixed;      // source kept (propagated from the previous keyframe)
  std::vector<int32_t> src;        // 2 per pixel, for T
  std::vector<int32_t> src_list;   // all source_ok pixel indices
  std::vector<int> row_x0, row_x1; // per row: first/last target column (x0 > x1: none)
  size_t Idx(int x, int y) const { return static_cast<size_t>(y) * w + x; }
};

void FinishLevel(Level& L) {
  const int w = L.w, h = L.h;
  // Integral image of "not usable as patch data".
  std::vector<int> integral(static_cast<size_t>(w + 1) * (h + 1), 0);
  for (int y = 0; y < h; ++y) {
    int run = 0;
    for (int x = 0; x < w; ++x) {
      run += L.data_ok[L.Idx(x, y)] ? 0 : 1;
      integral[static_cast<size_t>(y + 1) * (w + 1) + x + 1] =
          integral[static_cast<size_t>(y) * (w + 1) + x + 1] + run;
    }
  }
  L.source_ok.assign(static_cast<size_t>(w) * h, 0);
  L.src_list.clear();
  for (int y = 2; y + 2 < h; ++y) {
    for (int x = 2; x + 2 < w; ++x) {
      const int x0 = x - 2, y0 = y - 2, x1 = x + 3, y1 = y + 3;
      const int bad = integral[static_cast<size_t>(y1) * (w + 1) + x1] -
                      integral[static_cast<size_t>(y0) * (w + 1) + x1] -
                      integral[static_cast<size_t>(y1) * (w + 1) + x0] +
                      integral[static_cast<size_t>(y0) * (w + 1) + x0];
      if (bad == 0) {
        L.source_ok[L.Idx(x, y)] = 1;
        L.src_list.push_back(static_cast<int32_t>(L.Idx(x, y)));
      }
    }
  }
  L.row_x0.assign(h, w);
  L.row_x1.assign(h, -1);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (L.target[L.Idx(x, y)]) {
        L.row_x0[y] = std::min(L.row_x0[y], x);
        L.row_x1[y] = x;
      }
    }
  }
  if (L.src.size() != static_cast<size_t>(w) * h * 2) L.src.assign(static_cast<size_t>(w) * h * 2, -1);
  if (L.fixed.size() != static_cast<size_t>(w) * h) L.fixed.assign(static_cast<size_t>(w) * h, 0);
}

// Coarser level: T is any-of-2x2 (so 1-px slivers survive), colour and normals averaged over
// the pixels outside T.
Level Downsample(const Level& f) {
  Level c;
  c.w = (f.w + 1) / 2;
  c.h = (f.h + 1) / 2;
  const size_t n = static_cast<size_t>(c.w) * c.h;
  c.color.assign(n * 3, 0);
  c.normal.assign(n * 3, 0.f);
  c.target.assign(n, 0);
  c.data_ok.assign(n, 0);
  for (int y = 0; y < c.h; ++y) {
    for (int x = 0; x < c.w; ++x) {
      int col[3] = {0, 0, 0}, cnt = 0, nok = 0;
      float nrm[3] = {0, 0, 0};
      bool tgt = false, all_ok = true;
      for (int dy = 0; dy < 2; ++dy) {
        for (int dx = 0; dx < 2; ++dx) {
          const int fx = 2 * x + dx, fy = 2 * y + dy;
          if (fx >= f.w || fy >= f.h) continue;
          const size_t fi = f.Idx(fx, fy);
          if (f.target[fi]) tgt = true;
          if (!f.data_ok[fi]) all_ok = false;
          for (int k = 0; k < 3; ++k) col[k] += f.color[fi * 3 + k];
          ++cnt;
          const float* fn = &f.normal[fi * 3];
          if (fn[0] != 0.f || fn[1] != 0.f || fn[2] != 0.f) {
            for (int k = 0; k < 3; ++k) nrm[k] += fn[k];
            ++nok;
          }
        }
      }
      const size_t ci = c.Idx(x, y);
      c.target[ci] = tgt;
      for (int k = 0; k < 3; ++k) c.color[ci * 3 + k] = static_cast<uint8_t>((col[k] + cnt / 2) / cnt);
      const float len = std::sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
      if (nok > 0 && len > 1e-6f) {
        for (int k = 0; k < 3; ++k) c.normal[ci * 3 + k] = nrm[k] / len;
      }
      c.data_ok[ci] = !tgt && all_ok && nok > 0 && len > 1e-6f;
    }
  }
  FinishLevel(c);
  return c;
}

struct SearchParams {
  float w, one_minus_w, kappa, cap;
  bool geometry;
  bool peel_measured_normals_only;  // onion peel: rho_g over window pixels outside T only
};

}  // namespace

FusedGradient FuseGradientSamples(bool has1, float g1, float ref1, bool has2, float g2, float ref2,
                                  const InpaintOptions& options) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  if (!has1 && !has2) return {nan, 1.f};
  if (options.gradient_fusion == GradientFusion::kMean) {
    return {has1 && has2 ? 0.5f * (g1 + g2) : has1 ? g1 : g2, 1.f};
  }
  const float rel = static_cast<float>(options.jump_rel);
  // Jump test relative to the value the sample starts from (scale-invariant, any domain).
  const bool jump1 = has1 && std::fabs(g1) > rel * std::fabs(ref1);
  const bool jump2 = has2 && std::fabs(g2) > rel * std::fabs(ref2);
  float g;
  bool jump;
  if (has1 && has2) {
    if (jump1 != jump2) {
      g = jump1 ? g2 : g1;  // the other sample crossed a discontinuity at its source
      jump = false;
    } else if (std::fabs(g1 - g2) > rel * std::min(std::fabs(ref1), std::fabs(ref2))) {
      const bool first = std::fabs(g1) < std::fabs(g2);  // disagreeing: the smaller one
      g = first ? g1 : g2;
      jump = first ? jump1 : jump2;
    } else {
      g = 0.5f * (g1 + g2);
      jump = jump1 && jump2;
    }
  } else {
    g = has1 ? g1 : g2;
    jump = has1 ? jump1 : jump2;
  }
  return {g, jump ? static_cast<float>(options.jump_weight) : 1.f};
}

float GeometryCost(const float* a, const float* b, int count, float kappa) {
  if (count <= 0) return 1.f;
  float s = 0.f;
  for (int i = 0; i < count; ++i) {
    const float d = a[3 * i] * b[3 * i] + a[3 * i + 1] * b[3 * i + 1] + a[3 * i + 2] * b[3 * i + 2];
    s += 1.f / std::max(kappa, d);  // kappa guard: opposite/zero normals never divide by <= 0
  }
  return s / count;
}

namespace {

// Cost (4.7) of mapping target pixel (x, y) to source (sx, sy); returns +inf as soon as a lower
// bound exceeds `best`.
inline float Cost(const Level& L, int x, int y, int sx, int sy, float best, const SearchParams& p) {
  // rho_s (4.9): capped squared incoherence with the 4 neighbours' sources; a neighbour outside
  // T maps to itself, which pulls the border towards continuity.
  float rs = 0.f;
  int ns = 0;
  static constexpr int kDx[4] = {-1, 1, 0, 0}, kDy[4] = {0, 0, -1, 1};
  for (int k = 0; k < 4; ++k) {
    const int nx = x + kDx[k], ny = y + kDy[k];
    if (nx < 0 || ny < 0 || nx >= L.w || ny >= L.h) continue;
    const size_t ni = L.Idx(nx, ny);
    int fx = nx, fy = ny;
    if (L.target[ni]) {
      fx = L.src[ni * 2];
      fy = L.src[ni * 2 + 1];
      if (fx < 0) continue;
    }
    const float ex = static_cast<float>(sx + kDx[k] - fx), ey = static_cast<float>(sy + kDy[k] - fy);
    rs += std::min(p.cap, ex * ex + ey * ey);
    ++ns;
  }
  if (ns > 0) rs /= ns;
  const float spatial = p.one_minus_w * rs;
  if (spatial >= best) return std::numeric_limits<float>::infinity();
  // rho_t (4.8): mean squared colour difference over the 5x5 window (inside the image).
  const int y0 = std::max(0, y - 2), y1 = std::min(L.h - 1, y + 2);
  const int x0 = std::max(0, x - 2), x1 = std::min(L.w - 1, x + 2);
  const float inv_n = 1.f / (3.f * (y1 - y0 + 1) * (x1 - x0 + 1));
  const float budget = (best - spatial) / (p.w * inv_n);  // in raw SSD units (rho_g >= 1)
  int ssd = 0;
  const int dxs = sx - x, dys = sy - y;
  for (int yy = y0; yy <= y1; ++yy) {
    const uint8_t* a = &L.color[L.Idx(x0, yy) * 3];
    const uint8_t* b = &L.color[L.Idx(x0 + dxs, yy + dys) * 3];
    const int n = (x1 - x0 + 1) * 3;
    for (int i = 0; i < n; ++i) {
      const int d = static_cast<int>(a[i]) - static_cast<int>(b[i]);
      ssd += d * d;
    }
    if (static_cast<float>(ssd) >= budget) return std::numeric_limits<float>::infinity();
  }
  const float rho_t = ssd * inv_n;
  float rho_g = 1.f;
  if (p.geometry) {
    // rho_g (4.10) on a 3x3 lattice at 2 px spacing covering the same window.
    float s = 0.f;
    int cnt = 0;
    for (int dy = -2; dy <= 2; dy += 2) {
      const int yy = y + dy;
      if (yy < 0 || yy >= L.h) continue;
      for (int dx = -2; dx <= 2; dx += 2) {
        const int xx = x + dx;
        if (xx < 0 || xx >= L.w) continue;
        const float* na = &L.normal[L.Idx(xx, yy) * 3];
        const float* nb = &L.normal[L.Idx(sx + dx, sy + dy) * 3];
        const float d = na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2];
        s += 1.f / std::max(p.kappa, d);
        ++cnt;
      }
    }
    rho_g = s / cnt;
  }
  return p.w * rho_t * rho_g + spatial;
}

// Runs fn(band) for the bands of one phase on `threads` threads. Bands of a phase never share
// a row or a row's direct neighbours' writes, so the outcome does not depend on `threads`.
template <typename Fn>
void ForBands(int num_bands, int phase, int threads, const Fn& fn) {
  std::vector<int> bands;
  for (int b = phase; b < num_bands; b += 2) bands.push_back(b);
  const int t_count = std::max(1, std::min<int>(threads, static_cast<int>(bands.size())));
  auto worker = [&](int t) {
    for (size_t i = t; i < bands.size(); i += t_count) fn(bands[i]);
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < t_count; ++t) pool.emplace_back(worker, t);
  worker(0);
  for (auto& th : pool) th.join();
}

// Copies colour and normals of T from the sources (4.11-4.12); sources lie outside T.
void CopyFromSources(Level& L, int threads) {
  ParallelRows(L.h, threads, [&](int y) {
    for (int x = L.row_x0[y]; x <= L.row_x1[y]; ++x) {
      const size_t i = L.Idx(x, y);
      if (!L.target[i] || L.src[i * 2] < 0) continue;
      const size_t s = L.Idx(L.src[i * 2], L.src[i * 2 + 1]);
      for (int k = 0; k < 3; ++k) {
        L.color[i * 3 + k] = L.color[s * 3 + k];
        L.normal[i * 3 + k] = L.normal[s * 3 + k];
      }
    }
  });
}

// One PatchMatch sweep (propagation + random search) over T. Returns how many pixels changed
// their source (a per-band count, summed in band order: deterministic).
int Sweep(Level& L, int level, int iter, int radius0, bool global_candidate, const SearchParams& p,
          const InpaintOptions& o) {
  const int band_rows = o.band_rows;
  const int num_bands = (L.h + band_rows - 1) / band_rows;
  std::vector<int> changed(num_bands, 0);
  const bool forward = (iter % 2) == 0;
  const int d = forward ? 1 : -1;
  for (int phase = 0; phase < 2; ++phase) {
    ForBands(num_bands, phase, o.num_threads, [&](int band) {
      const int ya = band * band_rows, yb = std::min(L.h, ya + band_rows) - 1;
      for (int yi = 0; yi <= yb - ya; ++yi) {
        const int y = forward ? ya + yi : yb - yi;
        if (L.row_x0[y] > L.row_x1[y]) continue;
        for (int xi = L.row_x0[y]; xi <= L.row_x1[y]; ++xi) {
          const int x = forward ? xi : L.row_x0[y] + L.row_x1[y] - xi;
          const size_t i = L.Idx(x, y);
          if (!L.target[i] || L.fixed[i]) continue;
          int bx = L.src[i * 2], by = L.src[i * 2 + 1];
          float best = Cost(L, x, y, bx, by, std::numeric_limits<float>::infinity(), p);
          auto consider = [&](int cx, int cy) {
            if (cx < 0 || cy < 0 || cx >= L.w || cy >= L.h) return;
            if (!L.source_ok[L.Idx(cx, cy)] || (cx == bx && cy == by)) return;
            const float c = Cost(L, x, y, cx, cy, best, p);
            if (c < best) {
              best = c;
              bx = cx;
              by = cy;
            }
          };
          // Propagation from the already visited neighbours (left/up or right/down).
          {
            const int nx = x - d;
            if (nx >= 0 && nx < L.w) {
              const size_t ni = L.Idx(nx, y);
              if (L.target[ni] && L.src[ni * 2] >= 0) consider(L.src[ni * 2] + d, L.src[ni * 2 + 1]);
            }
            const int ny = y - d;
            if (ny >= 0 && ny < L.h) {
              const size_t ni = L.Idx(x, ny);
              if (L.target[ni] && L.src[ni * 2] >= 0) consider(L.src[ni * 2], L.src[ni * 2 + 1] + d);
            }
          }
          // Random search around the current best, radius halving.
          Rng rng(o.seed, level, iter, static_cast<int>(i));
          if (global_candidate && !L.src_list.empty()) {
            const int s = L.src_list[rng.Uniform(static_cast<int>(L.src_list.size()))];
            consider(s % L.w, s / L.w);
          }
          for (int r = radius0; r >= 1; r /= 2) {
            const int cx = bx + rng.Uniform(2 * r + 1) - r;
            const int cy = by + rng.Uniform(2 * r + 1) - r;
            consider(cx, cy);
          }
          if (bx != L.src[i * 2] || by != L.src[i * 2 + 1]) ++changed[band];
          L.src[i * 2] = bx;
          L.src[i * 2 + 1] = by;
        }
      }
    });
  }
  int total = 0;
  for (int c : changed) total += c;
  return total;
}

// Cost (4.7) restricted to the window pixels already known (outside T or filled earlier):
// the onion-peel initialisation of the coarsest level. With peel_measured_normals_only, rho_g
// uses only the window pixels outside T.
float CostKnown(const Level& L, const std::vector<uint8_t>& known, int x, int y, int sx, int sy,
                const SearchParams& p) {
  float rs = 0.f;
  int ns = 0;
  static constexpr int kDx[4] = {-1, 1, 0, 0}, kDy[4] = {0, 0, -1, 1};
  for (int k = 0; k < 4; ++k) {
    const int nx = x + kDx[k], ny = y + kDy[k];
    if (nx < 0 || ny < 0 || nx >= L.w || ny >= L.h) continue;
    const size_t ni = L.Idx(nx, ny);
    if (!known[ni]) continue;
    const int fx = L.target[ni] ? L.src[ni * 2] : nx, fy = L.target[ni] ? L.src[ni * 2 + 1] : ny;
    const float ex = static_cast<float>(sx + kDx[k] - fx), ey = static_cast<float>(sy + kDy[k] - fy);
    rs += std::min(p.cap, ex * ex + ey * ey);
    ++ns;
  }
  if (ns > 0) rs /= ns;
  int ssd = 0, n = 0;
  float g = 0.f;
  int ng = 0;
  for (int dy = -2; dy <= 2; ++dy) {
    const int yy = y + dy;
    if (yy < 0 || yy >= L.h) continue;
    for (int dx = -2; dx <= 2; ++dx) {
      const int xx = x + dx;
      if (xx < 0 || xx >= L.w || !known[L.Idx(xx, yy)]) continue;
      const size_t a = L.Idx(xx, yy), b = L.Idx(sx + dx, sy + dy);
      for (int k = 0; k < 3; ++k) {
        const int d = static_cast<int>(L.color[a * 3 + k]) - static_cast<int>(L.color[b * 3 + k]);
        ssd += d * d;
      }
      n += 3;
      // rho_g against the measured normals of the window only (optionally): the normals the
      // peel has copied into T so far would otherwise reinforce its own earlier choices.
      if (p.geometry && (dx % 2 == 0) && (dy % 2 == 0) &&
          !(p.peel_measured_normals_only && L.target[a])) {
        const float* na = &L.normal[a * 3];
        const float* nb = &L.normal[b * 3];
        g += 1.f / std::max(p.kappa, na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2]);
        ++ng;
      }
    }
  }
  const float rho_t = n ? static_cast<float>(ssd) / n : 0.f;
  const float rho_g = ng ? g / ng : 1.f;
  return p.w * rho_t * rho_g + p.one_minus_w * rs;
}

// Onion-peel initialisation: rings of T from the border inwards, each pixel matched against
// the known part of its window (exhaustive over up to 4096 sources plus the shifted sources of
// its known neighbours), then its colour and normal filled in before the next ring.
void OnionPeelInit(Level& L, int level, const SearchParams& p, const InpaintOptions& o) {
  const size_t n = static_cast<size_t>(L.w) * L.h;
  std::vector<uint8_t> known(n);
  for (size_t i = 0; i < n; ++i) known[i] = !L.target[i];
  std::vector<int> ring;
  const int ns = static_cast<int>(L.src_list.size());
  const int max_cand = 4096;
  static constexpr int kDx[4] = {-1, 1, 0, 0}, kDy[4] = {0, 0, -1, 1};
  for (int round = 0;; ++round) {
    ring.clear();
    for (int y = 0; y < L.h; ++y) {
      for (int x = L.row_x0[y]; x <= L.row_x1[y]; ++x) {
        const size_t i = L.Idx(x, y);
        if (!L.target[i] || known[i]) continue;
        for (int k = 0; k < 4; ++k) {
          const int nx = x + kDx[k], ny = y + kDy[k];
          if (nx >= 0 && ny >= 0 && nx < L.w && ny < L.h && known[L.Idx(nx, ny)]) {
            ring.push_back(static_cast<int>(i));
            break;
          }
        }
      }
    }
    if (ring.empty()) break;
    std::vector<int32_t> choice(ring.size() * 2);
    ParallelRows(static_cast<int>(ring.size()), o.num_threads, [&](int r) {
      const int i = ring[r], x = i % L.w, y = i / L.w;
      float best = std::numeric_limits<float>::infinity();
      int bx = -1, by = -1;
      auto consider = [&](int cx, int cy) {
        if (cx < 0 || cy < 0 || cx >= L.w || cy >= L.h || !L.source_ok[L.Idx(cx, cy)]) return;
        const float c = CostKnown(L, known, x, y, cx, cy, p);
        if (c < best) {
          best = c;
          bx = cx;
          by = cy;
        }
      };
      for (int k = 0; k < 4; ++k) {
        const int nx = x + kDx[k], ny = y + kDy[k];
        if (nx < 0 || ny < 0 || nx >= L.w || ny >= L.h) continue;
        const size_t ni = L.Idx(nx, ny);
        if (known[ni] && L.target[ni]) consider(L.src[ni * 2] - kDx[k], L.src[ni * 2 + 1] - kDy[k]);
      }
      if (ns <= max_cand) {
        for (int s : L.src_list) consider(s % L.w, s / L.w);
      } else {
        Rng rng(o.seed, level, -4 - round, i);
        for (int c = 0; c < max_cand; ++c) {
          const int s = L.src_list[rng.Uniform(ns)];
          consider(s % L.w, s / L.w);
        }
      }
      choice[r * 2] = bx;
      choice[r * 2 + 1] = by;
    });
    for (size_t r = 0; r < ring.size(); ++r) {
      const size_t i = ring[r];
      L.src[i * 2] = choice[r * 2];
      L.src[i * 2 + 1] = choice[r * 2 + 1];
      const size_t s = L.Idx(choice[r * 2], choice[r * 2 + 1]);
      for (int k = 0; k < 3; ++k) {
        L.color[i * 3 + k] = L.color[s * 3 + k];
        L.normal[i * 3 + k] = L.normal[s * 3 + k];
      }
      known[i] = 1;
    }
  }
}

// Random source for every unmapped, unfixed pixel of T.
void RandomInit(Level& L, int level, uint64_t seed) {
  const int n = static_cast<int>(L.src_list.size());
  for (int y = 0; y < L.h; ++y) {
    for (int x = L.row_x0[y]; x <= L.row_x1[y]; ++x) {
      const size_t i = L.Idx(x, y);
      if (!L.target[i] || L.fixed[i]) continue;
      Rng rng(seed, level, -1, static_cast<int>(i));
      const int s = L.src_list[rng.Uniform(n)];
      L.src[i * 2] = s % L.w;
      L.src[i * 2 + 1] = s / L.w;
    }
  }
}

// Push-pull estimate of colour and normals inside T (the starting image of the coarsest level).
void SmoothFillTarget(Level& L) {
  const size_t n = static_cast<size_t>(L.w) * L.h;
  std::vector<uint8_t> known(n);
  for (size_t i = 0; i < n; ++i) known[i] = !L.target[i];
  std::vector<float> col(n * 3);
  for (size_t i = 0; i < n * 3; ++i) col[i] = L.color[i];
  PushPullFill(col, 3, known, L.w, L.h);
  std::vector<float> nrm = L.normal;
  PushPullFill(nrm, 3, known, L.w, L.h);
  for (size_t i = 0; i < n; ++i) {
    if (!L.target[i]) continue;
    for (int k = 0; k < 3; ++k) {
      L.color[i * 3 + k] = static_cast<uint8_t>(std::clamp(std::lround(col[i * 3 + k]), 0L, 255L));
    }
    const float len = std::sqrt(nrm[i * 3] * nrm[i * 3] + nrm[i * 3 + 1] * nrm[i * 3 + 1] +
                                nrm[i * 3 + 2] * nrm[i * 3 + 2]);
    for (int k = 0; k < 3; ++k) L.normal[i * 3 + k] = len > 1e-6f ? nrm[i * 3 + k] / len : 0.f;
  }
}

// Coarse -> fine: f(u) = 2 f(u/2) + (u mod 2) where valid, else the nearest valid of the four
// children, else random.
void Upsample(const Level& c, Level& f, int level, uint64_t seed) {
  const int n = static_cast<int>(f.src_list.size());
  for (int y = 0; y < f.h; ++y) {
    for (int x = f.row_x0[y]; x <= f.row_x1[y]; ++x) {
      const size_t i = f.Idx(x, y);
      if (!f.target[i] || f.fixed[i]) continue;
      const size_t ci = c.Idx(x / 2, y / 2);
      bool done = false;
      if (c.target[ci] && c.src[ci * 2] >= 0) {
        const int bx = 2 * c.src[ci * 2], by = 2 * c.src[ci * 2 + 1];
        const int order[4][2] = {{x & 1, y & 1}, {1 - (x & 1), y & 1}, {x & 1, 1 - (y & 1)},
                                 {1 - (x & 1), 1 - (y & 1)}};
        for (const auto& o : order) {
          const int sx = bx + o[0], sy = by + o[1];
          if (sx < f.w && sy < f.h && f.source_ok[f.Idx(sx, sy)]) {
            f.src[i * 2] = sx;
            f.src[i * 2 + 1] = sy;
            done = true;
            break;
          }
        }
      }
      if (!done) {
        Rng rng(seed, level, -2, static_cast<int>(i));
        const int s = f.src_list[rng.Uniform(n)];
        f.src[i * 2] = s % f.w;
        f.src[i * 2 + 1] = s / f.w;
      }
    }
  }
}

// Keyframe propagation (4.3-4.6): previous map -> sources of this keyframe. Marks mapped
// pixels as fixed; returns their number.
int Propagate(const InpaintResult& prev, const RgbdKeyframe& frame, Level& L) {
  const PinholeCamera& cam_k = frame.camera;
  const PinholeCamera& cam_p = prev.camera;
  const Rigid3d k_from_p = frame.world_from_cam.Inverse() * prev.world_from_cam;
  const Rigid3d p_from_k = k_from_p.Inverse();
  const int w = L.w, h = L.h;
  // Depth of T in this keyframe: forward-warp the previous inpainted depth (z-buffer, 2x2
  // footprint), standing in for the projection of the fused global map.
  std::vector<float> zbuf(static_cast<size_t>(w) * h, std::numeric_limits<float>::infinity());
  const int pw = prev.depth_m.width(), ph = prev.depth_m.height();
  for (int y = 0; y < ph; ++y) {
    for (int x = 0; x < pw; ++x) {
      const float z = prev.depth_m.at(x, y);
      if (!(z > 0.f) || !std::isfinite(z)) continue;
      const glm::dvec3 pk = k_from_p * cam_p.Unproject({x, y}, z);
      glm::dvec2 uv;
      if (!cam_k.Project(pk, &uv)) continue;
      const int ux = static_cast<int>(std::floor(uv.x)), uy = static_cast<int>(std::floor(uv.y));
      for (int dy = 0; dy < 2; ++dy) {
        for (int dx = 0; dx < 2; ++dx) {
          const int qx = ux + dx, qy = uy + dy;
          if (qx < 0 || qy < 0 || qx >= w || qy >= h) continue;
          float& zb = zbuf[static_cast<size_t>(qy) * w + qx];
          zb = std::min(zb, static_cast<float>(pk.z));
        }
      }
    }
  }
  int mapped = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = L.row_x0[y]; x <= L.row_x1[y]; ++x) {
      const size_t i = L.Idx(x, y);
      if (!L.target[i]) continue;
      const float zk = zbuf[i];
      if (!std::isfinite(zk)) continue;
      const glm::dvec3 p = cam_k.Unproject({x, y}, zk);                         // 4.3
      glm::dvec2 uvp;
      if (!cam_p.Project(p_from_k * p, &uvp) || !cam_p.InImage(uvp)) continue;  // 4.4
      const int px = static_cast<int>(std::lround(uvp.x)), py = static_cast<int>(std::lround(uvp.y));
      int sx = px, sy = py;                                                       // 4.5
      if (prev.mask.at(px, py)) {
        sx = prev.source.at(px, py, 0);
        sy = prev.source.at(px, py, 1);
        if (sx < 0) continue;
      }
      const float zs = prev.depth_m.at(sx, sy);
      if (!(zs > 0.f)) continue;
      const glm::dvec3 ps = k_from_p * cam_p.Unproject({sx, sy}, zs);            // 4.3
      glm::dvec2 uvs;
      if (!cam_k.Project(ps, &uvs)) continue;                                     // 4.4
      const int qx = static_cast<int>(std::lround(uvs.x)), qy = static_cast<int>(std::lround(uvs.y));
      if (qx < 0 || qy < 0 || qx >= w || qy >= h || !L.source_ok[L.Idx(qx, qy)]) continue;
      L.src[i * 2] = qx;
      L.src[i * 2 + 1] = qy;
      L.fixed[i] = 1;
      ++mapped;
    }
  }
  return mapped;
}

// Unmapped pixels next to mapped ones take the neighbour's source shifted by one pixel
// (breadth-first), the rest a random source.
void GrowFromMapped(Level& L, uint64_t seed) {
  std::vector<int> frontier, next;
  std::vector<uint8_t> has(static_cast<size_t>(L.w) * L.h, 0);
  for (int y = 0; y < L.h; ++y) {
    for (int x = L.row_x0[y]; x <= L.row_x1[y]; ++x) {
      const size_t i = L.Idx(x, y);
      if (L.target[i] && L.fixed[i]) {
        has[i] = 1;
        frontier.push_back(static_cast<int>(i));
      }
    }
  }
  static constexpr int kDx[4] = {-1, 1, 0, 0}, kDy[4] = {0, 0, -1, 1};
  while (!frontier.empty()) {
    next.clear();
    for (int i : frontier) {
      const int x = i % L.w, y = i / L.w;
      for (int k = 0; k < 4; ++k) {
        const int nx = x + kDx[k], ny = y + kDy[k];
        if (nx < 0 || ny < 0 || nx >= L.w || ny >= L.h) continue;
        const size_t ni = L.Idx(nx, ny);
        if (!L.target[ni] || has[ni]) continue;
        const int sx = L.src[i * 2] + kDx[k], sy = L.src[i * 2 + 1] + kDy[k];
        has[ni] = 1;
        if (sx >= 0 && sy >= 0 && sx < L.w && sy < L.h && L.source_ok[L.Idx(sx, sy)]) {
          L.src[ni * 2] = sx;
          L.src[ni * 2 + 1] = sy;
          next.push_back(static_cast<int>(ni));
        } else {
          L.src[ni * 2] = -1;
        }
      }
    }
    std::swap(frontier, next);
  }
  const int n = static_cast<int>(L.src_list.size());
  for (int y = 0; y < L.h; ++y) {
    for (int x = L.row_x0[y]; x <= L.row_x1[y]; ++x) {
      const size_t i = L.Idx(x, y);
      if (!L.target[i] || L.fixed[i] || (has[i] && L.src[i * 2] >= 0)) continue;
      Rng rng(seed, 0, -3, static_cast<int>(i));
      const int s = L.src_list[rng.Uniform(n)];
      L.src[i * 2] = s % L.w;
      L.src[i * 2 + 1] = s / L.w;
    }
  }
}

}  // namespace

int BuildSurfacePrior(const ImageU8& region, const ImageF& values, int ox, int oy, int frame_w,
                      int frame_h, const InpaintOptions& o, ImageF* prior, ImageF* prior_weight) {
  if (!(o.neumann_prior_weight > 0.0)) return 0;
  const int cw = region.width(), ch = region.height();
  if (cw == 0 || ch == 0 || values.width() != cw || values.height() != ch) return 0;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // Seeds of the two borders (0 = seed, for the distance transforms): Dirichlet = known pixel
  // 4-adjacent to T (also the samples of the fit), Neumann = T pixel on the frame's edge or
  // next to a pixel that is neither in T nor known.
  cv::Mat not_dir(ch, cw, CV_8U, cv::Scalar(1)), not_neu(ch, cw, CV_8U, cv::Scalar(1));
  struct Sample {
    double x, y, v;  // x, y in units of 640 px (conditioning), v = known value
  };
  std::vector<Sample> ring;
  bool any_neumann = false;
  for (int cy = 0; cy < ch; ++cy) {
    for (int cx = 0; cx < cw; ++cx) {
      const int nx[4] = {cx - 1, cx + 1, cx, cx}, ny[4] = {cy, cy, cy - 1, cy + 1};
      if (region.at(cx, cy)) {
        const int x = ox + cx, y = oy + cy;
        bool neu = x == 0 || y == 0 || x == frame_w - 1 || y == frame_h - 1;
        for (int k = 0; k < 4 && !neu; ++k) {
          if (nx[k] < 0 || ny[k] < 0 || nx[k] >= cw || ny[k] >= ch) continue;
          neu = !region.at(nx[k], ny[k]) && !std::isfinite(values.at(nx[k], ny[k]));
        }
        if (neu) {
          not_neu.at<uint8_t>(cy, cx) = 0;
          any_neumann = true;
        }
        continue;
      }
      if (!std::isfinite(values.at(cx, cy))) continue;
      bool border = false;
      for (int k = 0; k < 4; ++k)
        border |= nx[k] >= 0 && ny[k] >= 0 && nx[k] < cw && ny[k] < ch && region.at(nx[k], ny[k]);
      if (!border) continue;
      not_dir.at<uint8_t>(cy, cx) = 0;
      ring.push_back({(ox + cx) / 640.0, (oy + cy) / 640.0, values.at(cx, cy)});
    }
  }
  if (ring.size() < 3) return 0;
  // Global least-squares plane (normal equations averaged per sample).
  Eigen::Matrix3d ata_g = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb_g = Eigen::Vector3d::Zero();
  double vlo = std::numeric_limits<double>::infinity(), vhi = -vlo;
  for (const Sample& p : ring) {
    const Eigen::Vector3d a(p.x, p.y, 1.0);
    ata_g += a * a.transpose();
    atb_g += a * p.v;
    vlo = std::min(vlo, p.v);
    vhi = std::max(vhi, p.v);
  }
  ata_g /= static_cast<double>(ring.size());
  atb_g /= static_cast<double>(ring.size());
  if (!(std::fabs(ata_g.determinant()) > 1e-14)) return 0;  // collinear border: no plane
  const Eigen::Vector3d global = ata_g.ldlt().solve(atb_g);
  if (!global.allFinite()) return 0;
  // Locally weighted planes (prior_local_px > 0): per 8x8 block of the crop, least squares over
  // the border pixels with Gaussian weights of their distance to the block centre (cut at 3
  // sigma), plus the global fit's normal equations with the weight of one border pixel (keeps
  // a collinear local border well-posed).
  constexpr int kBlock = 8;
  const int bw = (cw + kBlock - 1) / kBlock, bh = (ch + kBlock - 1) / kBlock;
  std::vector<Eigen::Vector3d> block_plane;
  if (o.prior_local_px > 0.0) {
    block_plane.assign(static_cast<size_t>(bw) * bh, global);
    const double inv2s2 = 1.0 / (2.0 * o.prior_local_px * o.prior_local_px);
    const double cut2 = 9.0 * o.prior_local_px * o.prior_local_px;
    for (int by = 0; by < bh; ++by) {
      for (int bx = 0; bx < bw; ++bx) {
        bool any = false;
        for (int cy = by * kBlock; cy < std::min(ch, (by + 1) * kBlock) && !any; ++cy)
          for (int cx = bx * kBlock; cx < std::min(cw, (bx + 1) * kBlock) && !any; ++cx)
            any = region.at(cx, cy) != 0;
        if (!any) continue;
        const double px = ox + bx * kBlock + 0.5 * kBlock, py = oy + by * kBlock + 0.5 * kBlock;
        Eigen::Matrix3d ata = ata_g;
        Eigen::Vector3d atb = atb_g;
        for (const Sample& p : ring) {
          const double dx = p.x * 640.0 - px, dy = p.y * 640.0 - py, d2 = dx * dx + dy * dy;
          if (d2 > cut2) continue;
          const double wr = std::exp(-d2 * inv2s2);
          const Eigen::Vector3d a(p.x, p.y, 1.0);
          ata += wr * a * a.transpose();
          atb += wr * a * p.v;
        }
        const Eigen::Vector3d cl = ata.ldlt().solve(atb);
        if (cl.allFinite()) block_plane[static_cast<size_t>(by) * bw + bx] = cl;
      }
    }
  }
  cv::Mat d_dir, d_neu;
  if (o.neumann_prior_weight > 0.0 && any_neumann) {
    cv::distanceTransform(not_dir, d_dir, cv::DIST_L2, cv::DIST_MASK_5);
    cv::distanceTransform(not_neu, d_neu, cv::DIST_L2, cv::DIST_MASK_5);
  }
  *prior = ImageF(cw, ch, 1, nan);
  *prior_weight = ImageF(cw, ch, 1, nan);
  int count = 0;
  for (int cy = 0; cy < ch; ++cy) {
    for (int cx = 0; cx < cw; ++cx) {
      if (!region.at(cx, cy)) continue;
      double wgt = 0.0;
      if (!d_neu.empty()) {
        const double dd = d_dir.at<float>(cy, cx), dn = d_neu.at<float>(cy, cx);
        const double share = dd / std::max(1e-6, dd + dn);  // 0 at the known border, 1 at the free one
        wgt += o.neumann_prior_weight * share * share;
      }
      if (!(wgt > 0.0)) continue;
      const Eigen::Vector3d& c =
          block_plane.empty() ? global : block_plane[static_cast<size_t>(cy / kBlock) * bw + cx / kBlock];
      // Extrapolated beyond the border (regions on the image edge), a plane is clamped to the
      // range of the border values it was fitted to: a tilt never runs off to a surface nearer
      // or farther than anything around T (in inverse depth: never through 0).
      const double v = c[0] * (ox + cx) / 640.0 + c[1] * (oy + cy) / 640.0 + c[2];
      prior->at(cx, cy) = static_cast<float>(std::clamp(v, vlo, vhi));
      prior_weight->at(cx, cy) = static_cast<float>(wgt);
      ++count;
    }
  }
  if (count == 0) {
    *prior = ImageF();
    *prior_weight = ImageF();
  }
  return count;
}

namespace {

// Layered depth setup (InpaintOptions::layered_depth) on the Poisson crop at (ox, oy): clusters
// the measured border of T in inverse depth, labels T's pixels with layers (Potts, graph_cut.h),
// and rewrites the problem so that each layer is solved on its own: pairs between layers and
// pairs from a T pixel to a border pixel of another layer lose their constraint (NaN target =
// natural boundary), border values that match no layer are dropped, and the surface prior is
// built per layer region. Returns the number of layers (<= 1: nothing was changed).
struct LayerPlane {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();  // v = c0 * x / 640 + c1 * y / 640 + c2
  double vlo = 0, vhi = 0;                      // range of the cluster's values
  double At(double x, double y) const { return c[0] * x / 640.0 + c[1] * y / 640.0 + c[2]; }
};

LayerPlane FitLayerPlane(const std::vector<Eigen::Vector3d>& pts) {  // (x, y, v), frame px
  LayerPlane pl;
  std::vector<double> vs;
  for (const auto& p : pts) vs.push_back(p[2]);
  std::nth_element(vs.begin(), vs.begin() + vs.size() / 2, vs.end());
  const double med = vs[vs.size() / 2];
  pl.vlo = *std::min_element(vs.begin(), vs.end());
  pl.vhi = *std::max_element(vs.begin(), vs.end());
  pl.c = Eigen::Vector3d(0, 0, med);  // fallback: fronto-parallel at the median
  // Iteratively reweighted least squares, Huber weights on the relative residual (2 %).
  std::vector<double> wt(pts.size(), 1.0);
  for (int iter = 0; iter < 4; ++iter) {
    Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
    Eigen::Vector3d atb = Eigen::Vector3d::Zero();
    double sw = 0;
    for (size_t k = 0; k < pts.size(); ++k) {
      const Eigen::Vector3d a(pts[k][0] / 640.0, pts[k][1] / 640.0, 1.0);
      ata += wt[k] * a * a.transpose();
      atb += wt[k] * a * pts[k][2];
      sw += wt[k];
    }
    ata /= sw;
    atb /= sw;
    if (!(std::fabs(ata.determinant()) > 1e-12)) break;  // collinear border: keep the fallback
    const Eigen::Vector3d c = ata.ldlt().solve(atb);
    if (!c.allFinite()) break;
    pl.c = c;
    for (size_t k = 0; k < pts.size(); ++k) {
      const double r = std::fabs(pl.At(pts[k][0], pts[k][1]) - pts[k][2]) / std::max(1e-9, std::fabs(pts[k][2]));
      wt[k] = r <= 0.02 ? 1.0 : 0.02 / r;
    }
  }
  return pl;
}

int SetupLayers(const ImageU8& region, const std::vector<uint8_t>& measured, int ox, int oy, int w,
                int h,
                const ImageU8& color, const InpaintOptions& o, ImageF* q, ImageF* gx, ImageF* gy,
                const ImageF& wx, const ImageF& wy, ImageF* prior, ImageF* prior_w,
                std::vector<int>* layer_pixels, float* seed_dist_px, ImageU8* layer_map,
                InpaintTrace* trace) {
  const int cw = region.width(), ch = region.height();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  auto in_r = [&](int cx, int cy) {
    return cx >= 0 && cy >= 0 && cx < cw && cy < ch && region.at(cx, cy) != 0;
  };
  auto next_to_r = [&](int cx, int cy) {
    return in_r(cx - 1, cy) || in_r(cx + 1, cy) || in_r(cx, cy - 1) || in_r(cx, cy + 1);
  };
  // 1. The measured ring, clustered in inverse depth.
  struct RingPx {
    int cx, cy;
    float v;
  };
  std::vector<RingPx> ring;
  for (int cy = 0; cy < ch; ++cy)
    for (int cx = 0; cx < cw; ++cx) {
      if (region.at(cx, cy) || !std::isfinite(q->at(cx, cy)) || !(q->at(cx, cy) > 0.f)) continue;
      if (!measured[static_cast<size_t>(oy + cy) * w + ox + cx] || !next_to_r(cx, cy)) continue;
      ring.push_back({cx, cy, q->at(cx, cy)});
    }
  if (ring.size() < 16) return 1;
  std::vector<int> order(ring.size());
  for (size_t k = 0; k < order.size(); ++k) order[k] = static_cast<int>(k);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return ring[a].v < ring[b].v; });
  std::vector<std::pair<int, int>> runs;  // [begin, end) in `order`
  int start = 0;
  for (size_t k = 1; k <= order.size(); ++k) {
    if (k == order.size() ||
        ring[order[k]].v - ring[order[k - 1]].v > o.layer_gap_rel * ring[order[k]].v) {
      runs.push_back({start, static_cast<int>(k)});
      start = static_cast<int>(k);
    }
  }
  const int min_size = std::max(8, static_cast<int>(std::ceil(o.layer_min_share * ring.size())));
  std::vector<std::pair<int, int>> kept;
  for (const auto& r : runs)
    if (r.second - r.first >= min_size) kept.push_back(r);
  if (kept.size() < 2) return 1;
  if (static_cast<int>(kept.size()) > o.max_layers) {
    std::stable_sort(kept.begin(), kept.end(), [](const auto& a, const auto& b) {
      return a.second - a.first > b.second - b.first;
    });
    kept.resize(o.max_layers);
    std::sort(kept.begin(), kept.end());
  }
  const int K = static_cast<int>(kept.size());
  // 2. A robust inverse-depth plane per layer (1/z is affine in pixel coordinates on a plane).
  std::vector<LayerPlane> planes(K);
  ImageI32 blabel(cw, ch, 1, -1);  // border pixel labels (-1: none)
  for (int l = 0; l < K; ++l) {
    std::vector<Eigen::Vector3d> pts;
    for (int k = kept[l].first; k < kept[l].second; ++k) {
      const RingPx& r = ring[order[k]];
      pts.emplace_back(ox + r.cx, oy + r.cy, r.v);
      blabel.at(r.cx, r.cy) = l;
    }
    planes[l] = FitLayerPlane(pts);
  }
  // Other border values (push-pull-filled, measured in no kept cluster): the layer whose plane
  // they match; none -> no boundary value at all.
  for (int cy = 0; cy < ch; ++cy)
    for (int cx = 0; cx < cw; ++cx) {
      if (region.at(cx, cy) || !std::isfinite(q->at(cx, cy)) || !next_to_r(cx, cy)) continue;
      if (blabel.at(cx, cy) >= 0) continue;
      const double v = q->at(cx, cy);
      int best = -1;
      double best_r = o.layer_agree_rel;
      for (int l = 0; l < K; ++l) {
        const double p = std::clamp(planes[l].At(ox + cx, oy + cy), 0.5 * planes[l].vlo, 2.0 * planes[l].vhi);
        const double r = std::fabs(v - p) / std::max(1e-9, std::fabs(p));
        if (r <= best_r) {
          best_r = r;
          best = l;
        }
      }
      blabel.at(cx, cy) = best;
      if (best < 0) q->at(cx, cy) = nan;
    }
  // Seeds of the labelling (distances, fixed-label border pairs): with layer_seed_measured_only
  // only the measured ring, else every labelled border pixel.
  ImageI32 slabel = blabel;
  if (o.layer_seed_measured_only) {
    for (int cy = 0; cy < ch; ++cy)
      for (int cx = 0; cx < cw; ++cx)
        if (!measured[static_cast<size_t>(oy + cy) * w + ox + cx]) slabel.at(cx, cy) = -1;
  }
  // 3. Labels of T: distances to each layer's border, copied normals and colour.
  std::vector<cv::Mat> dist(K);
  for (int l = 0; l < K; ++l) {
    cv::Mat seeds(ch, cw, CV_8U, cv::Scalar(1));
    for (int cy = 0; cy < ch; ++cy)
      for (int cx = 0; cx < cw; ++cx)
        if (slabel.at(cx, cy) == l) seeds.at<uint8_t>(cy, cx) = 0;
    cv::distanceTransform(seeds, dist[l], cv::DIST_L2, cv::DIST_MASK_5);
  }
  // With layer_edge_seeds, T's free border pixels (on the frame's edge, or next to pixels that
  // seed no layer: holes, push-pull-filled depth) continue the labels of the seeds along T's
  // border: breadth-first over T's 8-connected border pixels from those next to a seed, so a
  // free stretch between two seeds of one layer belongs to that layer (an occlusion edge that
  // enters T must leave it again), and they become seeds themselves.
  ImageI32 elabel(cw, ch, 1, -1);
  if (o.layer_edge_seeds) {
    bool any = false;
    ImageI32 glabel(cw, ch, 1, -1);
    std::vector<int> queue;
    auto on_border = [&](int cx, int cy) {
      const int x = ox + cx, y = oy + cy;
      if (!region.at(cx, cy)) return false;
      if (x == 0 || y == 0 || x == w - 1 || y == h - 1) return true;
      return !in_r(cx - 1, cy) || !in_r(cx + 1, cy) || !in_r(cx, cy - 1) || !in_r(cx, cy + 1);
    };
    ImageU8 free_px(cw, ch, 1, 0);
    for (int cy = 0; cy < ch; ++cy)
      for (int cx = 0; cx < cw; ++cx) {
        if (!on_border(cx, cy)) continue;
        int seed = -1;
        const int nx[4] = {cx - 1, cx + 1, cx, cx}, ny[4] = {cy, cy, cy - 1, cy + 1};
        for (int k = 0; k < 4; ++k) {
          if (nx[k] < 0 || ny[k] < 0 || nx[k] >= cw || ny[k] >= ch || region.at(nx[k], ny[k])) continue;
          const int sl = slabel.at(nx[k], ny[k]);
          if (sl >= 0 && (seed < 0 || sl < seed)) seed = sl;
        }
        if (seed >= 0) {
          glabel.at(cx, cy) = seed;
          queue.push_back(cy * cw + cx);
        } else {
          free_px.at(cx, cy) = 1;
        }
      }
    for (size_t qi = 0; qi < queue.size(); ++qi) {
      const int cx = queue[qi] % cw, cy = queue[qi] / cw;
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int nx = cx + dx, ny = cy + dy;
          if (nx < 0 || ny < 0 || nx >= cw || ny >= ch || !free_px.at(nx, ny) || glabel.at(nx, ny) >= 0) continue;
          glabel.at(nx, ny) = glabel.at(cx, cy);
          queue.push_back(ny * cw + nx);
        }
    }
    for (int cy = 0; cy < ch; ++cy)
      for (int cx = 0; cx < cw; ++cx)
        if (free_px.at(cx, cy) && glabel.at(cx, cy) >= 0) {
          elabel.at(cx, cy) = glabel.at(cx, cy);
          any = true;
        }
    if (any) {
      for (int l = 0; l < K; ++l) {
        cv::Mat seeds(ch, cw, CV_8U, cv::Scalar(1));
        for (int cy = 0; cy < ch; ++cy)
          for (int cx = 0; cx < cw; ++cx)
            if (slabel.at(cx, cy) == l || elabel.at(cx, cy) == l) seeds.at<uint8_t>(cy, cx) = 0;
        cv::distanceTransform(seeds, dist[l], cv::DIST_L2, cv::DIST_MASK_5);
      }
    }
  }
  // How far the cut has to be extrapolated: the largest distance of a T pixel to the nearest
  // seed of any layer (InpaintStats::layer_seed_dist_px, a diagnostic).
  float far_px = 0.f;
  for (int cy = 0; cy < ch; ++cy)
    for (int cx = 0; cx < cw; ++cx) {
      if (!region.at(cx, cy)) continue;
      float dm = std::numeric_limits<float>::infinity();
      for (int l = 0; l < K; ++l) dm = std::min(dm, dist[l].at<float>(cy, cx));
      far_px = std::max(far_px, dm);
    }
  *seed_dist_px = far_px;
  // The labelling runs on blocks of layer_label_block^2 pixels (one label per block; the block
  // energy is the exact sum of its pixels' terms, pairs inside a block drop out): the cut is a
  // long smooth curve, and a 4x coarser graph makes the max-flow ~20x cheaper.
  const int bs = o.layer_label_block;
  const int nbw = (cw + bs - 1) / bs, nbh = (ch + bs - 1) / bs;
  std::vector<int> bnode(static_cast<size_t>(nbw) * nbh, -1);
  int nn = 0;
  for (int cy = 0; cy < ch; ++cy)
    for (int cx = 0; cx < cw; ++cx) {
      int& b = bnode[static_cast<size_t>(cy / bs) * nbw + cx / bs];
      if (region.at(cx, cy) && b < 0) b = nn++;
    }
  auto node_of = [&](int cx, int cy) {
    return region.at(cx, cy) ? bnode[static_cast<size_t>(cy / bs) * nbw + cx / bs] : -1;
  };
  std::vector<float> unary(static_cast<size_t>(nn) * K, 0.f);
  const double inv2s2 = 1.0 / (2.0 * o.layer_color_sigma * o.layer_color_sigma);
  auto colour_w = [&](int x0, int y0, int x1, int y1) {
    double d2 = 0;
    for (int k = 0; k < 3; ++k) {
      const double d = static_cast<double>(color.at(x0, y0, k)) - color.at(x1, y1, k);
      d2 += d * d;
    }
    return std::exp(-d2 * inv2s2);
  };
  std::vector<double> ew_r(bnode.size(), 0.0), ew_d(bnode.size(), 0.0);  // block pair weights
  for (int cy = 0; cy < ch; ++cy)
    for (int cx = 0; cx < cw; ++cx) {
      const int p = node_of(cx, cy);
      if (p < 0) continue;
      const int x = ox + cx, y = oy + cy;
      for (int l = 0; l < K; ++l) {
        double u = 0.0;
        double dmin = std::numeric_limits<double>::infinity();
        for (int m = 0; m < K; ++m)
          if (m != l) dmin = std::min<double>(dmin, dist[m].at<float>(cy, cx));
        const double dl = dist[l].at<float>(cy, cx);
        u += o.layer_distance_weight * dl / std::max(1e-6, dl + dmin);
        unary[static_cast<size_t>(p) * K + l] += static_cast<float>(u);
      }
      if (elabel.at(cx, cy) >= 0) {
        for (int l = 0; l < K; ++l)
          if (l != elabel.at(cx, cy)) unary[static_cast<size_t>(p) * K + l] += static_cast<float>(o.layer_smooth);
      }
      const int nx[4] = {cx - 1, cx + 1, cx, cx}, ny[4] = {cy, cy, cy - 1, cy + 1};
      for (int k = 0; k < 4; ++k) {
        if (nx[k] < 0 || ny[k] < 0 || nx[k] >= cw || ny[k] >= ch) continue;
        // Pair weight; the pair's fused gradient weight marks copied jumps.
        const bool fwd = k == 1 || k == 3;
        const int pcx = fwd ? cx : nx[k], pcy = fwd ? cy : ny[k];
        const float pw = (k < 2 ? wx : wy).at(pcx, pcy);
        const double jf = std::isfinite(pw) && pw < 1.f ? o.layer_jump_factor : 1.0;
        const double cwgt = o.layer_color_sigma > 0.0 && o.layer_color_sigma < 1e6 ? colour_w(x, y, ox + nx[k], oy + ny[k]) : 1.0;
        const double wgt = o.layer_smooth * jf * cwgt;
        const int qn = node_of(nx[k], ny[k]);
        if (qn >= 0) {
          if (fwd && qn != p) (k == 1 ? ew_r : ew_d)[static_cast<size_t>(cy / bs) * nbw + cx / bs] += wgt;
        } else if (slabel.at(nx[k], ny[k]) >= 0) {
          // A fixed-label border pixel: a T pixel of another layer pays the pair weight.
          for (int l = 0; l < K; ++l)
            if (l != slabel.at(nx[k], ny[k])) unary[static_cast<size_t>(p) * K + l] += static_cast<float>(wgt);
        }
      }
    }
  std::vector<PottsEdge> edges;
  for (int by = 0; by < nbh; ++by)
    for (int bx = 0; bx < nbw; ++bx) {
      const size_t b = static_cast<size_t>(by) * nbw + bx;
      if (ew_r[b] > 0.0) edges.push_back({bnode[b], bnode[b + 1], static_cast<float>(ew_r[b])});
      if (ew_d[b] > 0.0) edges.push_back({bnode[b], bnode[b + nbw], static_cast<float>(ew_d[b])});
    }
  std::vector<int> labels(nn, 0);
  if (trace != nullptr) trace->labellings.push_back({nn, K, K == 2 ? 1 : 3, unary, edges, labels});
  PottsAlphaExpansion(nn, K, unary, edges, &labels, K == 2 ? 1 : 3);
  ImageI32 tl(cw, ch, 1, -1);
  layer_pixels->assign(K, 0);
  *layer_map = ImageU8(w, h, 1, 0);
  for (int cy = 0; cy < ch; ++cy)  // outside T: the labelling's seeds
    for (int cx = 0; cx < cw; ++cx)
      if (!region.at(cx, cy) && slabel.at(cx, cy) >= 0)
        layer_map->at(ox + cx, oy + cy) = static_cast<uint8_t>(1 + slabel.at(cx, cy));
  for (int cy = 0; cy < ch; ++cy)
    for (int cx = 0; cx < cw; ++cx) {
      const int p = node_of(cx, cy);
      if (p < 0) continue;
      tl.at(cx, cy) = labels[p];
      ++(*layer_pixels)[labels[p]];
      layer_map->at(ox + cx, oy + cy) = static_cast<uint8_t>(1 + labels[p]);
    }
  // 4. Pairs: between layers, and from a T pixel to a border pixel of another layer, free.
  for (int cy = 0; cy < ch; ++cy)
    for (int cx = 0; cx < cw; ++cx)
      for (int dir = 0; dir < 2; ++dir) {
        const int qx = cx + (dir == 0), qy = cy + (dir == 1);
        if (qx >= cw || qy >= ch) continue;
        const bool tp = region.at(cx, cy), tq = region.at(qx, qy);
        if (!tp && !tq) continue;
        const int lp = tp ? tl.at(cx, cy) : blabel.at(cx, cy);
        const int lq = tq ? tl.at(qx, qy) : blabel.at(qx, qy);
        const bool other_known = (!tp && std::isfinite(q->at(cx, cy))) || (!tq && std::isfinite(q->at(qx, qy)));
        if (tp && tq ? lp != lq : (other_known && lp != lq)) (dir == 0 ? *gx : *gy).at(cx, cy) = nan;
      }
  // 5. The surface prior per layer region, from that layer's border values only.
  *prior = ImageF(cw, ch, 1, nan);
  *prior_w = ImageF(cw, ch, 1, nan);
  int count = 0;
  for (int l = 0; l < K; ++l) {
    ImageU8 rl(cw, ch, 1, 0);
    ImageF ql(cw, ch, 1, nan);
    for (int cy = 0; cy < ch; ++cy)
      for (int cx = 0; cx < cw; ++cx) {
        if (region.at(cx, cy)) rl.at(cx, cy) = tl.at(cx, cy) == l;
        else if (blabel.at(cx, cy) == l) ql.at(cx, cy) = q->at(cx, cy);
      }
    ImageF pl, pw;
    if (BuildSurfacePrior(rl, ql, ox, oy, w, h, o, &pl, &pw) > 0) {
      for (int cy = 0; cy < ch; ++cy)
        for (int cx = 0; cx < cw; ++cx)
          if (rl.at(cx, cy) && std::isfinite(pw.at(cx, cy))) {
            prior->at(cx, cy) = pl.at(cx, cy);
            prior_w->at(cx, cy) = pw.at(cx, cy);
            ++count;
          }
    } else if (o.neumann_prior_weight > 0.0) {
      // Too few border samples of its own: the layer's plane anchors the region.
      for (int cy = 0; cy < ch; ++cy)
        for (int cx = 0; cx < cw; ++cx)
          if (rl.at(cx, cy)) {
            prior->at(cx, cy) = static_cast<float>(
                std::clamp(planes[l].At(ox + cx, oy + cy), planes[l].vlo, planes[l].vhi));
            prior_w->at(cx, cy) = static_cast<float>(o.neumann_prior_weight);
            ++count;
          }
    }
  }
  if (count == 0) {
    *prior = ImageF();
    *prior_w = ImageF();
  }
  return K;
}

}  // namespace

absl::Status InpaintOptions::Validate() const {
  if (!(w > 0.0 && w <= 1.0)) return absl::InvalidArgumentError("InpaintOptions.w must be in (0, 1]");
  if (!(kappa > 0.0 && kappa <= 1.0)) {
    return absl::InvalidArgumentError("InpaintOptions.kappa must be in (0, 1]");
  }
  if (!(spatial_cap_px2 > 0.0)) return absl::InvalidArgumentError("spatial_cap_px2 must be > 0");
  if (pyramid_levels < 0 || pyramid_levels > 12) {
    return absl::InvalidArgumentError("pyramid_levels must be in [0, 12]");
  }
  if (min_coarse_side < 8) return absl::InvalidArgumentError("min_coarse_side must be >= 8");
  if (coarse_iterations < 1 || fine_iterations < 1 || propagated_iterations < 1) {
    return absl::InvalidArgumentError("iteration counts must be >= 1");
  }
  if (band_rows < 2) return absl::InvalidArgumentError("band_rows must be >= 2");
  if (!(converged_fraction >= 0.0 && converged_fraction < 1.0)) {
    return absl::InvalidArgumentError("converged_fraction must be in [0, 1)");
  }
  if (num_threads < 1 || num_threads > 64) return absl::InvalidArgumentError("num_threads in [1, 64]");
  if (!(max_median_depth_m > 0.0)) return absl::InvalidArgumentError("max_median_depth_m > 0");
  if (!(normal_rel_discontinuity > 0.f)) return absl::InvalidArgumentError("normal_rel_discontinuity > 0");
  if (!(poisson_tolerance > 0.0 && poisson_tolerance < 1.0)) {
    return absl::InvalidArgumentError("poisson_tolerance in (0, 1)");
  }
  if (!(jump_rel > 0.0)) return absl::InvalidArgumentError("jump_rel must be > 0");
  if (!(neumann_prior_weight >= 0.0)) return absl::InvalidArgumentError("neumann_prior_weight >= 0");
  if (!(prior_local_px >= 0.0)) return absl::InvalidArgumentError("prior_local_px must be >= 0");
  if (!(jump_weight > 0.0 && jump_weight <= 1.0)) {
    return absl::InvalidArgumentError("jump_weight must be in (0, 1]");
  }
  if (!(layer_gap_rel > 0.0)) return absl::InvalidArgumentError("layer_gap_rel must be > 0");
  if (!(layer_min_share >= 0.0 && layer_min_share < 1.0)) {
    return absl::InvalidArgumentError("layer_min_share must be in [0, 1)");
  }
  if (max_layers < 1 || max_layers > 3) return absl::InvalidArgumentError("max_layers in [1, 3]");
  if (!(layer_agree_rel >= 0.0)) return absl::InvalidArgumentError("layer_agree_rel must be >= 0");
  if (!(layer_distance_weight >= 0.0) || !(layer_smooth >= 0.0)) {
    return absl::InvalidArgumentError("layer weights must be >= 0");
  }
  if (!(layer_color_sigma > 0.0)) return absl::InvalidArgumentError("layer_color_sigma must be > 0");
  if (layer_label_block < 1 || layer_label_block > 32) {
    return absl::InvalidArgumentError("layer_label_block must be in [1, 32]");
  }
  if (!(layer_jump_factor >= 0.0 && layer_jump_factor <= 1.0)) {
    return absl::InvalidArgumentError("layer_jump_factor must be in [0, 1]");
  }
  return absl::OkStatus();
}

absl::StatusOr<InpaintResult> InpaintKeyframe(const RgbdKeyframe& frame, const ImageU8& mask,
                                              const InpaintOptions& options,
                                              const InpaintResult* previous, InpaintTrace* trace) {
  const auto t_start = Clock::now();
  const double c_start = CpuMs();
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(frame.camera.Validate());
  const int w = frame.color.width(), h = frame.color.height();
  if (frame.color.empty() || frame.color.channels() != 3) {
    return absl::InvalidArgumentError("InpaintKeyframe: colour must be a non-empty RGB8 image");
  }
  if (frame.depth_m.width() != w || frame.depth_m.height() != h || frame.depth_m.channels() != 1) {
    return absl::InvalidArgumentError("InpaintKeyframe: depth must be 1-channel, size of colour");
  }
  if (frame.camera.width != w || frame.camera.height != h) {
    return absl::InvalidArgumentError("InpaintKeyframe: camera size differs from the image size");
  }
  if (mask.width() != w || mask.height() != h || mask.channels() != 1) {
    return absl::InvalidArgumentError("InpaintKeyframe: mask must be 1-channel, size of colour");
  }
  EXO_RETURN_IF_ERROR(CheckDepthUnits(frame.depth_m, options.max_median_depth_m));
  const size_t n = static_cast<size_t>(w) * h;
  int target_count = 0;
  for (size_t i = 0; i < n; ++i) target_count += mask.data()[i] != 0;
  if (target_count == 0) return absl::InvalidArgumentError("InpaintKeyframe: the mask is empty");
  if (target_count == static_cast<int>(n)) {
    return absl::InvalidArgumentError(
        "InpaintKeyframe: the mask covers the whole frame; nothing is left to copy from");
  }
  if (previous) {
    if (previous->source.width() == 0 || previous->mask.width() == 0 ||
        previous->depth_m.width() != previous->camera.width ||
        previous->depth_m.height() != previous->camera.height ||
        previous->mask.width() != previous->depth_m.width() ||
        previous->source.width() != previous->depth_m.width()) {
      return absl::InvalidArgumentError("InpaintKeyframe: previous keyframe result is incomplete");
    }
  }

  InpaintResult out;
  out.stats.target_pixels = target_count;
  out.camera = frame.camera;
  out.world_from_cam = frame.world_from_cam;
  out.mask = ImageU8(w, h, 1, 0);
  std::vector<uint8_t> target(n), outside(n);
  for (size_t i = 0; i < n; ++i) {
    target[i] = mask.data()[i] != 0;
    outside[i] = !target[i];
    out.mask.data()[i] = target[i] ? 255 : 0;
  }
  std::vector<uint8_t> measured(n);  // outside T with sensor depth
  for (size_t i = 0; i < n; ++i) {
    const float z = frame.depth_m.data()[i];
    measured[i] = !target[i] && std::isfinite(z) && z > 0.f;
  }
  // Pre-processing: fill sensor holes outside T, normals from the densified depth.
  out.depth_m = frame.depth_m;
  for (size_t i = 0; i < n; ++i) {
    float& z = out.depth_m.data()[i];
    if (!std::isfinite(z) || z < 0.f) z = 0.f;
    if (target[i]) z = 0.f;  // T's own depth (the object to remove / a hole) is never used
  }
  out.stats.prefilled_pixels = PrefillDepth(out.depth_m, outside, outside);
  const ImageF normals0 = NormalsFromDepth(out.depth_m, frame.camera, 2, options.normal_rel_discontinuity,
                                          options.num_threads);

  std::vector<Level> levels(1);
  {
    Level& L = levels[0];
    L.w = w;
    L.h = h;
    L.color.assign(frame.color.data(), frame.color.data() + n * 3);
    L.normal.assign(normals0.data(), normals0.data() + n * 3);
    L.target = target;
    L.data_ok.assign(n, 0);
    for (size_t i = 0; i < n; ++i) {
      const float* nn = &L.normal[i * 3];
      L.data_ok[i] = !target[i] && out.depth_m.data()[i] > 0.f &&
                     (nn[0] != 0.f || nn[1] != 0.f || nn[2] != 0.f);
    }
    FinishLevel(L);
  }
  out.stats.source_pixels = static_cast<int>(levels[0].src_list.size());
  if (levels[0].src_list.empty()) {
    return absl::FailedPreconditionError(
        "InpaintKeyframe: no valid source patch (a 5x5 window outside the mask with valid depth "
        "and normals); enlarge the visible area or fix the depth");
  }
  const SearchParams params{static_cast<float>(options.w), static_cast<float>(1.0 - options.w),
                            static_cast<float>(options.kappa),
                            static_cast<float>(options.spatial_cap_px2), options.use_geometry,
                            options.peel_measured_normals_only};

  int propagated = 0;
  if (previous) propagated = Propagate(*previous, frame, levels[0]);
  out.stats.propagated_pixels = propagated;
  out.stats.ms_prepare = MsSince(t_start);
  const double c_search = CpuMs();
  out.stats.cpu_ms_prepare = c_search - c_start;
  const auto t_search = Clock::now();
  const bool fine_only = propagated > 0 && propagated * 2 >= target_count;
  if (fine_only) {
    // Only what the previous keyframe could not map is searched, at full resolution.
    Level& L = levels[0];
    GrowFromMapped(L, options.seed);
    CopyFromSources(L, options.num_threads);
    const int radius0 = std::max(w, h) / 4;
    for (int it = 0; it < options.propagated_iterations; ++it) {
      Sweep(L, 0, it, radius0, true, params, options);
      CopyFromSources(L, options.num_threads);
    }
    out.stats.levels = 1;
  } else {
    const int max_levels = options.pyramid_levels > 0 ? options.pyramid_levels : 12;
    while (static_cast<int>(levels.size()) < max_levels) {
      const Level& f = levels.back();
      if (options.pyramid_levels == 0 && std::min((f.w + 1) / 2, (f.h + 1) / 2) < options.min_coarse_side) break;
      if (std::min(f.w, f.h) < 10) break;
      Level c = Downsample(f);
      if (c.src_list.empty()) break;  // too coarse to hold a single source patch
      bool any_target = false;
      for (uint8_t t : c.target) any_target |= t != 0;
      if (!any_target) break;
      levels.push_back(std::move(c));
    }
    const int nl = static_cast<int>(levels.size());
    out.stats.levels = nl;
    for (int li = nl - 1; li >= 0; --li) {
      Level& L = levels[li];
      if (li == nl - 1) {
        // T pixels not reached by the onion peel (cut off from every known pixel) keep the
        // random source; the peel overwrites the rest.
        SmoothFillTarget(L);
        RandomInit(L, li, options.seed);
        OnionPeelInit(L, li, params, options);
      } else {
        Upsample(levels[li + 1], L, li, options.seed);
        CopyFromSources(L, options.num_threads);
      }
      const int iters = nl == 1 ? options.fine_iterations
                                : options.fine_iterations +
                                      (options.coarse_iterations - options.fine_iterations) * li / (nl - 1);
      const int radius0 = li == nl - 1 ? std::max(L.w, L.h) : std::max(4, std::max(L.w, L.h) / 8);
      int level_target = 0;
      for (uint8_t t : L.target) level_target += t != 0;
      for (int it = 0; it < iters; ++it) {
        const int changed = Sweep(L, li, it, radius0, li == nl - 1, params, options);
        CopyFromSources(L, options.num_threads);
        ++out.stats.sweeps;
        // Converged: the sweep changed (almost) nothing, later sweeps would repeat it.
        if (it + 1 < iters && changed <= options.converged_fraction * level_target) break;
      }
      if (li > 0) levels[li].color.shrink_to_fit();
    }
  }
  out.stats.ms_search = MsSince(t_search);
  out.stats.cpu_ms_search = CpuMs() - c_search;

  // Copy colour (4.11) and the source map.
  const auto t_copy = Clock::now();
  const Level& L0 = levels[0];
  out.color = ImageU8(w, h, 3);
  std::copy(L0.color.begin(), L0.color.end(), out.color.data());
  out.source = ImageI32(w, h, 2, -1);
  for (size_t i = 0; i < n; ++i) {
    if (!target[i]) continue;
    out.source.data()[i * 2] = L0.src[i * 2];
    out.source.data()[i * 2 + 1] = L0.src[i * 2 + 1];
  }
  out.stats.ms_copy = MsSince(t_copy);

  // Depth (4.13-4.16): Poisson on the mean bidirectional gradients of the copied samples,
  // set up on T's bounding box plus one pixel (every pair touching T lies inside it).
  const auto t_poisson = Clock::now();
  const double c_poisson = CpuMs();
  const bool inv = options.depth_domain == DepthDomain::kInverseDepth;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<uint8_t>& in_region = target;  // the solve's region: T
  int bx0 = w, by0 = h, bx1 = -1, by1 = -1;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (!in_region[static_cast<size_t>(y) * w + x]) continue;
      bx0 = std::min(bx0, x);
      bx1 = std::max(bx1, x);
      by0 = std::min(by0, y);
      by1 = y;
    }
  }
  const int ox = std::max(0, bx0 - 1), oy = std::max(0, by0 - 1);
  const int cw = std::min(w - 1, bx1 + 1) - ox + 1, ch = std::min(h - 1, by1 + 1) - oy + 1;
  // Domain value of a pixel outside T (sources and their 5x5 windows have valid depth).
  auto qv = [&](int x, int y) {
    const float z = out.depth_m.at(x, y);
    return z > 0.f ? (inv ? 1.f / z : z) : nan;
  };
  ImageF q(cw, ch, 1, nan), gx(cw, ch, 1, nan), gy(cw, ch, 1, nan), gauge(cw, ch, 1, nan);
  ImageF wx(cw, ch, 1, nan), wy(cw, ch, 1, nan);  // pair weights (NaN = 1)
  ImageU8 region(cw, ch, 1, 0);
  for (int cy = 0; cy < ch; ++cy) {
    for (int cx = 0; cx < cw; ++cx) {
      const int x = ox + cx, y = oy + cy;
      const size_t i = static_cast<size_t>(y) * w + x;
      const bool tp = in_region[i];
      region.at(cx, cy) = tp;
      if (!tp) q.at(cx, cy) = qv(x, y);  // Dirichlet value: measured or push-pull pre-fill
      if (tp) gauge.at(cx, cy) = qv(L0.src[i * 2], L0.src[i * 2 + 1]);
      for (int dir = 0; dir < 2; ++dir) {
        const int dx = dir == 0 ? 1 : 0, dy = dir == 0 ? 0 : 1;
        if (cx + dx >= cw || cy + dy >= ch) continue;
        const size_t j = static_cast<size_t>(y + dy) * w + x + dx;
        const bool tq = in_region[j];
        if (!tp && !tq) continue;
        // The two copied samples of this pair's gradient and the value they start from.
        float g1 = nan, g2 = nan, ref1 = nan, ref2 = nan;
        if (tp) {  // gradient sampled at u's source: d(f(u)) - d(f(u) + v)
          const int sx = L0.src[i * 2], sy = L0.src[i * 2 + 1];
          ref1 = qv(sx, sy);
          g1 = ref1 - qv(sx + dx, sy + dy);
        }
        if (tq) {  // gradient sampled at (u+v)'s source: d(f(u+v) - v) - d(f(u+v))
          const int sx = L0.src[j * 2], sy = L0.src[j * 2 + 1];
          ref2 = qv(sx, sy);
          g2 = qv(sx - dx, sy - dy) - ref2;
        }
        const FusedGradient fg = FuseGradientSamples(tp, g1, ref1, tq, g2, ref2, options);
        const float g = fg.g, wgt = fg.weight;
        (dir == 0 ? gx : gy).at(cx, cy) = g;
        if (wgt != 1.f) (dir == 0 ? wx : wy).at(cx, cy) = wgt;
      }
    }
  }
  // Optional surface prior (screening term): a robust plane (affine in the depth domain) fitted
  // to the known pixels next to T, weighted per pixel by how weakly the Dirichlet border anchors
  // it (see SurfacePrior).
  ImageF prior, prior_w;
  int layers = 1;
  if (options.layered_depth && inv && options.max_layers > 1) {
    layers = SetupLayers(region, measured, ox, oy, w, h, out.color, options,
                         &q, &gx, &gy, wx, wy, &prior, &prior_w, &out.stats.layer_pixels,
                         &out.stats.layer_seed_dist_px, &out.layers, trace);
  }
  out.stats.depth_layers = layers;
  if (layers <= 1) {
    out.stats.prior_pixels = BuildSurfacePrior(region, q, ox, oy, w, h, options, &prior, &prior_w);
  } else {
    for (int cy = 0; cy < ch; ++cy)
      for (int cx = 0; cx < cw; ++cx) out.stats.prior_pixels += !prior.empty() && std::isfinite(prior_w.at(cx, cy));
  }
  PoissonProblem prob;
  if (!prior.empty()) {
    prob.prior = &prior;
    prob.prior_weight = &prior_w;
  }
  prob.region = &region;
  prob.values = &q;
  prob.gx = &gx;
  prob.gy = &gy;
  prob.gauge = &gauge;
  prob.wx = &wx;
  prob.wy = &wy;
  // No initial guess: the solver's coarse levels give a better one than the previous
  // keyframe's forward-warped depth, whose splatting noise cost more iterations (measured).
  PoissonOptions popt;
  popt.tolerance = options.poisson_tolerance;
  PoissonStats pst;
  EXO_ASSIGN_OR_RETURN(ImageF solved, SolvePoisson(prob, popt, &pst));
  out.stats.poisson_iterations = pst.iterations;
  out.stats.neumann_components = pst.neumann_components;
  // Range guard: the solved depth stays within [1/2, 2] x the range of the depths it was
  // built from (boundary and copied samples). In inverse depth a solution drifting towards 0
  // would otherwise become an arbitrarily distant surface.
  float zlo = std::numeric_limits<float>::infinity(), zhi = 0.f;
  for (int cy = 0; cy < ch; ++cy) {
    for (int cx = 0; cx < cw; ++cx) {
      for (float v : {q.at(cx, cy), gauge.at(cx, cy)}) {
        if (!std::isfinite(v) || !(v > 0.f)) continue;
        const float z = inv ? 1.f / v : v;
        zlo = std::min(zlo, z);
        zhi = std::max(zhi, z);
      }
    }
  }
  for (int cy = 0; cy < ch; ++cy) {
    for (int cx = 0; cx < cw; ++cx) {
      if (!region.at(cx, cy)) continue;
      const float v = solved.at(cx, cy);
      float z = 0.f;
      if (std::isfinite(v) && v > 0.f) z = inv ? 1.f / v : v;
      if (inv && !(v > 0.f) && std::isfinite(v)) z = 2.f * zhi;  // beyond infinity: farthest
      if (z > 0.f && zhi > 0.f) {
        const float zc = std::clamp(z, 0.5f * zlo, 2.f * zhi);
        if (zc != z) ++out.stats.clamped_depth_pixels;
        z = zc;
      }
      if (!(z > 0.f) || !std::isfinite(z)) {
        z = 0.f;
        ++out.stats.invalid_depth_pixels;
      }
      out.depth_m.at(ox + cx, oy + cy) = z;
    }
  }
  out.stats.ms_poisson = MsSince(t_poisson);
  out.stats.cpu_ms_poisson = CpuMs() - c_poisson;
  // Normals of the result: unchanged outside T's neighbourhood (the smoothing reaches 2 px, the
  // differences 2 px more), recomputed on T's bounding box plus a margin.
  out.normals = normals0;
  {
    const int margin = 8;
    const int x0 = std::max(0, bx0 - margin), y0 = std::max(0, by0 - margin);
    const int x1 = std::min(w - 1, bx1 + margin), y1 = std::min(h - 1, by1 + margin);
    const int nw = x1 - x0 + 1, nh = y1 - y0 + 1;
    ImageF crop(nw, nh, 1);
    for (int y = 0; y < nh; ++y)
      std::copy(out.depth_m.row(y0 + y) + x0, out.depth_m.row(y0 + y) + x0 + nw, crop.row(y));
    PinholeCamera cc = frame.camera;
    cc.cx -= x0;
    cc.cy -= y0;
    cc.width = nw;
    cc.height = nh;
    const ImageF nc =
        NormalsFromDepth(crop, cc, 2, options.normal_rel_discontinuity, options.num_threads);
    const int inner = 4;  // the crop's own border lacks neighbours: keep the full-image values
    for (int y = 0; y < nh; ++y) {
      if ((y0 + y >= inner && y < inner) || (y0 + y < h - inner && y >= nh - inner)) continue;
      for (int x = 0; x < nw; ++x) {
        if ((x0 + x >= inner && x < inner) || (x0 + x < w - inner && x >= nw - inner)) continue;
        for (int k = 0; k < 3; ++k) out.normals.at(x0 + x, y0 + y, k) = nc.at(x, y, k);
      }
    }
  }
  out.stats.ms_total = MsSince(t_start);
  out.stats.cpu_ms_total = CpuMs() - c_start;
  return out;
}

}  // namespace exo::inpaint
