#include "server/service/pipeline.h"

#include <pthread.h>

#include <chrono>
#include <cmath>
#include <cstdio>

#include "common/log/log.h"

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
  if (options_.admission_block || block) return queues_[0]->Push(std::move(frame)) ? Admission::kAccepted : Admission::kDropped;
  return queues_[0]->TryPush(std::move(frame)) ? Admission::kAccepted : Admission::kDropped;
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
