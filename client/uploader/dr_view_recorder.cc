#include "client/uploader/dr_view_recorder.h"

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <thread>

#include <grpcpp/grpcpp.h>
#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "proto/exoview.grpc.pb.h"
#include "proto/frame_proto.h"

namespace exo {

absl::Status DrViewRecordOptions::Validate() const {
  if (out_dir.empty()) return absl::InvalidArgumentError("the DR view needs an output folder");
  if (jpeg_quality < 1 || jpeg_quality > 100)
    return absl::InvalidArgumentError("DR view JPEG quality must be in [1, 100]");
  return absl::OkStatus();
}

std::string DrViewRecordStats::ToJson() const {
  nlohmann::ordered_json j;
  j["frames"] = frames;
  j["composited"] = composited;
  j["written"] = written;
  j["fps"] = fps;
  j["latency_ms_mean"] = latency_ms_mean;
  if (!error.empty()) j["error"] = error;
  return j.dump();
}

struct DrViewRecorder::Impl {
  std::shared_ptr<grpc::Channel> channel;
  DrViewRecordOptions options;
  grpc::ClientContext ctx;
  std::thread thread;
  std::mutex mu;
  DrViewRecordStats stats;
  double latency_sum = 0;
  bool stopping = false;

  void Run() {
    auto stub = v1::Exoview::NewStub(channel);
    v1::WatchDrViewRequest req;
    req.set_jpeg_quality(options.jpeg_quality);
    auto reader = stub->WatchDrView(&ctx, req);
    v1::DrViewFrame m;
    std::chrono::steady_clock::time_point first, last;
    while (reader->Read(&m)) {
      const auto now = std::chrono::steady_clock::now();
      bool wrote = false;
      if (!m.color_jpeg().empty()) {
        const std::string path = absl::StrCat(options.out_dir, "/dr_", m.sequence(), ".jpg");
        std::ofstream f(path, std::ios::binary);
        f.write(m.color_jpeg().data(), static_cast<std::streamsize>(m.color_jpeg().size()));
        wrote = static_cast<bool>(f);
      }
      std::lock_guard lock(mu);
      if (stats.frames == 0) first = now;
      last = now;
      ++stats.frames;
      stats.composited += m.composited();
      stats.written += wrote;
      latency_sum += m.latency_ms();
      const double span = std::chrono::duration<double>(last - first).count();
      stats.fps = span > 0 ? (stats.frames - 1) / span : 0.0;
    }
    const grpc::Status st = reader->Finish();
    std::lock_guard lock(mu);
    if (!st.ok() && !(stopping && st.error_code() == grpc::StatusCode::CANCELLED))
      stats.error = absl::StrCat("WatchDrView: ", st.error_message(), " (code ",
                                 static_cast<int>(st.error_code()), ")");
  }
};

absl::StatusOr<std::unique_ptr<DrViewRecorder>> DrViewRecorder::Start(
    std::shared_ptr<grpc::Channel> channel, const DrViewRecordOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  std::error_code ec;
  std::filesystem::create_directories(options.out_dir, ec);
  if (ec || !std::filesystem::is_directory(options.out_dir))
    return absl::InvalidArgumentError(
        absl::StrCat("cannot create the DR view folder ", options.out_dir, ": ", ec.message()));
  std::unique_ptr<DrViewRecorder> r(new DrViewRecorder());
  r->impl_ = std::make_unique<Impl>();
  r->impl_->channel = std::move(channel);
  r->impl_->options = options;
  Impl* impl = r->impl_.get();
  impl->thread = std::thread([impl] { impl->Run(); });
  return r;
}

DrViewRecordStats DrViewRecorder::Stop(double linger_s) {
  if (!impl_ || !impl_->thread.joinable()) return impl_ ? impl_->stats : DrViewRecordStats{};
  if (linger_s > 0) std::this_thread::sleep_for(std::chrono::duration<double>(linger_s));
  {
    std::lock_guard lock(impl_->mu);
    impl_->stopping = true;
  }
  impl_->ctx.TryCancel();
  impl_->thread.join();
  std::lock_guard lock(impl_->mu);
  DrViewRecordStats s = impl_->stats;
  s.latency_ms_mean = s.frames ? impl_->latency_sum / s.frames : 0.0;
  return s;
}

DrViewRecorder::~DrViewRecorder() { Stop(0); }

}  // namespace exo
