#include "server/service/inpainting_stage.h"

#include <chrono>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>

#include "common/log/log.h"
#include "proto/frame_proto.h"
#include "server/core/online_model.h"

namespace exo {

absl::Status InpaintingStageOptions::Validate() const {
  EXO_RETURN_IF_ERROR(inpaint.Validate());
  EXO_RETURN_IF_ERROR(policy.Validate());
  if (max_keyframes == 0 || max_keyframes > 256)
    return absl::InvalidArgumentError("inpaint_max_keyframes must be in [1, 256]");
  return absl::OkStatus();
}

namespace {

using inpainting::InpaintResult;

struct Keyframe {
  ViewId id = 0;
  std::shared_ptr<const InpaintResult> result;  // colour, depth, mask, source map, camera
  Rigid3d local_from_cam;
};

struct Job {
  std::shared_ptr<const RegionSet> regions;
  inpainting::RgbdKeyframe frame;  // pose: scene-local
  ImageU8 mask;
  std::shared_ptr<const InpaintResult> previous;  // the nearest keyframe (propagation)
  double timestamp_s = 0;
  uint64_t sequence = 0;
  const char* reason = "";
};

class InpaintingStageImpl final : public InpaintingStage {
 public:
  InpaintingStageImpl(const InpaintingStageOptions& o, std::shared_ptr<RegionRegistry> regions,
                      ModelStore* store)
      : options_(o), regions_(std::move(regions)), store_(store) {
    RestoreFromStore();
    worker_ = std::thread([this] { WorkerLoop(); });
  }
  ~InpaintingStageImpl() override { StopWorker(); }

  std::string name() const override { return "inpainting"; }

  absl::Status Process(const PipelineFrame& pf, const SceneContext& ctx) override {
    const std::shared_ptr<const RegionSet> set = regions_->Get();
    if (set->regions.empty()) return absl::OkStatus();
    const Frame& f = pf.frame;
    if (f.depth_m.empty()) return absl::OkStatus();
    {
      std::lock_guard lock(mu_);
      if (job_ || busy_) {  // the one slot is taken: this frame is only counted
        ++skipped_busy_;
        return absl::OkStatus();
      }
    }
    const int64_t t0 = SteadyNowNs();
    const Rigid3d local_from_cam = ctx.origin.ToLocal(f.world_from_cam);
    ImageF depth = core::RegisterDepthToColor(f);
    ImageU8 mask = inpainting::ProjectRegions(set->labels, depth, f.color_camera, local_from_cam,
                                              options_.region);
    const int roi = inpainting::CountNonZero(mask);
    Job job;
    {
      std::lock_guard lock(mu_);
      if (roi == 0) {
        ++frames_without_roi_;
        return absl::OkStatus();
      }
      ++frames_with_roi_;
      std::vector<inpainting::KeyframeView> views;
      for (const Keyframe& k : keyframes_)
        views.push_back({&k.result->mask, &k.result->depth_m, k.result->camera, k.local_from_cam});
      const inpainting::KeyframeDecision d =
          inpainting::DecideKeyframe(mask, f.color_camera, local_from_cam, views, options_.policy);
      decide_ns_ += SteadyNowNs() - t0;
      log::Get("inpainting")->debug("frame {}: ROI {} px, nearest keyframe {} at {:.3f}, {:.1f} % unlabelled -> {}",
                f.sequence, roi, d.nearest, d.pose_distance, 100.0 * d.unlabelled_fraction,
                d.insert ? d.reason : "no keyframe");
      ++decisions_;
      if (!d.insert) return absl::OkStatus();
      if (d.nearest >= 0 && keyframes_[d.nearest].result->source.width() > 0)
        job.previous = keyframes_[d.nearest].result;
      job.reason = d.reason;
    }
    job.regions = set;
    job.frame.color = f.color;
    job.frame.depth_m = std::move(depth);
    job.frame.camera = f.color_camera;
    job.frame.world_from_cam = local_from_cam;  // the library only needs one consistent frame
    job.mask = std::move(mask);
    job.timestamp_s = f.timestamp_s;
    job.sequence = f.sequence;
    {
      std::lock_guard lock(mu_);
      job_ = std::move(job);
    }
    cv_.notify_all();
    return absl::OkStatus();
  }

  void Finish(const SceneContext&) override { WaitIdle(60.0); }

  uint64_t pending() const override {
    std::lock_guard lock(mu_);
    return (job_ ? 1 : 0) + (busy_ ? 1 : 0);
  }

  void AddCounters(std::map<std::string, double>* out) const override {
    std::lock_guard lock(mu_);
    auto& c = *out;
    c["inpainting.regions"] = static_cast<double>(regions_->Get()->regions.size());
    c["inpainting.keyframes"] = static_cast<double>(keyframes_.size());
    c["inpainting.keyframes_published"] = static_cast<double>(published_);
    c["inpainting.keyframes_propagated"] = static_cast<double>(propagated_);
    c["inpainting.keyframes_discarded"] = static_cast<double>(discarded_);
    c["inpainting.keyframes_failed"] = static_cast<double>(failed_);
    c["inpainting.frames_with_roi"] = static_cast<double>(frames_with_roi_);
    c["inpainting.frames_without_roi"] = static_cast<double>(frames_without_roi_);
    c["inpainting.frames_skipped_busy"] = static_cast<double>(skipped_busy_);
    c["inpainting.views_withdrawn"] = static_cast<double>(withdrawn_);
    c["inpainting.decide_ms_mean"] = decisions_ ? decide_ns_ * 1e-6 / decisions_ : 0.0;
    c["inpainting.first_keyframe_ms"] = first_ms_;
    c["inpainting.propagated_keyframe_ms_mean"] = propagated_ ? propagated_ms_ / propagated_ : 0.0;
    c["inpainting.keyframe_ms_last"] = last_ms_;
  }

  uint32_t Withdraw() override {
    std::lock_guard publish(publish_mu_);
    std::vector<ViewId> ids;
    {
      std::lock_guard lock(mu_);
      for (const Keyframe& k : keyframes_) ids.push_back(k.id);
      keyframes_.clear();
    }
    uint32_t n = 0;
    for (const auto& v : store_->Views())
      if (v->inpainted() && store_->RemoveView(v->view_id()).ok()) ++n;
    std::lock_guard lock(mu_);
    withdrawn_ += n;
    return n;
  }

  std::string status() const override {
    std::lock_guard lock(mu_);
    return last_error_;
  }

  bool WaitIdle(double timeout_s) override {
    std::unique_lock lock(mu_);
    return idle_cv_.wait_for(lock, std::chrono::duration<double>(timeout_s),
                             [this] { return !job_ && !busy_; });
  }

 private:
  // A restarted server: the inpainted views of the checkpoint are the keyframes again (without
  // their source maps, so the next keyframe is searched from scratch rather than propagated).
  void RestoreFromStore() {
    for (const auto& v : store_->Views()) {
      if (!v->inpainted()) continue;
      next_id_ = std::max<ViewId>(next_id_, v->view_id() + 1);
      auto view = ViewFromProto(*v);
      if (!view.ok() || view->labels.empty()) continue;
      auto r = std::make_shared<InpaintResult>();
      r->color = view->color;
      r->depth_m = view->depth_m;
      r->camera = view->camera;
      r->world_from_cam = view->local_from_cam;
      r->mask = view->labels;
      keyframes_.push_back({view->id, std::move(r), view->local_from_cam});
    }
  }

  void WorkerLoop() {
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
      const int64_t t0 = SteadyNowNs();
      absl::StatusOr<InpaintResult> r =
          inpainting::InpaintKeyframe(job.frame, job.mask, options_.inpaint, job.previous.get());
      const double ms = (SteadyNowNs() - t0) * 1e-6;
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
      Publish(job, std::make_shared<InpaintResult>(*std::move(r)), ms, log);
      std::lock_guard lock(mu_);
      busy_ = false;
      idle_cv_.notify_all();
    }
  }


  void Publish(const Job& job, std::shared_ptr<const InpaintResult> r, double ms,
               const std::shared_ptr<spdlog::logger>& log) {
    std::lock_guard publish(publish_mu_);
    if (regions_->generation() != job.regions->generation) {
      std::lock_guard lock(mu_);
      ++discarded_;  // the regions changed while it was in flight
      return;
    }
    StoredView v;
    {
      std::lock_guard lock(mu_);
      v.id = next_id_++;
    }
    v.camera = r->camera;
    v.local_from_cam = job.frame.world_from_cam;
    v.color = r->color;
    v.depth_m = r->depth_m;
    v.inpainted = true;
    v.labels = r->mask;
    auto msg = ViewToProto(v, options_.publish);
    if (!msg.ok()) {
      log->warn("inpainted keyframe not published: {}", std::string(msg.status().message()));
      std::lock_guard lock(mu_);
      ++failed_;
      return;
    }
    for (uint32_t id : job.regions->ids()) msg->add_region_ids(id);
    {
      ScopedDeltaSource source(job.timestamp_s);
      store_->AddView(*std::move(msg));
    }
    std::optional<ViewId> evict;
    {
      std::lock_guard lock(mu_);
      keyframes_.push_back({v.id, r, v.local_from_cam});
      if (keyframes_.size() > options_.max_keyframes) {
        evict = keyframes_.front().id;
        keyframes_.erase(keyframes_.begin());
      }
      ++published_;
      last_error_ = "ok";
      last_ms_ = ms;
      if (job.previous) {
        ++propagated_;
        propagated_ms_ += ms;
      } else if (first_ms_ == 0.0) {
        first_ms_ = ms;
      }
    }
    if (evict) (void)store_->RemoveView(*evict);
    log->info("inpainted keyframe {} of frame {} ({}; {} ROI px, {} propagated) in {:.0f} ms",
              v.id, job.sequence, job.reason, r->stats.target_pixels,
              r->stats.propagated_pixels, ms);
  }

  void StopWorker() {
    {
      std::lock_guard lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    if (worker_.joinable()) worker_.join();
  }

  const InpaintingStageOptions options_;
  std::shared_ptr<RegionRegistry> regions_;
  ModelStore* store_;
  std::mutex publish_mu_;  // publish vs Withdraw
  mutable std::mutex mu_;
  std::condition_variable cv_, idle_cv_;
  std::optional<Job> job_;
  bool busy_ = false, stop_ = false;
  std::vector<Keyframe> keyframes_;
  ViewId next_id_ = kInpaintedViewIdBase;
  uint64_t published_ = 0, propagated_ = 0, discarded_ = 0, failed_ = 0, frames_with_roi_ = 0,
           frames_without_roi_ = 0, skipped_busy_ = 0, withdrawn_ = 0, decisions_ = 0;
  int64_t decide_ns_ = 0;
  double first_ms_ = 0, propagated_ms_ = 0, last_ms_ = 0;
  std::string last_error_;
  std::thread worker_;
};

}  // namespace

std::unique_ptr<InpaintingStage> MakeInpaintingStage(const InpaintingStageOptions& options,
                                                     std::shared_ptr<RegionRegistry> regions,
                                                     ModelStore* store) {
  return std::make_unique<InpaintingStageImpl>(options, std::move(regions), store);
}

}  // namespace exo
