#include "server/service/planning_stage.h"

#include <cmath>
#include <cstdio>

#include <map>
#include <mutex>

#include "server/planning/cell_id_proxy.h"
#include "server/planning/view_planner.h"
#ifdef EXOVIEW_HAVE_REFINEMENT
#include "server/service/refinement_worker.h"
#endif

namespace exo {

absl::Status PlanningStageOptions::Validate() const {
  if (!(max_candidates_per_s_when_full >= 0.0))
    return absl::InvalidArgumentError("max_candidates_per_s_when_full must be >= 0");
  if (refine_queue < 1) return absl::InvalidArgumentError("refine_queue must be >= 1");
  if (refine_downscale < 1 || refine_downscale > 8)
    return absl::InvalidArgumentError("refine_downscale must be in [1, 8]");
  if (id_buffer_stride < 1 || id_buffer_stride > 32)
    return absl::InvalidArgumentError("id_buffer_stride must be in [1, 32]");
  if (!std::isfinite(cellid_lod_m) || !std::isfinite(proxy_voxel_m))
    return absl::InvalidArgumentError("cellid_lod_m and proxy_voxel_m must be finite");
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
  PlanningStage(planning::ViewPlanner planner, const PlanningStageOptions& options,
                std::unique_ptr<planning::CellIdRenderer> cell_ids)
      : planner_(std::move(planner)), options_(options), cell_ids_(std::move(cell_ids)) {
#ifdef EXOVIEW_HAVE_REFINEMENT
    if (options_.refine) {
      RefinementWorkerOptions wo;
      wo.queue = options_.refine_queue;
      wo.downscale = options_.refine_downscale;
      worker_ = std::make_unique<RefinementWorker>(
          wo, [this](const RefinementJob& job, const absl::StatusOr<RefinementResult>& r) {
            ApplyRefinement(job, r);
          });
    }
#endif
  }
  ~PlanningStage() override {
#ifdef EXOVIEW_HAVE_REFINEMENT
    if (worker_) worker_->Stop();
#endif
  }
  std::string name() const override { return "planning"; }

  absl::Status Process(const PipelineFrame& pf, const SceneContext& ctx) override {
    std::lock_guard lock(mu_);
    store_ = ctx.store;
    EXO_RETURN_IF_ERROR(ApplyAreaChangesLocked());
    if (!rebuilt_) {
      rebuilt_ = true;
      EXO_RETURN_IF_ERROR(RebuildFromStoreLocked());
    }
    const Frame& f = pf.frame;
    if (f.depth_m.empty()) return absl::OkStatus();  // no depth: no cells to cover
    if (options_.max_candidates_per_s_when_full > 0 &&
        planner_.num_views() >= options_.max_views) {
      const double min_gap_s = 1.0 / options_.max_candidates_per_s_when_full;
      if (f.timestamp_s - last_candidate_s_ < min_gap_s && f.timestamp_s >= last_candidate_s_) {
        ++governed_;
        return absl::OkStatus();  // governed: not a candidate
      }
      last_candidate_s_ = f.timestamp_s;
    }
    const Rigid3d local_from_cam = ctx.origin.ToLocal(f.world_from_cam);
    const int64_t t_ids = SteadyNowNs();
    if (cell_ids_ && options_.take_chunk_changes) {
      // A malformed chunk is skipped (the rest applied) and counted; the frame goes on.
      if (!cell_ids_->Update(options_.take_chunk_changes()).ok()) ++cellid_update_errors_;
    }
    planning::Candidate cand;
    if (cell_ids_ && cell_ids_->num_chunks() > 0) {
      EXO_ASSIGN_OR_RETURN(
          planning::CellIdBuffer r,
          cell_ids_->Render(local_from_cam, f.color_camera,
                            f.color_camera.width / options_.id_buffer_stride,
                            f.color_camera.height / options_.id_buffer_stride));
      cand.id = next_id_;
      cand.local_from_cam = local_from_cam;
      cand.id_camera = r.camera;
      cand.cells = planning::CountCellPixels(r.cell_id.data(), r.cell_id.size());
      cand.bytes = f.color.bytes() + static_cast<size_t>(f.color.width()) * f.color.height() * sizeof(float) +
                   sizeof(StoredView);
      ++ids_from_proxy_;
    } else {
      EXO_ASSIGN_OR_RETURN(cand, MakeCandidate(next_id_, f.depth_m, f.depth_camera,
                                               local_from_cam * f.color_from_depth, local_from_cam,
                                               f.color));
    }
    id_buffer_ns_ += SteadyNowNs() - t_ids;
    ++candidates_;
    EXO_ASSIGN_OR_RETURN(planning::Decision d, planner_.Consider(cand));
    if (!d.accepted) return absl::OkStatus();
    ++accepted_;
    ++next_id_;
    for (ViewId victim : d.removed) {
      (void)ctx.store->RemoveView(victim);
      ref_cache_.erase(victim);
    }
    StoredView view;
    view.id = cand.id;
    view.camera = f.color_camera;
    view.local_from_cam = local_from_cam;
    view.color = f.color;
    view.depth_m = RegisterDepthToColor(f);
    view.exposure = f.exposure ? static_cast<float>(*f.exposure) : 1.0f;
    EXO_ASSIGN_OR_RETURN(v1::ViewAdded msg, ViewToProto(view, options_.publish));
    ctx.store->AddView(std::move(msg));
    PublishCellRefsLocked(d.changed_cells);
#ifdef EXOVIEW_HAVE_REFINEMENT
    if (worker_) {
      // The first view fixes the exposure gauge (E = 1); later ones are refined against the
      // stored views (as cached at 1/k resolution) off this thread.
      auto small = std::make_shared<const StoredView>(DownscaleView(view, options_.refine_downscale));
      if (!ref_cache_.empty()) {
        RefinementJob job;
        job.id = view.id;
        job.source_timestamp_s = f.timestamp_s;
        job.candidate = small;
        job.refs.reserve(ref_cache_.size());
        for (const auto& [id, v] : ref_cache_) job.refs.push_back(v);
        worker_->TrySubmit(std::move(job));
      }
      ref_cache_[view.id] = std::move(small);
    }
#endif
    return absl::OkStatus();
  }

  void Finish(const SceneContext&) override {
#ifdef EXOVIEW_HAVE_REFINEMENT
    if (worker_) worker_->Stop();  // applies every queued refinement
#endif
    std::lock_guard lock(mu_);
    (void)ApplyAreaChangesLocked();
  }

  uint64_t pending() const override {
#ifdef EXOVIEW_HAVE_REFINEMENT
    if (worker_) return worker_->pending();
#endif
    return 0;
  }

  void AddCounters(std::map<std::string, double>* out) const override {
    std::lock_guard lock(mu_);
    (*out)["planning.candidates"] = static_cast<double>(candidates_);
    (*out)["planning.accepted"] = static_cast<double>(accepted_);
    (*out)["planning.governed"] = static_cast<double>(governed_);
    (*out)["planning.cell_areas_set"] = static_cast<double>(areas_set_);
    (*out)["planning.views"] = static_cast<double>(planner_.num_views());
    (*out)["planning.ids_from_proxy"] = static_cast<double>(ids_from_proxy_);
    (*out)["planning.cellid_update_errors"] = static_cast<double>(cellid_update_errors_);
    (*out)["planning.id_buffer_ms_mean"] =
        candidates_ ? id_buffer_ns_ * 1e-6 / static_cast<double>(candidates_) : 0.0;
    (*out)["planning.rebuilt_views"] = static_cast<double>(rebuilt_views_);
    (*out)["planning.rebuild_removed"] = static_cast<double>(rebuild_removed_);
#ifdef EXOVIEW_HAVE_REFINEMENT
    if (worker_) {
      const RefinementWorkerStats w = worker_->stats();
      (*out)["refinement.submitted"] = static_cast<double>(w.submitted);
      (*out)["refinement.skipped_under_load"] = static_cast<double>(w.skipped_under_load);
      (*out)["refinement.refined"] = static_cast<double>(w.refined);
      (*out)["refinement.errors"] = static_cast<double>(w.errors);
      (*out)["refinement.pose_refused"] = static_cast<double>(w.pose_refused);
      (*out)["refinement.outliers"] = static_cast<double>(w.outliers);
      (*out)["refinement.outliers_removed"] = static_cast<double>(outliers_removed_);
      (*out)["refinement.outliers_kept"] = static_cast<double>(outliers_kept_);
      (*out)["refinement.updated"] = static_cast<double>(updated_);
      (*out)["refinement.stale"] = static_cast<double>(stale_);
      (*out)["refinement.mean_ms"] = w.refined ? w.total_ms / static_cast<double>(w.refined) : 0.0;
    }
#endif
  }

 private:
  // Cell-id buffer from a depth map (the visible surface) at reduced resolution -> candidate.
  absl::StatusOr<planning::Candidate> MakeCandidate(ViewId id, const ImageF& depth,
                                                    const PinholeCamera& depth_camera,
                                                    const Rigid3d& local_from_depth,
                                                    const Rigid3d& local_from_cam,
                                                    const ImageU8& color) {
    planning::Candidate cand;
    EXO_ASSIGN_OR_RETURN(cand.cells, planning::CountDepthCellPixels(
                                         depth, depth_camera, local_from_depth, planner_.grid(),
                                         options_.id_buffer_stride, &cand.id_camera));
    cand.id = id;
    cand.local_from_cam = local_from_cam;
    cand.bytes = color.bytes() + static_cast<size_t>(color.width()) * color.height() * sizeof(float) +
                 sizeof(StoredView);
    return cand;
  }

  // A server restarted from a checkpoint: the planner's state is recomputed from the stored views
  // (their published depth, the same cell-id buffer as live) in id order, i.e. the order they
  // were accepted in. A view the rebuilt planner does not keep is removed (ViewRemoved), and the
  // store's cell references are replaced by the planner's (one CellRefsChanged), so planner and
  // store agree again. View ids continue after the largest stored id.
  absl::Status RebuildFromStoreLocked() {
    const auto views = store_->Views();
    if (views.empty()) return absl::OkStatus();
    for (const auto& msg : views) {
      EXO_ASSIGN_OR_RETURN(StoredView v, ViewFromProto(*msg));
      next_id_ = std::max<ViewId>(next_id_, v.id + 1);
      EXO_ASSIGN_OR_RETURN(planning::Candidate cand,
                           MakeCandidate(v.id, v.depth_m, v.camera, v.local_from_cam,
                                         v.local_from_cam, v.color));
      absl::StatusOr<planning::Decision> d = planner_.Consider(cand);
      if (!d.ok() || !d->accepted) {
        (void)store_->RemoveView(v.id);
        ++rebuild_removed_;
        continue;
      }
      for (ViewId victim : d->removed) {
        (void)store_->RemoveView(victim);
        ref_cache_.erase(victim);
        ++rebuild_removed_;
      }
#ifdef EXOVIEW_HAVE_REFINEMENT
      if (worker_)
        ref_cache_[v.id] = std::make_shared<const StoredView>(DownscaleView(v, options_.refine_downscale));
#endif
      ++rebuilt_views_;
    }
    std::map<CellId, std::vector<ViewId>> refs;
    for (CellId c : store_->CellIds()) refs[c];  // cells the planner no longer references: cleared
    for (auto& [c, r] : planner_.CellRefs()) refs[c] = std::move(r);
    std::vector<std::pair<CellId, std::vector<ViewId>>> cells(refs.begin(), refs.end());
    if (!cells.empty()) store_->SetCellRefs(cells);
    return absl::OkStatus();
  }

  absl::Status ApplyAreaChangesLocked() {
    if (!options_.take_area_changes) return absl::OkStatus();
    for (const auto& [cell, area] : options_.take_area_changes()) {
      EXO_RETURN_IF_ERROR(planner_.SetCellArea(cell, area));
      ++areas_set_;
    }
    return absl::OkStatus();
  }

  void PublishCellRefsLocked(const std::vector<CellId>& changed) {
    if (changed.empty()) return;
    std::vector<std::pair<CellId, std::vector<ViewId>>> cells;
    cells.reserve(changed.size());
    for (CellId c : changed) cells.emplace_back(c, planner_.Refs(c));
    store_->SetCellRefs(cells);
  }

#ifdef EXOVIEW_HAVE_REFINEMENT
  // On the refinement thread. The view may have been evicted meanwhile (stale: nothing to do).
  void ApplyRefinement(const RefinementJob& job, const absl::StatusOr<RefinementResult>& r) {
    if (!r.ok()) return;  // counted by the worker; the view stays as published
    std::lock_guard lock(mu_);
    if (store_ == nullptr || !planner_.HasView(job.id)) {
      ++stale_;
      return;
    }
    if (r->rejected_outlier && options_.refine_remove_outliers) {
      // Consistently out of planner (its coverage leaves τ, references refilled), store (ViewRemoved)
      // and clients (CellRefsChanged for the refilled cells).
      auto changed = planner_.Remove(job.id);
      if (!changed.ok()) return;
      (void)store_->RemoveView(job.id);
      PublishCellRefsLocked(*changed);
      ref_cache_.erase(job.id);
      ++outliers_removed_;
      return;
    }
    if (r->rejected_outlier) {  // kept as published: input pose and exposure, not refined
      ++outliers_kept_;
      return;
    }
    if (!store_->UpdateView(job.id, r->local_from_cam, static_cast<float>(r->exposure)).ok()) return;
    ++updated_;
    auto it = ref_cache_.find(job.id);
    if (it != ref_cache_.end()) {
      auto v = std::make_shared<StoredView>(*it->second);
      v->local_from_cam = r->local_from_cam;
      v->exposure = static_cast<float>(r->exposure);
      it->second = std::move(v);
    }
  }
  std::unique_ptr<RefinementWorker> worker_;
#endif

  mutable std::mutex mu_;  // planner, store writes of views/cell refs, caches (ingest vs refinement)
  planning::ViewPlanner planner_;
  const PlanningStageOptions options_;
  ModelStore* store_ = nullptr;
  ViewId next_id_ = 1;
  double last_candidate_s_ = -1e300;
  std::map<ViewId, std::shared_ptr<const StoredView>> ref_cache_;
  uint64_t candidates_ = 0, accepted_ = 0, governed_ = 0, areas_set_ = 0;
  uint64_t outliers_removed_ = 0, outliers_kept_ = 0, updated_ = 0, stale_ = 0;
  bool rebuilt_ = false;
  uint64_t ids_from_proxy_ = 0, cellid_update_errors_ = 0;
  std::unique_ptr<planning::CellIdRenderer> cell_ids_;  // null unless id_from_proxy
  int64_t id_buffer_ns_ = 0;
  uint64_t rebuilt_views_ = 0, rebuild_removed_ = 0;
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
  std::unique_ptr<planning::CellIdRenderer> cell_ids;
  if (options.id_from_proxy) {
    planning::CellIdRendererOptions co;
    co.grid = planner.grid();
    co.lod_cluster_m = options.cellid_lod_m >= 0.0
                           ? options.cellid_lod_m
                           : planning::DefaultCellIdLodM(cell_size_m, options.proxy_voxel_m);
    co.lod_keep_fraction = 0.1;
    EXO_ASSIGN_OR_RETURN(auto r, planning::CellIdRenderer::Create(co));
    cell_ids = std::make_unique<planning::CellIdRenderer>(std::move(r));
  }
  return std::unique_ptr<PipelineStage>(
      new PlanningStage(std::move(planner), options, std::move(cell_ids)));
}

}  // namespace exo
