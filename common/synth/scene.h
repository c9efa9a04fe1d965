// Synthetic scenes with ground truth (the embedded default of the main job, SPEC §9): an
// outdoor "village" (streets, buildings as occluders, roofs, walls, trees) and an indoor
// "apartment" (rooms, walls with door openings, floor/ceiling, furniture). Generated
// deterministically from a seed, no downloaded assets. Geometry is a TriangleMesh in the
// scene-local frame (metres, z up, ground at z = 0) with one material id per triangle; the
// colour comes from procedural textures evaluated per pixel (synth/material.h).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <glm/glm.hpp>

#include "common/mesh.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo::synth {

// Material ids stored in TriangleMesh::material.
enum class Material : uint32_t {
  kGrass = 0,
  kAsphalt,     // street with lane stripes
  kPavement,    // stone pavers (sidewalks, plaza)
  kBrick,       // brick walls with mortar and windows
  kPlaster,     // rendered walls with windows
  kRoofTiles,
  kWood,        // wooden planks (floors, furniture, doors)
  kFloorTiles,  // ceramic tiles with grout
  kWallpaper,   // striped/patterned interior walls
  kCeiling,
  kFabric,      // sofa/bed: woven pattern
  kBark,
  kLeaves,
  kMetal,       // painted metal (cars, lamps): the optional specular material
  kMarble,      // kitchen counter / table tops: specular
  kCount
};
const char* MaterialName(Material m);

struct Box3 {
  glm::dvec3 min{0.0}, max{0.0};
  bool Contains(const glm::dvec3& p, double margin = 0.0) const {
    return p.x >= min.x - margin && p.y >= min.y - margin && p.z >= min.z - margin &&
           p.x <= max.x + margin && p.y <= max.y + margin && p.z <= max.z + margin;
  }
  glm::dvec3 Centre() const { return 0.5 * (min + max); }
  glm::dvec3 Size() const { return max - min; }
};

enum class SceneKind { kVillage, kApartment };
const char* SceneKindName(SceneKind k);
absl::StatusOr<SceneKind> ParseSceneKind(const std::string& name);

struct SceneOptions {
  uint64_t seed = 1;
  // Faces are split so that no triangle edge is longer than this (metres): keeps per-cell
  // areas and clipping well behaved. 0 = no subdivision.
  double max_edge_m = 2.0;
  // Scene-local origin in the world: frames carry world poses = local + origin (test 1e5 m).
  glm::dvec3 origin_in_world{0.0};
  // Removable objects (issue 18, diminished-reality ground truth): a chair in the apartment's
  // living room, a hand cart in the village street. Off by default (the scenes stay as they
  // were). They are appended after everything else and draw nothing from the seed's random
  // stream, so RemoveObjects() of a scene built with them is the scene built without them.
  bool removable_objects = false;
  absl::Status Validate() const;
};

// One removable object: its triangles are mesh.indices[3 * first_triangle ...] (contiguous).
struct RemovableObject {
  std::string name;       // "chair", "cart"
  Box3 bounds;            // AABB (local frame)
  uint32_t first_triangle = 0, num_triangles = 0;
};

struct SynthScene {
  std::string name;
  SceneKind kind = SceneKind::kVillage;
  TriangleMesh mesh;               // local frame, per-triangle material, no vertex normals
  LocalOrigin origin;              // world = local + origin.origin_in_world
  Box3 bounds;                     // AABB of the mesh
  std::vector<Box3> solids;        // volumes a camera must not enter (buildings, furniture...)
  Box3 navigable;                  // where cameras may be (inside: eye height .. altitude)
  std::vector<glm::dvec3> walk_waypoints;  // eye-height path through streets / rooms & doors
  double eye_height_m = 1.6;
  double flyover_altitude_m = 0;   // 0 = no fly-over (indoor)
  bool indoor = false;
  glm::dvec3 sun_dir{0, 0, 1};     // unit, towards the light
  double ambient = 0.35;           // ambient light fraction
  uint32_t texture_seed = 1;       // varies the procedural textures
  // Street centre lines (village): asphalt draws lane markings along them.
  std::vector<double> street_x;    // streets running along y at these x
  std::vector<double> street_y;    // streets running along x at these y
  double street_half_width_m = 3.0;
  std::vector<RemovableObject> removable;  // empty unless SceneOptions::removable_objects

  // Scene diameter (AABB diagonal), metres: others derive cell size and d_max from it.
  double ExtentM() const { return glm::length(bounds.Size()); }
  // True when p is inside navigable and at least `clearance_m` away from every solid.
  bool IsFree(const glm::dvec3& p, double clearance_m = 0.3) const;
};

absl::StatusOr<SynthScene> MakeScene(SceneKind kind, const SceneOptions& options);
absl::StatusOr<SynthScene> MakeVillage(const SceneOptions& options);
absl::StatusOr<SynthScene> MakeApartment(const SceneOptions& options);

// The scene without the named removable objects (empty = all of them): their triangles and
// solids are dropped, the rest is unchanged. NotFound for a name the scene does not have.
absl::StatusOr<SynthScene> RemoveObjects(const SynthScene& scene,
                                         const std::vector<std::string>& names = {});

}  // namespace exo::synth
