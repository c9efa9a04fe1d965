#include "server/inpainting/patch_match.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <thread>
#include <utility>
#include <vector>

#include "server/inpainting/depth_maps.h"
#include "server/inpainting/parallel_rows.h"

namespace exo::inpainting {
namespace {

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
                         (static_cast<uint64_t>(iter + 7) << 32) ^ static_cast<uint32_t>(pixel)))) {
  }
  uint32_t Next() {
    s = Mix(s);
    return static_cast<uint32_t>(s >> 32);
  }
  int Uniform(int n) { return static_cast<int>((static_cast<uint64_t>(Next()) * n) >> 32); }
};

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
      for (int k = 0; k < 3; ++k)
        c.color[ci * 3 + k] = static_cast<uint8_t>((col[k] + cnt / 2) / cnt);
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
    const float ex = static_cast<float>(sx + kDx[k] - fx),
                ey = static_cast<float>(sy + kDy[k] - fy);
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
              if (L.target[ni] && L.src[ni * 2] >= 0)
                consider(L.src[ni * 2] + d, L.src[ni * 2 + 1]);
            }
            const int ny = y - d;
            if (ny >= 0 && ny < L.h) {
              const size_t ni = L.Idx(x, ny);
              if (L.target[ni] && L.src[ni * 2] >= 0)
                consider(L.src[ni * 2], L.src[ni * 2 + 1] + d);
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
    const float ex = static_cast<float>(sx + kDx[k] - fx),
                ey = static_cast<float>(sy + kDy[k] - fy);
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
        const int order[4][2] = {
            {x & 1, y & 1}, {1 - (x & 1), y & 1}, {x & 1, 1 - (y & 1)}, {1 - (x & 1), 1 - (y & 1)}};
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
  if (L.src.size() != static_cast<size_t>(w) * h * 2)
    L.src.assign(static_cast<size_t>(w) * h * 2, -1);
  if (L.fixed.size() != static_cast<size_t>(w) * h) L.fixed.assign(static_cast<size_t>(w) * h, 0);
}

int Propagate(const InpaintResult& prev, const RgbdKeyframe& frame, Level& L) {
  const PinholeCamera& cam_k = frame.camera;
  const PinholeCamera& cam_p = prev.camera;
  const Rigid3d k_from_p = frame.world_from_cam.Inverse() * prev.world_from_cam;
  const Rigid3d p_from_k = k_from_p.Inverse();
  const int w = L.w, h = L.h;
  // Depth of T in this keyframe: forward-warp the previous inpainted depth (z-buffer, 2x2
  // footprint), standing in for the projection of the fused global map.
  std::vector<float> zbuf(static_cast<size_t>(w) * h, std::numeric_limits<float>::infinity());
  // Only T's pixels read the z-buffer: only the previous pixels whose 2x2 footprint can reach
  // T's bounding box are warped (SourcePixelsOnto; the same z-buffer values there).
  PixelRect tbox{w, h, 0, 0};
  for (int y = 0; y < h; ++y)
    if (L.row_x1[y] >= 0) {
      tbox.x0 = std::min(tbox.x0, L.row_x0[y]);
      tbox.x1 = std::max(tbox.x1, L.row_x1[y] + 1);
      tbox.y0 = std::min(tbox.y0, y);
      tbox.y1 = y + 1;
    }
  if (tbox.x1 <= tbox.x0) return 0;
  const PixelRect rect = SourcePixelsOnto(prev.depth_m, cam_p, cam_k, k_from_p, tbox);
  for (int y = rect.y0; y < rect.y1; ++y) {
    for (int x = rect.x0; x < rect.x1; ++x) {
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
      const glm::dvec3 p = cam_k.Unproject({x, y}, zk);  // 4.3
      glm::dvec2 uvp;
      if (!cam_p.Project(p_from_k * p, &uvp) || !cam_p.InImage(uvp)) continue;  // 4.4
      const int px = static_cast<int>(std::lround(uvp.x)),
                py = static_cast<int>(std::lround(uvp.y));
      int sx = px, sy = py;  // 4.5
      if (prev.mask.at(px, py)) {
        sx = prev.source.at(px, py, 0);
        sy = prev.source.at(px, py, 1);
        if (sx < 0) continue;
      }
      const float zs = prev.depth_m.at(sx, sy);
      if (!(zs > 0.f)) continue;
      const glm::dvec3 ps = k_from_p * cam_p.Unproject({sx, sy}, zs);  // 4.3
      glm::dvec2 uvs;
      if (!cam_k.Project(ps, &uvs)) continue;  // 4.4
      const int qx = static_cast<int>(std::lround(uvs.x)),
                qy = static_cast<int>(std::lround(uvs.y));
      if (qx < 0 || qy < 0 || qx >= w || qy >= h || !L.source_ok[L.Idx(qx, qy)]) continue;
      L.src[i * 2] = qx;
      L.src[i * 2 + 1] = qy;
      L.fixed[i] = 1;
      ++mapped;
    }
  }
  return mapped;
}

void SearchFromPropagated(Level& L, const SearchParams& p, const InpaintOptions& o) {
  // Only what the previous keyframe could not map is searched, at full resolution.
  GrowFromMapped(L, o.seed);
  CopyFromSources(L, o.num_threads);
  const int radius0 = std::max(L.w, L.h) / 4;
  for (int it = 0; it < o.propagated_iterations; ++it) {
    Sweep(L, 0, it, radius0, true, p, o);
    CopyFromSources(L, o.num_threads);
  }
}

int SearchPyramid(std::vector<Level>* levels_io, const SearchParams& p, const InpaintOptions& o,
                  int* sweeps) {
  std::vector<Level>& levels = *levels_io;
  const int max_levels = o.pyramid_levels > 0 ? o.pyramid_levels : 12;
  while (static_cast<int>(levels.size()) < max_levels) {
    const Level& f = levels.back();
    if (o.pyramid_levels == 0 && std::min((f.w + 1) / 2, (f.h + 1) / 2) < o.min_coarse_side) break;
    if (std::min(f.w, f.h) < 10) break;
    Level c = Downsample(f);
    if (c.src_list.empty()) break;  // too coarse to hold a single source patch
    bool any_target = false;
    for (uint8_t t : c.target) any_target |= t != 0;
    if (!any_target) break;
    levels.push_back(std::move(c));
  }
  const int nl = static_cast<int>(levels.size());
  for (int li = nl - 1; li >= 0; --li) {
    Level& L = levels[li];
    if (li == nl - 1) {
      // T pixels not reached by the onion peel (cut off from every known pixel) keep the
      // random source; the peel overwrites the rest.
      SmoothFillTarget(L);
      RandomInit(L, li, o.seed);
      OnionPeelInit(L, li, p, o);
    } else {
      Upsample(levels[li + 1], L, li, o.seed);
      CopyFromSources(L, o.num_threads);
    }
    const int iters =
        nl == 1 ? o.fine_iterations
                : o.fine_iterations + (o.coarse_iterations - o.fine_iterations) * li / (nl - 1);
    const int radius0 = li == nl - 1 ? std::max(L.w, L.h) : std::max(4, std::max(L.w, L.h) / 8);
    int level_target = 0;
    for (uint8_t t : L.target) level_target += t != 0;
    for (int it = 0; it < iters; ++it) {
      const int changed = Sweep(L, li, it, radius0, li == nl - 1, p, o);
      CopyFromSources(L, o.num_threads);
      ++*sweeps;
      // Converged: the sweep changed (almost) nothing, later sweeps would repeat it.
      if (it + 1 < iters && changed <= o.converged_fraction * level_target) break;
    }
    if (li > 0) levels[li].color.shrink_to_fit();
  }
  return nl;
}

}  // namespace exo::inpainting
