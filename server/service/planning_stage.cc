#include "server/service/planning_stage.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>

#include "common/state_io.h"

#include "server/service/refinement_worker.h"

namespace exo {

absl::Status PlanningStageOptions::Validate() const {
  if (refine_queue < 1) return absl::InvalidArgumentError("refine_queue must be >= 1");
  if (refine_downscale < 1 || refine_downscale > 8)
    return absl::InvalidArgumentError("refine_downscale must be in [1, 8]");
  return publish.Validate();
}

namespace {

class PlanningStage final : public PipelineStage {
 public:
  PlanningStage(const PlanningStageOptions& options, const core::OnlineModelOptions& model,
                std::shared_ptr<GeometryHandoff> handoff)
      : options_(options), model_(model), handoff_(std::move(handoff)) {
    if (options_.refine) {
      RefinementWorkerOptions wo;
      wo.queue = options_.refine_queue;
      wo.downscale = options_.refine_downscale;
      wo.refine.max_pose_correction_m = options_.refine_max_pose_m;
      wo.refine.max_pose_correction_deg = options_.refine_max_pose_deg;
      wo.refine.max_exposure_ratio = options_.refine_max_exposure_ratio;
      worker_ = std::make_unique<RefinementWorker>(
          wo, [this](const RefinementJob& job, const absl::StatusOr<RefinementResult>& r) {
            ApplyRefinement(job, r);
          });
    }
  }
  ~PlanningStage() override {
    if (worker_) worker_->Stop();
  }
  std::string name() const override { return "planning"; }

  absl::Status Process(const PipelineFrame& pf, const SceneContext& ctx) override {
    std::lock_guard lock(mu_);
    store_ = ctx.store;
    // Exactly one geometry update per frame is taken, first, whatever fails below (the planner
    // stays aligned with the geometry stage's frames); it waits while there is no planner yet.
    if (handoff_) {
      if (auto u = handoff_->Pop()) unapplied_.push_back(*std::move(u));
    }
    if (!planner_) {  // the first frame: the scene set-up is known now
      EXO_ASSIGN_OR_RETURN(planner_, core::OnlinePlanner::Create(model_, ctx.setup));
      EXO_RETURN_IF_ERROR(RebuildFromStoreLocked());
    }
    const int64_t t_apply = SteadyNowNs();
    for (const core::GeometryUpdate& u : unapplied_) EXO_RETURN_IF_ERROR(planner_->Apply(u));
    unapplied_.clear();
    apply_ns_ += SteadyNowNs() - t_apply;
    const Frame& f = pf.frame;
    const int64_t t_plan = SteadyNowNs();
    EXO_ASSIGN_OR_RETURN(core::HandOff h, planner_->Plan(core::PlanFrame::Of(f, ctx.origin)));
    plan_ns_ += SteadyNowNs() - t_plan;
    if (!h.accepted) return absl::OkStatus();
    const int64_t t_publish = SteadyNowNs();
    struct AddNs {  // publication (encode + store) and refinement hand-off time, on every return
      int64_t* acc;
      int64_t t0;
      ~AddNs() { *acc += SteadyNowNs() - t0; }
    } publish_timer{&publish_ns_, t_publish};
    for (ViewId victim : h.removed) {
      (void)ctx.store->RemoveView(victim);
      ref_cache_.erase(victim);
    }
    StoredView view = core::StoredViewOf(f, h.id, ctx.origin);
    EXO_ASSIGN_OR_RETURN(v1::ViewAdded msg, ViewToProto(view, options_.publish));
    ctx.store->AddView(std::move(msg));
    {
      const auto coverage = CoverageChangesLocked(h.cell_refs);
      if (!h.cell_refs.empty() || !coverage.empty()) store_->SetCellRefs(h.cell_refs, coverage);
    }
    if (worker_) {
      // The first view fixes the exposure gauge (E = 1); later ones are refined against the
      // stored views (as cached at 1/k resolution) off this thread.
      auto small =
          std::make_shared<const StoredView>(DownscaleView(view, options_.refine_downscale));
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
    return absl::OkStatus();
  }

  // The planner's whole state (server/core OnlinePlanner::SaveState). Not saved: the
  // refinement worker's reference cache (the views at 1/k resolution; rebuilt from the stored,
  // published views on restore) and its queue (empty: the pipeline is quiescent).
  absl::StatusOr<std::string> SaveState() const override {
    std::lock_guard lock(mu_);
    if (!planner_) return std::string();
    if (!unapplied_.empty())
      return absl::FailedPreconditionError("planning: geometry updates not yet applied");
    StateWriter w;
    EXO_RETURN_IF_ERROR(planner_->SaveState(&w));
    for (uint64_t v : {outliers_removed_, outliers_kept_, updated_, stale_}) w.Put(v);
    return std::move(w.str());
  }

  absl::Status RestoreState(std::string_view state, const SceneContext& ctx) override {
    if (state.empty()) return absl::OkStatus();
    std::lock_guard lock(mu_);
    store_ = ctx.store;
    EXO_ASSIGN_OR_RETURN(planner_, core::OnlinePlanner::Create(model_, ctx.setup));
    StateReader r(state);
    absl::Status s = planner_->LoadState(&r);
    for (uint64_t* v : {&outliers_removed_, &outliers_kept_, &updated_, &stale_}) r.Get(v);
    if (s.ok()) s = r.Status("planning stage");
    if (s.ok() && !r.done()) s = absl::DataLossError("planning stage state: trailing bytes");
    if (!s.ok()) {
      planner_.reset();  // the first frame rebuilds the planner from the stored views
      return s;
    }
    if (worker_)
      for (const auto& msg : store_->Views()) {
        if (msg->inpainted() || !planner_->planner().HasView(msg->view_id())) continue;
        EXO_ASSIGN_OR_RETURN(StoredView v, ViewFromProto(*msg));
        ref_cache_[v.id] =
            std::make_shared<const StoredView>(DownscaleView(v, options_.refine_downscale));
      }
    return absl::OkStatus();
  }

  void Finish(const SceneContext&) override {
    if (worker_) worker_->Stop();  // applies every queued refinement
  }

  uint64_t pending() const override { return worker_ ? worker_->pending() : 0; }

  void AddCounters(std::map<std::string, double>* out) const override {
    std::lock_guard lock(mu_);
    if (planner_) {
      const core::OnlinePlanner::Counters& c = planner_->counters();
      (*out)["planning.candidates"] = static_cast<double>(c.candidates);
      (*out)["planning.accepted"] = static_cast<double>(c.accepted);
      (*out)["planning.governed"] = static_cast<double>(c.governed);
      (*out)["planning.cell_areas_set"] = static_cast<double>(c.areas_set);
      (*out)["planning.views"] = static_cast<double>(planner_->planner().num_views());
      (*out)["planning.ids_from_proxy"] = static_cast<double>(c.ids_from_proxy);
      (*out)["planning.cellid_update_errors"] = static_cast<double>(c.cellid_update_errors);
      (*out)["planning.id_buffer_ms_mean"] =  // cell ids + Consider per planned frame
          c.frames ? plan_ns_ * 1e-6 / static_cast<double>(c.frames) : 0.0;
      (*out)["planning.apply_ms_mean"] =  // proxy update: cell areas (+ cell-id meshes)
          c.frames ? apply_ns_ * 1e-6 / static_cast<double>(c.frames) : 0.0;
      (*out)["planning.publish_ms_mean_per_accepted"] =
          c.accepted ? publish_ns_ * 1e-6 / static_cast<double>(c.accepted) : 0.0;
      (*out)["planning.digest"] = static_cast<double>(planner_->Digest());
      (*out)["planning.cell_m"] = planner_->setup().cell_m;
      // The time term's measured switch (planning/stream_drift.h): the stream's depth
      // disagreement 1 and 15 frames apart and the scale the planner uses (docs/planning.md
      // "Session 16 (lead)").
      (*out)["planning.drift_near"] = planner_->drift().Near();
      (*out)["planning.drift_far"] = planner_->drift().Far();
      (*out)["planning.time_scale"] = planner_->planner().time_scale();
    }
    (*out)["planning.rebuilt_views"] = static_cast<double>(rebuilt_views_);
    (*out)["planning.rebuild_removed"] = static_cast<double>(rebuild_removed_);
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
  }

 private:
  // A server restarted from a checkpoint: the planner's state is recomputed from the stored views
  // (their published depth, the same cell-id buffer as live) in id order, i.e. the order they
  // were accepted in. A view the rebuilt planner does not keep is removed (ViewRemoved), and the
  // store's cell references are replaced by the planner's (one CellRefsChanged), so planner and
  // store agree again. View ids continue after the largest stored id.
  absl::Status RebuildFromStoreLocked() {
    const auto views = store_->Views();
    if (views.empty()) return absl::OkStatus();
    for (const auto& msg : views) {
      if (msg->inpainted()) continue;  // hallucinated pixels never reach the planner (SPEC §7)
      EXO_ASSIGN_OR_RETURN(StoredView v, ViewFromProto(*msg));
      absl::StatusOr<core::HandOff> h = planner_->Readmit(v);
      if (!h.ok() || !h->accepted) {
        (void)store_->RemoveView(v.id);
        ++rebuild_removed_;
        continue;
      }
      for (ViewId victim : h->removed) {
        (void)store_->RemoveView(victim);
        ref_cache_.erase(victim);
        ++rebuild_removed_;
      }
      if (worker_)
        ref_cache_[v.id] =
            std::make_shared<const StoredView>(DownscaleView(v, options_.refine_downscale));
      ++rebuilt_views_;
    }
    std::map<CellId, std::vector<ViewId>> refs;
    for (CellId c : store_->CellIds()) refs[c];  // cells the planner no longer references: cleared
    for (auto& [c, r] : planner_->planner().CellPublishedRefs()) refs[c] = std::move(r);
    std::vector<std::pair<CellId, std::vector<ViewId>>> cells(refs.begin(), refs.end());
    const auto coverage = CoverageChangesLocked(cells);
    if (!cells.empty() || !coverage.empty()) store_->SetCellRefs(cells, coverage);
    return absl::OkStatus();
  }

  // The cells whose published coverage (CellCoverage: τ/τ_max in whole percent) differs from the
  // planner's now: every cell with references in the store or in `refs` (the references about
  // to be published). O(cells) lookups per accepted frame; only changed values go on the wire.
  std::vector<std::pair<CellId, uint8_t>> CoverageChangesLocked(
      const std::vector<std::pair<CellId, std::vector<ViewId>>>& refs) const {
    const auto& planner = planner_->planner();
    const double tau_max = planner.options().tau_max;
    const auto published = store_->CellCoverage();
    std::vector<CellId> cells = store_->CellIds();
    for (const auto& [c, r] : refs) cells.push_back(c);
    std::sort(cells.begin(), cells.end());
    cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
    std::vector<std::pair<CellId, uint8_t>> out;
    for (CellId c : cells) {
      const double f = tau_max > 0 ? std::clamp(planner.CellTau(c) / tau_max, 0.0, 1.0) : 0.0;
      const uint8_t q = uint8_t(std::lround(100.0 * f));
      auto it = published.find(c);
      if (it == published.end() || it->second != q) out.emplace_back(c, q);
    }
    return out;
  }

  // On the refinement thread. The view may have been evicted meanwhile (stale: nothing to do).
  void ApplyRefinement(const RefinementJob& job, const absl::StatusOr<RefinementResult>& r) {
    if (!r.ok()) return;  // counted by the worker; the view stays as published
    std::lock_guard lock(mu_);
    if (store_ == nullptr || !planner_ || !planner_->planner().HasView(job.id)) {
      ++stale_;
      return;
    }
    if (r->rejected_outlier && options_.refine_remove_outliers) {
      // Consistently out of planner (its coverage leaves τ, references refilled), store
      // (ViewRemoved) and clients (CellRefsChanged for the refilled cells).
      auto changed = planner_->Remove(job.id);
      if (!changed.ok()) return;
      (void)store_->RemoveView(job.id);
      const auto coverage = CoverageChangesLocked(*changed);
      if (!changed->empty() || !coverage.empty()) store_->SetCellRefs(*changed, coverage);
      ref_cache_.erase(job.id);
      ++outliers_removed_;
      return;
    }
    if (r->rejected_outlier) {  // kept as published: input pose and exposure, not refined
      ++outliers_kept_;
      return;
    }
    if (!store_->UpdateView(job.id, r->local_from_cam, static_cast<float>(r->exposure)).ok())
      return;
    ++updated_;
    auto it = ref_cache_.find(job.id);
    if (it != ref_cache_.end()) {
      auto v = std::make_shared<StoredView>(*it->second);
      v->local_from_cam = r->local_from_cam;
      v->exposure = static_cast<float>(r->exposure);
      it->second = std::move(v);
    }
  }
  const PlanningStageOptions options_;
  const core::OnlineModelOptions model_;
  std::shared_ptr<GeometryHandoff> handoff_;
  std::unique_ptr<RefinementWorker> worker_;
  mutable std::mutex
      mu_;  // planner, store writes of views/cell refs, caches (ingest vs refinement)
  std::unique_ptr<core::OnlinePlanner> planner_;  // created on the first frame (scene set-up)
  std::vector<core::GeometryUpdate> unapplied_;   // taken from the hand-off, not yet applied
  ModelStore* store_ = nullptr;
  std::map<ViewId, std::shared_ptr<const StoredView>> ref_cache_;
  uint64_t outliers_removed_ = 0, outliers_kept_ = 0, updated_ = 0, stale_ = 0;
  int64_t plan_ns_ = 0, apply_ns_ = 0, publish_ns_ = 0;
  uint64_t rebuilt_views_ = 0, rebuild_removed_ = 0;
};

}  // namespace

absl::StatusOr<std::unique_ptr<PipelineStage>> MakePlanningStage(
    const PlanningStageOptions& options, const core::OnlineModelOptions& model,
    std::shared_ptr<GeometryHandoff> handoff) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(model.Validate());
  return std::unique_ptr<PipelineStage>(new PlanningStage(options, model, std::move(handoff)));
}

}  // namespace exo
