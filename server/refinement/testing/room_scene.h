// A small analytic test scene for refinement tests and benchmarks: the inside of a box room
// (optionally with a box occluder) with band-limited procedural value-noise textures, rendered by
// exact ray casting with 2x2 supersampling. Known truth: pose, exposure, z-depth. A uniform
// albedo gives the textureless case; `noise_u8` adds seeded sensor noise after sRGB encoding.
#pragma once

#include <cstdint>

#include <glm/glm.hpp>

#include "common/camera.h"
#include "common/lumigraph/model.h"
#include "common/rigid3.h"

namespace exo::refinement_testing {

struct RoomScene {
  glm::dvec3 room_min{-2.0, -1.2, -2.5}, room_max{2.0, 1.2, 2.5};
  bool occluder = true;  // a box standing in the room
  glm::dvec3 box_min{-0.4, 0.3, -0.4}, box_max{0.4, 1.2, 0.4};
  bool textureless = false;
  double uniform_albedo = 0.4;
  double albedo_min = 0.03, albedo_max = 0.85;  // texture range (linear)
  double feature_m = 0.15;                      // finest texture wavelength
  uint64_t seed = 1;
};

// A pose at `eye` looking at `target` (camera y points down, world y is down too: room
// coordinates are y-down so that no roll appears).
Rigid3d LookAt(const glm::dvec3& eye, const glm::dvec3& target);

// Renders a view: colour = sRGB(exposure * albedo), z-depth. `noise_u8` > 0 adds uniform noise
// of that amplitude (seeded) to each 8-bit channel.
StoredView RenderRoom(const RoomScene& scene, const PinholeCamera& cam, const Rigid3d& local_from_cam,
                      double exposure, double noise_u8 = 0.0, uint64_t noise_seed = 0);

// Pose perturbed by `rot_deg` about a seeded random axis and `trans_m` in a random direction
// (applied to the camera centre).
Rigid3d Perturb(const Rigid3d& local_from_cam, double rot_deg, double trans_m, uint64_t seed);

}  // namespace exo::refinement_testing
