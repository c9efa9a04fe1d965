// The render thread of the interactive viewer (issue 17): the UI thread posts the view it wants
// (Post: never waits for a render) and picks up finished frames (TakeFrame: never waits); a worker
// thread renders the newest posted view at the divisor AdaptiveResolution chooses (moving: the
// moving divisor; stopped: the divisor halves frame by frame up to full resolution, then nothing
// until something changes). Views posted while a frame renders are coalesced: only the newest is
// rendered next. So input, the HUD and the overlays stay live while a full-resolution frame takes
// a second, and rendering overlaps presentation (the UI thread presents frame N while frame N+1
// renders). A render already submitted is not interrupted: motion that starts during a
// full-resolution render is shown when that render ends (measured: docs/viewer.md).
// Pure: no SDL, no Vulkan; the render and the model poll are callbacks run on the worker thread.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>

#include "client/navigation/navigation.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo::nav {

struct ViewRequest {
  Rigid3d pose;  // local_from_cam
  int width = 0, height = 0;  // window size (pixels); nothing is rendered (paused) while 0
  uint64_t epoch = 0;         // bump to force a re-render of the same pose (e.g. overlays on)
  bool operator==(const ViewRequest& o) const {
    return pose.translation == o.pose.translation && pose.rotation == o.pose.rotation &&
           width == o.width && height == o.height && epoch == o.epoch;
  }
};

struct RenderJob {
  ViewRequest request;
  int divisor = 1;       // render request.width / divisor x request.height / divisor
  bool changed = false;  // the view or the model changed since the previous frame
};

template <typename Frame>
class RenderScheduler {
 public:
  // render(job, &frame): runs on the worker; its wall time feeds the moving-frame budget.
  using RenderFn = std::function<absl::Status(const RenderJob&, Frame*)>;
  // poll(): runs on the worker before each decision; true when the model changed (a re-render is
  // due even for the same view). Called at least every poll_ms while idle.
  using PollFn = std::function<absl::StatusOr<bool>()>;
  struct Done {
    RenderJob job;
    Frame frame;
    uint64_t seq = 0;       // 1, 2, ... per rendered frame
    double render_ms = 0;   // wall time of render()
  };

  // on_frame() runs on the worker after each frame (and after an error): e.g. wake the UI loop.
  RenderScheduler(const AdaptiveOptions& options, RenderFn render, PollFn poll,
                  std::function<void()> on_frame, int poll_ms = 100)
      : adaptive_(options),
        render_(std::move(render)),
        poll_(std::move(poll)),
        on_frame_(std::move(on_frame)),
        poll_ms_(poll_ms) {
    thread_ = std::thread([this] { Run(); });
  }
  ~RenderScheduler() { Stop(); }
  RenderScheduler(const RenderScheduler&) = delete;
  RenderScheduler& operator=(const RenderScheduler&) = delete;

  // The view to show from now on (replaces any not yet started).
  void Post(const ViewRequest& r) {
    {
      std::lock_guard lock(mu_);
      if (has_request_ && request_ == r) return;
      request_ = r;
      has_request_ = true;
      ++serial_;
    }
    cv_.notify_all();
  }
  // The newest finished frame not taken yet (older unfetched ones are dropped).
  std::optional<Done> TakeFrame() {
    std::lock_guard lock(mu_);
    std::optional<Done> d = std::move(done_);
    done_.reset();
    return d;
  }
  // Divisor of the frame being rendered now (0 = idle).
  int busy_divisor() const {
    std::lock_guard lock(mu_);
    return busy_;
  }
  uint64_t frames_rendered() const {
    std::lock_guard lock(mu_);
    return seq_;
  }
  // True while the last posted view has been rendered at full quality and nothing is due.
  bool converged() const {
    std::lock_guard lock(mu_);
    return converged_ && rendered_serial_ == serial_;
  }
  // The first error of render() or poll(); the worker stops at it.
  absl::Status status() const {
    std::lock_guard lock(mu_);
    return status_;
  }
  // Blocks until the running frame (if any) ends; idempotent.
  void Stop() {
    {
      std::lock_guard lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    if (thread_.joinable()) thread_.join();
  }

 private:
  void Run() {
    uint64_t seen = 0;
    bool refining = false, first = true;
    ViewRequest last;
    for (;;) {
      ViewRequest rq;
      {
        std::unique_lock lock(mu_);
        if (!refining)
          cv_.wait_for(lock, std::chrono::milliseconds(poll_ms_),
                       [&] { return stop_ || serial_ != seen; });
        if (stop_) return;
        if (!has_request_) continue;
        rq = request_;
        seen = serial_;
      }
      if (rq.width <= 0 || rq.height <= 0) {  // paused (e.g. the window shows the live DR view):
        refining = false;                     // no renders, the model is not polled either
        continue;
      }
      absl::StatusOr<bool> polled = poll_();
      if (!polled.ok()) return Fail(polled.status());
      const bool changed = first || *polled || !(rq == last);
      const int d = adaptive_.Next(changed);
      if (d == 0) {
        refining = false;
        std::lock_guard lock(mu_);
        converged_ = true;
        rendered_serial_ = seen;
        continue;
      }
      {
        std::lock_guard lock(mu_);
        busy_ = d;
        converged_ = false;
      }
      Done done;
      done.job = {rq, d, changed};
      const auto t0 = std::chrono::steady_clock::now();
      absl::Status st = render_(done.job, &done.frame);
      done.render_ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      if (!st.ok()) return Fail(st);
      if (changed) adaptive_.ReportMovingFrame(done.render_ms);
      last = rq;
      first = false;
      refining = true;  // the next Next(false) refines or says converged
      {
        std::lock_guard lock(mu_);
        busy_ = 0;
        done.seq = ++seq_;
        done_ = std::move(done);
      }
      on_frame_();
    }
  }
  void Fail(const absl::Status& s) {
    {
      std::lock_guard lock(mu_);
      status_ = s;
      busy_ = 0;
    }
    on_frame_();
  }

  AdaptiveResolution adaptive_;  // worker only
  RenderFn render_;
  PollFn poll_;
  std::function<void()> on_frame_;
  const int poll_ms_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  ViewRequest request_;
  bool has_request_ = false, stop_ = false, converged_ = false;
  uint64_t serial_ = 0, rendered_serial_ = 0, seq_ = 0;
  int busy_ = 0;
  std::optional<Done> done_;
  absl::Status status_;
  std::thread thread_;  // last: starts after every member above is initialised
};

}  // namespace exo::nav
