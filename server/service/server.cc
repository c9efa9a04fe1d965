#include "server/service/server.h"

#include <unistd.h>

#include <filesystem>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <mutex>

#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>

#include "absl/strings/numbers.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include "proto/exoview.grpc.pb.h"
#include "server/service/stages.h"
#include "server/service/udp_pose_input.h"

namespace exo {
namespace {

template <typename T>
absl::Status ParseNumber(const std::string& key, const std::string& v, T* out) {
  if constexpr (std::is_same_v<T, double>) {
    if (absl::SimpleAtod(v, out)) return absl::OkStatus();
  } else if constexpr (std::is_same_v<T, bool>) {
    if (absl::SimpleAtob(v, out)) return absl::OkStatus();
  } else {
    int64_t x;
    if (absl::SimpleAtoi(v, &x) && x >= 0) {
      *out = static_cast<T>(x);
      return absl::OkStatus();
    }
  }
  return absl::InvalidArgumentError(absl::StrCat("config ", key, ": cannot parse '", v, "'"));
}

}  // namespace

absl::Status ServerConfig::Validate() const {
  if (listen.empty()) return absl::InvalidArgumentError("listen address is empty");
  EXO_RETURN_IF_ERROR(ingest.Validate());
  if (transport_max_bytes < ingest.max_frame_bytes)
    return absl::InvalidArgumentError("transport_max_bytes must be >= max_frame_bytes");
  EXO_RETURN_IF_ERROR(pipeline.Validate());
  EXO_RETURN_IF_ERROR(store.Validate());
  EXO_RETURN_IF_ERROR(publish.Validate());
  EXO_RETURN_IF_ERROR(geometry.Validate());
  EXO_RETURN_IF_ERROR(planning.Validate());
  if (!(checkpoint_interval_s >= 0.0))
    return absl::InvalidArgumentError("checkpoint_interval_s must be >= 0 (0 = only at shutdown)");
  return absl::OkStatus();
}

absl::Status ApplyConfigValue(const std::string& key, const std::string& value, ServerConfig* c) {
  if (key == "listen") { c->listen = value; return absl::OkStatus(); }
  if (key == "max_frame_bytes") return ParseNumber(key, value, &c->ingest.max_frame_bytes);
  if (key == "transport_max_bytes") return ParseNumber(key, value, &c->transport_max_bytes);
  if (key == "admission_queue") return ParseNumber(key, value, &c->pipeline.admission_queue);
  if (key == "stage_queue") return ParseNumber(key, value, &c->pipeline.stage_queue);
  if (key == "admission_block") return ParseNumber(key, value, &c->pipeline.admission_block);
  if (key == "cell_size_m") return ParseNumber(key, value, &c->pipeline.model.cell_m);
  if (key == "max_log_deltas") return ParseNumber(key, value, &c->store.max_log_deltas);
  if (key == "max_log_bytes") return ParseNumber(key, value, &c->store.max_log_bytes);
  if (key == "max_subscriber_lag") return ParseNumber(key, value, &c->store.max_subscriber_lag);
  if (key == "snapshot_when_cheaper") return ParseNumber(key, value, &c->store.snapshot_when_cheaper);
  if (key == "publish_jpeg_quality") return ParseNumber(key, value, &c->publish.jpeg_quality);
  if (key == "publish_depth_downscale") return ParseNumber(key, value, &c->publish.depth_downscale);
  if (key == "geometry") return ParseNumber(key, value, &c->enable_geometry);
  if (key == "voxel_size_m") return ParseNumber(key, value, &c->pipeline.model.voxel_m);
  if (key == "max_depth_m") return ParseNumber(key, value, &c->pipeline.model.max_depth_m);
  if (key == "mesh_every_n_frames") return ParseNumber(key, value, &c->pipeline.model.mesh_every_n_frames);
  if (key == "fuse_depth_downscale") return ParseNumber(key, value, &c->pipeline.model.fuse_depth_downscale);
  if (key == "tsdf_threads") return ParseNumber(key, value, &c->pipeline.model.tsdf_threads);
  if (key == "chunk_republish_change") return ParseNumber(key, value, &c->geometry.republish_change_fraction);
  if (key == "chunk_republish_interval_s") return ParseNumber(key, value, &c->geometry.republish_interval_s);
  if (key == "planning") return ParseNumber(key, value, &c->enable_planning);
  if (key == "max_views") return ParseNumber(key, value, &c->pipeline.model.max_views);
  if (key == "max_store_bytes") return ParseNumber(key, value, &c->pipeline.model.max_bytes);
  if (key == "r_max") return ParseNumber(key, value, &c->pipeline.model.r_max);
  if (key == "d_max_m") return ParseNumber(key, value, &c->pipeline.model.d_max_m);
  if (key == "sigma_m") return ParseNumber(key, value, &c->pipeline.model.sigma_m);
  if (key == "lambda") return ParseNumber(key, value, &c->pipeline.model.lambda);
  if (key == "delta_tau_sum") return ParseNumber(key, value, &c->pipeline.model.delta_tau_sum);
  if (key == "max_candidates_per_s_when_full")
    return ParseNumber(key, value, &c->pipeline.model.max_candidates_per_s_when_full);
  if (key == "refinement") return ParseNumber(key, value, &c->planning.refine);
  if (key == "refine_queue") return ParseNumber(key, value, &c->planning.refine_queue);
  if (key == "refine_downscale") return ParseNumber(key, value, &c->planning.refine_downscale);
  if (key == "refine_remove_outliers") return ParseNumber(key, value, &c->planning.refine_remove_outliers);
  if (key == "planning_id_from_proxy") return ParseNumber(key, value, &c->pipeline.model.id_from_proxy);
  if (key == "planning_cell_areas") return ParseNumber(key, value, &c->planning_cell_areas);
  if (key == "id_buffer_stride") return ParseNumber(key, value, &c->pipeline.model.id_buffer_stride);
  if (key == "checkpoint_path") { c->checkpoint_path = value; return absl::OkStatus(); }
  if (key == "checkpoint_interval_s") return ParseNumber(key, value, &c->checkpoint_interval_s);
  if (key == "checkpoint_max_log_bytes") return ParseNumber(key, value, &c->checkpoint_max_log_bytes);
  if (key == "udp_pose_address") { c->udp_pose_address = value; return absl::OkStatus(); }
  if (key == "udp_pose_tolerance_s") return ParseNumber(key, value, &c->udp_pose_tolerance_s);
  if (key == "udp_pose_port") {
    int64_t p;
    if (!absl::SimpleAtoi(value, &p) || p < -1 || p > 65535)
      return absl::InvalidArgumentError("config udp_pose_port: -1 (off) or 0..65535");
    c->udp_pose_port = static_cast<int>(p);
    return absl::OkStatus();
  }
  return absl::InvalidArgumentError(absl::StrCat("unknown config key '", key, "'"));
}

absl::Status LoadConfigFile(const std::string& path, ServerConfig* c) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open config file ", path));
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    if (auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    absl::string_view s = absl::StripAsciiWhitespace(line);
    if (s.empty()) continue;
    const auto eq = s.find('=');
    if (eq == absl::string_view::npos)
      return absl::InvalidArgumentError(absl::StrCat(path, ":", n, ": expected key = value"));
    const std::string key(absl::StripAsciiWhitespace(s.substr(0, eq)));
    const std::string value(absl::StripAsciiWhitespace(s.substr(eq + 1)));
    if (auto st = ApplyConfigValue(key, value, c); !st.ok())
      return absl::InvalidArgumentError(absl::StrCat(path, ":", n, ": ", st.message()));
  }
  return absl::OkStatus();
}

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
    v1::Frame msg;
    while (stream->Read(&msg)) {
      received_.fetch_add(1);
      const int64_t t0 = SteadyNowNs();
      v1::Ack ack;
      ack.set_sequence(msg.sequence());
      if (shutting_down_->load()) {
        ack.set_status(v1::Ack::REJECTED);
        ack.set_reason("server is shutting down");
        rejected_.fetch_add(1);
      } else if (auto frame = ingest.Admit(msg, msg.ByteSizeLong()); !frame.ok()) {
        ack.set_status(v1::Ack::REJECTED);
        ack.set_reason(std::string(frame.status().message()));
        rejected_.fetch_add(1);
      } else if (absl::Status pose = FillPoseFromUdp(msg, &*frame); !pose.ok()) {
        ack.set_status(v1::Ack::REJECTED);
        ack.set_reason(std::string(pose.message()));
        rejected_.fetch_add(1);
      } else {
        auto pf = std::make_shared<PipelineFrame>();
        pf->frame = *std::move(frame);
        pf->received_ns = t0;
        if (pipeline_->Submit(std::move(pf)) == Pipeline::Admission::kAccepted) {
          ack.set_status(v1::Ack::ACCEPTED);
          accepted_.fetch_add(1);
        } else {
          ack.set_status(v1::Ack::DROPPED);
          ack.set_reason("overload: planning queue full, candidate dropped");
          dropped_.fetch_add(1);
        }
      }
      ack.set_model_version(store_->version());
      if (!stream->Write(ack)) break;
    }
    return grpc::Status::OK;
  }

  grpc::Status Subscribe(grpc::ServerContext* ctx, const v1::SubscribeRequest* req,
                         grpc::ServerWriter<v1::Delta>* writer) override {
    auto sub = store_->Subscribe(req->last_version(), req->last_model_epoch());
    while (!ctx->IsCancelled() && !shutting_down_->load()) {
      const std::vector<DeltaPtr> batch = sub->Next(100);
      for (size_t i = 0; i < batch.size(); ++i) {
        if (!writer->Write(*batch[i])) return grpc::Status::OK;
        bytes_published_.fetch_add(batch[i]->ByteSizeLong());
      }
    }
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
  // A frame without a pose takes it from the UDP pose stream at its timestamp (SPEC §2).
  absl::Status FillPoseFromUdp(const v1::Frame& msg, Frame* frame) const {
    if (msg.has_world_from_cam() || udp_ == nullptr) return absl::OkStatus();
    auto pose = udp_->PoseAt(frame->timestamp_s, config_.udp_pose_tolerance_s);
    if (!pose.ok())
      return absl::InvalidArgumentError(
          absl::StrCat("no pose for the frame from the UDP pose stream: ", pose.status().message()));
    frame->world_from_cam = *pose;
    return frame->Validate();
  }

  const ServerConfig& config_;
  ModelStore* store_;
  Pipeline* pipeline_;
  const std::atomic<bool>* shutting_down_;
  const UdpPoseInput* udp_;
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
    std::fprintf(stderr, "exoview_server: restored checkpoint %s at version %llu (%u views)\n",
                 config_.checkpoint_path.c_str(), static_cast<unsigned long long>(c.version()),
                 store_->GetSummary().num_views);
  }
  if (!config_.checkpoint_path.empty() && config_.checkpoint_interval_s > 0) {
    checkpoint_thread_ = std::thread([this] {
      std::unique_lock lock(checkpoint_mu_);
      while (!checkpoint_cv_.wait_for(lock,
                                      std::chrono::duration<double>(config_.checkpoint_interval_s),
                                      [this] { return shutting_down_.load(); })) {
        lock.unlock();
        if (auto s = WriteCheckpoint(); !s.ok())
          std::fprintf(stderr, "exoview_server: checkpoint: %s\n", std::string(s.message()).c_str());
        lock.lock();
      }
    });
  }
  if (config_.udp_pose_port >= 0) {
    EXO_ASSIGN_OR_RETURN(udp_, UdpPoseInput::Start(config_.udp_pose_address, config_.udp_pose_port));
  }
  service_ = std::make_unique<Service>(config_, store_.get(), pipeline_.get(), &shutting_down_,
                                       udp_.get());
  grpc::EnableDefaultHealthCheckService(true);
  grpc::ServerBuilder builder;
  builder.AddListeningPort(config_.listen, grpc::InsecureServerCredentials(), &port_);
  builder.SetMaxReceiveMessageSize(static_cast<int>(config_.transport_max_bytes));
  builder.SetMaxSendMessageSize(static_cast<int>(config_.transport_max_bytes));
  builder.RegisterService(service_.get());
  server_ = builder.BuildAndStart();
  if (!server_ || port_ == 0)
    return absl::UnavailableError(absl::StrCat("cannot listen on ", config_.listen));
  server_->GetHealthCheckService()->SetServingStatus(true);
  return absl::OkStatus();
}

void ExoviewServer::Shutdown() {
  if (shutting_down_.exchange(true)) return;
  if (server_) server_->GetHealthCheckService()->SetServingStatus(false);
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
      std::fprintf(stderr, "exoview_server: checkpoint: %s\n", std::string(s.message()).c_str());
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
