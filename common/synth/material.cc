#include "common/synth/material.h"

#include <algorithm>
#include <cmath>

namespace exo::synth {
namespace {

inline uint32_t Hash(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return x;
}
inline uint32_t Hash3i(int32_t a, int32_t b, int32_t c, uint32_t seed) {
  return Hash(static_cast<uint32_t>(a) * 0x8da6b343U ^ Hash(static_cast<uint32_t>(b) * 0xd8163841U ^
                                                            Hash(static_cast<uint32_t>(c) * 0xcb1ab31fU ^ seed)));
}
// Uniform [0,1) from integer coordinates.
inline double Rand01(int32_t a, int32_t b, int32_t c, uint32_t seed) {
  return (Hash3i(a, b, c, seed) >> 8) * (1.0 / 16777216.0);
}
inline double Fade(double t) { return t * t * (3 - 2 * t); }
inline double Clamp01(double x) { return std::clamp(x, 0.0, 1.0); }
inline glm::dvec3 Mix(const glm::dvec3& a, const glm::dvec3& b, double t) { return a + (b - a) * t; }

// 2D value noise in [0,1].
double ValueNoise2(double x, double y, uint32_t seed) {
  const double fx = std::floor(x), fy = std::floor(y);
  const int32_t ix = static_cast<int32_t>(fx), iy = static_cast<int32_t>(fy);
  const double tx = Fade(x - fx), ty = Fade(y - fy);
  const double a = Rand01(ix, iy, 0, seed), b = Rand01(ix + 1, iy, 0, seed);
  const double c = Rand01(ix, iy + 1, 0, seed), d = Rand01(ix + 1, iy + 1, 0, seed);
  return (a + (b - a) * tx) + ((c + (d - c) * tx) - (a + (b - a) * tx)) * ty;
}

// Band-limited fractal noise on a 2D surface parametrisation, normalised to [0,1] with mean 0.5.
// Octaves whose wavelength is below 2 footprints contribute their mean (fade between 2 and 4).
double Fbm2(double u, double v, double wavelength, int octaves, double footprint, uint32_t seed) {
  double sum = 0, norm = 0, amp = 1;
  for (int o = 0; o < octaves; ++o) {
    const double ratio = wavelength / std::max(footprint, 1e-9);
    const double w = Clamp01((ratio - 2.0) / 2.0);
    double n = 0.5;
    if (w > 0) n = 0.5 + w * (ValueNoise2(u / wavelength, v / wavelength, seed + 977 * o) - 0.5);
    sum += amp * n;
    norm += amp;
    if (w <= 0) {  // all finer octaves are at their mean as well
      for (int r = o + 1; r < octaves; ++r) {
        amp *= 0.55;
        sum += amp * 0.5;
        norm += amp;
      }
      break;
    }
    amp *= 0.55;
    wavelength *= 0.5;
  }
  return sum / norm;
}

// Fraction of a box filter of width fw centred at x covered by lines of width `width` repeating
// with `period` (lines occupy [k*period, k*period + width)).
double LineCoverage(double x, double period, double width, double fw) {
  if (fw >= period) return width / period;
  auto integral = [&](double t) {
    const double k = std::floor(t / period);
    return k * width + std::min(t - k * period, width);
  };
  fw = std::max(fw, 1e-6);
  return Clamp01((integral(x + 0.5 * fw) - integral(x - 0.5 * fw)) / fw);
}
// Coverage of [a, b] by a box filter of width fw centred at x.
double IntervalCoverage(double x, double a, double b, double fw) {
  fw = std::max(fw, 1e-6);
  return Clamp01((std::min(x + 0.5 * fw, b) - std::max(x - 0.5 * fw, a)) / fw);
}
// Fades a per-element variation to its mean when elements shrink below ~2 pixels.
double Detail(double element_size, double footprint) {
  return Clamp01((element_size / std::max(footprint, 1e-9) - 1.0) / 2.0);
}

// Authoring colour (sRGB-ish) -> linear, with gamma 2 (cheap: evaluated per pixel).
inline glm::dvec3 Srgb(double r, double g, double b) { return {r * r, g * g, b * b}; }

struct UV {
  double u, v;
};
// Surface parametrisation: horizontal faces use (x, y); others (horizontal tangent, z).
UV SurfaceUV(const glm::dvec3& p, const glm::dvec3& n) {
  if (std::abs(n.z) > 0.7) return {p.x, p.y};
  glm::dvec3 t(-n.y, n.x, 0.0);
  const double len = std::hypot(t.x, t.y);
  t = len > 1e-9 ? t / len : glm::dvec3(1, 0, 0);
  // Keep the same parametrisation for both sides of a wall (sign independent of n).
  if (t.x < -1e-9 || (std::abs(t.x) <= 1e-9 && t.y < 0)) t = -t;
  return {p.x * t.x + p.y * t.y, p.z};
}

// Windows on building facades (outdoor walls): glass with a white frame and a cross mullion.
bool Window(double u, double v, double fw, SurfaceSample* s) {
  if (v < 0.8) return false;
  const double wu = u - 3.0 * std::floor(u / 3.0), wv = v - 3.0 * std::floor(v / 3.0);
  if (wu < 0.9 || wu > 2.1 || wv < 0.9 || wv > 2.4) return false;
  const double fu = std::min(wu - 0.9, 2.1 - wu), fv = std::min(wv - 0.9, 2.4 - wv);
  const double mull = std::min(std::abs(wu - 1.5), std::abs(wv - 1.75));
  if (fu < 0.07 || fv < 0.07 || mull < 0.03) {
    s->albedo = glm::vec3(Srgb(0.85, 0.85, 0.82));
    return true;
  }
  const double g = 0.5 + 0.5 * std::sin(u * 1.7 + v * 0.6);  // faint reflection gradient
  s->albedo = glm::vec3(Srgb(0.10 + 0.08 * g, 0.13 + 0.08 * g, 0.18 + 0.1 * g));
  s->specular = 0.9f;
  s->shininess = 120.0f;
  return true;
}

}  // namespace

double ValueNoise3(const glm::dvec3& p, uint32_t seed) {
  const glm::dvec3 f = glm::floor(p);
  const int32_t ix = static_cast<int32_t>(f.x), iy = static_cast<int32_t>(f.y),
                iz = static_cast<int32_t>(f.z);
  const double tx = Fade(p.x - f.x), ty = Fade(p.y - f.y), tz = Fade(p.z - f.z);
  double c[2];
  for (int k = 0; k < 2; ++k) {
    const double a = Rand01(ix, iy, iz + k, seed), b = Rand01(ix + 1, iy, iz + k, seed);
    const double cc = Rand01(ix, iy + 1, iz + k, seed), d = Rand01(ix + 1, iy + 1, iz + k, seed);
    const double ab = a + (b - a) * tx, cd = cc + (d - cc) * tx;
    c[k] = ab + (cd - ab) * ty;
  }
  return c[0] + (c[1] - c[0]) * tz;
}

double Fbm3(const glm::dvec3& p, double wavelength, int octaves, double footprint, uint32_t seed) {
  double sum = 0, norm = 0, amp = 1;
  for (int o = 0; o < octaves; ++o) {
    const double w = Clamp01((wavelength / std::max(footprint, 1e-9) - 2.0) / 2.0);
    sum += amp * (0.5 + w * (w > 0 ? ValueNoise3(p / wavelength, seed + 131 * o) - 0.5 : 0.0));
    norm += amp;
    amp *= 0.55;
    wavelength *= 0.5;
  }
  return sum / norm;
}

SurfaceSample EvalMaterial(const SynthScene& scene, Material material, const glm::dvec3& p,
                           const glm::dvec3& n, double fw) {
  SurfaceSample s;
  const uint32_t seed = scene.texture_seed + 7919u * static_cast<uint32_t>(material);
  const UV uv = SurfaceUV(p, n);
  glm::dvec3 c(0.5);
  switch (material) {
    case Material::kGrass: {
      const double lush = Fbm2(uv.u, uv.v, 4.0, 3, fw, seed + 1);
      const double blades = Fbm2(uv.u, uv.v, 0.25, 5, fw, seed);
      const glm::dvec3 green = Srgb(0.30, 0.48, 0.16), dry = Srgb(0.52, 0.50, 0.26);
      c = Mix(green, dry, Clamp01((lush - 0.35) * 1.6)) * (0.55 + 0.9 * blades);
      break;
    }
    case Material::kAsphalt: {
      const double grain = Fbm2(uv.u, uv.v, 0.4, 6, fw, seed);
      const double patches = Fbm2(uv.u, uv.v, 5.0, 2, fw, seed + 5);
      c = Srgb(0.30, 0.30, 0.31) * (0.6 + 0.5 * grain) * (0.8 + 0.4 * patches);
      // Lane markings: dashed centre lines and solid edge lines, not inside crossings.
      double paint = 0;
      const double hw = scene.street_half_width_m;
      auto in_other = [&](const std::vector<double>& others, double coord) {
        for (double o : others)
          if (std::abs(coord - o) < hw + 0.5) return true;
        return false;
      };
      for (double sx : scene.street_x) {
        if (std::abs(p.x - sx) > hw || in_other(scene.street_y, p.y)) continue;
        const double dash = IntervalCoverage(p.y - 3.0 * std::floor(p.y / 3.0), 0.0, 1.5, fw);
        paint = std::max(paint, IntervalCoverage(p.x, sx - 0.06, sx + 0.06, fw) * dash);
        paint = std::max(paint, IntervalCoverage(std::abs(p.x - sx), hw - 0.35, hw - 0.25, fw));
      }
      for (double sy : scene.street_y) {
        if (std::abs(p.y - sy) > hw || in_other(scene.street_x, p.x)) continue;
        const double dash = IntervalCoverage(p.x - 3.0 * std::floor(p.x / 3.0), 0.0, 1.5, fw);
        paint = std::max(paint, IntervalCoverage(p.y, sy - 0.06, sy + 0.06, fw) * dash);
        paint = std::max(paint, IntervalCoverage(std::abs(p.y - sy), hw - 0.35, hw - 0.25, fw));
      }
      c = Mix(c, Srgb(0.88, 0.88, 0.84), paint * 0.9);
      break;
    }
    case Material::kPavement: {
      const double size = 0.4;
      const double row = std::floor(uv.v / size);
      const double uu = uv.u + (static_cast<int64_t>(row) & 1 ? 0.5 * size : 0.0);
      const double col = std::floor(uu / size);
      const double var = Rand01(int32_t(col), int32_t(row), 1, seed);
      const double d = Detail(size, fw);
      const double grout = 1 - (1 - LineCoverage(uv.v, size, 0.012, fw)) *
                                   (1 - LineCoverage(uu, size, 0.012, fw));
      const glm::dvec3 stone = Srgb(0.62, 0.58, 0.52) * (1.0 + d * 0.35 * (var - 0.5)) *
                               (0.8 + 0.4 * Fbm2(uv.u, uv.v, 0.2, 4, fw, seed));
      c = Mix(stone, Srgb(0.35, 0.33, 0.30), grout);
      break;
    }
    case Material::kBrick:
    case Material::kPlaster: {
      if (!scene.indoor && std::abs(n.z) < 0.7 && Window(uv.u, uv.v, fw, &s)) return s;
      if (material == Material::kPlaster) {
        const double stucco = Fbm2(uv.u, uv.v, 0.6, 6, fw, seed);
        const glm::dvec3 base = scene.indoor ? Srgb(0.86, 0.83, 0.76) : Srgb(0.87, 0.78, 0.60);
        c = base * (0.78 + 0.4 * stucco);
        break;
      }
      const double bh = 0.075, bw = 0.24;
      const double row = std::floor(uv.v / bh);
      const double uu = uv.u + (static_cast<int64_t>(row) & 1 ? 0.5 * bw : 0.0);
      const double col = std::floor(uu / bw);
      const double var = Rand01(int32_t(col), int32_t(row), 2, seed);
      const double d = Detail(bh, fw);
      const double mortar = 1 - (1 - LineCoverage(uv.v, bh, 0.012, fw)) *
                                    (1 - LineCoverage(uu, bw, 0.012, fw));
      const glm::dvec3 brick = Mix(Srgb(0.62, 0.30, 0.20), Srgb(0.50, 0.22, 0.15), var * d + 0.5 * (1 - d)) *
                               (0.8 + 0.4 * Fbm2(uv.u, uv.v, 0.08, 3, fw, seed + 3));
      c = Mix(brick, Srgb(0.72, 0.70, 0.66), mortar);
      break;
    }
    case Material::kRoofTiles: {
      const double th = 0.12, tw = 0.22;
      const double row = std::floor(uv.v / th);
      const double uu = uv.u + (static_cast<int64_t>(row) & 1 ? 0.5 * tw : 0.0);
      const double col = std::floor(uu / tw);
      const double var = Rand01(int32_t(col), int32_t(row), 3, seed);
      const double d = Detail(th, fw);
      const double in_row = (uv.v - row * th) / th;  // 0 at the lower edge
      const double shade = 1.0 - d * 0.45 * (1.0 - in_row) * (1.0 - in_row);
      const double seam = LineCoverage(uu, tw, 0.01, fw);
      c = Srgb(0.66, 0.30, 0.20) * (1.0 + d * 0.3 * (var - 0.5)) * shade * (1 - 0.5 * seam) *
          (0.85 + 0.3 * Fbm2(uv.u, uv.v, 1.5, 3, fw, seed));
      break;
    }
    case Material::kWood: {
      const bool horizontal = std::abs(n.z) > 0.7;
      const double along = horizontal ? p.x : uv.u, across = horizontal ? p.y : uv.v;
      const double pw = 0.14, pl = 1.2;
      const double prow = std::floor(across / pw);
      const double shift = Rand01(int32_t(prow), 0, 4, seed) * pl;
      const double pcol = std::floor((along + shift) / pl);
      const double var = Rand01(int32_t(pcol), int32_t(prow), 5, seed);
      const double d = Detail(pw, fw);
      const double grain_w = Clamp01((0.01 / std::max(fw, 1e-9) - 1.0) / 2.0);
      const double grain =
          0.5 + 0.5 * std::sin(across * 260.0 + 9.0 * Fbm2(along * 0.15, across * 2, 0.1, 3, fw, seed));
      const double gaps = 1 - (1 - LineCoverage(across, pw, 0.004, fw)) *
                                  (1 - LineCoverage(along + shift, pl, 0.004, fw));
      c = Srgb(0.62, 0.42, 0.26) * (1.0 + d * 0.45 * (var - 0.5)) *
          (1.0 + grain_w * 0.25 * (grain - 0.5)) * (1 - 0.6 * gaps);
      break;
    }
    case Material::kFloorTiles: {
      const double ts = 0.3;
      const double iu = std::floor(uv.u / ts), iv = std::floor(uv.v / ts);
      const bool alt = (static_cast<int64_t>(iu + iv) & 1) != 0;
      const double d = Detail(ts, fw);
      const double grout = 1 - (1 - LineCoverage(uv.u, ts, 0.006, fw)) *
                                   (1 - LineCoverage(uv.v, ts, 0.006, fw));
      const glm::dvec3 light = Srgb(0.85, 0.84, 0.80), dark = Srgb(0.55, 0.58, 0.62);
      const glm::dvec3 tile = Mix(light, dark, alt ? d : 0.5 * (1 - d)) *
                              (0.85 + 0.3 * Fbm2(uv.u, uv.v, 0.15, 4, fw, seed));
      c = Mix(tile, Srgb(0.4, 0.4, 0.38), grout);
      s.specular = 0.25f;
      s.shininess = 60;
      break;
    }
    case Material::kWallpaper: {
      const double period = 0.12;
      const double stripe = LineCoverage(uv.u, period, 0.05, fw);
      const glm::dvec3 a = Srgb(0.80, 0.78, 0.64), b = Srgb(0.47, 0.58, 0.50);
      c = Mix(a, b, stripe);
      // Small diamonds every 6 cm on the light stripes.
      const double du = uv.u - period * std::floor(uv.u / period) - 0.085;
      const double dv = uv.v - 0.06 * std::floor(uv.v / 0.06) - 0.03;
      const double dia = Clamp01((0.014 - std::abs(du) - std::abs(dv)) / std::max(fw, 1e-4) + 0.5);
      c = Mix(c, Srgb(0.62, 0.35, 0.30), dia * Detail(0.03, fw) * (1 - stripe));
      c *= 0.9 + 0.2 * Fbm2(uv.u, uv.v, 0.5, 3, fw, seed);
      break;
    }
    case Material::kCeiling:
      c = Srgb(0.92, 0.92, 0.90) * (0.9 + 0.2 * Fbm2(uv.u, uv.v, 0.3, 5, fw, seed));
      break;
    case Material::kFabric: {
      const double hue = Rand01(int32_t(std::floor(p.x / 3)), int32_t(std::floor(p.y / 3)), 6, seed);
      const glm::dvec3 base = hue < 0.33 ? Srgb(0.25, 0.35, 0.62)
                              : hue < 0.66 ? Srgb(0.62, 0.25, 0.25) : Srgb(0.35, 0.50, 0.38);
      const double weave = 1 - (1 - LineCoverage(uv.u, 0.006, 0.002, fw)) *
                                   (1 - LineCoverage(uv.v, 0.006, 0.002, fw));
      const double check = LineCoverage(uv.u, 0.12, 0.02, fw) + LineCoverage(uv.v, 0.12, 0.02, fw);
      c = base * (1.0 - 0.25 * weave) * (1.0 + 0.35 * std::min(1.0, check)) *
          (0.85 + 0.3 * Fbm2(uv.u, uv.v, 0.3, 3, fw, seed));
      break;
    }
    case Material::kBark:
      c = Srgb(0.36, 0.26, 0.18) * (0.5 + 0.9 * Fbm2(uv.u * 6.0, uv.v * 0.5, 0.5, 4, fw * 3, seed));
      break;
    case Material::kLeaves: {
      const double f = Fbm3(p, 0.6, 6, fw, seed);
      c = Mix(Srgb(0.18, 0.38, 0.10), Srgb(0.40, 0.55, 0.18), Fbm3(p, 2.0, 2, fw, seed + 1)) *
          (0.35 + 1.3 * f * f);
      break;
    }
    case Material::kMetal: {
      const double hue = Rand01(int32_t(std::floor(p.x / 5)), int32_t(std::floor(p.y / 5)), 8, seed);
      c = hue < 0.25 ? Srgb(0.70, 0.12, 0.10)
          : hue < 0.5 ? Srgb(0.15, 0.28, 0.62)
          : hue < 0.75 ? Srgb(0.80, 0.80, 0.82) : Srgb(0.25, 0.27, 0.28);
      c *= 0.92 + 0.16 * Fbm2(uv.u, uv.v, 0.5, 3, fw, seed);
      s.specular = 0.7f;
      s.shininess = 80;
      break;
    }
    case Material::kMarble: {
      const double t = Fbm2(uv.u, uv.v, 0.4, 5, fw, seed);
      const double vein = std::abs(std::sin((uv.u * 3.0 + uv.v * 2.0 + 7.0 * t) * 3.14159));
      c = Mix(Srgb(0.35, 0.35, 0.38), Srgb(0.90, 0.89, 0.86), Clamp01(vein * 3.0)) *
          (0.9 + 0.2 * t);
      s.specular = 0.5f;
      s.shininess = 90;
      break;
    }
    case Material::kCount:
      break;
  }
  s.albedo = glm::vec3(glm::clamp(c, 0.0, 1.0));
  return s;
}

}  // namespace exo::synth
