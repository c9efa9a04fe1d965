// Pipeline stage "planning" (SPEC §4): the online model's planning half (server/core
// OnlinePlanner: cell areas, cell ids, ViewPlanner, store hand-off) on its own thread. Each frame
// first applies the geometry stage's update of that frame (GeometryHandoff), then is planned; the
// hand-off is published: ViewRemoved for the views that leave, ViewAdded (encoded per
// ViewEncodeOptions) for an accepted frame, CellRefsChanged for every cell whose R(b_k) changed.
// Accepted views are refined asynchronously (SPEC §5, RefinementWorker).
#pragma once

#include <memory>

#include "proto/model_proto.h"
#include "server/core/online_model.h"
#include "server/service/geometry_stage.h"
#include "server/service/pipeline.h"

namespace exo {

struct PlanningStageOptions {
  ViewEncodeOptions publish;
  // Refinement (SPEC §5), async after acceptance: the view is published at once and a ViewUpdated
  // (exposure, pose) follows; under load views stay unrefined (skipped).
  bool refine = true;
  size_t refine_queue = 2;
  int refine_downscale = 2;  // refined at 1/k resolution; the reference cache is kept at 1/k
  // A view refinement flags as a pose outlier is removed (true) or kept as published, at its
  // input pose and exposure, unrefined (false, default): on real RGB-D (registered 7-Scenes)
  // removing the flagged views lowered held-out SSIM 0.678 -> 0.562 (docs/refinement.md).
  bool refine_remove_outliers = false;
  // Trust region of the refinement (RefinementOptions::max_pose_correction_*, max_exposure_ratio).
  double refine_max_pose_m = 0.03;
  double refine_max_pose_deg = 2.0;
  double refine_max_exposure_ratio = 1.25;  // issue 15, session 8: real 7-Scenes exposures
  absl::Status Validate() const;
};

// `handoff`: the geometry stage's per-frame updates (null: no geometry stage, no proxy areas).
absl::StatusOr<std::unique_ptr<PipelineStage>> MakePlanningStage(
    const PlanningStageOptions& options, const core::OnlineModelOptions& model,
    std::shared_ptr<GeometryHandoff> handoff);

}  // namespace exo
