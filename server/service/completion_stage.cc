#include "server/service/completion_stage.h"

#include <optional>

#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <future>
#include <mutex>
#include <set>
#include <thread>

#include "common/log/log.h"
#include "proto/frame_proto.h"
#include "server/inpainting/region_labels.h"

namespace exo {
namespace {

double WallMs() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}
double ThreadCpuMs() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}

void NiceThisThread(int nice) {
  if (nice <= 0) return;
  const id_t tid = static_cast<id_t>(syscall(SYS_gettid));
  errno = 0;
  const int now = getpriority(PRIO_PROCESS, tid);
  if (errno != 0) return;
  (void)setpriority(PRIO_PROCESS, tid, std::min(19, now + nice));
}

bool FinitePose(const Rigid3d& p) {
  const glm::dquat& q = p.rotation;
  return std::isfinite(q.w) && std::isfinite(q.x) && std::isfinite(q.y) && std::isfinite(q.z) &&
         std::isfinite(p.translation.x) && std::isfinite(p.translation.y) &&
         std::isfinite(p.translation.z);
}

class CompletionStageImpl final : public CompletionStage {
 public:
  CompletionStageImpl(const CompletionStageOptions& options, ModelStore* store,
                      std::shared_ptr<ObservedChunks> coloured)
      : options_(options), store_(store), coloured_(std::move(coloured)) {
    TakeOverRestoredViews();
    worker_ = std::thread([this] { WorkerLoop(); });
  }
  ~CompletionStageImpl() override {
    {
      std::lock_guard lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    worker_.join();
    for (auto& j : queue_) j->result.set_value(absl::UnavailableError("the server is shutting down"));
  }

  absl::StatusOr<v1::CompleteViewReply> Complete(const CompletionRequest& request) override {
    // Checked here, on the caller's thread: a bad request never takes the slot.
    EXO_RETURN_IF_ERROR(request.camera.Validate());
    if (request.camera.width > 4096 || request.camera.height > 4096)
      return absl::InvalidArgumentError("the completion camera is larger than 4096x4096");
    if (request.max_side_px > 4096)
      return absl::InvalidArgumentError("max_side_px must be at most 4096 (0 = the server's default)");
    if (!FinitePose(request.local_from_cam))
      return absl::InvalidArgumentError("the completion camera's pose is not finite");
    if (!store_->Origin())
      return absl::FailedPreconditionError("no scene yet: upload frames before completing a view");
    auto job = std::make_shared<Job>();
    job->request = request;
    job->queued_ms = WallMs();
    std::future<absl::StatusOr<v1::CompleteViewReply>> done = job->result.get_future();
    {
      std::lock_guard lock(mu_);
      if (stop_) return absl::UnavailableError("the server is shutting down");
      if (queue_.size() + (busy_ ? 1 : 0) >= 2) {
        ++refused_busy_;
        return absl::ResourceExhaustedError(
            "a scene completion is in flight and another one waits; try again when it is done");
      }
      job->kind = Job::kComplete;
      queue_.push_back(job);
    }
    cv_.notify_all();
    return done.get();
  }

  absl::StatusOr<int> RefreshNow() override {
    auto job = std::make_shared<Job>();
    job->kind = Job::kRefresh;
    job->queued_ms = WallMs();
    auto done = job->result.get_future();
    {
      std::lock_guard lock(mu_);
      if (stop_) return absl::UnavailableError("the server is shutting down");
      queue_.push_back(job);
    }
    cv_.notify_all();
    EXO_ASSIGN_OR_RETURN(v1::CompleteViewReply r, done.get());
    return static_cast<int>(r.view_id());  // (refresh: the count of changed views)
  }

  void AddCounters(std::map<std::string, double>* c) const override {
    std::lock_guard lock(mu_);
    (*c)["completion.requests"] = static_cast<double>(requests_);
    (*c)["completion.completed"] = static_cast<double>(completed_);
    (*c)["completion.nothing_to_complete"] = static_cast<double>(nothing_);
    (*c)["completion.failed"] = static_cast<double>(failed_);
    (*c)["completion.refused_busy"] = static_cast<double>(refused_busy_);
    (*c)["completion.views"] = static_cast<double>(entries_.size());
    (*c)["completion.refreshed"] = static_cast<double>(refreshed_);
    (*c)["completion.withdrawn"] = static_cast<double>(withdrawn_);
    (*c)["completion.evicted"] = static_cast<double>(evicted_);
    (*c)["completion.ms_mean"] = completed_ ? sum_ms_ / completed_ : 0.0;
    (*c)["completion.cpu_ms_mean"] = completed_ ? sum_cpu_ms_ / completed_ : 0.0;
    (*c)["completion.hole_px_total"] = static_cast<double>(hole_px_);
    (*c)["completion.fused_color_px_total"] = static_cast<double>(fused_px_);
  }

 private:
  struct Job {
    enum Kind { kComplete, kRefresh } kind = kComplete;
    CompletionRequest request;
    double queued_ms = 0;
    std::promise<absl::StatusOr<v1::CompleteViewReply>> result;
  };
  struct Entry {
    ViewId id = 0;
    uint64_t chunk_id = 0;       // 0: no mesh chunk
    uint64_t chunk_version = 0;
    int hole_px = 0;             // labels now
  };
  struct CachedView {
    std::shared_ptr<const v1::ViewAdded> msg;  // the part the decode is of
    StoredView view;
  };

  // The model as published (as the clients hold it). `observed_only`: without completion views
  // and completion chunks (the refresh asks what the observations alone cover now).
  absl::StatusOr<LumigraphModel> Snapshot(bool observed_only) {
    LumigraphModel m;
    const std::optional<LocalOrigin> origin = store_->Origin();
    if (!origin) return absl::FailedPreconditionError("no scene yet");
    m.origin = *origin;
    m.grid.cell_size_m = store_->scene().cell_size_m();
    if (!(m.grid.cell_size_m > 0)) m.grid.cell_size_m = 0.5;
    std::map<ViewId, CachedView> next;
    for (const auto& msg : store_->Views()) {
      const ViewId id = msg->view_id();
      auto it = cache_.find(id);
      if (it != cache_.end() && it->second.msg == msg) {
        next[id] = std::move(it->second);
      } else {
        auto v = ViewFromProto(*msg);
        if (!v.ok()) continue;  // (never: the store holds what it encoded)
        next[id] = {msg, *std::move(v)};
      }
    }
    cache_ = std::move(next);
    for (const auto& [id, cv] : cache_) {
      if (observed_only && IsCompletionView(id)) continue;
      m.views[id] = cv.view;  // (shares nothing: Image copies; fine at this scale)
    }
    for (auto& [cell, refs] : store_->CellRefs()) m.cell_refs[cell] = std::move(refs);
    for (const auto& c : store_->Chunks()) {
      if (observed_only && IsCompletionChunk(c->chunk_id())) continue;
      EXO_ASSIGN_OR_RETURN(TriangleMesh mesh, MeshFromProto(*c));
      MeshChunk mc;
      mc.id = c->chunk_id();
      mc.version = c->chunk_version();
      mc.mesh = std::move(mesh);
      m.chunks[mc.id] = std::move(mc);
    }
    return m;
  }

  // What the observations are: the ids and parts of the views that are not inpainted and the
  // (id, version) of the chunks that are not completion chunks.
  uint64_t ObservedSignature() const {
    uint64_t h = 0xcbf29ce484222325ull;
    const auto mix = [&h](uint64_t v) {
      h ^= v;
      h *= 0x100000001b3ull;
    };
    for (const auto& msg : store_->Views()) {
      if (msg->inpainted()) continue;
      mix(msg->view_id());
      mix(reinterpret_cast<uintptr_t>(msg.get()));
    }
    for (const auto& c : store_->Chunks()) {
      if (IsCompletionChunk(c->chunk_id())) continue;
      mix(c->chunk_id());
      mix(reinterpret_cast<uintptr_t>(c.get()));
    }
    return h;
  }

  void TakeOverRestoredViews() {
    std::map<uint64_t, uint64_t> chunks;
    for (const auto& c : store_->Chunks())
      if (IsCompletionChunk(c->chunk_id())) chunks[c->chunk_id()] = c->chunk_version();
    for (const auto& msg : store_->Views()) {
      if (!IsCompletionView(msg->view_id())) continue;
      Entry e;
      e.id = msg->view_id();
      next_id_ = std::max<ViewId>(next_id_, e.id + 1);
      auto v = ViewFromProto(*msg);
      if (v.ok()) e.hole_px = inpainting::CountNonZero(v->labels);
      const uint64_t cid = kCompletionChunkBit | e.id;
      if (auto it = chunks.find(cid); it != chunks.end()) {
        e.chunk_id = cid;
        e.chunk_version = it->second;
      }
      entries_.push_back(e);
    }
    if (!entries_.empty())
      log::Get("completion")->info("{} completion view(s) taken over from the checkpoint",
                                   entries_.size());
  }

  void WorkerLoop() {
    pthread_setname_np(pthread_self(), "exo-completion");
    NiceThisThread(options_.nice);
    std::unique_lock lock(mu_);
    double last_check = WallMs();
    for (;;) {
      const auto period = std::chrono::duration<double>(
          options_.refresh_period_s > 0 ? options_.refresh_period_s : 3600.0);
      cv_.wait_for(lock, period, [this] { return stop_ || !queue_.empty(); });
      if (stop_) return;
      std::shared_ptr<Job> job;
      if (!queue_.empty()) {
        job = queue_.front();
        queue_.pop_front();
      }
      const bool periodic = !job && options_.refresh_period_s > 0 && !entries_.empty() &&
                            WallMs() - last_check >= options_.refresh_period_s * 1e3;
      if (!job && !periodic) continue;
      busy_ = true;
      lock.unlock();
      if (job && job->kind == Job::kComplete) {
        job->result.set_value(Run(*job));
      } else if (job) {
        auto n = Refresh(/*force=*/true);
        v1::CompleteViewReply r;
        if (n.ok()) r.set_view_id(static_cast<uint32_t>(*n));
        job->result.set_value(n.ok() ? absl::StatusOr<v1::CompleteViewReply>(r)
                                     : absl::StatusOr<v1::CompleteViewReply>(n.status()));
      } else {
        (void)Refresh(/*force=*/false);
        last_check = WallMs();
      }
      lock.lock();
      busy_ = false;
    }
  }

  absl::StatusOr<v1::CompleteViewReply> Run(const Job& job) {
    auto log = log::Get("completion");
    const double t0 = WallMs(), c0 = ThreadCpuMs();
    {
      std::lock_guard lock(mu_);
      ++requests_;
    }
    auto fail = [&](absl::Status s) -> absl::Status {
      std::lock_guard lock(mu_);
      ++failed_;
      log->info("completion for {} refused: {}", job.request.who, std::string(s.message()));
      return s;
    };
    // The keyframe's size: the camera scaled down so its longer side is at most max_side_px.
    PinholeCamera cam = job.request.camera;
    const int side = static_cast<int>(
        job.request.max_side_px ? std::min<uint32_t>(job.request.max_side_px, options_.max_side_px)
                                : options_.max_side_px);
    const int longer = std::max(cam.width, cam.height);
    if (longer > side) {
      const double s = double(side) / longer;
      cam = cam.Scaled(std::max(1, int(std::lround(cam.width * s))),
                       std::max(1, int(std::lround(cam.height * s))));
    }
    auto model = Snapshot(/*observed_only=*/false);
    if (!model.ok()) return fail(model.status());
    std::optional<TriangleMesh> coloured;
    if (coloured_ && options_.completion.use_vertex_color) coloured = coloured_->Merged();
    auto r = inpainting::CompleteView(*model, cam, job.request.local_from_cam, options_.completion,
                                      coloured && !coloured->empty() ? &*coloured : nullptr);
    if (!r.ok()) return fail(r.status());
    v1::CompleteViewReply out;
    out.set_width(cam.width);
    out.set_height(cam.height);
    out.set_hole_px(r->before.hole_px);
    out.set_surface_hole_px(r->before.surface_hole_px);
    out.set_void_hole_px(r->before.void_hole_px);
    out.set_covered_px(r->before.covered_px);
    out.set_background_px(r->before.background_px);
    out.set_render_ms(r->render_ms);
    out.set_inpaint_ms(r->inpaint_ms);
    out.set_wait_ms(t0 - job.queued_ms);
    if (!r->completed) {
      out.set_outcome(v1::CompleteViewReply::NOTHING_TO_COMPLETE);
      out.set_model_version(store_->version());
      out.set_total_ms(WallMs() - t0);
      out.set_cpu_ms(ThreadCpuMs() - c0);
      std::lock_guard lock(mu_);
      ++nothing_;
      return out;
    }
    Entry e;
    {
      std::lock_guard lock(mu_);
      if (next_id_ >= kCompletionViewIdEnd) next_id_ = kCompletionViewIdBase;  // (2^28 later)
      e.id = next_id_++;
    }
    r->view.id = e.id;
    auto msg = ViewToProto(r->view, options_.publish);
    if (!msg.ok()) return fail(msg.status());
    if (!r->void_mesh.empty()) {
      e.chunk_id = kCompletionChunkBit | e.id;
      e.chunk_version = 1;
      store_->UpsertChunk(e.chunk_id, e.chunk_version, r->void_mesh);
      out.set_mesh_chunk_id(e.chunk_id);
      out.set_mesh_triangles(static_cast<uint32_t>(r->void_mesh.num_triangles()));
    }
    const uint64_t version = store_->AddView(*std::move(msg));
    e.hole_px = r->before.hole_px;
    std::optional<Entry> evict;
    {
      std::lock_guard lock(mu_);
      entries_.push_back(e);
      if (entries_.size() > options_.max_views) {
        evict = entries_.front();
        entries_.pop_front();
        ++evicted_;
      }
    }
    if (evict) Withdraw(*evict);
    out.set_outcome(v1::CompleteViewReply::COMPLETED);
    out.set_view_id(e.id);
    out.set_model_version(version);
    out.set_total_ms(WallMs() - t0);
    out.set_cpu_ms(ThreadCpuMs() - c0);
    {
      std::lock_guard lock(mu_);
      ++completed_;
      sum_ms_ += out.total_ms();
      sum_cpu_ms_ += out.cpu_ms();
      hole_px_ += r->before.hole_px;
      fused_px_ += r->before.fused_color_px;
    }
    log->info("completion view {:#x} for {}: {}x{}, {} hole px ({} surface, {} of them with "
              "fused colour, {} void; {} covered, "
              "{} background), mesh {} triangles, render {:.0f} ms, inpaint {:.0f} ms, total "
              "{:.0f} ms ({:.0f} ms CPU)",
              e.id, job.request.who.empty() ? "a viewer" : job.request.who, cam.width, cam.height,
              r->before.hole_px, r->before.surface_hole_px, r->before.fused_color_px,
              r->before.void_hole_px,
              r->before.covered_px, r->before.background_px, r->void_mesh.num_triangles(),
              r->render_ms, r->inpaint_ms, out.total_ms(), out.cpu_ms());
    return out;
  }

  void Withdraw(const Entry& e) {
    (void)store_->RemoveView(e.id);
    if (e.chunk_id) (void)store_->RemoveChunk(e.chunk_id);
  }

  // Observations preferred: see the header. Returns how many views changed.
  absl::StatusOr<int> Refresh(bool force) {
    std::deque<Entry> entries;
    {
      std::lock_guard lock(mu_);
      entries = entries_;
    }
    if (entries.empty()) return 0;
    // Bounded work per period while frames arrive (every chunk or view change is a change): the
    // views to re-check since the last change, at most refresh_views_per_check of them per call.
    const uint64_t sig = ObservedSignature();
    if (sig != last_signature_) {
      last_signature_ = sig;
      to_check_.clear();
      for (const Entry& e : entries) to_check_.insert(e.id);
    }
    if (!force && to_check_.empty()) return 0;
    EXO_ASSIGN_OR_RETURN(LumigraphModel observed, Snapshot(/*observed_only=*/true));
    int changed = 0, checked = 0;
    std::deque<Entry> keep;
    for (Entry e : entries) {
      const bool due = force || (to_check_.count(e.id) &&
                                 checked < std::max(1, options_.refresh_views_per_check));
      if (!due) {
        keep.push_back(e);
        continue;
      }
      ++checked;
      to_check_.erase(e.id);
      auto it = cache_.find(e.id);
      if (it == cache_.end()) continue;  // removed meanwhile
      const StoredView& v = it->second.view;
      auto holes = inpainting::FindHoles(observed, v.camera, v.local_from_cam, options_.completion);
      if (!holes.ok()) {
        keep.push_back(e);
        continue;
      }
      StoredView nv = v;
      int remaining = 0;
      ImageU8 void_mask(v.camera.width, v.camera.height, 1, 0);
      for (int y = 0; y < v.camera.height; ++y)
        for (int x = 0; x < v.camera.width; ++x) {
          const bool hole = v.labels.at(x, y) != 0 && holes->holes.at(x, y) != 0;
          nv.labels.at(x, y) = hole ? 255 : 0;
          const float zp = holes->proxy_depth.at(x, y);
          if (zp > 0.0f) nv.depth_m.at(x, y) = zp;  // the proxy now has a surface here
          if (hole && !(zp > 0.0f)) void_mask.at(x, y) = 255;
          remaining += hole;
        }
      if (remaining < options_.completion.min_hole_px) {
        Withdraw(e);
        ++changed;
        std::lock_guard lock(mu_);
        ++withdrawn_;
        log::Get("completion")->info("completion view {:#x} withdrawn: observations cover its "
                                     "holes ({} of {} px left)", e.id, remaining, e.hole_px);
        continue;
      }
      if (e.hole_px - remaining < std::max(1, options_.refresh_min_px)) {
        keep.push_back(e);
        continue;
      }
      const TriangleMesh mesh = inpainting::MeshFromDepth(
          nv.depth_m, void_mask, nv.camera, nv.local_from_cam, options_.completion.mesh_step_px,
          options_.completion.mesh_jump_rel);
      auto msg = ViewToProto(nv, options_.publish);
      if (!msg.ok()) {
        keep.push_back(e);
        continue;
      }
      if (mesh.empty() && e.chunk_id) {
        (void)store_->RemoveChunk(e.chunk_id);
        e.chunk_id = 0;
      } else if (!mesh.empty()) {
        e.chunk_id = kCompletionChunkBit | e.id;
        store_->UpsertChunk(e.chunk_id, ++e.chunk_version, mesh);
      }
      store_->AddView(*std::move(msg));  // same id: replaces the view for every viewer
      log::Get("completion")->info("completion view {:#x} refreshed: {} of {} hole px now "
                                   "observed", e.id, e.hole_px - remaining, e.hole_px);
      e.hole_px = remaining;
      keep.push_back(e);
      ++changed;
      std::lock_guard lock(mu_);
      ++refreshed_;
    }
    std::lock_guard lock(mu_);
    // Entries added meanwhile (none: the worker is the only writer) are kept as they are.
    entries_ = std::move(keep);
    return changed;
  }

  const CompletionStageOptions options_;
  ModelStore* store_;
  std::shared_ptr<ObservedChunks> coloured_;  // may be null
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::shared_ptr<Job>> queue_;
  bool busy_ = false, stop_ = false;
  std::deque<Entry> entries_;  // oldest first
  ViewId next_id_ = kCompletionViewIdBase;
  uint64_t requests_ = 0, completed_ = 0, nothing_ = 0, failed_ = 0, refused_busy_ = 0,
           refreshed_ = 0, withdrawn_ = 0, evicted_ = 0, hole_px_ = 0, fused_px_ = 0;
  double sum_ms_ = 0, sum_cpu_ms_ = 0;
  // Worker only.
  std::map<ViewId, CachedView> cache_;
  uint64_t last_signature_ = 0;
  std::set<ViewId> to_check_;  // completion views not re-checked since the observations changed
  std::thread worker_;
};

}  // namespace

absl::Status CompletionStageOptions::Validate() const {
  EXO_RETURN_IF_ERROR(completion.Validate());
  if (max_side_px < 16 || max_side_px > 4096)
    return absl::InvalidArgumentError("completion_max_side_px must be in [16, 4096]");
  if (max_views < 1 || max_views > 64)
    return absl::InvalidArgumentError("completion_max_views must be in [1, 64]");
  if (!(refresh_period_s >= 0.0) || !std::isfinite(refresh_period_s))
    return absl::InvalidArgumentError("completion_refresh_period_s must be >= 0");
  if (refresh_min_px < 0) return absl::InvalidArgumentError("completion_refresh_min_px must be >= 0");
  if (refresh_views_per_check < 1 || refresh_views_per_check > 64)
    return absl::InvalidArgumentError("completion_refresh_views_per_check must be in [1, 64]");
  if (nice < 0 || nice > 19) return absl::InvalidArgumentError("completion_nice must be in [0, 19]");
  return absl::OkStatus();
}

absl::StatusOr<std::unique_ptr<CompletionStage>> CompletionStage::Create(
    const CompletionStageOptions& options, ModelStore* store,
    std::shared_ptr<ObservedChunks> coloured) {
  EXO_RETURN_IF_ERROR(options.Validate());
  if (store == nullptr) return absl::InvalidArgumentError("no model store");
  return std::unique_ptr<CompletionStage>(
      new CompletionStageImpl(options, store, std::move(coloured)));
}

}  // namespace exo
