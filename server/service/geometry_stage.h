// Pipeline stage "geometry" (SPEC §3): fuses each admitted frame into the sparse TSDF of
// server/geometry and publishes re-meshed chunks (MeshChunkUpserted/Removed deltas). Re-meshing
// runs every `mesh_every_n_frames` frames; a chunk that already exists on the clients is only
// re-published when its triangle count changed by more than `republish_change_fraction` or its
// last publication is older than `republish_interval_s` (fusion noise would otherwise re-send
// the whole visible proxy every few frames: the steady-state bandwidth target of SPEC §10).
#pragma once

#include <cmath>
#include <memory>
#include <map>
#include <mutex>
#include <utility>
#include <vector>

#include "common/cells.h"
#include "common/lumigraph/model.h"

#include "server/service/pipeline.h"

namespace exo {

struct GeometryStageOptions {
  double voxel_size_m = 0.08;     // proxy only: coarse is enough for projective texturing
  double max_depth_m = 6.0;
  int mesh_every_n_frames = 5;
  int fuse_depth_downscale = 2;   // depth fused at 1/k resolution (nearest sample): speed knob
  double republish_change_fraction = 0.2;
  double republish_interval_s = 60.0;
  absl::Status Validate() const {
    if (!(voxel_size_m > 0.0)) return absl::InvalidArgumentError("voxel_size_m must be > 0");
    if (!(max_depth_m > 0.0)) return absl::InvalidArgumentError("max_depth_m must be > 0");
    if (mesh_every_n_frames < 1) return absl::InvalidArgumentError("mesh_every_n_frames must be >= 1");
    if (fuse_depth_downscale < 1 || fuse_depth_downscale > 8)
      return absl::InvalidArgumentError("fuse_depth_downscale must be in [1, 8]");
    if (!(republish_change_fraction >= 0.0))
      return absl::InvalidArgumentError("republish_change_fraction must be >= 0");
    if (!(republish_interval_s >= 0.0))
      return absl::InvalidArgumentError("republish_interval_s must be >= 0");
    return absl::OkStatus();
  }
};

// Per-cell proxy areas A(b_k) (server/geometry CellAreas) maintained by the geometry stage from
// every re-meshed chunk and read by the planning stage (ViewPlanner::SetCellArea); optionally
// also the re-meshed chunks themselves, for the planning stage's cell-id renderer. Thread-safe.
class SharedCellAreas {
 public:
  // keep_chunk_changes: also queue the changed chunks for TakeChunkChanges (one entry per chunk
  // id, the newest; bounded by the number of chunks).
  explicit SharedCellAreas(double cell_size_m, bool keep_chunk_changes = false);
  ~SharedCellAreas();
  void Update(const MeshChunk& chunk);
  void Remove(uint64_t chunk_id);
  // Cells whose area changed since the last call, with their current area (0 = no surface).
  std::vector<std::pair<CellId, double>> TakeChanges();
  // Chunks re-meshed or removed (empty mesh, newer version) since the last call, newest version
  // per id (planning::CellIdRenderer::Update takes them as they are). Empty unless
  // keep_chunk_changes.
  std::vector<MeshChunk> TakeChunkChanges();
  double TotalArea() const;

 private:
  mutable std::mutex mu_;
  std::unique_ptr<class CellAreas> areas_;
  const bool keep_chunk_changes_;
  std::map<uint64_t, uint64_t> versions_;      // newest version per live chunk
  std::map<uint64_t, MeshChunk> pending_;      // changes not yet taken
};

absl::StatusOr<std::unique_ptr<PipelineStage>> MakeGeometryStage(
    const GeometryStageOptions& options, std::shared_ptr<SharedCellAreas> areas = nullptr);

}  // namespace exo
