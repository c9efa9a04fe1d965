// Proxy geometry (SPEC §3): a sparse truncated signed distance field (TSDF) in voxel blocks,
// allocated only near observed surfaces, fused from depth frames, and meshed incrementally with
// marching cubes into versioned MeshChunks (one chunk per block; what clients receive as deltas).
//
// Frames and coordinates:
// - Everything inside lives in the scene-local frame of a LocalOrigin (float voxels, double poses):
//   a scene 1e5 m from the world origin fuses exactly like one at the origin.
// - Voxel g (integer 3-vector) samples the field at p_local = g * voxel_size_m. Block b holds
//   voxels g = b * block_size + [0, block_size)^3; its key is PackCell(b) (common/cells.h).
// - A chunk holds the marching-cubes triangles of the cubes whose lowest corner is a voxel of its
//   block; the cubes on the block's upper faces read the neighbouring blocks' voxels, so the
//   chunks join without cracks (vertex positions on shared edges are bitwise identical).
// - Mesh vertex colours are linear [0,1] (TriangleMesh convention); voxels store the weighted
//   running mean of the sRGB8 colour (a cheap, standard approximation) converted at extraction.
//
// Use:
//   TsdfVolume vol(options);                        // options.Validate() is checked
//   vol.Integrate(frame, origin);                   // per depth frame
//   for (MeshChunk& c : vol.ExtractDirtyChunks()) { ... }  // new/changed chunks only
//   for (uint64_t id : vol.TakeRemovedChunkIds()) { ... }  // chunks that became empty
// Integrate and Extract* must not run concurrently with each other (no internal lock); each is
// internally parallel over options.num_threads.
#pragma once

#include <array>
#include <functional>
#include <cstdint>
#include <memory>
#include <vector>

#include <absl/container/flat_hash_map.h>
#include <absl/container/flat_hash_set.h>
#include <glm/glm.hpp>

#include "common/cells.h"
#include "common/frame.h"
#include "common/lumigraph/model.h"
#include "common/mesh.h"
#include "common/rigid3.h"
#include "common/state_io.h"
#include "common/status.h"

namespace exo {

struct TsdfOptions {
  float voxel_size_m = 0.02f;
  // Truncation distance (band half-width along each depth ray). <= 0 means 4 voxels.
  float truncation_m = 0.0f;
  float max_weight = 64.0f;      // running-average weight cap (lets the field adapt)
  float min_depth_m = 0.1f;      // depth samples outside [min, max] are ignored
  float max_depth_m = 6.0f;
  int block_size = 8;            // voxels per block edge, 2..32
  bool integrate_color = true;
  // Voxels with weight below this are treated as unobserved by marching cubes. Each observation
  // adds its incidence cosine (from the depth map's normals, floored at 0.1) to the weight.
  float min_extract_weight = 0.25f;
  int num_threads = 2;
  // Block allocation samples one s x s cell of depth pixels at a time (s = alloc_stride): one
  // "thick" ray walk per cell covers every block the cell's per-pixel truncation bands cross
  // (the cell's depth spread plus its lateral footprint), so the allocated set is a superset of
  // per-pixel allocation (stride 1, the exact reference). The per-voxel update is the same.
  int alloc_stride = 8;

  absl::Status Validate() const;
  float EffectiveTruncation() const { return truncation_m > 0 ? truncation_m : 4 * voxel_size_m; }
};

struct TsdfVoxel {
  float sdf_m = 0.0f;   // truncated signed distance (positive in front of the surface)
  float weight = 0.0f;  // sum of observation weights (capped); 0 = never observed
  uint8_t r = 0, g = 0, b = 0;
  uint8_t color_weight = 0;  // saturating count of colour observations
};

// Statistics of one Integrate call.
struct TsdfIntegrateStats {
  size_t valid_pixels = 0;      // depth pixels inside [min, max]
  size_t touched_blocks = 0;    // blocks the band of this frame reaches
  size_t new_blocks = 0;        // of those, newly allocated
};

class TsdfVolume {
 public:
  explicit TsdfVolume(const TsdfOptions& options);
  ~TsdfVolume();
  TsdfVolume(const TsdfVolume&) = delete;
  TsdfVolume& operator=(const TsdfVolume&) = delete;

  // Fuses frame.depth_m (z-depth, camera = frame.depth_camera, pose = frame.world_from_cam *
  // frame.color_from_depth). Invalid depth (0, negative, NaN, Inf, outside [min,max]) is
  // skipped. Colour is sampled from frame.color through color_from_depth when present and
  // options.integrate_color. Errors: bad options/frame (sizes, intrinsics, NaN pose), or an
  // origin different from the one of the first call.
  absl::StatusOr<TsdfIntegrateStats> Integrate(const Frame& frame, const LocalOrigin& origin);
  // Same, with the depth camera pose already in the local frame.
  absl::StatusOr<TsdfIntegrateStats> IntegrateDepth(const ImageF& depth_m,
                                                    const PinholeCamera& depth_camera,
                                                    const Rigid3d& local_from_depth_cam,
                                                    const ImageU8* color = nullptr,
                                                    const PinholeCamera* color_camera = nullptr,
                                                    const Rigid3d* color_from_depth = nullptr);

  // Re-meshes the blocks changed since the last call (and the neighbours whose chunks read
  // them). Returns only non-empty chunks; each has id = block key and a version one higher than
  // the last one returned for that id (first version is 1).
  std::vector<MeshChunk> ExtractDirtyChunks();
  // Ids of chunks returned earlier that became empty since (clients should drop them).
  std::vector<uint64_t> TakeRemovedChunkIds();
  // Whole mesh (every block), one vertex set per chunk; does not touch the dirty state.
  TriangleMesh ExtractAll() const;
  // One block's chunk mesh, computed now (empty if the block does not exist).
  TriangleMesh ExtractBlock(uint64_t block_key) const;

  // One block's chunk mesh from a caller's field (InpaintFusion's labelled proxy,
  // geometry/inpainted_surface.h): `voxel(g)` is the voxel to mesh at global voxel g (nullptr or
  // weight < min_extract_weight = none); same marching cubes as ExtractBlock, which it equals
  // bit for bit when `voxel` returns this volume's voxels.
  TriangleMesh MeshBlockFrom(const glm::ivec3& block,
                             const std::function<const TsdfVoxel*(const glm::ivec3&)>& voxel) const;
  // The voxel at global voxel coordinate g (block * block_size + local); nullptr when its block
  // is not allocated.
  const TsdfVoxel* VoxelAt(const glm::ivec3& g) const;
  TsdfVoxel* MutableVoxelAt(const glm::ivec3& g);
  // A block's block_size^3 voxels (x fastest), nullptr when it is not allocated.
  const TsdfVoxel* BlockVoxels(const glm::ivec3& block) const;
  // The blocks changed since the last ExtractDirtyChunks / TakeDirtyBlocks (sorted), without
  // meshing them; clears the dirty set.
  std::vector<uint64_t> TakeDirtyBlocks();
  // The last chunk version handed out for a block (0: none, or no such block).
  uint64_t ChunkVersion(uint64_t block_key) const;

  // Signed distance at a local point (trilinear); false if any of the 8 voxels is unobserved.
  bool SdfAt(const glm::vec3& p_local, float* sdf_m) const;

  size_t num_blocks() const { return blocks_.size(); }
  size_t num_dirty_blocks() const { return dirty_.size(); }
  // Memory held by blocks, the hash table and the per-pixel scratch (bytes).
  size_t bytes() const;
  // Axis-aligned bounds of all allocated blocks in the local frame (empty volume: false).
  bool Bounds(glm::dvec3* min_local, glm::dvec3* max_local) const;
  const TsdfOptions& options() const { return options_; }
  const LocalOrigin& origin() const { return origin_; }
  float block_size_m() const { return options_.voxel_size_m * options_.block_size; }
  // Block coordinate / key of the block containing a local point.
  glm::ivec3 BlockCoordOf(const glm::vec3& p_local) const;
  // All allocated block keys (unordered).
  std::vector<uint64_t> BlockKeys() const;

  // The whole field (blocks, chunk versions, dirty / removed sets, origin) for the server's
  // checkpoint (common/state_io.h); LoadState into a volume of the same voxel and block size
  // (an error otherwise, or for a truncated / corrupt state) replaces everything.
  void SaveState(StateWriter* w) const;
  absl::Status LoadState(StateReader* r);

 private:
  struct Block;
  struct Context;
  Block* FindBlock(const glm::ivec3& b) const;
  TriangleMesh MeshBlock(const glm::ivec3& b) const;
  TriangleMesh MeshGrid(const glm::ivec3& b) const;  // marching cubes over the thread's scratch
  void IntegrateBlock(Block* block, const Context& ctx) const;
  static float CosIncidence(const Context& c, int u, int v);
  // Keys of the blocks the frame's truncation bands cross, per task of image rows (duplicates
  // possible); counts valid pixels per task.
  void CollectBandBlocks(const ImageF& depth_m, const PinholeCamera& cam,
                         const Rigid3d& local_from_cam, std::vector<std::vector<uint64_t>>* keys,
                         std::vector<size_t>* valid) const;

  TsdfOptions options_;
  float truncation_m_;
  LocalOrigin origin_;
  bool origin_set_ = false;
  absl::flat_hash_map<uint64_t, std::unique_ptr<Block>> blocks_;
  absl::flat_hash_set<uint64_t> dirty_;
  std::vector<uint64_t> removed_;
  glm::ivec3 bmin_{0}, bmax_{-1};
  uint64_t stamp_ = 0;  // integration counter
  std::vector<float> cos_scratch_;  // per-pixel incidence cosines of the current frame (reused)
};

}  // namespace exo
