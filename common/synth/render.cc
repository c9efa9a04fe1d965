#include "common/synth/render.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <thread>
#include <vector>

#include <glm/gtc/quaternion.hpp>

#include "common/raster/rasterizer.h"
#include "common/synth/material.h"

namespace exo::synth {
namespace {

constexpr int kSrgbLutSize = 8192;

const std::array<uint8_t, kSrgbLutSize + 1>& SrgbLut() {
  static const auto lut = [] {
    std::array<uint8_t, kSrgbLutSize + 1> t{};
    for (int i = 0; i <= kSrgbLutSize; ++i) {
      const double c = double(i) / kSrgbLutSize;
      const double s = c <= 0.0031308 ? 12.92 * c : 1.055 * std::pow(c, 1.0 / 2.4) - 0.055;
      t[i] = static_cast<uint8_t>(std::lround(std::clamp(s, 0.0, 1.0) * 255.0));
    }
    return t;
  }();
  return lut;
}

glm::dvec3 Sky(const glm::dvec3& dir_local) {
  const double e = std::clamp(dir_local.z, 0.0, 1.0);
  const glm::dvec3 horizon(0.62, 0.70, 0.80), zenith(0.18, 0.32, 0.62);
  glm::dvec3 c = horizon + (zenith - horizon) * std::sqrt(e);
  if (dir_local.z < 0) c *= 0.8;  // below the horizon (outside the ground patch)
  return c;
}

}  // namespace

absl::Status RenderOptions::Validate() const {
  if (width < 8 || height < 8 || width > 8192 || height > 8192)
    return absl::InvalidArgumentError(
        absl::StrCat("render size must be in [8, 8192], got ", width, "x", height));
  if (!(hfov_deg > 5 && hfov_deg < 170))
    return absl::InvalidArgumentError(
        absl::StrCat("render hfov_deg must be in (5, 170), got ", hfov_deg));
  if (num_threads < 1 || num_threads > 256)
    return absl::InvalidArgumentError("render num_threads must be in [1, 256]");
  return absl::OkStatus();
}

absl::Status FrameNoise::Validate() const {
  if (!(exposure > 0) || !std::isfinite(exposure))
    return absl::InvalidArgumentError(absl::StrCat("exposure must be > 0, got ", exposure));
  if (!(rotation_deg >= 0 && rotation_deg < 180))
    return absl::InvalidArgumentError("pose noise rotation_deg must be in [0, 180)");
  if (!(translation_m >= 0) || !std::isfinite(translation_m))
    return absl::InvalidArgumentError("pose noise translation_m must be >= 0");
  return absl::OkStatus();
}

uint8_t LinearToSrgb8(float linear) {
  if (!(linear > 0)) return 0;
  if (linear >= 1) return 255;
  return SrgbLut()[static_cast<int>(linear * kSrgbLutSize + 0.5f)];
}

float Srgb8ToLinear(uint8_t srgb) {
  const double s = srgb / 255.0;
  return static_cast<float>(s <= 0.04045 ? s / 12.92 : std::pow((s + 0.055) / 1.055, 2.4));
}

Rigid3d PerturbPose(const Rigid3d& pose, double rotation_deg, double translation_m,
                    uint64_t seed) {
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ull + 0x1234567);
  std::normal_distribution<double> g(0, 1);
  auto random_unit = [&] {
    glm::dvec3 v;
    do v = {g(rng), g(rng), g(rng)};
    while (glm::length(v) < 1e-6);
    return glm::normalize(v);
  };
  Rigid3d out = pose;
  const glm::dvec3 axis = random_unit();
  const glm::dvec3 dir = random_unit();
  out.rotation = glm::normalize(glm::angleAxis(glm::radians(rotation_deg), axis) * pose.rotation);
  out.translation = pose.translation + translation_m * dir;
  return out;
}

absl::StatusOr<ImageF> RenderLinear(const SynthScene& scene, const Rigid3d& local_from_cam,
                                    const RenderOptions& options, ImageF* z_depth_m) {
  EXO_RETURN_IF_ERROR(options.Validate());
  const PinholeCamera cam = options.Camera();
  RasterOptions ro;
  ro.z_depth = true;
  ro.range = true;
  ro.position = true;
  ro.normal = true;
  ro.triangle_id = true;
  ro.num_threads = options.num_threads;
  ro.near_m = 0.05;
  EXO_ASSIGN_OR_RETURN(RasterOutput r, Rasterize(scene.mesh, cam, local_from_cam, ro));

  const int W = cam.width, H = cam.height;
  ImageF rgb(W, H, 3, 0.0f);
  const glm::dvec3 cam_pos = local_from_cam.translation;
  const glm::dmat3 R = local_from_cam.RotationMatrix();
  const glm::dvec3 l = glm::normalize(scene.sun_dir);
  const double sun = scene.indoor ? 0.75 : 1.15;
  auto shade_rows = [&](int y0, int step) {
    for (int y = y0; y < H; y += step) {
      for (int x = 0; x < W; ++x) {
        const uint32_t tri = r.triangle_id.at(x, y);
        glm::dvec3 color;
        if (tri == kNoTriangle) {
          color = scene.indoor ? glm::dvec3(0.0) : Sky(R * glm::normalize(cam.RayZ1({x, y})));
        } else {
          const glm::dvec3 p(r.position_local.at(x, y, 0), r.position_local.at(x, y, 1),
                             r.position_local.at(x, y, 2));
          glm::dvec3 n(r.normal_local.at(x, y, 0), r.normal_local.at(x, y, 1),
                       r.normal_local.at(x, y, 2));
          const glm::dvec3 v = glm::normalize(cam_pos - p);
          double nv = glm::dot(n, v);
          if (nv < 0) {
            n = -n;
            nv = -nv;
          }
          const double footprint = r.range_m.at(x, y) / cam.fx / std::max(nv, 0.25);
          const auto mat = static_cast<Material>(
              scene.mesh.material.empty() ? 0 : scene.mesh.material[tri]);
          const SurfaceSample s = EvalMaterial(scene, mat, p, n, footprint);
          const double nl = std::max(0.0, glm::dot(n, l));
          // Hemisphere ambient (sky above, bounce below) + directional sun / room light.
          const double amb = scene.ambient * (0.8 + 0.2 * n.z);
          color = glm::dvec3(s.albedo) * (amb + sun * (1 - scene.ambient) * nl);
          if (options.specular && s.specular > 0 && nl > 0) {
            const glm::dvec3 h = glm::normalize(l + v);
            const double spec = s.specular * std::pow(std::max(0.0, glm::dot(n, h)), s.shininess);
            color += glm::dvec3(spec * sun);
          }
        }
        for (int c = 0; c < 3; ++c) rgb.at(x, y, c) = static_cast<float>(color[c]);
      }
    }
  };
  const int threads = std::max(1, std::min(options.num_threads, H));
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(shade_rows, t, threads);
  shade_rows(0, threads);
  for (auto& th : pool) th.join();
  if (z_depth_m) *z_depth_m = std::move(r.z_depth_m);
  return rgb;
}

absl::StatusOr<RenderedFrame> RenderFrame(const SynthScene& scene, const Rigid3d& local_from_cam,
                                          const RenderOptions& options, const FrameNoise& noise,
                                          uint64_t sequence, double timestamp_s) {
  EXO_RETURN_IF_ERROR(noise.Validate());
  ImageF depth;
  EXO_ASSIGN_OR_RETURN(ImageF linear, RenderLinear(scene, local_from_cam, options, &depth));
  RenderedFrame out;
  Frame& f = out.frame;
  f.sequence = sequence;
  f.timestamp_s = timestamp_s;
  f.color_camera = f.depth_camera = options.Camera();
  f.color_from_depth = Rigid3d::Identity();
  f.color = ImageU8(linear.width(), linear.height(), 3);
  const float e = static_cast<float>(noise.exposure);
  for (size_t i = 0; i < linear.size(); ++i) f.color.data()[i] = LinearToSrgb8(linear.data()[i] * e);
  f.depth_m = std::move(depth);
  f.exposure = noise.exposure;
  auto to_world = [&](const Rigid3d& local) {
    return Rigid3d{local.rotation, local.translation + scene.origin.origin_in_world};
  };
  out.true_world_from_cam = to_world(local_from_cam);
  const bool noisy = noise.rotation_deg > 0 || noise.translation_m > 0;
  f.world_from_cam = noisy ? to_world(PerturbPose(local_from_cam, noise.rotation_deg,
                                                  noise.translation_m, noise.seed))
                           : out.true_world_from_cam;
  return out;
}

}  // namespace exo::synth
