#include "server/service/pipeline.h"

#include <pthread.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>

#include "common/log/log.h"
#include "common/state_io.h"

namespace exo {

int64_t SteadyNowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

absl::Status PipelineOptions::Validate() const {
  if (admission_queue < 1) return absl::InvalidArgumentError("admission_queue must be >= 1");
  if (stage_queue < 1) return absl::InvalidArgumentError("stage_queue must be >= 1");
  return model.Validate();
}

Pipeline::Pipeline(const PipelineOptions& options, ModelStore* store,
                   std::vector<std::unique_ptr<PipelineStage>> stages)
    : options_(options), stages_(std::move(stages)), timers_(stages_.size()) {
  EXO_CHECK(options_.Validate().ok());
  ctx_.store = store;
  for (size_t i = 0; i < stages_.size(); ++i)
    queues_.push_back(std::make_unique<BoundedQueue<PipelineFramePtr>>(
        i == 0 ? options_.admission_queue : options_.stage_queue));
}

Pipeline::~Pipeline() { Stop(); }

Pipeline::Admission Pipeline::Submit(PipelineFramePtr frame, bool block) {
  {
    std::unique_lock lock(pause_mu_);
    pause_cv_.wait(lock, [this] { return !paused_; });
    inflight_.fetch_add(1);
  }
  struct Leave {  // a frame that does not enter the queue is no longer in flight
    std::atomic<int64_t>* n;
    bool entered = false;
    ~Leave() {
      if (!entered) n->fetch_sub(1);
    }
  } leave{&inflight_};
  if (!origin_set_.load(std::memory_order_acquire)) {
    // The first admitted frame fixes the scene set-up (server/core ChooseSceneSetup: origin =
    // its camera centre, voxel / cell / d_max from what it observes; a restored checkpoint keeps
    // its origin and cell size). Only the ingest thread(s) submit and stages start reading ctx_
    // after their first Pop, which happens-after this.
    static std::mutex origin_mu;
    std::lock_guard lock(origin_mu);
    if (!origin_set_.load()) {
      auto setup = core::ChooseSceneSetup(frame->frame, options_.model, restored_origin_,
                                          restored_cell_m_);
      EXO_CHECK(setup.ok());  // options validated with the config
      ctx_.setup = *setup;
      ctx_.origin = setup->origin;
      ctx_.cell_size_m = setup->cell_m;
      if (!restored_origin_) ctx_.store->SetSceneParams(ctx_.origin, ctx_.cell_size_m);
      log::Get("pipeline")->info(
          "scene set-up from the first frame: diameter {:.2f} m, voxel {:.3f} m, cell {:.2f} m, "
          "d_max {:.2f} m, sigma {:.2f} m",
          setup->diameter_m, setup->voxel_m, setup->cell_m, setup->d_max_m, setup->sigma_m);
      for (size_t i = 0; i < stages_.size(); ++i) threads_.emplace_back([this, i] { RunStage(i); });
      origin_set_.store(true, std::memory_order_release);
    }
  }
  if (stages_.empty()) {
    ctx_.store->BeginApply();
    ctx_.store->EndApply(frame->lsn, frame->uploader, frame->frame.sequence);
    processed_.fetch_add(1);
    last_latency_ns_.store(SteadyNowNs() - frame->received_ns);
    return Admission::kAccepted;
  }
  leave.entered = options_.admission_block || block ? queues_[0]->Push(std::move(frame))
                                                    : queues_[0]->TryPush(std::move(frame));
  return leave.entered ? Admission::kAccepted : Admission::kDropped;
}

bool Pipeline::Quiesce(double timeout_s, const std::function<void()>& fn) {
  {
    std::lock_guard lock(pause_mu_);
    paused_ = true;
  }
  struct Resume {
    Pipeline* p;
    ~Resume() {
      {
        std::lock_guard lock(p->pause_mu_);
        p->paused_ = false;
      }
      p->pause_cv_.notify_all();
    }
  } resume{this};
  const int64_t deadline = SteadyNowNs() + static_cast<int64_t>(timeout_s * 1e9);
  while (inflight_.load() > 0 || async_pending() > 0) {
    if (SteadyNowNs() > deadline) return false;
    std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
  fn();
  return true;
}

namespace {
constexpr uint32_t kPipelineStateFormat = 0x45585034;  // "EXP4" (session 17: the planner policy and its baseline selector)
}  // namespace

absl::StatusOr<std::string> Pipeline::SaveState() const {
  if (!origin_set_.load()) return std::string();
  StateWriter w;
  w.Put(kPipelineStateFormat);
  const core::SceneSetup& s = ctx_.setup;
  w.Put(s.origin.origin_in_world);
  for (double v : {s.diameter_m, s.view_depth_m, s.voxel_m, s.cell_m, s.d_max_m, s.sigma_m,
                   s.scale.diameter_m, s.scale.cell_size_m, s.scale.d_max_m, s.scale.sigma_m})
    w.Put(v);
  w.Put<uint64_t>(stages_.size());
  for (const auto& stage : stages_) {
    EXO_ASSIGN_OR_RETURN(std::string state, stage->SaveState());
    w.PutBytes(stage->name());
    w.PutBytes(state);
  }
  return std::move(w.str());
}

absl::Status Pipeline::RestoreState(std::string_view state) {
  if (state.empty()) return absl::OkStatus();
  if (origin_set_.load()) return absl::FailedPreconditionError("pipeline already started");
  StateReader r(state);
  uint32_t format = 0;
  r.Get(&format);
  if (r.ok() && format != kPipelineStateFormat)
    return absl::FailedPreconditionError("pipeline state of another format");
  core::SceneSetup s;
  r.Get(&s.origin.origin_in_world);
  for (double* v : {&s.diameter_m, &s.view_depth_m, &s.voxel_m, &s.cell_m, &s.d_max_m,
                    &s.sigma_m, &s.scale.diameter_m, &s.scale.cell_size_m, &s.scale.d_max_m,
                    &s.scale.sigma_m})
    r.Get(v);
  uint64_t n = 0;
  r.Count(&n, 16);
  if (r.ok() && n != stages_.size())
    return absl::FailedPreconditionError(
        absl::StrCat("pipeline state of ", n, " stages, this server runs ", stages_.size()));
  std::vector<std::string> states(stages_.size());
  for (size_t i = 0; r.ok() && i < stages_.size(); ++i) {
    std::string name;
    r.GetBytes(&name) && r.GetBytes(&states[i]);
    if (r.ok() && name != stages_[i]->name())
      return absl::FailedPreconditionError(absl::StrCat(
          "pipeline state: stage ", i, " is ", name, ", this server runs ", stages_[i]->name()));
  }
  EXO_RETURN_IF_ERROR(r.Status("pipeline"));
  if (!r.done()) return absl::DataLossError("pipeline state: trailing bytes");
  ctx_.setup = s;
  ctx_.origin = s.origin;
  ctx_.cell_size_m = s.cell_m;
  for (size_t i = 0; i < stages_.size(); ++i)
    EXO_RETURN_IF_ERROR(stages_[i]->RestoreState(states[i], ctx_));
  for (size_t i = 0; i < stages_.size(); ++i) threads_.emplace_back([this, i] { RunStage(i); });
  origin_set_.store(true, std::memory_order_release);
  log::Get("pipeline")->info(
      "scene set-up and the state of {} stages restored from the checkpoint: voxel {:.3f} m, "
      "cell {:.2f} m, d_max {:.2f} m",
      stages_.size(), s.voxel_m, s.cell_m, s.d_max_m);
  return absl::OkStatus();
}

void Pipeline::RunStage(size_t i) {
  pthread_setname_np(pthread_self(), ("exo-" + stages_[i]->name()).substr(0, 15).c_str());
  while (auto item = queues_[i]->Pop()) {
    const PipelineFramePtr& f = *item;
    const ScopedDeltaSource source(f->frame.timestamp_s);
    stages_[i]->SetBacklog(queues_[i]->size(), queues_[i]->capacity());
    const int64_t t0 = SteadyNowNs();
    const bool last = i + 1 == stages_.size();
    // The last stage's changes and the frame's ledger entry go into a checkpoint together.
    if (last) ctx_.store->BeginApply();
    const absl::Status s = stages_[i]->Process(*f, ctx_);
    if (last) ctx_.store->EndApply(f->lsn, f->uploader, f->frame.sequence);
    timers_[i].Add(SteadyNowNs() - t0);
    if (!s.ok()) {
      errors_.fetch_add(1);
      log::Get("pipeline")->error("stage {}, frame {}: {}", stages_[i]->name(), f->frame.sequence,
                                  std::string(s.message()));
    }
    if (i + 1 < stages_.size()) {
      queues_[i + 1]->Push(std::move(*item));
    } else {
      processed_.fetch_add(1);
      last_latency_ns_.store(SteadyNowNs() - f->received_ns);
      inflight_.fetch_sub(1);
    }
  }
  stages_[i]->Finish(ctx_);
  // Upstream closed and drained: close ours so the next stage drains too.
  if (i + 1 < queues_.size()) queues_[i + 1]->Close();
}

void Pipeline::Stop() {
  if (stopped_) return;
  stopped_ = true;
  if (!queues_.empty()) queues_[0]->Close();
  for (auto& t : threads_) t.join();
  threads_.clear();
}

uint64_t Pipeline::async_pending() const {
  uint64_t n = 0;
  for (const auto& s : stages_) n += s->pending();
  return n;
}

std::map<std::string, double> Pipeline::counters() const {
  std::map<std::string, double> out;
  for (const auto& s : stages_) s->AddCounters(&out);
  for (size_t i = 0; i < stages_.size(); ++i) {
    const StageTimer::Snapshot t = timers_[i].Get();
    const std::string n = stages_[i]->name();
    out[n + ".process_ms_mean"] = t.count ? t.total_ns * 1e-6 / static_cast<double>(t.count) : 0.0;
    out[n + ".process_ms_max"] = t.max_ns * 1e-6;
    out[n + ".process_ms_total"] = t.total_ns * 1e-6;
  }
  return out;
}

std::vector<std::string> Pipeline::stage_names() const {
  std::vector<std::string> names;
  for (const auto& s : stages_) names.push_back(s->name());
  return names;
}

}  // namespace exo
