#include "server/service/inpainting_stage.h"
#include "server/service/completion_stage.h"  // IsCompletionView

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>
#include <optional>
#include <thread>

#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>

#include "common/log/log.h"
#include "proto/frame_proto.h"
#include "server/core/online_model.h"

namespace exo {

absl::Status InpaintingStageOptions::Validate() const {
  EXO_RETURN_IF_ERROR(inpaint.Validate());
  EXO_RETURN_IF_ERROR(policy.Validate());
  if (max_keyframes == 0 || max_keyframes > 256)
    return absl::InvalidArgumentError("inpaint_max_keyframes must be in [1, 256]");
  if (method != "dr" && method != "keyframe")
    return absl::InvalidArgumentError("inpaint_method must be dr or keyframe");
  if (observation_views < 0 || observation_views > 256)
    return absl::InvalidArgumentError("inpaint_observation_views must be in [0, 256]");
  if (observation_stride < 1 || observation_stride > 1000)
    return absl::InvalidArgumentError("inpaint_observation_stride must be in [1, 1000]");
  if (frame_stride < 1 || frame_stride > 100)
    return absl::InvalidArgumentError("inpaint_frame_stride must be in [1, 100]");
  if (refresh_min_px < 0) return absl::InvalidArgumentError("inpaint_refresh_min_px must be >= 0");
  if (live_views < 1 || live_views > 64)
    return absl::InvalidArgumentError("inpaint_live_views must be in [1, 64]");
  if (nice < 0 || nice > 19) return absl::InvalidArgumentError("inpaint_nice must be in [0, 19]");
  if (keyframe_nice < -1 || keyframe_nice > 19)
    return absl::InvalidArgumentError("inpaint_keyframe_nice must be -1 (= inpaint_nice) or in [0, 19]");
  if (frame_nice < -1 || frame_nice > 19)
    return absl::InvalidArgumentError("inpaint_frame_nice must be -1 (= inpaint_nice) or in [0, 19]");
  if (!(frame_backoff_ms >= 0.0 && frame_backoff_ms <= 60000.0))
    return absl::InvalidArgumentError("inpaint_frame_backoff_ms must be in [0, 60000]");
  if (kf_crop_margin_px < 0 || !(kf_crop_margin_rel >= 0.0 && kf_crop_margin_rel <= 100.0))
    return absl::InvalidArgumentError(
        "inpaint_kf_crop_margin_px must be >= 0 and inpaint_kf_crop_margin_rel in [0, 100]");
  return absl::OkStatus();
}

namespace {

using inpainting::DiminishedReality;
using inpainting::DrKeyframe;
using inpainting::DrOptions;

double ThreadCpuMs() {
  timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}

// How long the calling thread has waited runnable for a CPU (ms, the scheduler's run delay from
// /proc/thread-self/schedstat; 0 where the kernel does not keep it).
double ThreadRunDelayMs() {
  FILE* f = std::fopen("/proc/thread-self/schedstat", "r");
  if (!f) return 0.0;
  unsigned long long run = 0, wait = 0;
  const int n = std::fscanf(f, "%llu %llu", &run, &wait);
  std::fclose(f);
  return n == 2 ? wait * 1e-6 : 0.0;
}

// The calling thread's niceness (Linux: per thread), or `fallback` when it cannot be read.
int ThreadNice(int fallback) {
  const id_t tid = static_cast<id_t>(syscall(SYS_gettid));
  errno = 0;
  const int now = getpriority(PRIO_PROCESS, tid);
  return errno != 0 ? fallback : now;
}

// Sets the calling thread's niceness to `base + nice` (clamped to 19; nice >= 0). Raising it
// needs no privilege; lowering it again needs CAP_SYS_NICE or a large enough RLIMIT_NICE (Linux),
// so that can fail (AdaptiveNice then keeps the thread at the nicer value).
bool SetThreadNice(int base, int nice) {
  const id_t tid = static_cast<id_t>(syscall(SYS_gettid));
  const int target = std::min(19, base + std::max(0, nice));
  return setpriority(PRIO_PROCESS, tid, target) == 0;
}

// Lowers the calling thread's priority by `nice` below the server's own (Linux: nice is per
// thread; a server started at nice -10 runs these at 0).
void NiceThisThread(int nice) {
  if (nice <= 0) return;
  const id_t tid = static_cast<id_t>(syscall(SYS_gettid));
  errno = 0;
  const int now = getpriority(PRIO_PROCESS, tid);
  if (errno != 0) return;
  const int target = std::min(19, now + nice);
  if (setpriority(PRIO_PROCESS, tid, target) != 0)
    log::Get("inpainting")->warn("setpriority({}) failed: {}", target, errno);
}

// A stage thread's two priorities (InpaintingStageOptions::frame_backoff_ms): `fast` while
// frames reach the stage soon after their admission, `slow` while they arrive late (the modelling
// stages are behind and ingest would wait for them). Used on the thread itself.
class AdaptiveNice {
 public:
  AdaptiveNice(const char* who, int fast, int slow, double backoff_ms)
      : who_(who), fast_(fast), slow_(std::max(fast, slow)), backoff_ms_(backoff_ms) {}
  void Start() {
    base_ = ThreadNice(0);
    backed_off_ = fast_ == slow_;
    NiceThisThread(backed_off_ ? slow_ : fast_);
  }
  // Given the newest frame's delay from admission to the stage; true when it just backed off.
  bool Update(double handoff_ms) {
    if (fast_ == slow_ || backoff_ms_ <= 0) return false;
    if (!backed_off_ && handoff_ms > backoff_ms_) {
      backed_off_ = SetThreadNice(base_, slow_);
      return backed_off_;
    }
    if (backed_off_ && can_return_ && handoff_ms < 0.5 * backoff_ms_) {
      if (SetThreadNice(base_, fast_)) {
        backed_off_ = false;
      } else {
        can_return_ = false;  // lowering the niceness again needs CAP_SYS_NICE or RLIMIT_NICE
        log::Get("inpainting")->warn("the {} thread cannot return to nice {} (needs CAP_SYS_NICE "
                                     "or RLIMIT_NICE); it stays at {}",
                                     who_, base_ + fast_, base_ + slow_);
      }
    }
    return false;
  }
  bool backed_off() const { return backed_off_; }

 private:
  const char* who_;
  int fast_, slow_;
  double backoff_ms_;
  int base_ = 0;
  bool backed_off_ = false, can_return_ = true;
};

DrOptions ToDrOptions(const InpaintingStageOptions& o) {
  DrOptions d;
  d.inpaint = o.inpaint;
  d.policy = o.policy;
  d.max_keyframes = o.max_keyframes;
  d.obs_stride = std::max(1, o.observation_stride / std::max(1, o.frame_stride));  // in looked-at frames
  const bool dr = o.method == "dr";
  d.obs_views = dr ? o.observation_views : 0;
  d.kf_context = dr;  // "keyframe" (session 9): the library inpaints the whole ROI
  if (dr) {
    d.kf_crop_margin_px = o.kf_crop_margin_px;
    d.kf_crop_margin_rel = o.kf_crop_margin_rel;
  }
  return d;
}

struct Job {
  std::shared_ptr<const RegionSet> regions;
  // A refresh of an existing keyframe (observations preferred) instead of a new keyframe.
  std::shared_ptr<const inpainting::DrView> refresh;
  uint64_t refresh_obs = 0;      // observation views kept when the refresh was asked for
  inpainting::DrKeyframeJob dr;  // frame (pose: scene-local), ROI, the views it may look up
  double timestamp_s = 0;
  uint64_t sequence = 0;
  const char* reason = "";
};

class InpaintingStageImpl final : public InpaintingStage {
 public:
  InpaintingStageImpl(const InpaintingStageOptions& o, std::shared_ptr<RegionRegistry> regions,
                      ModelStore* store, std::shared_ptr<InpaintedProxyLink> link)
      : options_(o), dr_options_(ToDrOptions(o)), dr_(dr_options_), regions_(std::move(regions)),
        store_(store), link_(std::move(link)) {
    RestoreFromStore();
    publisher_ = std::thread([this] { PublisherLoop(); });
    worker_ = std::thread([this] { WorkerLoop(); });
    frames_thread_ = std::thread([this] { FrameLoop(); });
  }
  ~InpaintingStageImpl() override { StopWorker(); }

  std::string name() const override { return "inpainting"; }

  // On the pipeline thread: only a hand-off. The frame is copied into a one-frame slot (a newer
  // frame replaces one the stage's frame thread has not taken yet: the DR view and the rule need
  // the newest frame, not every frame), so the stage never holds the chain of stages back and
  // ingest keeps its rate whatever the DR work costs.
  absl::Status Process(const PipelineFrame& pf, const SceneContext& ctx) override {
    const std::shared_ptr<const RegionSet> set = regions_->Get();
    if (set->regions.empty()) return absl::OkStatus();
    const Frame& f = pf.frame;
    if (f.depth_m.empty()) return absl::OkStatus();
    int64_t next_index = 0;  // counts the frames that arrive (observation stride)
    {
      // slot_mu_ only: the stage's own threads run niced and may hold mu_ for milliseconds
      // (the rule, job snapshots); the pipeline thread must never wait behind them.
      std::lock_guard lock(slot_mu_);
      const int64_t seen = frames_seen_++;
      // Only every frame_stride-th frame is looked at.
      if (seen % options_.frame_stride != 0) {
        ++frames_strided_;
        return absl::OkStatus();
      }
      if (!origin_) origin_ = ctx.origin;
      next_index = seen / options_.frame_stride;
    }
    // How long after its admission the frame reached this (the last) stage: the modelling
    // stages' delay, which the frame thread's priority follows (frame_backoff_ms).
    const double handoff_ms = (SteadyNowNs() - pf.received_ns) * 1e-6;
    auto copy = std::make_shared<PipelineFrame>();
    copy->frame = f;  // ~2 MB at 640x480: well under a millisecond
    copy->received_ns = pf.received_ns;
    {
      std::lock_guard lock(slot_mu_);
      if (slot_) ++frames_superseded_;
      slot_ = std::move(copy);
      slot_set_ = set;
      slot_index_ = next_index;
      handoff_ms_ = handoff_ms;
      handoff_ms_sum_ += handoff_ms;
      ++handoffs_;
    }
    frame_cv_.notify_all();
    return absl::OkStatus();
  }

  std::shared_ptr<const DrLiveFrame> WaitLiveFrame(uint64_t after, double timeout_s) override {
    std::unique_lock lock(mu_);
    live_cv_.wait_for(lock, std::chrono::duration<double>(timeout_s),
                      [&] { return stop_ || (live_ && live_->index > after); });
    return live_ && live_->index > after ? live_ : nullptr;
  }

  void AddLiveWatcher(int delta) override {
    std::lock_guard lock(mu_);
    watchers_ += delta;
  }

 private:
  // The stage's frame thread: re-projection of the labels, the keyframe rule, observations and
  // the live DR view, for the newest handed-off frame.
  void FrameLoop() {
    pthread_setname_np(pthread_self(), "exo-dr-frames");
    AdaptiveNice prio("DR frame", options_.frame_nice >= 0 ? options_.frame_nice : options_.nice,
                      options_.nice, options_.frame_backoff_ms);
    prio.Start();
    for (;;) {
      std::shared_ptr<PipelineFrame> pf;
      std::shared_ptr<const RegionSet> set;
      LocalOrigin origin;
      int64_t index = 0;
      double handoff_ms = 0;
      {
        std::unique_lock lock(slot_mu_);
        frame_cv_.wait(lock, [this] { return frame_stop_ || slot_; });
        if (frame_stop_) return;
        pf = std::move(slot_);
        slot_.reset();
        set = std::move(slot_set_);
        index = slot_index_;
        origin = *origin_;
        frame_busy_ = true;
        handoff_ms = handoff_ms_;
      }
      {
        const bool backoff = prio.Update(handoff_ms);
        std::lock_guard lock(slot_mu_);
        frame_backoffs_ += backoff;
        frames_backed_off_ += prio.backed_off();
      }
      ProcessFrame(*pf, set, origin, index);
      {
        std::lock_guard lock(slot_mu_);
        frame_busy_ = false;
      }
      std::lock_guard lock(mu_);  // WaitIdle checks under mu_ (then slot_mu_)
      idle_cv_.notify_all();
    }
  }

  // `index` counts the frames that arrived (not only those looked at), so observation views stay
  // one every obs_stride arriving frames however many the slot superseded.
  void ProcessFrame(const PipelineFrame& pf, const std::shared_ptr<const RegionSet>& set,
                    const LocalOrigin& origin, int64_t index) {
    const Frame& f = pf.frame;
    bool live = false;
    {
      std::lock_guard lock(mu_);
      ++frames_looked_;
      live = options_.live_always || watchers_ > 0;
      // The keyframe slot is taken and no live view is watched: this frame is only counted,
      // unless it is due as an observation.
      if (!live && SlotTakenLocked() && !ObservationDueLocked(index)) {
        ++skipped_busy_;
        return;
      }
    }
    const int64_t t0 = SteadyNowNs();
    const double c0 = ThreadCpuMs();
    struct CpuTally {  // CPU, wall and run delay of this frame's work, however it returns
      InpaintingStageImpl* self;
      double c0, r0;
      int64_t t0, received_ns;
      ~CpuTally() {
        const double cpu = ThreadCpuMs() - c0, runq = ThreadRunDelayMs() - r0;
        const int64_t t1 = SteadyNowNs();
        std::lock_guard lock(self->mu_);
        self->frame_cpu_ms_ += cpu;
        self->frame_wall_ms_ += (t1 - t0) * 1e-6;
        self->frame_runq_ms_ += runq;
        self->frame_pickup_ms_ += (t0 - received_ns) * 1e-6;
        ++self->frames_measured_;
      }
    } tally{this, c0, ThreadRunDelayMs(), t0, pf.received_ns};
    const Rigid3d local_from_cam = origin.ToLocal(f.world_from_cam);
    ImageF depth = core::RegisterDepthToColor(f);
    const double c1 = ThreadCpuMs();
    ImageU8 mask = inpainting::ProjectRegions(set->labels, depth, f.color_camera, local_from_cam,
                                              options_.region);
    const int roi = inpainting::CountNonZero(mask);
    inpainting::RgbdKeyframe frame{f.color, std::move(depth), f.color_camera, local_from_cam};
    const double c2 = ThreadCpuMs();
    Job job;
    bool submit = false;
    inpainting::DrLiveSnapshot snap;
    {
      std::lock_guard lock(mu_);
      if (roi == 0) {
        ++frames_without_roi_;
      } else {
        ++frames_with_roi_;
        if (live) snap = dr_.LiveSnapshot(local_from_cam, options_.live_views);
        if (SlotTakenLocked()) {
          ++skipped_busy_;
          AddObservationLocked(frame, mask, index);
        } else {
          const inpainting::KeyframeDecision d = dr_.Decide(mask, f.color_camera, local_from_cam);
          decide_ns_ += SteadyNowNs() - t0;
          log::Get("inpainting")->debug("frame {}: ROI {} px, nearest keyframe {} at {:.3f}, {:.1f} % unlabelled -> {}",
                    f.sequence, roi, d.nearest, d.pose_distance, 100.0 * d.unlabelled_fraction,
                    d.insert ? d.reason : "no keyframe");
          ++decisions_;
          if (d.insert) {
            job.dr = dr_.MakeJob(frame, mask, d);
            if (options_.method == "keyframe") {  // session 9: nothing is looked up
              job.dr.views.clear();
              job.dr.nearest.reset();
            }
            job.reason = d.reason;
            submit = true;
          } else if (PickRefreshLocked(&job)) {
            // The worker is idle: a keyframe whose holes a newer observation may show.
            job.reason = "refresh";
            submit = true;
          }
          AddObservationLocked(frame, mask, index);
        }
      }
      phase_register_cpu_ms_ += c1 - c0;
      phase_project_cpu_ms_ += c2 - c1;
      phase_rule_cpu_ms_ += ThreadCpuMs() - c2;
      ++phase_frames_;
    }
    if (submit) {
      job.regions = set;
      job.timestamp_s = f.timestamp_s;
      job.sequence = f.sequence;
      {
        std::lock_guard lock(mu_);
        job_ = std::move(job);
      }
      cv_.notify_all();
    }
    if (live) {
      if (set->generation != live_generation_) live_state_.Reset();  // the regions changed
      live_generation_ = set->generation;
      ComposeLive(pf, frame, mask, snap);
    }
  }

  // The live DR view of this frame (outside the lock: the snapshot's views are immutable).
  void ComposeLive(const PipelineFrame& pf, const inpainting::RgbdKeyframe& frame,
                   const ImageU8& mask, const inpainting::DrLiveSnapshot& snap) {
    const int64_t t0 = SteadyNowNs();
    const double c0 = ThreadCpuMs();
    inpainting::DrLiveOptions lo;
    lo.max_views = options_.live_views;
    lo.temporal = dr_options_.temporal;
    auto r = inpainting::ComposeLiveFrame(frame, mask, snap, lo, &live_state_);
    const double ms = (SteadyNowNs() - t0) * 1e-6, cpu = ThreadCpuMs() - c0;
    auto lf = std::make_shared<DrLiveFrame>();
    lf->sequence = pf.frame.sequence;
    lf->timestamp_s = pf.frame.timestamp_s;
    lf->world_from_cam = pf.frame.world_from_cam;
    if (r.ok()) {
      lf->color = std::move(r->color);
      lf->composited = r->composited;
      lf->roi_px = r->roi_px;
    } else {
      log::Get("inpainting")->warn("live DR frame {}: {}", pf.frame.sequence,
                                   std::string(r.status().message()));
      lf->color = frame.color;
    }
    lf->compose_ms = ms;
    lf->compose_cpu_ms = cpu;
    lf->latency_ms = (SteadyNowNs() - pf.received_ns) * 1e-6;
    {
      std::lock_guard lock(mu_);
      lf->index = ++live_frames_;
      live_composited_ += lf->composited;
      live_roi_px_ += lf->roi_px;
      live_ms_ += ms;
      live_cpu_ms_ += cpu;
      live_latency_ms_ += lf->latency_ms;
      live_ = std::move(lf);
    }
    live_cv_.notify_all();
  }

 public:
  void Finish(const SceneContext&) override { WaitIdle(60.0); }

  uint64_t pending() const override {
    std::lock_guard lock(mu_);
    std::lock_guard slot(slot_mu_);
    return (job_ ? 1 : 0) + (busy_ ? 1 : 0) + (slot_ ? 1 : 0) + (frame_busy_ ? 1 : 0);
  }

  void AddCounters(std::map<std::string, double>* out) const override {
    std::lock_guard lock(mu_);
    auto& c = *out;
    c["inpainting.regions"] = static_cast<double>(regions_->Get()->regions.size());
    c["inpainting.keyframes"] = static_cast<double>(ids_.size());
    c["inpainting.keyframes_published"] = static_cast<double>(published_);
    c["inpainting.keyframes_propagated"] = static_cast<double>(propagated_);
    c["inpainting.keyframes_discarded"] = static_cast<double>(discarded_);
    c["inpainting.keyframes_failed"] = static_cast<double>(failed_);
    c["inpainting.frames_with_roi"] = static_cast<double>(frames_with_roi_);
    c["inpainting.frames_without_roi"] = static_cast<double>(frames_without_roi_);
    c["inpainting.frames_skipped_busy"] = static_cast<double>(skipped_busy_);
    std::lock_guard slot(slot_mu_);  // lock order: mu_, then slot_mu_
    c["inpainting.frames_skipped_stride"] = static_cast<double>(frames_strided_);
    c["inpainting.views_withdrawn"] = static_cast<double>(withdrawn_);
    c["inpainting.decide_ms_mean"] = decisions_ ? decide_ns_ * 1e-6 / decisions_ : 0.0;
    c["inpainting.first_keyframe_ms"] = first_ms_;
    c["inpainting.propagated_keyframe_ms_mean"] = propagated_ ? propagated_ms_ / propagated_ : 0.0;
    c["inpainting.first_keyframe_cpu_ms"] = first_cpu_ms_;
    c["inpainting.propagated_keyframe_cpu_ms_mean"] =
        propagated_ ? propagated_cpu_ms_ / propagated_ : 0.0;
    c["inpainting.keyframe_ms_last"] = last_ms_;
    c["inpainting.keyframe_ms_mean"] = published_ ? sum_ms_ / published_ : 0.0;
    c["inpainting.keyframe_cpu_ms_mean"] = published_ ? sum_cpu_ms_ / published_ : 0.0;
    c["inpainting.keyframe_observed_fraction"] =
        keyframe_roi_px_ ? static_cast<double>(keyframe_observed_px_) / keyframe_roi_px_ : 0.0;
    c["inpainting.observation_views"] = static_cast<double>(dr_.observations());
    c["inpainting.keyframes_refreshed"] = static_cast<double>(refreshed_);
    c["inpainting.refreshed_pixels"] = static_cast<double>(refreshed_px_);
    c["inpainting.refresh_jobs"] = static_cast<double>(refresh_jobs_);
    c["inpainting.refresh_cpu_ms_total"] = refresh_cpu_ms_;
    // CPU of the stage's per-frame work on the pipeline thread (registration, re-projection,
    // the rule, observation copies), frames that got past the busy check.
    c["inpainting.frame_cpu_ms_mean"] = frames_measured_ ? frame_cpu_ms_ / frames_measured_ : 0.0;
    // The frame thread per looked-at frame: wall, time runnable but waiting for a CPU (run
    // delay), time from the frame's admission to the thread taking it, and the CPU by phase
    // (depth registration; re-projection of the labels; rule + snapshot + observation copy under
    // the lock); the compose is live_compose_cpu_ms_mean.
    c["inpainting.frame_wall_ms_mean"] = frames_measured_ ? frame_wall_ms_ / frames_measured_ : 0.0;
    c["inpainting.frame_runq_ms_mean"] = frames_measured_ ? frame_runq_ms_ / frames_measured_ : 0.0;
    c["inpainting.frame_pickup_ms_mean"] =
        frames_measured_ ? frame_pickup_ms_ / frames_measured_ : 0.0;
    c["inpainting.frame_register_cpu_ms_mean"] =
        phase_frames_ ? phase_register_cpu_ms_ / phase_frames_ : 0.0;
    c["inpainting.frame_project_cpu_ms_mean"] =
        phase_frames_ ? phase_project_cpu_ms_ / phase_frames_ : 0.0;
    c["inpainting.frame_rule_cpu_ms_mean"] = phase_frames_ ? phase_rule_cpu_ms_ / phase_frames_ : 0.0;
    // The keyframe thread: run delay per keyframe (waiting for a CPU while computing it).
    c["inpainting.keyframe_runq_ms_mean"] = published_ ? keyframe_runq_ms_ / published_ : 0.0;
    c["inpainting.in_flight"] = (job_ || busy_) ? 1.0 : 0.0;  // a keyframe is being computed
    // Frames handed to the frame thread that a newer one replaced before it was looked at.
    c["inpainting.frames_superseded"] = static_cast<double>(frames_superseded_);
    // Delay from admission to this stage's hand-off, and the frame thread's priority back-offs
    // (frame_backoff_ms): times it went to inpaint_nice, frames it looked at while there.
    c["inpainting.handoff_latency_ms_mean"] = handoffs_ ? handoff_ms_sum_ / handoffs_ : 0.0;
    c["inpainting.frame_backoffs"] = static_cast<double>(frame_backoffs_);
    c["inpainting.frames_backed_off"] = static_cast<double>(frames_backed_off_);
    c["inpainting.keyframe_backoffs"] = static_cast<double>(keyframe_backoffs_);
    c["inpainting.keyframe_jobs_backed_off"] = static_cast<double>(jobs_backed_off_);
    c["inpainting.frames_looked_at"] = static_cast<double>(frames_looked_);
    // The live DR view: frames out, of them composited (a keyframe existed, ROI in view), and
    // per frame the compose's wall / CPU and the latency from admission to output.
    c["inpainting.live_frames"] = static_cast<double>(live_frames_);
    c["inpainting.live_composited"] = static_cast<double>(live_composited_);
    c["inpainting.live_compose_ms_mean"] = live_frames_ ? live_ms_ / live_frames_ : 0.0;
    c["inpainting.live_compose_cpu_ms_mean"] = live_frames_ ? live_cpu_ms_ / live_frames_ : 0.0;
    c["inpainting.live_latency_ms_mean"] = live_frames_ ? live_latency_ms_ / live_frames_ : 0.0;
    c["inpainting.live_watchers"] = static_cast<double>(watchers_);
    // ROI pixels per live frame and per keyframe (the per-pixel work scales with them).
    c["inpainting.live_roi_px_mean"] = live_frames_ ? double(live_roi_px_) / live_frames_ : 0.0;
    c["inpainting.keyframe_roi_px_mean"] = published_ ? double(keyframe_roi_px_) / published_ : 0.0;
    c["inpainting.keyframe_hallucinated_px_mean"] =
        published_ ? double(keyframe_hallucinated_px_) / published_ : 0.0;
  }

  uint32_t Withdraw() override {
    uint32_t n = 0;
    {
      std::lock_guard publish(publish_mu_);
      {
        std::lock_guard lock(mu_);
        dr_.Clear();
        ids_.clear();
        last_obs_index_ = -1;
      }
      for (const auto& v : store_->Views())
        if (v->inpainted() && !IsCompletionView(v->view_id()) &&  // (scene completion's own)
            store_->RemoveView(v->view_id()).ok())
          ++n;
      if (link_) link_->Reset();  // the labelled proxy forgets the inpainted depth
      std::lock_guard lock(mu_);
      withdrawn_ += n;
    }
    // The proxy without the cleared regions' carving and fill, now (not at the next frame).
    if (link_) link_->Kick();
    return n;
  }

  std::string status() const override {
    std::lock_guard lock(mu_);
    return last_error_;
  }

  bool WaitIdle(double timeout_s) override {
    std::unique_lock lock(mu_);
    return idle_cv_.wait_for(lock, std::chrono::duration<double>(timeout_s),
                             [this] { return !job_ && !busy_ && FrameThreadIdle(); });
  }

 private:
  bool FrameThreadIdle() const {
    std::lock_guard lock(slot_mu_);
    return !slot_ && !frame_busy_;
  }

  // A keyframe is computed or waits for the worker (a waiting refresh gives way to a keyframe).
  bool SlotTakenLocked() const { return busy_ || (job_ && !job_->refresh); }

  // An observation view is due once obs_stride frames arrived since the last one kept (the
  // frame thread may not see the one frame in obs_stride that a modulo would pick).
  bool ObservationDueLocked(int64_t index) const {
    return dr_options_.obs_views > 0 &&
           (last_obs_index_ < 0 || index - last_obs_index_ >= dr_options_.obs_stride);
  }
  void AddObservationLocked(const inpainting::RgbdKeyframe& frame, const ImageU8& mask,
                            int64_t index) {
    if (!ObservationDueLocked(index)) return;
    dr_.AddObservation(frame, mask, 0);  // index 0: kept (the library's own stride rule)
    last_obs_index_ = index;
    ++obs_kept_;
  }

  // The oldest keyframe with holes that has not been looked up in the newest observations.
  bool PickRefreshLocked(Job* job) {
    if (options_.method != "dr" || options_.refresh_min_px <= 0) return false;
    const auto& kfs = dr_.keyframes();
    for (size_t i = 0; i < ids_.size() && i < kfs.size(); ++i) {
      KeyframeMeta& m = ids_[i];
      if (m.holes < options_.refresh_min_px || m.refreshed_at >= obs_kept_) continue;
      job->refresh = kfs[i];
      job->refresh_obs = obs_kept_;
      job->dr.views = dr_.ViewsAround(*kfs[i]);
      ++refresh_jobs_;
      return true;
    }
    return false;
  }

  void PublishRefresh(const Job& job, DiminishedReality::Refresh r, double cpu_ms,
                      const std::shared_ptr<spdlog::logger>& log) {
    std::lock_guard publish(publish_mu_);
    if (regions_->generation() != job.regions->generation) return;
    std::optional<ViewId> id;
    {
      std::lock_guard lock(mu_);
      const auto& kfs = dr_.keyframes();
      for (size_t i = 0; i < ids_.size() && i < kfs.size(); ++i)
        if (kfs[i] == job.refresh) {
          ids_[i].refreshed_at = job.refresh_obs;
          if (r.view && r.replaced >= options_.refresh_min_px) {
            id = ids_[i].id;
            ids_[i].holes = r.hallucinated_before - r.replaced;
          }
        }
    }
    if (!id) return;  // evicted meanwhile, or too little to republish
    const inpainting::DrView& kv = *r.view;
    StoredView v;
    v.id = *id;
    v.camera = kv.cam;
    v.local_from_cam = kv.world_from_cam;
    v.color = kv.color;
    v.depth_m = kv.depth;
    v.inpainted = true;
    v.labels = kv.roi;
    auto msg = ViewToProto(v, options_.publish);
    if (!msg.ok()) return;
    for (uint32_t rid : job.regions->ids()) msg->add_region_ids(rid);
    AtServerPriority([&] {
      ScopedDeltaSource source(job.timestamp_s);
      store_->AddView(*std::move(msg));  // same id: replaces the keyframe for every viewer
    });
    std::lock_guard lock(mu_);
    dr_.ReplaceKeyframe(job.refresh.get(), r.view);
    ++refreshed_;
    refreshed_px_ += r.replaced;
    log->info("keyframe {} refreshed: {} of {} hallucinated pixels replaced by observations "
              "({:.0f} ms CPU)", *id, r.replaced, r.hallucinated_before, cpu_ms);
  }

  // A restarted server: the inpainted views of the checkpoint are the keyframes again (without
  // their source maps, so the next keyframe is searched from scratch rather than propagated;
  // their whole ROI counts as inpainted, so their colour there is never taken as observed).
  void RestoreFromStore() {
    for (const auto& v : store_->Views()) {
      if (!v->inpainted() || IsCompletionView(v->view_id())) continue;  // scene completion's
      next_id_ = std::max<ViewId>(next_id_, v->view_id() + 1);
      auto view = ViewFromProto(*v);
      if (!view.ok() || view->labels.empty()) continue;
      ImageU8 roi = view->labels;
      for (size_t i = 0; i < roi.size(); ++i) roi.data()[i] = roi.data()[i] ? 255 : 0;
      dr_.AddKeyframe(inpainting::MakeKeyframeView(
          {view->color, view->depth_m, view->camera, view->local_from_cam}, roi, {}));
      if (link_) link_->Add({view->depth_m, roi, view->color, view->camera, view->local_from_cam});
      ids_.push_back({view->id, 0, inpainting::CountNonZero(roi)});
      if (ids_.size() > options_.max_keyframes) ids_.pop_front();
    }
  }

  // Runs `fn` (a store update: it takes the store's lock, which ingest's stages take too) on the
  // publisher thread, at the server's priority, and waits for it. A niced thread holding the
  // store's lock could be kept off the CPU by the machine's other work for a long time while
  // the geometry and planning stages wait for that lock (priority inversion).
  void AtServerPriority(const std::function<void()>& fn) {
    std::unique_lock lock(pub_mu_);
    pub_fn_ = &fn;
    pub_cv_.notify_all();
    pub_cv_.wait(lock, [this] { return pub_fn_ == nullptr || pub_stop_; });
  }

  void PublisherLoop() {
    pthread_setname_np(pthread_self(), "exo-dr-publish");
    std::unique_lock lock(pub_mu_);
    for (;;) {
      pub_cv_.wait(lock, [this] { return pub_stop_ || pub_fn_ != nullptr; });
      if (pub_fn_) {
        (*pub_fn_)();
        pub_fn_ = nullptr;
        pub_cv_.notify_all();
        continue;
      }
      if (pub_stop_) return;
    }
  }

  void WorkerLoop() {
    pthread_setname_np(pthread_self(), "exo-dr-keyframe");
    AdaptiveNice prio("DR keyframe",
                      options_.keyframe_nice >= 0 ? options_.keyframe_nice : options_.nice,
                      options_.nice, options_.frame_backoff_ms);
    prio.Start();
    auto log = log::Get("inpainting");
    for (;;) {
      Job job;
      {
        std::unique_lock lock(mu_);
        cv_.wait(lock, [this] { return stop_ || job_; });
        if (stop_) return;
        job = std::move(*job_);
        job_.reset();
        busy_ = true;
      }
      {
        double handoff_ms = 0;
        {
          std::lock_guard slot(slot_mu_);
          handoff_ms = handoff_ms_;
        }
        const bool backoff = prio.Update(handoff_ms);
        std::lock_guard lock(mu_);
        keyframe_backoffs_ += backoff;
        jobs_backed_off_ += prio.backed_off();
      }
      if (job.refresh) {
        const double c0 = ThreadCpuMs();
        auto r = DiminishedReality::RefreshKeyframe(*job.refresh, job.dr.views);
        const double cpu_ms = ThreadCpuMs() - c0;
        {
          std::lock_guard lock(mu_);
          refresh_cpu_ms_ += cpu_ms;
        }
        PublishRefresh(job, std::move(r), cpu_ms, log);
        std::lock_guard lock(mu_);
        busy_ = false;
        QueueRefreshLocked();
        idle_cv_.notify_all();
        continue;
      }
      const int64_t t0 = SteadyNowNs();
      const double c0 = ThreadCpuMs(), r0 = ThreadRunDelayMs();
      absl::StatusOr<DrKeyframe> r = DiminishedReality::ComputeKeyframe(job.dr, dr_options_);
      const double ms = (SteadyNowNs() - t0) * 1e-6, cpu_ms = ThreadCpuMs() - c0;
      {
        std::lock_guard lock(mu_);
        keyframe_runq_ms_ += ThreadRunDelayMs() - r0;
      }
      if (!r.ok()) {
        // E.g. "no valid source patch": the ROI stays as observed in this frame.
        log->warn("inpainting keyframe failed: {}", std::string(r.status().message()));
        std::lock_guard lock(mu_);
        ++failed_;
        last_error_ = std::string(r.status().message());
        busy_ = false;
        idle_cv_.notify_all();
        continue;
      }
      Publish(job, *std::move(r), ms, cpu_ms, log);
      // The proxy chunks with the keyframe's depth, now: keyframes also come after the last
      // frame. At the server's priority (the geometry stage's lock and the store's are taken).
      if (link_) AtServerPriority([&] { link_->Kick(); });
      std::lock_guard lock(mu_);
      busy_ = false;
      QueueRefreshLocked();
      idle_cv_.notify_all();
    }
  }

  // The worker just became idle: when a keyframe's holes may be shown by observations kept since
  // it was made (or last refreshed), its refresh is the next job (a newer keyframe job from the
  // frame thread replaces it if that comes first). Frames need not arrive for it: the frame
  // thread looks at fewer frames when the machine is busy.
  void QueueRefreshLocked() {
    if (job_ || stop_) return;
    Job job;
    if (!PickRefreshLocked(&job)) return;
    job.reason = "refresh";
    job.regions = regions_->Get();
    job_ = std::move(job);
    cv_.notify_all();
  }

  void Publish(const Job& job, DrKeyframe k, double ms, double cpu_ms,
               const std::shared_ptr<spdlog::logger>& log) {
    std::lock_guard publish(publish_mu_);
    if (regions_->generation() != job.regions->generation) {
      std::lock_guard lock(mu_);
      ++discarded_;  // the regions changed while it was in flight
      return;
    }
    const inpainting::DrView& kv = *k.view;
    StoredView v;
    {
      std::lock_guard lock(mu_);
      v.id = next_id_++;
    }
    v.camera = kv.cam;
    v.local_from_cam = kv.world_from_cam;
    v.color = kv.color;
    v.depth_m = kv.depth;
    v.inpainted = true;
    v.labels = kv.roi;
    auto msg = ViewToProto(v, options_.publish);
    if (!msg.ok()) {
      log->warn("inpainted keyframe not published: {}", std::string(msg.status().message()));
      std::lock_guard lock(mu_);
      ++failed_;
      return;
    }
    for (uint32_t id : job.regions->ids()) msg->add_region_ids(id);
    AtServerPriority([&] {
      ScopedDeltaSource source(job.timestamp_s);
      store_->AddView(*std::move(msg));
    });
    // Its depth into the labelled proxy (L_IP voxels; the geometry stage applies it on Kick).
    if (link_) link_->Add({kv.depth, kv.roi, kv.color, kv.cam, kv.world_from_cam});
    const int roi_px = inpainting::CountNonZero(kv.roi);
    std::optional<ViewId> evict;
    {
      std::lock_guard lock(mu_);
      dr_.AddKeyframe(k.view, &k);  // forgets its oldest beyond max_keyframes, as ids_ below
      ids_.push_back({v.id, obs_kept_, k.hallucinated_px});
      if (ids_.size() > options_.max_keyframes) {
        evict = ids_.front().id;
        ids_.pop_front();
      }
      ++published_;
      last_error_ = "ok";
      last_ms_ = ms;
      sum_ms_ += ms;
      sum_cpu_ms_ += cpu_ms;
      keyframe_roi_px_ += roi_px;
      keyframe_observed_px_ += k.observed_px;
      keyframe_hallucinated_px_ += k.hallucinated_px;
      if (k.propagated) {
        ++propagated_;
        propagated_ms_ += ms;
        propagated_cpu_ms_ += cpu_ms;
      } else if (first_ms_ == 0.0) {
        first_ms_ = ms;
        first_cpu_ms_ = cpu_ms;
      }
    }
    if (evict) AtServerPriority([&] { (void)store_->RemoveView(*evict); });
    log->info("inpainted keyframe {} of frame {} ({}; {} ROI px, {} observed in other views, {} "
              "inpainted, {} propagated) in {:.0f} ms ({:.0f} ms CPU)",
              v.id, job.sequence, job.reason, roi_px, k.observed_px, k.hallucinated_px,
              k.stats.propagated_pixels, ms, cpu_ms);
  }

  void StopWorker() {
    {
      std::lock_guard lock(mu_);
      stop_ = true;
    }
    {
      std::lock_guard lock(slot_mu_);
      frame_stop_ = true;
    }
    cv_.notify_all();
    frame_cv_.notify_all();
    live_cv_.notify_all();
    if (frames_thread_.joinable()) frames_thread_.join();
    if (worker_.joinable()) worker_.join();
    {
      std::lock_guard lock(pub_mu_);
      pub_stop_ = true;
    }
    pub_cv_.notify_all();
    if (publisher_.joinable()) publisher_.join();
  }

  const InpaintingStageOptions options_;
  const DrOptions dr_options_;
  DiminishedReality dr_;  // under mu_ (ComputeKeyframe works on a job's own snapshot)
  std::shared_ptr<RegionRegistry> regions_;
  ModelStore* store_;
  std::shared_ptr<InpaintedProxyLink> link_;  // the labelled proxy (null: off)
  std::mutex publish_mu_;  // publish vs Withdraw
  mutable std::mutex mu_;
  std::condition_variable cv_, idle_cv_, frame_cv_, live_cv_;
  // The frame thread's one-frame slot (Process -> FrameLoop), under slot_mu_ with the arrival
  // counters, origin_ and frame_busy_ (lock order: mu_ before slot_mu_, never the reverse).
  mutable std::mutex slot_mu_;
  bool frame_stop_ = false;
  std::shared_ptr<PipelineFrame> slot_;
  std::shared_ptr<const RegionSet> slot_set_;
  std::optional<LocalOrigin> origin_;
  bool frame_busy_ = false;
  uint64_t frames_superseded_ = 0, frames_looked_ = 0;
  double handoff_ms_ = 0, handoff_ms_sum_ = 0;  // the newest frame's; sum over hand-offs
  uint64_t handoffs_ = 0, frame_backoffs_ = 0, frames_backed_off_ = 0;
  // The live DR view.
  int watchers_ = 0;
  inpainting::DrLiveState live_state_;  // frame thread only
  uint64_t live_generation_ = 0;        // frame thread only
  std::shared_ptr<const DrLiveFrame> live_;
  uint64_t live_frames_ = 0, live_composited_ = 0;
  double live_ms_ = 0, live_cpu_ms_ = 0, live_latency_ms_ = 0;
  std::optional<Job> job_;
  bool busy_ = false, stop_ = false;
  struct KeyframeMeta {
    ViewId id = 0;
    uint64_t refreshed_at = 0;  // obs_kept_ when it was made or last refreshed
    int holes = 0;              // hallucinated pixels
  };
  std::deque<KeyframeMeta> ids_;  // the published keyframes, in dr_.keyframes() order
  uint64_t obs_kept_ = 0;         // observation views kept so far
  int64_t last_obs_index_ = -1;   // arrival index of the last one (-1: none yet)
  int64_t slot_index_ = 0;        // arrival index of the frame in the slot
  ViewId next_id_ = kInpaintedViewIdBase;
  uint64_t published_ = 0, propagated_ = 0, discarded_ = 0, failed_ = 0, frames_with_roi_ = 0,
           frames_without_roi_ = 0, skipped_busy_ = 0, withdrawn_ = 0, decisions_ = 0,
           frames_seen_ = 0, frames_strided_ = 0, refreshed_ = 0, refreshed_px_ = 0, refresh_jobs_ = 0;
  int64_t decide_ns_ = 0, keyframe_roi_px_ = 0, keyframe_observed_px_ = 0,
          keyframe_hallucinated_px_ = 0, live_roi_px_ = 0;
  double first_cpu_ms_ = 0, propagated_cpu_ms_ = 0;
  double first_ms_ = 0, propagated_ms_ = 0, last_ms_ = 0, sum_ms_ = 0, sum_cpu_ms_ = 0;
  double refresh_cpu_ms_ = 0, frame_cpu_ms_ = 0;  // worker's refreshes; pipeline thread per frame
  double frame_wall_ms_ = 0, frame_runq_ms_ = 0, frame_pickup_ms_ = 0;
  double phase_register_cpu_ms_ = 0, phase_project_cpu_ms_ = 0, phase_rule_cpu_ms_ = 0;
  uint64_t phase_frames_ = 0;
  double keyframe_runq_ms_ = 0;
  uint64_t keyframe_backoffs_ = 0, jobs_backed_off_ = 0;  // under mu_
  uint64_t frames_measured_ = 0;
  std::string last_error_;
  std::thread worker_, frames_thread_, publisher_;
  // The publisher thread's one-call hand-off (AtServerPriority).
  std::mutex pub_mu_;
  std::condition_variable pub_cv_;
  const std::function<void()>* pub_fn_ = nullptr;
  bool pub_stop_ = false;
};

}  // namespace

std::unique_ptr<InpaintingStage> MakeInpaintingStage(const InpaintingStageOptions& options,
                                                     std::shared_ptr<RegionRegistry> regions,
                                                     ModelStore* store,
                                                     std::shared_ptr<InpaintedProxyLink> link) {
  return std::make_unique<InpaintingStageImpl>(options, std::move(regions), store, std::move(link));
}

}  // namespace exo
