// Renders synthetic RGB-D frames with ground truth: the CPU rasterizer gives local position,
// normal and material per pixel; colour is a procedural texture (per pixel, band-limited by the
// pixel footprint) lit by a fixed sun + ambient (outdoor) or ceiling light (indoor), optionally
// with a view-dependent Blinn-Phong highlight on specular materials. Colour is linear * exposure,
// then sRGB-encoded and clamped; depth is z-depth in metres.
#pragma once

#include <cstdint>

#include "common/camera.h"
#include "common/frame.h"
#include "common/rigid3.h"
#include "common/status.h"
#include "common/synth/scene.h"

namespace exo::synth {

struct RenderOptions {
  int width = 640, height = 480;
  double hfov_deg = 65.0;
  bool specular = false;     // Blinn-Phong highlights on kMetal/kMarble/window glass
  int num_threads = 2;
  absl::Status Validate() const;
  PinholeCamera Camera() const { return PinholeCamera::FromFov(width, height, hfov_deg * 0.017453292519943295); }
};

// Per-frame perturbations for refinement tests.
struct FrameNoise {
  double exposure = 1.0;        // multiplies linear intensity before sRGB encoding
  double rotation_deg = 0.0;    // std-dev-free magnitude: a random axis, this angle
  double translation_m = 0.0;   // a random direction, this length
  uint64_t seed = 0;
  absl::Status Validate() const;
};

struct RenderedFrame {
  Frame frame;                  // world_from_cam = NOISY pose (when noise is set)
  Rigid3d true_world_from_cam;  // the pose the image was rendered from
};

// Renders the scene from `local_from_cam` (true pose). sequence/timestamp are copied.
absl::StatusOr<RenderedFrame> RenderFrame(const SynthScene& scene, const Rigid3d& local_from_cam,
                                          const RenderOptions& options,
                                          const FrameNoise& noise = {}, uint64_t sequence = 0,
                                          double timestamp_s = 0.0);

// Colour only (linear RGB before exposure, 3 ch float) for a pose: the ground truth for test
// views and the basis of RenderFrame.
absl::StatusOr<ImageF> RenderLinear(const SynthScene& scene, const Rigid3d& local_from_cam,
                                    const RenderOptions& options, ImageF* z_depth_m = nullptr);

// sRGB encode of linear [0,1] (clamped) to 8 bits, and its inverse.
uint8_t LinearToSrgb8(float linear);
float Srgb8ToLinear(uint8_t srgb);

// A perturbed pose: rotation by `rotation_deg` about a seeded random axis, translation by
// `translation_m` in a seeded random direction.
Rigid3d PerturbPose(const Rigid3d& pose, double rotation_deg, double translation_m, uint64_t seed);

}  // namespace exo::synth
