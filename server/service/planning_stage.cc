#include "server/service/planning_stage.h"

#include <cmath>
#include <cstdio>

#include "server/planning/view_planner.h"

namespace exo {

absl::Status PlanningStageOptions::Validate() const {
  if (!(max_candidates_per_s_when_full >= 0.0))
    return absl::InvalidArgumentError("max_candidates_per_s_when_full must be >= 0");
  if (id_buffer_stride < 1 || id_buffer_stride > 32)
    return absl::InvalidArgumentError("id_buffer_stride must be in [1, 32]");
  return publish.Validate();
}

ImageF RegisterDepthToColor(const Frame& f) {
  const PinholeCamera& dc = f.depth_camera;
  const PinholeCamera& cc = f.color_camera;
  const bool same_camera = dc.fx == cc.fx && dc.fy == cc.fy && dc.cx == cc.cx && dc.cy == cc.cy &&
                           dc.width == cc.width && dc.height == cc.height;
  const bool identity = f.color_from_depth.translation == glm::dvec3(0.0) &&
                        std::abs(std::abs(f.color_from_depth.rotation.w) - 1.0) < 1e-12;
  if (same_camera && identity) return f.depth_m;
  ImageF out(cc.width, cc.height);
  for (int y = 0; y < f.depth_m.height(); ++y)
    for (int x = 0; x < f.depth_m.width(); ++x) {
      const float z = f.depth_m.at(x, y);
      if (!(z > 0.0f) || !std::isfinite(z)) continue;
      const glm::dvec3 p_color = f.color_from_depth * dc.Unproject({x, y}, z);
      glm::dvec2 uv;
      if (!cc.Project(p_color, &uv)) continue;
      const int u = static_cast<int>(std::lround(uv.x)), v = static_cast<int>(std::lround(uv.y));
      if (!out.Contains(u, v)) continue;
      float& dst = out.at(u, v);
      if (dst == 0.0f || p_color.z < dst) dst = static_cast<float>(p_color.z);
    }
  return out;
}

namespace {

class PlanningStage final : public PipelineStage {
 public:
  PlanningStage(planning::ViewPlanner planner, const PlanningStageOptions& options)
      : planner_(std::move(planner)), options_(options) {}
  std::string name() const override { return "planning"; }

  absl::Status Process(const PipelineFrame& pf, const SceneContext& ctx) override {
    const Frame& f = pf.frame;
    if (f.depth_m.empty()) return absl::OkStatus();  // no depth: no cells to cover
    if (options_.max_candidates_per_s_when_full > 0 &&
        planner_.num_views() >= options_.max_views) {
      const double min_gap_s = 1.0 / options_.max_candidates_per_s_when_full;
      if (f.timestamp_s - last_candidate_s_ < min_gap_s && f.timestamp_s >= last_candidate_s_)
        return absl::OkStatus();  // governed: not a candidate
      last_candidate_s_ = f.timestamp_s;
    }
    const Rigid3d local_from_cam = ctx.origin.ToLocal(f.world_from_cam);
    const Rigid3d local_from_depth = local_from_cam * f.color_from_depth;
    // Cell-id buffer from the frame's own depth (the visible surface), reduced resolution.
    const int s = options_.id_buffer_stride;
    const int w = f.depth_m.width() / s, h = f.depth_m.height() / s;
    if (w < 1 || h < 1) return absl::InvalidArgumentError("depth smaller than the id-buffer stride");
    ids_.assign(static_cast<size_t>(w) * h, kNoCell);
    const CellGrid& grid = planner_.grid();
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const int dx = x * s + s / 2, dy = y * s + s / 2;
        const float z = f.depth_m.at(dx, dy);
        if (!(z > 0.0f) || !std::isfinite(z)) continue;
        const glm::dvec3 p_local = local_from_depth * f.depth_camera.Unproject({dx, dy}, z);
        ids_[static_cast<size_t>(y) * w + x] = grid.IdOf(p_local);
      }
    planning::Candidate cand;
    cand.id = next_id_;
    cand.local_from_cam = local_from_cam;
    cand.id_camera = f.depth_camera.Scaled(w, h);
    cand.cells = planning::CountCellPixels(ids_.data(), ids_.size());
    cand.bytes = f.color.bytes() + static_cast<size_t>(f.color.width()) * f.color.height() * sizeof(float) +
                 sizeof(StoredView);
    EXO_ASSIGN_OR_RETURN(planning::Decision d, planner_.Consider(cand));
    if (!d.accepted) return absl::OkStatus();
    ++next_id_;
    for (ViewId victim : d.removed) (void)ctx.store->RemoveView(victim);
    StoredView view;
    view.id = cand.id;
    view.camera = f.color_camera;
    view.local_from_cam = local_from_cam;
    view.color = f.color;
    view.depth_m = RegisterDepthToColor(f);
    view.exposure = f.exposure ? static_cast<float>(*f.exposure) : 1.0f;
    EXO_ASSIGN_OR_RETURN(v1::ViewAdded msg, ViewToProto(view, options_.publish));
    ctx.store->AddView(std::move(msg));
    if (!d.changed_cells.empty()) {
      std::vector<std::pair<CellId, std::vector<ViewId>>> cells;
      cells.reserve(d.changed_cells.size());
      for (CellId c : d.changed_cells) cells.emplace_back(c, planner_.Refs(c));
      ctx.store->SetCellRefs(cells);
    }
    return absl::OkStatus();
  }

 private:
  planning::ViewPlanner planner_;
  const PlanningStageOptions options_;
  ViewId next_id_ = 1;
  double last_candidate_s_ = -1e300;
  std::vector<uint64_t> ids_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<PipelineStage>> MakePlanningStage(const PlanningStageOptions& options,
                                                                 double cell_size_m) {
  EXO_RETURN_IF_ERROR(options.Validate());
  planning::PlannerOptions po;
  po.r_max = options.r_max;
  po.max_views = options.max_views;
  po.max_bytes = options.max_bytes;
  po.d_max_m = options.d_max_m;
  po.sigma_m = options.sigma_m;
  po.delta_tau_sum = options.delta_tau_sum;
  po.cell_size_m = cell_size_m;
  EXO_ASSIGN_OR_RETURN(planning::ViewPlanner planner, planning::ViewPlanner::Create(po));
  return std::unique_ptr<PipelineStage>(new PlanningStage(std::move(planner), options));
}

}  // namespace exo
