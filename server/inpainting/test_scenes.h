// Test-only synthetic RGB-D scenes with exact ground truth: textured planes ray-cast from a
// pinhole camera. The texture is a function of the world point, so every view agrees.
#pragma once

#include <cmath>
#include <functional>
#include <vector>

#include "server/inpainting/inpaint.h"

namespace exo::inpainting::testing {

struct WorldPlane {
  glm::dvec3 n;  // unit normal (world)
  double c;      // n . X = c
  // Optional restriction: the plane only exists where keep(X) is true.
  std::function<bool(const glm::dvec3&)> keep;
};

// Smooth, non-periodic colour texture of a world point.
inline glm::dvec3 Texture(const glm::dvec3& p) {
  const double a = std::sin(7.1 * p.x + 1.3 * p.y + 0.7 * p.z) + 0.5 * std::sin(13.7 * p.y - 4.1 * p.z + 2.0);
  const double b = std::sin(5.3 * p.y + 2.9 * p.z) + 0.5 * std::sin(11.3 * p.x + 6.7 * p.z + 1.0);
  const double c = std::sin(3.7 * p.x - 8.3 * p.y + 3.1 * p.z + 0.5);
  return {128 + 60 * a, 128 + 60 * b, 128 + 90 * c};
}

inline RgbdKeyframe RenderPlanes(const std::vector<WorldPlane>& planes, const PinholeCamera& cam,
                                 const Rigid3d& world_from_cam,
                                 const std::function<glm::dvec3(const glm::dvec3&)>& texture = Texture) {
  RgbdKeyframe f;
  f.camera = cam;
  f.world_from_cam = world_from_cam;
  f.color = ImageU8(cam.width, cam.height, 3, 0);
  f.depth_m = ImageF(cam.width, cam.height, 1, 0.f);
  const glm::dmat3 R = world_from_cam.RotationMatrix();
  const glm::dvec3 o = world_from_cam.translation;
  for (int y = 0; y < cam.height; ++y) {
    for (int x = 0; x < cam.width; ++x) {
      const glm::dvec3 ray_cam = cam.RayZ1({x, y});  // z = 1
      const glm::dvec3 ray = R * ray_cam;
      double best_t = 1e30;
      glm::dvec3 best_p(0.0);
      for (const WorldPlane& pl : planes) {
        const double den = glm::dot(pl.n, ray);
        if (std::fabs(den) < 1e-12) continue;
        const double t = (pl.c - glm::dot(pl.n, o)) / den;  // t = z-depth since ray_cam.z = 1
        if (!(t > 0.0) || t >= best_t) continue;
        const glm::dvec3 p = o + t * ray;
        if (pl.keep && !pl.keep(p)) continue;
        best_t = t;
        best_p = p;
      }
      if (best_t >= 1e30) continue;
      f.depth_m.at(x, y) = static_cast<float>(best_t);
      const glm::dvec3 c = texture(best_p);
      for (int k = 0; k < 3; ++k) {
        f.color.at(x, y, k) = static_cast<uint8_t>(std::clamp(std::lround(c[k]), 0L, 255L));
      }
    }
  }
  return f;
}

inline PinholeCamera SmallCamera(int w = 160, int h = 120) {
  PinholeCamera c;
  c.width = w;
  c.height = h;
  c.fx = c.fy = 0.9 * w;
  c.cx = (w - 1) / 2.0;
  c.cy = (h - 1) / 2.0;
  return c;
}

inline ImageU8 RectMask(int w, int h, int x0, int y0, int x1, int y1) {
  ImageU8 m(w, h, 1, 0);
  for (int y = std::max(0, y0); y < std::min(h, y1); ++y)
    for (int x = std::max(0, x0); x < std::min(w, x1); ++x) m.at(x, y) = 255;
  return m;
}

}  // namespace exo::inpainting::testing
