// Asynchronous refinement of accepted views (SPEC §5) for the server pipeline: the planning stage
// hands each accepted view (with a snapshot of the stored views it may be compared against) to
// this worker, which runs server/refinement's RefineView on its own thread and reports the result
// through a callback (which publishes ViewUpdated, or removes a pose outlier consistently from
// planner + store). The queue is bounded and submission never blocks: under load a view is
// published unrefined (counted as skipped) — an accepted view is never dropped or delayed.
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <thread>
#include <vector>

#include "common/lumigraph/model.h"
#include "common/status.h"
#include "server/refinement/view_refiner.h"
#include "server/service/bounded_queue.h"

namespace exo {

struct RefinementWorkerOptions {
  size_t queue = 2;        // views waiting for refinement (beyond: skipped)
  int downscale = 2;       // candidate and references refined at 1/k resolution (speed, memory)
  // Reference pyramids kept between jobs (RefinementCache, LRU); 0 = no cache. A stored view is
  // a reference for many candidates; at 1/2 resolution each pyramid is ~0.4 MB.
  size_t cache_views = 64;
  // Nice value of the worker thread (Linux; 0 = the process's): refinement is asynchronous and
  // optional, so on a busy CPU it yields to the ingest path (decode, geometry, planning) instead
  // of slowing it down until admission drops frames (issue 15: 30 Hz on real frames).
  int nice = 10;
  RefinementOptions refine;
  absl::Status Validate() const;
};

struct RefinementJob {
  ViewId id = 0;
  double source_timestamp_s = 0.0;           // tags the resulting deltas
  std::shared_ptr<const StoredView> candidate;  // at the worker's resolution
  std::vector<std::shared_ptr<const StoredView>> refs;
};

// Counters for GetStats.
struct RefinementWorkerStats {
  uint64_t submitted = 0, skipped_under_load = 0, refined = 0, errors = 0, outliers = 0,
           pose_refused = 0;
  double total_ms = 0.0;
};

class RefinementWorker {
 public:
  using ApplyFn = std::function<void(const RefinementJob&, const absl::StatusOr<RefinementResult>&)>;
  RefinementWorker(const RefinementWorkerOptions& options, ApplyFn apply);
  ~RefinementWorker();  // Stop()

  // Never blocks; false = queue full, the view stays unrefined (counted).
  bool TrySubmit(RefinementJob job);
  // Refines everything queued, then joins.
  void Stop();
  size_t pending() const { return pending_.load(); }
  RefinementWorkerStats stats() const;

 private:
  void Run();
  const RefinementWorkerOptions options_;
  ApplyFn apply_;
  BoundedQueue<RefinementJob> queue_;
  std::unique_ptr<RefinementCache> cache_;  // used by the worker thread only (null: off)
  std::thread thread_;
  std::atomic<size_t> pending_{0};
  mutable std::mutex mu_;
  RefinementWorkerStats stats_;
  bool stopped_ = false;
};

// A copy of `view` at 1/k resolution (colour: box filter; depth: nearest valid sample at the
// block centre; camera scaled to match). k = 1 copies.
StoredView DownscaleView(const StoredView& view, int k);

}  // namespace exo
