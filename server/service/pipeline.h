// The modeling pipeline of the server (SPEC §1): accepted frames flow through a chain of stages
// (geometry -> planning -> refinement ...), each on its own thread, connected by bounded queues.
// Admission is the only place where work is dropped: when the first queue is full the frame is
// refused as a planning candidate (acked DROPPED); once admitted, a frame is never dropped (later
// queues block, which backs up into admission). Each stage publishes its model changes to the
// ModelStore itself. The pipeline runs with whatever stages the server was built with; with none
// it only validates and counts (it never invents model content).
#pragma once

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <functional>
#include <string_view>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "common/frame.h"
#include "common/rigid3.h"
#include "absl/strings/str_cat.h"
#include "common/status.h"
#include "server/core/online_model.h"
#include "server/service/bounded_queue.h"
#include "server/service/model_store.h"

namespace exo {

// One accepted frame on its way through the stages (pose still world_from_cam).
struct PipelineFrame {
  Frame frame;
  int64_t received_ns = 0;  // steady clock, when ingest accepted it
  // Frame journal (issue 20): the frame's log sequence number (0 = not journaled) and the named
  // uploader it came from ("" = anonymous); recorded in the store's applied ledger after the
  // last stage.
  uint64_t lsn = 0;
  std::string uploader;
};
using PipelineFramePtr = std::shared_ptr<const PipelineFrame>;

// Shared scene context every stage sees: the scene set-up of the online model (origin, voxel,
// cell size, view distance; fixed by the first accepted frame, server/core ChooseSceneSetup) and
// the published model.
struct SceneContext {
  LocalOrigin origin;
  double cell_size_m = 0.5;
  core::SceneSetup setup;
  ModelStore* store = nullptr;
};

class PipelineStage {
 public:
  virtual ~PipelineStage() = default;
  virtual std::string name() const = 0;
  // Processes one admitted frame; publishes its model changes to ctx.store. An error is counted
  // and logged; the pipeline goes on with the next frame.
  virtual absl::Status Process(const PipelineFrame& frame, const SceneContext& ctx) = 0;
  // Called once on the stage's thread after its last frame (shutdown): finish async work.
  virtual void Finish(const SceneContext& /*ctx*/) {}
  // Called on the stage's thread before each Process with the number of frames still waiting
  // in the stage's input queue and its capacity (load shedding, e.g. the geometry stage).
  virtual void SetBacklog(size_t /*queued*/, size_t /*capacity*/) {}
  // Work the stage still does asynchronously for frames it already processed (e.g. refinement).
  virtual uint64_t pending() const { return 0; }
  // Named counters for GetStats ("<stage>.<name>").
  virtual void AddCounters(std::map<std::string, double>* /*out*/) const {}
  // Checkpoint (issue 20, docs/service.md "Durability"): the stage's state after the frames it
  // processed, taken while the pipeline is quiescent (Pipeline::Quiesce; no frame in a queue,
  // no async work pending). "" = the stage keeps nothing a restart needs; an error = it cannot
  // save its state (the checkpoint then carries none and a restart rebuilds as before).
  virtual absl::StatusOr<std::string> SaveState() const { return std::string(); }
  // Before the first frame of a restarted server, with the restored scene set-up in `ctx`.
  virtual absl::Status RestoreState(std::string_view state, const SceneContext& /*ctx*/) {
    return state.empty() ? absl::OkStatus()
                         : absl::UnimplementedError(absl::StrCat(name(), " keeps no state"));
  }
};

struct PipelineOptions {
  size_t admission_queue = 8;  // frames waiting for the first stage (beyond: DROPPED)
  size_t stage_queue = 4;      // between later stages (blocking)
  // Lossless ingest: a full admission queue blocks the upload stream (back-pressure on the
  // client) instead of dropping the frame; every frame is then processed, in order (what a
  // deterministic run, e.g. the eval-equivalence test, needs).
  bool admission_block = false;
  // The online model the stages run (server/core): the evaluation's defaults. The bandwidth
  // governor (max_candidates_per_s_when_full, key of the same name) is off: at 2 candidates/s it
  // hid 14 of every 15 frames of a 30 Hz stream from the planner once the store was full, so the
  // store stayed the stream's first frames (real 7-Scenes folds, product path: SSIM 0.759 -> 0.798
  // at 50 views without it; docs/evaluation.md "Session 18"). The store's churn it saved decays
  // by itself (about capacity / frames-so-far replacements per frame; docs/service.md).
  core::OnlineModelOptions model;
  absl::Status Validate() const;
};

// Wall time a stage spends in Process (its thread's busy time), for the stats counters
// "<stage>.process_ms_mean / _max / _total": where the ingest rate goes.
class StageTimer {
 public:
  struct Snapshot {
    int64_t total_ns = 0, max_ns = 0;
    uint64_t count = 0;
  };
  void Add(int64_t ns) {
    std::lock_guard lock(mu_);
    s_.total_ns += ns;
    s_.max_ns = std::max(s_.max_ns, ns);
    ++s_.count;
  }
  Snapshot Get() const {
    std::lock_guard lock(mu_);
    return s_;
  }

 private:
  mutable std::mutex mu_;
  Snapshot s_;
};

class Pipeline {
 public:
  Pipeline(const PipelineOptions& options, ModelStore* store,
           std::vector<std::unique_ptr<PipelineStage>> stages);
  ~Pipeline();  // Stop()

  enum class Admission { kAccepted, kDropped };
  // Called by ingest with a validated frame. Never blocks (unless admission_block or `block`:
  // a journal replay must not drop what it replays).
  Admission Submit(PipelineFramePtr frame, bool block = false);
  // Drains the queues (every admitted frame is processed) and joins the threads.
  void Stop();

  std::vector<std::string> stage_names() const;
  uint64_t async_pending() const;
  std::map<std::string, double> counters() const;
  // Checkpoint of the stages' state (issue 20): pauses admission (Submit waits), waits until
  // every admitted frame went through every stage and no stage has async work pending, runs
  // `fn` (which reads the store and SaveState at one consistent frame) and resumes. false: the
  // pipeline did not drain within timeout_s (fn not run).
  bool Quiesce(double timeout_s, const std::function<void()>& fn);
  // Inside Quiesce: the scene set-up and every stage's state; "" before the first frame. An
  // error when a stage cannot save its state.
  absl::StatusOr<std::string> SaveState() const;
  // Before the first Submit of a restarted server: the scene set-up and the stages' state of
  // SaveState; the next frame continues exactly where the saved pipeline stood.
  absl::Status RestoreState(std::string_view state);
  // A restarted server keeps the origin of its checkpoint (call before the first Submit; the
  // store already holds the scene parameters).
  void RestoreOrigin(const LocalOrigin& origin, double cell_size_m) {
    restored_origin_ = origin;
    restored_cell_m_ = cell_size_m;
  }
  const SceneContext& context() const { return ctx_; }
  uint64_t frames_processed() const { return processed_.load(); }
  uint64_t stage_errors() const { return errors_.load(); }
  // Latency from admission to the end of the last stage (ns), for stats.
  int64_t last_latency_ns() const { return last_latency_ns_.load(); }

 private:
  void RunStage(size_t i);

  const PipelineOptions options_;
  SceneContext ctx_;
  std::atomic<bool> origin_set_{false};
  std::vector<std::unique_ptr<PipelineStage>> stages_;
  std::vector<StageTimer> timers_;                                       // per stage
  std::vector<std::unique_ptr<BoundedQueue<PipelineFramePtr>>> queues_;  // queues_[i] feeds stage i
  std::vector<std::thread> threads_;
  std::atomic<uint64_t> processed_{0}, errors_{0};
  // Quiesce: admission paused; frames admitted and not yet through the last stage.
  std::mutex pause_mu_;
  std::condition_variable pause_cv_;
  bool paused_ = false;
  std::atomic<int64_t> inflight_{0};
  std::atomic<int64_t> last_latency_ns_{0};
  bool stopped_ = false;
  std::optional<LocalOrigin> restored_origin_;
  std::optional<double> restored_cell_m_;
};

int64_t SteadyNowNs();

}  // namespace exo
