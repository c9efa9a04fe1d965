#include "server/service/stages.h"

#include "server/service/geometry_stage.h"
#include "server/service/planning_stage.h"
#include "server/service/server.h"

namespace exo {

std::vector<std::string> AvailableStages() { return {"geometry", "planning", "refinement"}; }

absl::StatusOr<std::vector<std::unique_ptr<PipelineStage>>> MakeStages(const ServerConfig& config) {
  std::vector<std::unique_ptr<PipelineStage>> stages;
  core::OnlineModelOptions model = config.pipeline.model;
  if (!config.planning_cell_areas) model.cell_areas = false;
  std::shared_ptr<GeometryHandoff> handoff;
  if (config.enable_geometry) {
    if (config.enable_planning) handoff = std::make_shared<GeometryHandoff>();
    GeometryStageOptions go = config.geometry;
    // Lossless (back-pressured) ingest processes every frame in order, deterministically: a
    // full queue there is not overload, nothing is shed.
    if (config.pipeline.admission_block) go.shed_backlog_fraction = 0.0;
    EXO_ASSIGN_OR_RETURN(auto g, MakeGeometryStage(go, model, handoff));
    stages.push_back(std::move(g));
  }
  if (config.enable_planning) {
    PlanningStageOptions p = config.planning;
    p.publish = config.publish;
    EXO_ASSIGN_OR_RETURN(auto s, MakePlanningStage(p, model, handoff));
    stages.push_back(std::move(s));
  }
  return stages;
}

}  // namespace exo
