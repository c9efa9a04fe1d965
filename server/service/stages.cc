#include "server/service/stages.h"

#include "server/service/geometry_stage.h"
#include "server/service/planning_stage.h"
#include "server/service/server.h"

namespace exo {

std::vector<std::string> AvailableStages() {
  return {"geometry", "planning", "refinement", "inpainting"};
}

absl::StatusOr<std::vector<std::unique_ptr<PipelineStage>>> MakeStages(
    const ServerConfig& config, std::shared_ptr<RegionRegistry> regions, ModelStore* store,
    InpaintingStage** inpainting, std::shared_ptr<ObservedChunks> observed,
    std::shared_ptr<ObservedChunks> coloured) {
  std::vector<std::unique_ptr<PipelineStage>> stages;
  core::OnlineModelOptions model = config.pipeline.model;
  if (!config.planning_cell_areas) model.cell_areas = false;
  std::shared_ptr<GeometryHandoff> handoff;
  // InpaintFusion's labelled proxy: the inpainting stage's keyframes into the geometry stage's
  // chunks (geometry_stage.h inpaint_fuse).
  std::shared_ptr<InpaintedProxyLink> link;
  if (regions && store && config.enable_geometry && config.geometry.inpaint_fuse)
    link = std::make_shared<InpaintedProxyLink>(regions, std::move(observed));
  if (config.enable_geometry) {
    if (config.enable_planning) handoff = std::make_shared<GeometryHandoff>();
    GeometryStageOptions go = config.geometry;
    // Lossless (back-pressured) ingest processes every frame in order, deterministically: a
    // full queue there is not overload, nothing is shed.
    if (config.pipeline.admission_block) go.shed_backlog_fraction = 0.0;
    EXO_ASSIGN_OR_RETURN(auto g, MakeGeometryStage(go, model, handoff, link, std::move(coloured)));
    stages.push_back(std::move(g));
  }
  // Inpainting before planning: the planning stage adds the frame's stored views, so it must be
  // the LAST stage, whose changes the pipeline applies together with the frame's journal ledger
  // entry (Pipeline::RunStage BeginApply/EndApply). With inpainting last, a checkpoint taken
  // between the two stages held a view whose frame the journal then replayed: the view was
  // stored twice (service_durable_test, 1 run in 3 after the merge of issues 18 and 20). The
  // inpainting stage needs only the regions and the frame, and publishes from its own worker.
  if (regions && store) {
    InpaintingStageOptions o = config.inpainting;
    o.publish = config.publish;
    o.region = config.regions.region;
    EXO_RETURN_IF_ERROR(o.Validate());
    auto s = MakeInpaintingStage(o, std::move(regions), store, link);
    if (inpainting) *inpainting = s.get();
    stages.push_back(std::move(s));
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
