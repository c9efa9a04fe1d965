#include "server/service/refinement_worker.h"

#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>

#include "server/service/model_store.h"

namespace exo {

absl::Status RefinementWorkerOptions::Validate() const {
  if (queue < 1) return absl::InvalidArgumentError("refine_queue must be >= 1");
  if (nice < -20 || nice > 19) return absl::InvalidArgumentError("nice must be in [-20, 19]");
  if (downscale < 1 || downscale > 8)
    return absl::InvalidArgumentError("refine_downscale must be in [1, 8]");
  return refine.Validate();
}

StoredView DownscaleView(const StoredView& v, int k) {
  if (k <= 1) return v;
  StoredView out;
  out.id = v.id;
  out.local_from_cam = v.local_from_cam;
  out.exposure = v.exposure;
  const int w = v.color.width() / k, h = v.color.height() / k;
  out.camera = v.camera.Scaled(w, h);
  out.color = ImageU8(w, h, 3);
  const bool has_depth = v.depth_m.width() == v.color.width() && v.depth_m.height() == v.color.height();
  if (has_depth) out.depth_m = ImageF(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      int sum[3] = {0, 0, 0};
      float zmin = 0.0f, zmax = 0.0f, zsum = 0.0f;
      int nz = 0;
      for (int dy = 0; dy < k; ++dy)
        for (int dx = 0; dx < k; ++dx) {
          const int sx = x * k + dx, sy = y * k + dy;
          for (int c = 0; c < 3; ++c) sum[c] += v.color.at(sx, sy, c);
          if (!has_depth) continue;
          const float z = v.depth_m.at(sx, sy);
          if (!(z > 0.0f) || !std::isfinite(z)) continue;
          zmin = nz ? std::min(zmin, z) : z;
          zmax = nz ? std::max(zmax, z) : z;
          zsum += z;
          ++nz;
        }
      for (int c = 0; c < 3; ++c) out.color.at(x, y, c) = static_cast<uint8_t>((sum[c] + k * k / 2) / (k * k));
      // Depth: mean of the valid samples on a smooth block, the nearest one across an edge
      // (never a mixed depth that lies on no surface).
      if (has_depth && nz > 0) out.depth_m.at(x, y) = (zmax - zmin < 0.05f) ? zsum / nz : zmin;
    }
  return out;
}

RefinementWorker::RefinementWorker(const RefinementWorkerOptions& options, ApplyFn apply)
    : options_(options), apply_(std::move(apply)), queue_(options.queue) {
  EXO_CHECK(options_.Validate().ok());
  if (options_.cache_views > 0) cache_ = std::make_unique<RefinementCache>(options_.cache_views);
  thread_ = std::thread([this] { Run(); });
}

RefinementWorker::~RefinementWorker() { Stop(); }

bool RefinementWorker::TrySubmit(RefinementJob job) {
  pending_.fetch_add(1);
  if (!queue_.TryPush(std::move(job))) {
    pending_.fetch_sub(1);
    std::lock_guard lock(mu_);
    ++stats_.skipped_under_load;
    return false;
  }
  std::lock_guard lock(mu_);
  ++stats_.submitted;
  return true;
}

void RefinementWorker::Run() {
  pthread_setname_np(pthread_self(), "exo-refine");
  if (options_.nice != 0) {
    // Per-thread nice (Linux threads are scheduled as tasks); a failure only loses the priority.
    const auto tid = static_cast<id_t>(syscall(SYS_gettid));
    (void)setpriority(PRIO_PROCESS, tid, options_.nice);
  }
  while (auto job = queue_.Pop()) {
    std::vector<const StoredView*> refs;
    refs.reserve(job->refs.size());
    for (const auto& r : job->refs) refs.push_back(r.get());
    absl::StatusOr<RefinementResult> r =
        RefineView(*job->candidate, refs, options_.refine, cache_.get());
    {
      std::lock_guard lock(mu_);
      if (r.ok()) {
        ++stats_.refined;
        stats_.outliers += r->rejected_outlier;
        stats_.pose_refused += r->pose_refused_rank_deficient;
        stats_.total_ms += r->ms;
      } else {
        ++stats_.errors;
      }
    }
    {
      const ScopedDeltaSource source(job->source_timestamp_s);
      apply_(*job, r);
    }
    pending_.fetch_sub(1);
  }
}

void RefinementWorker::Stop() {
  if (stopped_) return;
  stopped_ = true;
  queue_.Close();
  if (thread_.joinable()) thread_.join();
}

RefinementWorkerStats RefinementWorker::stats() const {
  std::lock_guard lock(mu_);
  return stats_;
}

}  // namespace exo
