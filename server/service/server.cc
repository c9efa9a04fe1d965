#include "server/service/server.h"

#include <unistd.h>

#include <filesystem>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <mutex>

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>

#include "absl/strings/numbers.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include "common/log/log.h"
#include "proto/exoview.grpc.pb.h"
#include "server/service/stages.h"
#include "server/service/udp_pose_input.h"
#include "server/service/upload_log.h"

namespace exo {

// ---------------------------------------------------------------------------------------------

class ExoviewServer::Service final : public v1::Exoview::Service {
 public:
  Service(const ServerConfig& config, ModelStore* store, Pipeline* pipeline,
          const std::atomic<bool>* shutting_down, const UdpPoseInput* udp)
      : config_(config), store_(store), pipeline_(pipeline), shutting_down_(shutting_down),
        udp_(udp) {}

  grpc::Status Upload(grpc::ServerContext* ctx,
                      grpc::ServerReaderWriter<v1::Ack, v1::Frame>* stream) override {
    IngestOptions io = config_.ingest;
    io.decode.pose_required = udp_ == nullptr;
    IngestStream ingest(io);
    UploadStreamLog stream_log(ctx->peer(), config_.log_rejections_per_s);
    v1::Frame msg;
    while (stream->Read(&msg)) {
      received_.fetch_add(1);
      const int64_t t0 = SteadyNowNs();
      v1::Ack ack;
      ack.set_sequence(msg.sequence());
      if (shutting_down_->load()) {
        Reject(absl::UnavailableError("server is shutting down"), &ack);
      } else if (auto frame = ingest.Admit(msg, msg.ByteSizeLong()); !frame.ok()) {
        Reject(frame.status(), &ack);
      } else if (absl::Status pose = FillPoseFromUdp(msg, &*frame); !pose.ok()) {
        Reject(pose, &ack);
      } else {
        auto pf = std::make_shared<PipelineFrame>();
        pf->frame = *std::move(frame);
        pf->received_ns = t0;
        if (pipeline_->Submit(std::move(pf)) == Pipeline::Admission::kAccepted) {
          ack.set_status(v1::Ack::ACCEPTED);
          ack.set_code(v1::Ack::OK);
          accepted_.fetch_add(1);
        } else {
          ack.set_status(v1::Ack::DROPPED);
          ack.set_code(v1::Ack::RESOURCE_EXHAUSTED);
          ack.set_reason("overload: planning queue full, candidate dropped");
          dropped_.fetch_add(1);
        }
      }
      ack.set_model_version(store_->version());
      stream_log.Record(ack);
      if (!stream->Write(ack)) break;
    }
    return grpc::Status::OK;
  }

  grpc::Status Subscribe(grpc::ServerContext* ctx, const v1::SubscribeRequest* req,
                         grpc::ServerWriter<v1::Delta>* writer) override {
    auto sub = store_->Subscribe(req->last_version(), req->last_model_epoch());
    const std::string peer = ctx->peer();  // "unknown" once the call is cancelled
    log_->info("subscriber connected: peer={} last_version={}", peer, req->last_version());
    uint64_t deltas = 0, bytes = 0;
    bool write_failed = false;
    while (!write_failed && !ctx->IsCancelled() && !shutting_down_->load()) {
      for (const DeltaPtr& d : sub->Next(100)) {
        if (!writer->Write(*d)) {
          write_failed = true;
          break;
        }
        ++deltas;
        bytes += d->ByteSizeLong();
        bytes_published_.fetch_add(d->ByteSizeLong());
      }
    }
    const char* end = ctx->IsCancelled()      ? "cancelled by the client"
                      : write_failed           ? "write failed"
                                               : "server shutting down";
    log_->info("subscriber disconnected: peer={} deltas={} bytes={} ({})", peer, deltas, bytes,
               end);
    return grpc::Status::OK;
  }

  grpc::Status GetStats(grpc::ServerContext*, const v1::StatsRequest*, v1::Stats* out) override {
    const ModelStore::Summary s = store_->GetSummary();
    out->set_model_version(s.version);
    out->set_model_digest(s.digest);
    out->set_num_views(s.num_views);
    out->set_num_cells(s.num_cells);
    out->set_num_chunks(s.num_chunks);
    out->set_frames_received(received_.load());
    out->set_frames_accepted(accepted_.load());
    out->set_frames_rejected(rejected_.load());
    out->set_frames_dropped(dropped_.load());
    out->set_subscribers(s.subscribers);
    out->set_bytes_published(bytes_published_.load());
    out->set_snapshots_sent(s.snapshots_sent);
    out->set_log_first_version(s.log_first_version);
    for (const auto& n : pipeline_->stage_names()) out->add_stages(n);
    out->set_frames_processed(pipeline_->frames_processed());
    out->set_async_pending(pipeline_->async_pending());
    for (const auto& [k, v] : pipeline_->counters()) (*out->mutable_counters())[k] = v;
    return grpc::Status::OK;
  }

 private:
  // A REJECTED ack: the reason text and its machine-readable code (Ack.code = the status code).
  void Reject(const absl::Status& status, v1::Ack* ack) {
    ack->set_status(v1::Ack::REJECTED);
    ack->set_code(AckCodeFromStatus(status.code()));
    ack->set_reason(std::string(status.message()));
    rejected_.fetch_add(1);
  }

  // A frame without a pose takes it from the UDP pose stream at its timestamp (SPEC §2).
  absl::Status FillPoseFromUdp(const v1::Frame& msg, Frame* frame) const {
    if (msg.has_world_from_cam() || udp_ == nullptr) return absl::OkStatus();
    auto pose = udp_->PoseAt(frame->timestamp_s, config_.udp_pose_tolerance_s);
    if (!pose.ok())
      return absl::FailedPreconditionError(
          absl::StrCat("no pose for the frame from the UDP pose stream: ", pose.status().message()));
    frame->world_from_cam = *pose;
    return frame->Validate();
  }

  const ServerConfig& config_;
  ModelStore* store_;
  Pipeline* pipeline_;
  const std::atomic<bool>* shutting_down_;
  const UdpPoseInput* udp_;
  std::shared_ptr<spdlog::logger> log_ = log::Get("server");
  std::atomic<uint64_t> received_{0}, accepted_{0}, rejected_{0}, dropped_{0}, bytes_published_{0};
};

ExoviewServer::ExoviewServer(const ServerConfig& config) : config_(config) {}

ExoviewServer::~ExoviewServer() { Shutdown(); }

absl::Status ExoviewServer::Start() {
  EXO_RETURN_IF_ERROR(config_.Validate());
  store_ = std::make_unique<ModelStore>(config_.store);
  EXO_ASSIGN_OR_RETURN(auto stages, MakeStages(config_));
  pipeline_ = std::make_unique<Pipeline>(config_.pipeline, store_.get(), std::move(stages));
  if (!config_.checkpoint_path.empty() && std::filesystem::exists(config_.checkpoint_path)) {
    std::ifstream in(config_.checkpoint_path, std::ios::binary);
    v1::Checkpoint c;
    if (!in || !c.ParseFromIstream(&in))
      return absl::DataLossError(absl::StrCat("cannot parse checkpoint ", config_.checkpoint_path));
    EXO_RETURN_IF_ERROR(store_->RestoreCheckpoint(c));
    for (const auto& d : c.model())
      if (d.has_scene_params()) {
        const auto& o = d.scene_params().origin_in_world();
        LocalOrigin origin;
        origin.origin_in_world = {o.x(), o.y(), o.z()};
        if (config_.pipeline.model.cell_m > 0 &&
            d.scene_params().cell_size_m() != config_.pipeline.model.cell_m)
          return absl::FailedPreconditionError("checkpoint: cell_size_m differs from the config");
        pipeline_->RestoreOrigin(origin, d.scene_params().cell_size_m());
      }
    restored_version_ = checkpoint_version_ = c.version();
    log::Get("server")->info("restored checkpoint {} at version {} ({} views)",
                             config_.checkpoint_path, c.version(), store_->GetSummary().num_views);
  }
  if (!config_.checkpoint_path.empty() && config_.checkpoint_interval_s > 0) {
    checkpoint_thread_ = std::thread([this] {
      std::unique_lock lock(checkpoint_mu_);
      while (!checkpoint_cv_.wait_for(lock,
                                      std::chrono::duration<double>(config_.checkpoint_interval_s),
                                      [this] { return shutting_down_.load(); })) {
        lock.unlock();
        if (auto s = WriteCheckpoint(); !s.ok())
          log::Get("server")->error("checkpoint: {}", std::string(s.message()));
        lock.lock();
      }
    });
  }
  if (config_.udp_pose_port >= 0) {
    EXO_ASSIGN_OR_RETURN(udp_, UdpPoseInput::Start(config_.udp_pose_address, config_.udp_pose_port));
  }
  service_ = std::make_unique<Service>(config_, store_.get(), pipeline_.get(), &shutting_down_,
                                       udp_.get());
  if (config_.control.enabled()) {
    EXO_ASSIGN_OR_RETURN(control_, ControlServiceHost::Start(config_.control, store_.get()));
  }
  grpc::EnableDefaultHealthCheckService(true);
  // Server reflection: grpcurl-style tools list exoview.v1.Exoview and fetch its descriptors.
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(config_.listen, grpc::InsecureServerCredentials(), &port_);
  builder.SetMaxReceiveMessageSize(static_cast<int>(config_.transport_max_bytes));
  builder.SetMaxSendMessageSize(static_cast<int>(config_.transport_max_bytes));
  builder.RegisterService(service_.get());
  if (control_) builder.RegisterService(control_->service());
  server_ = builder.BuildAndStart();
  if (!server_ || port_ == 0)
    return absl::UnavailableError(absl::StrCat("cannot listen on ", config_.listen));
  server_->GetHealthCheckService()->SetServingStatus(true);
  return absl::OkStatus();
}

void ExoviewServer::Shutdown() {
  if (shutting_down_.exchange(true)) return;
  if (server_) server_->GetHealthCheckService()->SetServingStatus(false);
  if (control_) control_->Stop();
  if (store_) store_->CloseAll();  // wakes subscription loops
  if (server_) server_->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(2));
  if (pipeline_) pipeline_->Stop();  // every admitted frame is processed before we return
  udp_.reset();
  {
    std::lock_guard lock(checkpoint_mu_);
    checkpoint_cv_.notify_all();
  }
  if (checkpoint_thread_.joinable()) checkpoint_thread_.join();
  if (store_ && !config_.checkpoint_path.empty())
    if (auto s = WriteCheckpoint(); !s.ok())
      log::Get("server")->error("checkpoint: {}", std::string(s.message()));
}

absl::Status ExoviewServer::WriteCheckpoint() {
  if (config_.checkpoint_path.empty() || !store_) return absl::OkStatus();
  if (store_->version() == checkpoint_version_) return absl::OkStatus();  // unchanged
  const v1::Checkpoint c = store_->MakeCheckpoint(config_.checkpoint_max_log_bytes);
  const std::string tmp = config_.checkpoint_path + ".tmp";
  {
    FILE* f = std::fopen(tmp.c_str(), "wb");
    if (!f) return absl::UnavailableError(absl::StrCat("cannot write ", tmp));
    const std::string bytes = c.SerializeAsString();
    const bool ok = std::fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size() &&
                    std::fflush(f) == 0 && ::fsync(fileno(f)) == 0;
    std::fclose(f);
    if (!ok) return absl::UnavailableError(absl::StrCat("short write to ", tmp));
  }
  // Atomic: a reader (a restarted server) sees the old or the new file, never a partial one.
  if (std::rename(tmp.c_str(), config_.checkpoint_path.c_str()) != 0)
    return absl::UnavailableError(absl::StrCat("cannot rename ", tmp));
  checkpoint_version_ = c.version();
  return absl::OkStatus();
}

int ExoviewServer::udp_pose_port() const { return udp_ ? udp_->port() : -1; }

void ExoviewServer::Wait() {
  if (server_) server_->Wait();
}

}  // namespace exo
