// The live DR view in the viewer (issue 18): a client of the server's WatchDrView stream (the
// camera's frames with the marked regions removed, JPEG). The subscription is opened on demand
// (Demand(), e.g. per browser request of /dr.jpg) and closed after `idle_s` without demand, so
// the server composites only while someone looks (it composites per frame while a watcher is
// registered). A server without inpainting (UNIMPLEMENTED) or a broken stream is retried every
// 2 s while demanded; status() says what happened.
#pragma once

#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include <grpcpp/grpcpp.h>

#include "proto/exoview.grpc.pb.h"

namespace exo {

namespace v1 = ::exoview::v1;

class DrViewWatcher {
 public:
  using Sink = std::function<void(const v1::DrViewFrame&)>;  // called on the watcher's thread
  DrViewWatcher(std::shared_ptr<grpc::Channel> channel, Sink sink, double idle_s = 5.0,
                int jpeg_quality = 85);
  ~DrViewWatcher();
  DrViewWatcher(const DrViewWatcher&) = delete;
  DrViewWatcher& operator=(const DrViewWatcher&) = delete;

  void Demand();
  // "idle" (not demanded), "connecting", "watching", or "error: <grpc status>".
  std::string status() const;
  uint64_t frames() const;

 private:
  void Loop();
  bool Demanded() const;  // under mu_

  std::shared_ptr<grpc::Channel> channel_;
  Sink sink_;
  const double idle_s_;
  const int jpeg_quality_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::chrono::steady_clock::time_point last_demand_{};
  bool stop_ = false;
  grpc::ClientContext* ctx_ = nullptr;  // the open stream's (cancelled on idle / stop)
  std::string status_ = "idle";
  uint64_t frames_ = 0;
  std::thread thread_, monitor_;
};

}  // namespace exo
