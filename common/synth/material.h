// Procedural, band-limited materials of the synthetic scenes: albedo (linear RGB) and specular
// parameters evaluated per pixel from the local position, normal and material id. Detail down
// to ~1 cm (bricks, mortar, grain, grout, stripes) fades out where the pixel footprint is larger
// than half its wavelength, so distant surfaces do not alias into noise.
#pragma once

#include <glm/glm.hpp>

#include "common/synth/scene.h"

namespace exo::synth {

struct SurfaceSample {
  glm::vec3 albedo{0.5f};  // linear RGB in [0,1]
  float specular = 0.0f;   // Blinn-Phong strength (used when RenderOptions::specular)
  float shininess = 32.0f;
};

// `footprint_m`: world size of one pixel at this point (range / fx, grown at grazing angles).
SurfaceSample EvalMaterial(const SynthScene& scene, Material material, const glm::dvec3& p_local,
                           const glm::dvec3& normal, double footprint_m);

// Seeded lattice value noise in [0,1] and its band-limited fractal sum (octaves whose
// wavelength is below 2 * footprint are faded out).
double ValueNoise3(const glm::dvec3& p, uint32_t seed);
double Fbm3(const glm::dvec3& p, double base_wavelength_m, int octaves, double footprint_m,
            uint32_t seed);

}  // namespace exo::synth
