#include "server/relay/relay.h"

#include <chrono>
#include <fstream>
#include <optional>
#include <sstream>

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>

#include "absl/strings/match.h"
#include "common/log/log.h"
#include "proto/exoview.grpc.pb.h"
#include "server/service/auth.h"

namespace exo {
namespace {

grpc::Status ToGrpc(const absl::Status& s) {
  return grpc::Status(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
}

}  // namespace

class Relay::Service final : public v1::Exoview::Service {
 public:
  Service(Relay* relay, std::unique_ptr<Authorizer> auth) : relay_(relay), auth_(std::move(auth)) {}

  grpc::Status Upload(grpc::ServerContext*, grpc::ServerReaderWriter<v1::Ack, v1::Frame>*) override {
    return grpc::Status(grpc::StatusCode::UNIMPLEMENTED,
                        "exoview_relay serves Subscribe and GetStats; upload frames to the "
                        "modeling server (exoview_server)");
  }

  grpc::Status Subscribe(grpc::ServerContext* ctx, const v1::SubscribeRequest* req,
                         grpc::ServerWriter<v1::Delta>* writer) override {
    if (auto s = Authorize(*ctx, Rpc::kSubscribe); !s.ok()) return ToGrpc(s);
    std::shared_ptr<ModelStore> store = relay_->CurrentStore();
    if (!store || !relay_->ready_.load())
      return grpc::Status(grpc::StatusCode::UNAVAILABLE,
                          "relay is not in sync with the scene's stream yet; retry");
    if (subscribers_.fetch_add(1) >= relay_->config_.max_subscribers) {
      subscribers_.fetch_sub(1);
      return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                          absl::StrCat("too many subscribers: the limit is max_subscribers = ",
                                       relay_->config_.max_subscribers));
    }
    auto sub = store->Subscribe(req->last_version(), req->last_model_epoch());
    uint64_t deltas = 0, bytes = 0;
    bool write_failed = false;
    while (!write_failed && !ctx->IsCancelled() && !relay_->stop_.load() && !store->closed()) {
      for (const DeltaPtr& d : sub->NextForWire(100)) {
        if (!writer->Write(*d)) {
          write_failed = true;
          break;
        }
        ++deltas;
        bytes += d->ByteSizeLong();
        bytes_published_.fetch_add(d->ByteSizeLong());
      }
    }
    subscribers_.fetch_sub(1);
    log_->debug("subscriber {} ended: {} deltas, {} bytes", ctx->peer(), deltas, bytes);
    if (store->closed() && !relay_->stop_.load())
      return grpc::Status(grpc::StatusCode::UNAVAILABLE,
                          "relay is rebuilding its replica from the stream; reconnect and resume");
    return grpc::Status::OK;
  }

  grpc::Status GetStats(grpc::ServerContext* ctx, const v1::StatsRequest*, v1::Stats* out) override {
    if (auto s = Authorize(*ctx, Rpc::kGetStats); !s.ok()) return ToGrpc(s);
    std::shared_ptr<ModelStore> store = relay_->CurrentStore();
    if (!store) return grpc::Status(grpc::StatusCode::UNAVAILABLE, "no replica yet");
    const ModelStore::Summary s = store->GetSummary();
    out->set_model_version(s.version);
    out->set_model_digest(s.digest);
    out->set_num_views(s.num_views);
    out->set_num_cells(s.num_cells);
    out->set_num_chunks(s.num_chunks);
    out->set_subscribers(static_cast<uint32_t>(subscribers_.load()));
    out->set_bytes_published(bytes_published_.load());
    out->set_snapshots_sent(s.snapshots_sent);
    out->set_log_first_version(s.log_first_version);
    auto& c = *out->mutable_counters();
    c["relay.ready"] = relay_->ready_.load() ? 1 : 0;
    c["relay.rebuilds"] = static_cast<double>(relay_->rebuilds_.load());
    c["relay.stream_last_seq_at_sync"] = static_cast<double>(relay_->stream_last_seq_.load());
    c["store.snapshot_bytes"] = static_cast<double>(s.snapshot_bytes);
    return grpc::Status::OK;
  }

 private:
  absl::Status Authorize(const grpc::ServerContext& ctx, Rpc rpc) {
    if (!auth_) return absl::OkStatus();
    std::optional<std::string> header;
    const auto& md = ctx.client_metadata();
    if (auto it = md.find("authorization"); it != md.end())
      header = std::string(it->second.data(), it->second.size());
    return auth_->Check(header, rpc).status();
  }

  Relay* relay_;
  std::unique_ptr<Authorizer> auth_;
  std::atomic<int> subscribers_{0};
  std::atomic<uint64_t> bytes_published_{0};
  std::shared_ptr<spdlog::logger> log_ = log::Get("relay");
};

Relay::Relay(RelayConfig config) : config_(std::move(config)) { config_.store.replica = true; }

Relay::~Relay() { Shutdown(); }

std::shared_ptr<ModelStore> Relay::CurrentStore() {
  std::lock_guard lock(mu_);
  return store_;
}

absl::Status Relay::Start() {
  EXO_RETURN_IF_ERROR(ValidateSceneName(config_.nats.scene));
  EXO_RETURN_IF_ERROR(config_.store.Validate());
  std::unique_ptr<Authorizer> auth;
  if (!config_.auth_tokens_file.empty()) {
    EXO_ASSIGN_OR_RETURN(auth, Authorizer::FromFile(config_.auth_tokens_file));
  }
  std::shared_ptr<grpc::ServerCredentials> creds;
  if (config_.tls_cert.empty()) {
    if (!IsLoopback(config_.listen) && !config_.allow_insecure_remote)
      return absl::FailedPreconditionError(absl::StrCat(
          "refusing plain text on ", config_.listen,
          ": not a loopback address; give --tls_cert and --tls_key, or --allow_insecure_remote"));
    if (auth) return absl::FailedPreconditionError("auth_tokens_file needs TLS (tls_cert, tls_key)");
    creds = grpc::InsecureServerCredentials();
  } else {
    EXO_ASSIGN_OR_RETURN(creds, SslServerCredentialsFromFiles(config_.tls_cert, config_.tls_key,
                                                              config_.tls_client_ca));
  }
  service_ = std::make_unique<Service>(this, std::move(auth));
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(config_.listen, creds, &port_);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS, 30000);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, 10000);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
  builder.SetMaxSendMessageSize(static_cast<int>(config_.transport_max_bytes));
  builder.RegisterService(service_.get());
  server_ = builder.BuildAndStart();
  if (!server_ || port_ == 0)
    return absl::UnavailableError(absl::StrCat("cannot listen on ", config_.listen));
  server_->GetHealthCheckService()->SetServingStatus(false);  // until the replica caught up
  follower_ = std::thread([this] { FollowLoop(); });
  return absl::OkStatus();
}

// Builds the replica (snapshot + stream) and follows the stream; on a gap, a replay error or a
// lost subscription it starts over with a fresh replica (the old one's subscribers are ended and
// reconnect). Never gives up while the relay runs.
void Relay::FollowLoop() {
  auto log = log::Get("relay");
  while (!stop_.load()) {
    auto pause = [&] {
      for (int i = 0; i < 10 && !stop_.load(); ++i)
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
    };
    auto js = JetStreamScene::Connect(config_.nats, /*create=*/false);
    if (!js.ok()) {
      log->warn("waiting for the scene's stream: {}", std::string(js.status().message()));
      pause();
      continue;
    }
    auto state = (*js)->DeltaStreamState();
    auto snap = state.ok() ? (*js)->ReadSnapshot() : state.status();
    if (!snap.ok()) {
      log->warn("stream/snapshot: {}", std::string(snap.status().message()));
      pause();
      continue;
    }
    auto store = std::make_shared<ModelStore>(config_.store);
    if (*snap && (*snap)->version() + 1 >= state->first_seq) {
      if (auto s = store->RestoreCheckpoint(**snap); !s.ok()) {
        log->error("snapshot: {}", std::string(s.message()));
        pause();
        continue;
      }
    } else if (state->first_seq > 1 && state->msgs > 0) {
      log->warn("the stream starts at version {} and no snapshot reaches it yet; waiting",
                state->first_seq);
      pause();
      continue;
    }
    const uint64_t target = state->last_seq;
    stream_last_seq_.store(target);
    log->info("replica from {} at version {}; following {} (ends at {})",
              *snap ? "the snapshot" : "the stream's start", store->version(), (*js)->stream(),
              target);
    std::shared_ptr<ModelStore> old;
    {
      std::lock_guard lock(mu_);
      old = std::exchange(store_, store);
    }
    if (old) old->CloseAll();  // its subscribers reconnect and resume on the new replica
    auto set_ready = [&] {
      if (!ready_.load() && store->version() >= target) {
        ready_.store(true);
        server_->GetHealthCheckService()->SetServingStatus(true);
        log->info("in sync at version {}: serving", store->version());
      }
    };
    set_ready();
    absl::Status why;
    absl::Status s = (*js)->Follow(
        store->version() + 1,
        [&](const v1::Delta& d) {
          if (d.version() <= store->version()) return true;  // already in the snapshot
          if (auto r = store->ReplayDelta(d); !r.ok()) {
            why = r;
            return false;
          }
          set_ready();
          return true;
        },
        [&] { return !stop_.load(); });
    if (stop_.load()) break;
    if (!why.ok()) s = why;
    log->error("replica at version {} stopped following: {}; rebuilding", store->version(),
               s.ok() ? std::string("(no reason)") : std::string(s.message()));
    rebuilds_.fetch_add(1);
    pause();
  }
}

void Relay::Shutdown() {
  if (stop_.exchange(true)) return;
  if (server_) server_->GetHealthCheckService()->SetServingStatus(false);
  if (auto s = CurrentStore()) s->CloseAll();
  if (follower_.joinable()) follower_.join();
  if (server_) server_->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(2));
}

void Relay::Wait() {
  if (server_) server_->Wait();
}

}  // namespace exo
