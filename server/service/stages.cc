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
  return s;
}

absl::StatusOr<std::vector<std::unique_ptr<PipelineStage>>> MakeStages(const ServerConfig& config) {
  std::vector<std::unique_ptr<PipelineStage>> stages;
#ifdef EXOVIEW_HAVE_GEOMETRY
  if (config.enable_geometry) {
    EXO_ASSIGN_OR_RETURN(auto g, MakeGeometryStage(config.geometry));
    stages.push_back(std::move(g));
  }
#endif
#ifdef EXOVIEW_HAVE_PLANNING
  if (config.enable_planning) {
    PlanningStageOptions p = config.planning;
    p.publish = config.publish;
    EXO_ASSIGN_OR_RETURN(auto s, MakePlanningStage(p, config.pipeline.cell_size_m));
    stages.push_back(std::move(s));
  }
#endif
  return stages;
}

}  // namespace exo
