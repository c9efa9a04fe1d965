#include "server/service/stages.h"

#include "server/service/server.h"
#ifdef EXOVIEW_HAVE_GEOMETRY
#include "server/service/geometry_stage.h"
#endif
#ifdef EXOVIEW_HAVE_PLANNING
#include "server/service/planning_stage.h"
#endif

namespace exo {

std::vector<std::string> AvailableStages() {
  std::vector<std::string> s;
#ifdef EXOVIEW_HAVE_GEOMETRY
  s.push_back("geometry");
#endif
#ifdef EXOVIEW_HAVE_PLANNING
  s.push_back("planning");
#endif
#ifdef EXOVIEW_HAVE_REFINEMENT
  s.push_back("refinement");
#endif
  return s;
}

absl::StatusOr<std::vector<std::unique_ptr<PipelineStage>>> MakeStages(const ServerConfig& config) {
  std::vector<std::unique_ptr<PipelineStage>> stages;
#ifdef EXOVIEW_HAVE_GEOMETRY
  std::shared_ptr<SharedCellAreas> areas;
  if (config.enable_geometry) {
    if (config.enable_planning && (config.planning_cell_areas || config.planning.id_from_proxy))
      areas = std::make_shared<SharedCellAreas>(config.pipeline.cell_size_m,
                                                /*keep_chunk_changes=*/config.planning.id_from_proxy);
    EXO_ASSIGN_OR_RETURN(auto g, MakeGeometryStage(config.geometry, areas));
    stages.push_back(std::move(g));
  }
#endif
#ifdef EXOVIEW_HAVE_PLANNING
  if (config.enable_planning) {
    PlanningStageOptions p = config.planning;
    p.publish = config.publish;
#ifdef EXOVIEW_HAVE_GEOMETRY
    if (areas) {
      if (config.planning_cell_areas) p.take_area_changes = [areas] { return areas->TakeChanges(); };
      if (config.planning.id_from_proxy) {
        p.take_chunk_changes = [areas] { return areas->TakeChunkChanges(); };
        p.proxy_voxel_m = config.geometry.voxel_size_m;
      }
    }
#endif
#ifndef EXOVIEW_HAVE_REFINEMENT
    p.refine = false;
#endif
    EXO_ASSIGN_OR_RETURN(auto s, MakePlanningStage(p, config.pipeline.cell_size_m));
    stages.push_back(std::move(s));
  }
#endif
  return stages;
}

}  // namespace exo
