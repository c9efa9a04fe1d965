// Test-only helpers for geometry tests and the geometry benchmark: analytic depth maps of spheres
// and planes (exact ray intersection per pixel centre), look-at poses, frame assembly.
#pragma once

#include <cmath>
#include <functional>
#include <optional>

#include <glm/glm.hpp>
#include <glm/gtc/quaternion.hpp>

#include "common/camera.h"
#include "common/frame.h"
#include "common/image.h"
#include "common/rigid3.h"

namespace exo::geometry_test {

// Pose of a camera at `eye` looking at `target` (OpenCV axes: x right, y down, z forward).
inline Rigid3d LookAt(const glm::dvec3& eye, const glm::dvec3& target,
                      glm::dvec3 up = {0, 0, 1}) {
  const glm::dvec3 z = glm::normalize(target - eye);
  if (std::abs(glm::dot(z, glm::normalize(up))) > 0.99) up = {0, 1, 0};
  const glm::dvec3 y = glm::normalize(-(up - glm::dot(up, z) * z));
  const glm::dvec3 x = glm::cross(y, z);
  Rigid3d p;
  p.rotation = glm::normalize(glm::quat_cast(glm::dmat3(x, y, z)));
  p.translation = eye;
  return p;
}

// A primitive's ray hit: the ray is origin + s * dir with dir = R * RayZ1, so s is z-depth.
using HitFn = std::function<std::optional<double>(const glm::dvec3& origin, const glm::dvec3& dir)>;

inline HitFn Sphere(const glm::dvec3& centre, double radius) {
  return [=](const glm::dvec3& o, const glm::dvec3& d) -> std::optional<double> {
    const glm::dvec3 oc = o - centre;
    const double a = glm::dot(d, d), b = 2 * glm::dot(oc, d), c = glm::dot(oc, oc) - radius * radius;
    const double disc = b * b - 4 * a * c;
    if (disc < 0) return std::nullopt;
    const double s = (-b - std::sqrt(disc)) / (2 * a);
    if (s > 0) return s;
    return std::nullopt;
  };
}
// Plane n . p = offset (n unit), seen from either side.
inline HitFn Plane(const glm::dvec3& n, double offset) {
  return [=](const glm::dvec3& o, const glm::dvec3& d) -> std::optional<double> {
    const double nd = glm::dot(n, d);
    if (std::abs(nd) < 1e-12) return std::nullopt;
    const double s = (offset - glm::dot(n, o)) / nd;
    if (s > 0) return s;
    return std::nullopt;
  };
}
// Nearest hit of several primitives.
inline HitFn Union(std::vector<HitFn> fns) {
  return [fns](const glm::dvec3& o, const glm::dvec3& d) -> std::optional<double> {
    std::optional<double> best;
    for (const auto& f : fns)
      if (auto s = f(o, d); s && (!best || *s < *best)) best = s;
    return best;
  };
}

// z-depth image of `hit` seen from `world_from_cam` (0 where nothing is hit).
inline ImageF RenderDepth(const PinholeCamera& cam, const Rigid3d& world_from_cam, const HitFn& hit) {
  ImageF depth(cam.width, cam.height, 1, 0.0f);
  const glm::dmat3 r = world_from_cam.RotationMatrix();
  for (int v = 0; v < cam.height; ++v)
    for (int u = 0; u < cam.width; ++u) {
      const glm::dvec3 dir = r * cam.RayZ1({double(u), double(v)});
      if (auto s = hit(world_from_cam.translation, dir)) depth.at(u, v) = float(*s);
    }
  return depth;
}

// Registered RGB-D frame; colour from a function of the world point (default mid grey).
inline Frame MakeFrame(const PinholeCamera& cam, const Rigid3d& world_from_cam, ImageF depth,
                       std::function<glm::u8vec3(const glm::dvec3&)> color_of = nullptr) {
  Frame f;
  f.color_camera = f.depth_camera = cam;
  f.world_from_cam = world_from_cam;
  f.color = ImageU8(cam.width, cam.height, 3, 128);
  if (color_of) {
    const glm::dmat3 r = world_from_cam.RotationMatrix();
    for (int v = 0; v < cam.height; ++v)
      for (int u = 0; u < cam.width; ++u) {
        const float d = depth.at(u, v);
        if (!(d > 0) || !std::isfinite(d)) continue;
        const glm::dvec3 p = world_from_cam.translation + r * cam.RayZ1({double(u), double(v)}) * double(d);
        const glm::u8vec3 c = color_of(p);
        for (int k = 0; k < 3; ++k) f.color.at(u, v, k) = c[k];
      }
  }
  f.depth_m = std::move(depth);
  return f;
}

}  // namespace exo::geometry_test
