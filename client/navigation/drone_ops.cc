#include "client/navigation/drone_ops.h"

#include <algorithm>
#include <cmath>

namespace exo::nav {
namespace {

bool Finite(const glm::dvec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

}  // namespace

Ray3 PixelRay(const PinholeCamera& camera, const Rigid3d& local_from_cam, const glm::dvec2& uv) {
  Ray3 r;
  r.origin = local_from_cam.translation;
  r.dir = glm::normalize(local_from_cam.rotation * camera.RayZ1(uv));
  return r;
}

Ray3 GazeRay(const PinholeCamera& camera, const Rigid3d& local_from_cam, const glm::dvec2& uv,
             double clip_m) {
  Ray3 r = PixelRay(camera, local_from_cam, uv);
  if (clip_m > 0) {
    // RayZ1 has z = 1: the ray reaches the camera's plane z = clip_m after clip_m * |RayZ1|.
    r.origin += r.dir * (clip_m * glm::length(camera.RayZ1(uv)));
  }
  return r;
}

MouseHand HandFromDrag(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                       const glm::dvec2& uv0, double hand_m0, const glm::dvec2& uv1,
                       double hand_m1) {
  MouseHand h;
  h.eye = local_from_cam.translation;
  const Ray3 a = PixelRay(camera, local_from_cam, uv0), b = PixelRay(camera, local_from_cam, uv1);
  h.hand = h.eye + std::max(0.0, hand_m0) * a.dir;
  h.displacement = h.eye + std::max(0.0, hand_m1) * b.dir - h.hand;
  return h;
}

PickPlacePreview PreviewPickAndPlace(const glm::dvec3& drone, const glm::dvec3& eye,
                                     const glm::dvec3& hand, const glm::dvec3& displacement,
                                     double min_hand_eye_m, double max_scale) {
  PickPlacePreview p;
  p.target = drone;
  if (!Finite(drone) || !Finite(eye) || !Finite(hand) || !Finite(displacement)) return p;
  const double hand_eye = glm::length(hand - eye);
  p.guarded = hand_eye < min_hand_eye_m;
  p.scale = glm::length(drone - eye) / std::max(hand_eye, min_hand_eye_m);
  if (p.scale > max_scale) {
    p.scale = max_scale;
    p.guarded = true;
  }
  p.target = drone + p.scale * displacement;
  return p;
}

Sticks SticksFromKeys(const JoypadKeys& k, double deflection) {
  const double d = std::clamp(deflection, 0.0, 1.0);
  Sticks s;
  s.left_x = d * (double(k.turn_left) - double(k.turn_right));
  s.left_y = d * (double(k.up) - double(k.down));
  s.right_x = d * (double(k.right) - double(k.left));
  s.right_y = d * (double(k.forward) - double(k.back));
  return s;
}

Sticks SticksFromGamepad(double left_x, double left_y, double right_x, double right_y,
                         double deadzone) {
  auto dz = [&](double v) {
    if (!std::isfinite(v)) return 0.0;
    v = std::clamp(v, -1.0, 1.0);
    return std::abs(v) < deadzone ? 0.0 : v;
  };
  Sticks s;
  s.left_x = -dz(left_x);    // stick right: turn right (yaw decreases)
  s.left_y = -dz(left_y);    // stick up (y < 0): climb
  s.right_x = dz(right_x);   // stick right: move right
  s.right_y = -dz(right_y);  // stick up: forward
  return s;
}

double XrayClipDistance(std::optional<double> picked_z_depth_m, double margin_m, double default_m) {
  if (picked_z_depth_m && std::isfinite(*picked_z_depth_m) && *picked_z_depth_m > 0)
    return *picked_z_depth_m + std::max(0.0, margin_m);
  return std::max(0.05, default_m);
}

glm::dvec2 XrayHoleCentre(const glm::dvec2& uv, int w, int h) {
  return {(uv.x + 0.5) / std::max(1, w), (uv.y + 0.5) / std::max(1, h)};
}

bool InsideXrayHole(const glm::dvec2& uv, int w, int h, const glm::dvec2& centre, double radius) {
  // The shader's test (shaders/xray_hole.glsl) on the fragment's centre (uv + 0.5).
  const glm::dvec2 d(uv.x + 0.5 - centre.x * w, uv.y + 0.5 - centre.y * h);
  const double r = radius * h;
  return glm::dot(d, d) <= r * r;
}

}  // namespace exo::nav
