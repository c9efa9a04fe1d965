#include "client/window/dr_view_watch.h"

#include <chrono>

namespace exo {

using Clock = std::chrono::steady_clock;

DrViewWatcher::DrViewWatcher(std::shared_ptr<grpc::Channel> channel, Sink sink, double idle_s,
                             int jpeg_quality)
    : channel_(std::move(channel)), sink_(std::move(sink)), idle_s_(idle_s),
      jpeg_quality_(jpeg_quality) {
  thread_ = std::thread([this] { Loop(); });
  // Closes the stream once nobody asked for the view for idle_s (a blocked Read wakes up).
  monitor_ = std::thread([this] {
    std::unique_lock lock(mu_);
    while (!stop_) {
      cv_.wait_for(lock, std::chrono::milliseconds(250));
      if (ctx_ && (stop_ || !Demanded())) ctx_->TryCancel();
    }
  });
}

DrViewWatcher::~DrViewWatcher() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
    if (ctx_) ctx_->TryCancel();
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
  if (monitor_.joinable()) monitor_.join();
}

bool DrViewWatcher::Demanded() const {
  return last_demand_ != Clock::time_point{} &&
         Clock::now() - last_demand_ < std::chrono::duration<double>(idle_s_);
}

void DrViewWatcher::Demand() {
  {
    std::lock_guard lock(mu_);
    last_demand_ = Clock::now();
  }
  cv_.notify_all();
}

std::string DrViewWatcher::status() const {
  std::lock_guard lock(mu_);
  return status_;
}

uint64_t DrViewWatcher::frames() const {
  std::lock_guard lock(mu_);
  return frames_;
}

void DrViewWatcher::Loop() {
  auto stub = v1::Exoview::NewStub(channel_);
  for (;;) {
    {
      std::unique_lock lock(mu_);
      cv_.wait(lock, [&] { return stop_ || Demanded(); });
      if (stop_) return;
      status_ = "connecting";
    }
    grpc::ClientContext ctx;
    {
      std::lock_guard lock(mu_);
      if (stop_) return;
      ctx_ = &ctx;
    }
    v1::WatchDrViewRequest req;
    req.set_jpeg_quality(jpeg_quality_);
    auto reader = stub->WatchDrView(&ctx, req);
    v1::DrViewFrame m;
    while (reader->Read(&m)) {
      {
        std::lock_guard lock(mu_);
        status_ = "watching";
        ++frames_;
      }
      sink_(m);
    }
    const grpc::Status st = reader->Finish();
    bool retry_later = false;
    {
      std::lock_guard lock(mu_);
      ctx_ = nullptr;
      if (stop_) return;
      if (!Demanded()) {
        status_ = "idle";
      } else {
        status_ = "error: " + std::to_string(st.error_code()) + " " + st.error_message();
        retry_later = true;
      }
    }
    if (retry_later) {
      std::unique_lock lock(mu_);
      cv_.wait_for(lock, std::chrono::seconds(2), [&] { return stop_; });
      if (stop_) return;
    }
  }
}

}  // namespace exo
