// InpaintFusion's labelled proxy (SPEC §7, thesis 4.1.8 "Keyframe Fusion"): the surface the
// clients get with the marked objects removed and the inpainted keyframes' depth in their place,
// while the observed TSDF (what the planner, the drone's map and everything else read) stays
// untouched.
//
// Labels per voxel of the TSDF grid (Label):
//   L_ROI  the voxel is in a marked region (the region's label voxels, grown by
//          carve_margin_voxels) and has no inpainted value: never meshed for the clients
//          (the object is carved);
//   L_IP   the inpainted field holds it: inside the ROI, or outside it where nothing was
//          observed (vacant space);
//   L_O    observed (weight >= min_extract_weight) outside the ROI: always the observation.
// Inpainted depth (the ROI pixels of an inpainted keyframe) is fused into a SEPARATE sparse TSDF
// (same voxel grid) and only into L_IP voxels: after each keyframe the inpainted field is erased
// at every voxel that is observed outside the ROI (IntegrateInpainted), so it never writes over
// observed surface. Observations stay preferred afterwards: a voxel that a later frame observes
// outside the ROI is L_O from then on (Label is evaluated at extraction), so a hole that is later
// observed gets the observation, while an object that is removed and then walked around stays
// removed (its voxels are in the ROI, where the observed field is never meshed).
//
// Use (one thread, or the caller's lock):
//   InpaintedSurface s(volume.options());
//   s.SetRoi(label_voxels, label_voxel_m);                 // when the regions change
//   s.IntegrateInpainted(volume, depth, roi_mask, &color, camera, local_from_cam);  // per keyframe
//   for (uint64_t key : s.TakeDirtyBlocks()) publish(key, s.ExtractBlock(volume, key));
//   ... and every chunk the observed volume re-meshes: Affects(key) ? s.ExtractBlock(volume, key)
// Pure library (no threads, no service code).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include <absl/container/flat_hash_map.h>
#include <absl/container/flat_hash_set.h>
#include <glm/glm.hpp>

#include "common/camera.h"
#include "common/image.h"
#include "common/mesh.h"
#include "common/rigid3.h"
#include "common/status.h"
#include "server/geometry/tsdf_volume.h"

namespace exo::geometry {

enum class VoxelLabel : uint8_t { kNone = 0, kObserved, kRoi, kInpainted };

struct InpaintedSurfaceOptions {
  // The ROI in TSDF voxels: every voxel whose sample point lies within this many TSDF voxels of a
  // region's label voxel (the labels are the object's surface points, grown by one label voxel).
  int carve_margin_voxels = 1;
  absl::Status Validate() const;
};

struct InpaintedFuseStats {
  size_t pixels = 0;         // ROI pixels with depth fused
  size_t blocks = 0;         // inpainted-field blocks touched
  size_t voxels_kept = 0;    // voxels of those blocks holding inpainted values (L_IP)
  size_t voxels_erased = 0;  // values erased because the voxel is observed outside the ROI
};

class InpaintedSurface {
 public:
  // `tsdf`: the options of the observed volume (same voxel, block, truncation, weights).
  explicit InpaintedSurface(const TsdfOptions& tsdf, const InpaintedSurfaceOptions& options = {});

  // The union of the marked regions: label voxels (integer coordinates of cubes of edge
  // label_voxel_m in the scene-local frame). Replaces the previous ROI; blocks whose client mesh
  // may change become dirty. Empty = no region (the inpainted field is kept: ClearInpainted).
  void SetRoi(std::span<const glm::ivec3> label_voxels, double label_voxel_m);
  // Forgets the inpainted field (e.g. the keyframes were withdrawn).
  void ClearInpainted();

  // Fuses the depth of an inpainted keyframe at its ROI pixels (mask != 0; colour and depth in
  // the same camera) into the inpainted field, then erases it at the voxels that are L_O.
  // Errors: sizes, camera, pose (TsdfVolume's), mask of the wrong size.
  absl::StatusOr<InpaintedFuseStats> IntegrateInpainted(const TsdfVolume& observed,
                                                        const ImageF& depth_m, const ImageU8& mask,
                                                        const ImageU8* color,
                                                        const PinholeCamera& camera,
                                                        const Rigid3d& local_from_cam);

  bool InRoi(const glm::ivec3& voxel) const;
  VoxelLabel Label(const TsdfVolume& observed, const glm::ivec3& voxel) const;
  // The voxel the clients' mesh uses at `voxel` (nullptr: none).
  const TsdfVoxel* ClientVoxel(const TsdfVolume& observed, const glm::ivec3& voxel) const;

  // Whether the clients' mesh of this block (chunk id = block key) may differ from the observed
  // volume's: the block or one of the 7 above it (whose voxels its cubes read) holds ROI voxels
  // or inpainted values.
  bool Affects(uint64_t block_key) const { return affected_.contains(block_key); }
  // The clients' mesh of one block: marching cubes over ClientVoxel (the observed volume's own
  // ExtractBlock, bit for bit, where !Affects).
  TriangleMesh ExtractBlock(const TsdfVolume& observed, uint64_t block_key) const;
  // Blocks whose client mesh may have changed through SetRoi / IntegrateInpainted /
  // ClearInpainted since the last call (sorted; includes the blocks below them, whose cubes read
  // them); clears the set.
  std::vector<uint64_t> TakeDirtyBlocks();

  bool empty() const { return roi_.empty() && ip_blocks_.empty(); }
  size_t roi_voxels() const { return roi_voxels_; }
  const TsdfVolume& inpainted() const { return *ip_; }

 private:
  void MarkDirty(uint64_t block_key);
  void RebuildAffected();
  glm::ivec3 BlockOf(const glm::ivec3& voxel) const;

  TsdfOptions tsdf_;
  InpaintedSurfaceOptions options_;
  std::unique_ptr<TsdfVolume> ip_;
  // The ROI voxels: per block holding any, one flag per voxel (x fastest, as the blocks).
  absl::flat_hash_map<uint64_t, std::vector<uint8_t>> roi_;
  size_t roi_voxels_ = 0;
  absl::flat_hash_set<uint64_t> roi_blocks_;  // the keys of roi_
  absl::flat_hash_set<uint64_t> ip_blocks_;   // blocks of the inpainted field
  absl::flat_hash_set<uint64_t> affected_;    // roi_blocks_, ip_blocks_ and the blocks below them
  absl::flat_hash_set<uint64_t> dirty_;
};

}  // namespace exo::geometry
