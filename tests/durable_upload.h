// The uploader of the kill -9 tests (service_durable_test, relay_nats_test): a thread that sends
// `frames` frames at 40 Hz, 4 in flight, under one uploader id, reconnecting for up to 120 s with
// a 50-200 ms backoff (gRPC's default first backoff is 1 s) so it finds each restarted server,
// and records the sequence of every ACCEPTED ack marked durable. The last 10 frames wait for
// ReleaseLastFrames(): every kill the test makes lands in the middle of the stream.
#pragma once

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <atomic>
#include <functional>
#include <mutex>
#include <set>
#include <string>
#include <thread>

#include "client/uploader/upload_client.h"

namespace exo::testing {

class DurableUploadThread {
 public:
  using Load = std::function<absl::StatusOr<v1::Frame>(size_t)>;
  DurableUploadThread(const std::string& target, const std::string& uploader_id, int frames,
                      Load load)
      : thread_([this, target, uploader_id, frames, load = std::move(load)] {
          UploadOptions o;
          o.rate_hz = 40;
          o.max_in_flight = 4;
          o.uploader_id = uploader_id;
          o.reconnect_s = 120;
          o.on_ack = [this](const v1::Ack& a) {
            if (a.status() != v1::Ack::ACCEPTED || !a.durable()) return;
            std::lock_guard lock(mu_);
            durable_acked_.insert(a.sequence());
            max_durable_acked_ = std::max(max_durable_acked_, a.sequence());
          };
          grpc::ChannelArguments args;
          args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 50);
          args.SetInt(GRPC_ARG_MIN_RECONNECT_BACKOFF_MS, 50);
          args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 200);
          auto channel = grpc::CreateCustomChannel(target, grpc::InsecureChannelCredentials(), args);
          result_ = UploadStream(channel, frames,
                                 [&](size_t i) -> absl::StatusOr<v1::Frame> {
                                   while (i + 10 >= static_cast<size_t>(frames) && !released_)
                                     std::this_thread::sleep_for(std::chrono::milliseconds(10));
                                   return load(i);
                                 },
                                 o);
          done_ = true;
        }) {}
  // On any early return of the test: let the upload finish (or give up) before the thread goes.
  ~DurableUploadThread() { Join(); }

  void ReleaseLastFrames() { released_ = true; }
  bool done() const { return done_; }
  // Releases the last frames, waits for the upload to end and returns its ack statistics.
  const absl::StatusOr<UploadAckStats>& Join() {
    released_ = true;
    if (thread_.joinable()) thread_.join();
    return result_;
  }
  uint64_t max_durable_acked() const {
    std::lock_guard lock(mu_);
    return max_durable_acked_;
  }
  // Every durable ack received, repeats included (a frame acked durable twice shows twice).
  std::multiset<uint64_t> durable_acked() const {
    std::lock_guard lock(mu_);
    return durable_acked_;
  }

 private:
  mutable std::mutex mu_;
  uint64_t max_durable_acked_ = 0;
  std::multiset<uint64_t> durable_acked_;
  std::atomic<bool> released_{false}, done_{false};
  absl::StatusOr<UploadAckStats> result_ = absl::UnknownError("not run");
  std::thread thread_;  // last: started after every other member exists
};

}  // namespace exo::testing
