// Pipeline stage "planning" (SPEC §4): turns each admitted frame into a view-planning candidate
// (visible pixels per scene cell from the frame's own depth, back-projected at reduced
// resolution), asks server/planning's ViewPlanner, and publishes its decision: ViewRemoved for
// victims, ViewAdded (encoded per ViewEncodeOptions) for an accepted frame, CellRefsChanged for
// every cell whose R(b_k) changed.
#pragma once

#include <functional>
#include <memory>
#include <utility>
#include <vector>

#include "proto/model_proto.h"
#include "server/service/pipeline.h"

namespace exo {

struct PlanningStageOptions {
  int id_buffer_stride = 4;     // cell-id buffer = depth subsampled by this factor
  size_t max_views = 200;
  size_t max_bytes = size_t{1} << 30;
  int r_max = 16;
  double d_max_m = 2.0;         // ideal view distance (3.11)
  double sigma_m = 2.0;
  double delta_tau_sum = 0.05;
  // Bandwidth governor: at most this many candidates per second (by frame timestamp) go to the
  // planner once the store is full; the others are skipped. 0 = off. Each accepted view costs
  // clients ~30 KB, so 3/s keeps the steady state near 1 Mbit/s (docs/service.md).
  double max_candidates_per_s_when_full = 2.0;
  ViewEncodeOptions publish;
  // Per-cell proxy areas A(b_k) changed since the last call (geometry's CellAreas); null = every
  // cell uses the face area A_cell.
  std::function<std::vector<std::pair<CellId, double>>()> take_area_changes;
  // SPEC §4: the cell-id buffer rendered from the proxy (planning::CellIdRenderer: per-chunk LOD,
  // frustum culling; at 1/id_buffer_stride of the colour size) instead of back-projected from the
  // frame's depth. Needs `take_chunk_changes` (the geometry stage's re-meshed chunks); falls back
  // to depth while there is no proxy. Measured cost in docs/service.md.
  bool id_from_proxy = false;
  std::function<std::vector<MeshChunk>()> take_chunk_changes;
  double proxy_voxel_m = 0.0;   // TSDF voxel, bounds the LOD (planning::DefaultCellIdLodM)
  double cellid_lod_m = -1.0;   // LOD cluster size; < 0: DefaultCellIdLodM; 0: full chunk meshes
  // Refinement (SPEC §5), async after acceptance (where the server is built with it): the view is
  // published at once and a ViewUpdated (exposure, pose) follows; a pose outlier is removed from
  // planner and store (ViewRemoved + CellRefsChanged). Under load views stay unrefined (skipped).
  bool refine = true;
  size_t refine_queue = 2;
  int refine_downscale = 2;     // refined at 1/k resolution; the reference cache is kept at 1/k
  // A view refinement flags as a pose outlier is removed (true) or kept as published, at its
  // input pose and exposure, unrefined (false, default): on real RGB-D (registered 7-Scenes)
  // removing the flagged views lowered held-out SSIM 0.678 -> 0.562 (docs/refinement.md).
  bool refine_remove_outliers = false;
  absl::Status Validate() const;
};

absl::StatusOr<std::unique_ptr<PipelineStage>> MakePlanningStage(const PlanningStageOptions& options,
                                                                 double cell_size_m);

// Depth registered to the colour camera (z-depth in the colour frame, colour size): identity
// when depth is already registered, else a forward z-buffered warp (0 = no sample).
ImageF RegisterDepthToColor(const Frame& frame);

}  // namespace exo
