#include "server/refinement/testing/room_scene.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace exo::refinement_testing {
namespace {

uint32_t Hash(int x, int y, uint32_t s) {
  uint32_t h = static_cast<uint32_t>(x) * 374761393u + static_cast<uint32_t>(y) * 668265263u +
               s * 2246822519u;
  h = (h ^ (h >> 13)) * 1274126177u;
  return h ^ (h >> 16);
}
double Lattice(int x, int y, uint32_t s) { return (Hash(x, y, s) & 0xffffff) / double(0xffffff); }
double Smooth(double t) { return t * t * (3 - 2 * t); }
double ValueNoise(double x, double y, uint32_t s) {
  const double fx = std::floor(x), fy = std::floor(y);
  const int ix = static_cast<int>(fx), iy = static_cast<int>(fy);
  const double tx = Smooth(x - fx), ty = Smooth(y - fy);
  const double a = Lattice(ix, iy, s), b = Lattice(ix + 1, iy, s), c = Lattice(ix, iy + 1, s),
               d = Lattice(ix + 1, iy + 1, s);
  return (1 - ty) * ((1 - tx) * a + tx * b) + ty * ((1 - tx) * c + tx * d);
}

uint8_t ToSrgb8(double l) {
  l = std::clamp(l, 0.0, 1.0);
  const double s = l <= 0.0031308 ? 12.92 * l : 1.055 * std::pow(l, 1 / 2.4) - 0.055;
  return static_cast<uint8_t>(std::lround(s * 255.0));
}

// Nearest hit along a ray: returns t (inf when none), the face id and 2D face coordinates.
struct Hit {
  double t = std::numeric_limits<double>::infinity();
  int face = -1;
  glm::dvec2 st{0.0};
};

void FaceCoords(const glm::dvec3& p, int axis, glm::dvec2* st) {
  if (axis == 0) *st = {p.y, p.z};
  else if (axis == 1) *st = {p.x, p.z};
  else *st = {p.x, p.y};
}

Hit Cast(const RoomScene& sc, const glm::dvec3& o, const glm::dvec3& d) {
  Hit h;
  // Room interior: exit distance.
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-12) continue;
    const double bound = d[a] > 0 ? sc.room_max[a] : sc.room_min[a];
    const double t = (bound - o[a]) / d[a];
    if (t > 0 && t < h.t) {
      h.t = t;
      h.face = a * 2 + (d[a] > 0 ? 1 : 0);
    }
  }
  if (sc.occluder) {
    double t0 = 0, t1 = std::numeric_limits<double>::infinity();
    int axis = -1;
    bool ok = true;
    for (int a = 0; a < 3 && ok; ++a) {
      if (std::abs(d[a]) < 1e-12) {
        if (o[a] < sc.box_min[a] || o[a] > sc.box_max[a]) ok = false;
        continue;
      }
      double ta = (sc.box_min[a] - o[a]) / d[a], tb = (sc.box_max[a] - o[a]) / d[a];
      if (ta > tb) std::swap(ta, tb);
      if (ta > t0) {
        t0 = ta;
        axis = a;
      }
      t1 = std::min(t1, tb);
      if (t0 > t1) ok = false;
    }
    if (ok && axis >= 0 && t0 > 0 && t0 < h.t) {
      h.t = t0;
      h.face = 6 + axis;
    }
  }
  if (h.face >= 0) FaceCoords(o + h.t * d, h.face < 6 ? h.face / 2 : h.face - 6, &h.st);
  return h;
}

glm::dvec3 Albedo(const RoomScene& sc, const Hit& h) {
  static const glm::dvec3 kTint[9] = {{1.0, 0.9, 0.8}, {0.8, 0.9, 1.0}, {1.0, 1.0, 0.9},
                                      {0.9, 1.0, 0.9}, {1.0, 0.85, 0.9}, {0.9, 0.9, 1.0},
                                      {1.0, 0.8, 0.7}, {0.8, 1.0, 0.8}, {0.9, 0.8, 1.0}};
  const glm::dvec3 tint = kTint[h.face];
  if (sc.textureless) return sc.uniform_albedo * tint;
  const uint32_t s = static_cast<uint32_t>(sc.seed * 31 + h.face);
  double n = 0, wsum = 0, w = 1.0;
  double f = 1.0 / (4.0 * sc.feature_m);
  for (int o = 0; o < 3; ++o, f *= 2, w *= 0.6) {
    n += w * ValueNoise(h.st.x * f, h.st.y * f, s + 101u * o);
    wsum += w;
  }
  n /= wsum;
  n = std::clamp((n - 0.2) / 0.6, 0.0, 1.0);  // stretch the contrast
  return (sc.albedo_min + (sc.albedo_max - sc.albedo_min) * n) * tint;
}

}  // namespace

Rigid3d LookAt(const glm::dvec3& eye, const glm::dvec3& target) {
  const glm::dvec3 z = glm::normalize(target - eye);
  glm::dvec3 y = glm::dvec3(0, 1, 0) - glm::dot(glm::dvec3(0, 1, 0), z) * z;
  y = glm::normalize(y);
  const glm::dvec3 x = glm::cross(y, z);
  glm::dmat3 r(x, y, z);  // columns
  Rigid3d p;
  p.rotation = glm::normalize(glm::quat_cast(r));
  p.translation = eye;
  return p;
}

StoredView RenderRoom(const RoomScene& sc, const PinholeCamera& cam, const Rigid3d& local_from_cam,
                      double exposure, double noise_u8, uint64_t noise_seed) {
  StoredView v;
  v.camera = cam;
  v.local_from_cam = local_from_cam;
  v.color = ImageU8(cam.width, cam.height, 3);
  v.depth_m = ImageF(cam.width, cam.height, 1);
  std::mt19937_64 rng(noise_seed);
  std::uniform_real_distribution<double> noise(-noise_u8, noise_u8);
  const glm::dmat3 r = local_from_cam.RotationMatrix();
  const glm::dvec3 o = local_from_cam.translation;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      glm::dvec3 acc(0.0);
      for (int sy = 0; sy < 2; ++sy)
        for (int sx = 0; sx < 2; ++sx) {
          const glm::dvec2 uv{x - 0.25 + 0.5 * sx, y - 0.25 + 0.5 * sy};
          const glm::dvec3 d = r * cam.RayZ1(uv);
          const Hit h = Cast(sc, o, d);
          if (h.face >= 0) acc += Albedo(sc, h);
        }
      acc *= 0.25 * exposure;
      const Hit hc = Cast(sc, o, r * cam.RayZ1({double(x), double(y)}));
      v.depth_m.at(x, y) = hc.face >= 0 ? static_cast<float>(hc.t) : 0.f;  // t along RayZ1 = z
      for (int c = 0; c < 3; ++c) {
        double s = ToSrgb8(acc[c]);
        if (noise_u8 > 0) s = std::clamp(std::round(s + noise(rng)), 0.0, 255.0);
        v.color.at(x, y, c) = static_cast<uint8_t>(s);
      }
    }
  return v;
}

Rigid3d Perturb(const Rigid3d& p, double rot_deg, double trans_m, uint64_t seed) {
  std::mt19937_64 rng(seed * 7919 + 17);
  std::normal_distribution<double> g(0.0, 1.0);
  glm::dvec3 axis, dir;
  do axis = {g(rng), g(rng), g(rng)}; while (glm::length(axis) < 1e-6);
  do dir = {g(rng), g(rng), g(rng)}; while (glm::length(dir) < 1e-6);
  Rigid3d out = p;
  out.rotation = glm::normalize(glm::angleAxis(glm::radians(rot_deg), glm::normalize(axis)) * p.rotation);
  out.translation = p.translation + trans_m * glm::normalize(dir);
  return out;
}

}  // namespace exo::refinement_testing
