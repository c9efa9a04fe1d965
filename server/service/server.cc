#include "server/service/server.h"

#include <fcntl.h>
#include <unistd.h>

#include <filesystem>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <span>
#include <fstream>
#include <optional>
#include <sstream>
#include <mutex>
#include <unordered_map>
#include <unordered_set>

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/resource_quota.h>
#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/support/method_handler.h>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include "common/io/jpeg.h"
#include "common/io/zstd.h"
#include "common/log/log.h"
#include "common/process/malloc_tuning.h"
#include "proto/exoview.grpc.pb.h"
#include "server/service/auth.h"
#include "proto/frame_proto.h"
#include "server/service/frame_journal.h"
#include "server/service/stages.h"
#include "server/service/udp_pose_input.h"
#include "server/service/upload_log.h"

namespace exo {

// ---------------------------------------------------------------------------------------------
namespace {

// Runs `f` at scope exit.
template <typename F>
struct ScopeExit {
  F f;
  ~ScopeExit() { f(); }
};
template <typename F>
ScopeExit(F) -> ScopeExit<F>;

// Takes one of `limit` slots; false when all are taken.
bool TakeSlot(std::atomic<int>* n, int limit) {
  int cur = n->load();
  while (cur < limit)
    if (n->compare_exchange_weak(cur, cur + 1)) return true;
  return false;
}

// The client a call comes from, for per-client accounting: the peer host without its port
// ("ipv4:127.0.0.1:40312" -> "ipv4:127.0.0.1").
std::string PeerHost(const std::string& peer) {
  const auto colon = peer.rfind(':');
  return colon == std::string::npos || colon < 5 ? peer : peer.substr(0, colon);
}

// Checkpoint.pipeline_state on disk: "EXZ1", the size of Pipeline::SaveState's bytes (u64) and
// their zstd frame (level 1; the TSDF's unobserved voxels and the mesh arrays compress well).
constexpr char kStateMagic[4] = {'E', 'X', 'Z', '1'};
absl::StatusOr<std::string> CompressState(const std::string& raw) {
  std::vector<uint8_t> out(sizeof(kStateMagic) + sizeof(uint64_t));
  std::memcpy(out.data(), kStateMagic, sizeof(kStateMagic));
  const uint64_t n = raw.size();
  std::memcpy(out.data() + sizeof(kStateMagic), &n, sizeof(n));
  EXO_ASSIGN_OR_RETURN(out, ZstdCompress(reinterpret_cast<const uint8_t*>(raw.data()), raw.size(),
                                         1, std::move(out)));
  return std::string(out.begin(), out.end());
}
absl::StatusOr<std::string> DecompressState(const std::string& stored) {
  constexpr size_t kHeader = sizeof(kStateMagic) + sizeof(uint64_t);
  if (stored.size() < kHeader || std::memcmp(stored.data(), kStateMagic, sizeof(kStateMagic)) != 0)
    return absl::DataLossError("pipeline state: not a compressed state");
  uint64_t n = 0;
  std::memcpy(&n, stored.data() + sizeof(kStateMagic), sizeof(n));
  const size_t z = stored.size() - kHeader;
  if (n > (uint64_t{4} << 30) || n > 4096 * static_cast<uint64_t>(z) + (1 << 20))
    return absl::DataLossError(absl::StrCat("pipeline state: implausible size ", n));
  std::string raw(n, '\0');
  EXO_RETURN_IF_ERROR(ZstdDecompress(
      std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(stored.data()) + kHeader, z),
      reinterpret_cast<uint8_t*>(raw.data()), n, "pipeline state"));
  return raw;
}

size_t FrameBytes(const Frame& f) { return f.color.size() + f.depth_m.size() * sizeof(float); }

// Decoded bytes of each client's accepted frames still referenced by the pipeline.
class InflightLedger {
 public:
  explicit InflightLedger(size_t limit) : limit_(limit) {}
  absl::Status Acquire(const std::string& client, size_t bytes) {
    std::lock_guard lock(mu_);
    size_t& held = held_[client];
    if (held + bytes > limit_) {
      const size_t h = held;
      if (h == 0) held_.erase(client);
      return absl::ResourceExhaustedError(absl::StrCat(
          "client ", client, " has ", h, " bytes of frames in the pipeline; this frame (", bytes,
          " bytes decoded) would exceed max_client_inflight_bytes = ", limit_));
    }
    held += bytes;
    return absl::OkStatus();
  }
  void Release(const std::string& client, size_t bytes) {
    std::lock_guard lock(mu_);
    auto it = held_.find(client);
    if (it == held_.end()) return;
    it->second -= std::min(bytes, it->second);
    if (it->second == 0) held_.erase(it);
  }

 private:
  const size_t limit_;
  std::mutex mu_;
  std::unordered_map<std::string, size_t> held_;
};

}  // namespace

// The frame journal's side of ingest (issue 20 item 3): log sequence numbers in pipeline order,
// the highest durable sequence per named uploader (de-duplication of resent frames), counters.
struct ExoviewServer::Durability {
  std::unique_ptr<FrameJournal> journal;  // null: acks are not durable
  std::mutex submit_mu;                   // lsn order == pipeline order
  uint64_t next_lsn = 1;
  std::function<void()> request_checkpoint;
  std::atomic<uint64_t> duplicates{0}, replayed{0}, replay_skipped{0}, not_durable{0},
      journal_full{0};

  static constexpr size_t kMaxUploaders = ModelStore::kMaxUploaders;
  uint64_t DurableSequence(const std::string& uploader) {
    std::lock_guard lock(seq_mu);
    auto it = durable_seq.find(uploader);
    return it == durable_seq.end() ? 0 : it->second.first;
  }
  void NoteDurable(const std::string& uploader, uint64_t sequence) {
    if (uploader.empty()) return;
    std::lock_guard lock(seq_mu);
    auto it = durable_seq.find(uploader);
    if (it == durable_seq.end()) {
      if (durable_seq.size() >= kMaxUploaders) {  // the least recently seen uploader goes
        auto oldest = std::min_element(durable_seq.begin(), durable_seq.end(),
                                       [](const auto& a, const auto& b) {
                                         return a.second.second < b.second.second;
                                       });
        durable_seq.erase(oldest);
      }
      it = durable_seq.emplace(uploader, std::make_pair(uint64_t{0}, uint64_t{0})).first;
    }
    it->second.first = std::max(it->second.first, sequence);
    it->second.second = ++touch;
  }

 private:
  std::mutex seq_mu;
  std::unordered_map<std::string, std::pair<uint64_t, uint64_t>> durable_seq;  // seq, last touch
  uint64_t touch = 0;
};

namespace {
// The `exoview-uploader-id` call header: 1..64 of [A-Za-z0-9._:-]; "" when absent.
absl::StatusOr<std::string> UploaderId(const grpc::ServerContext& ctx) {
  const auto& md = ctx.client_metadata();
  auto it = md.find("exoview-uploader-id");
  if (it == md.end()) return std::string();
  std::string id(it->second.data(), it->second.size());
  bool ok = !id.empty() && id.size() <= 64;
  for (char ch : id)
    ok = ok && (std::isalnum(static_cast<unsigned char>(ch)) || ch == '.' || ch == '_' ||
                ch == '-' || ch == ':');
  if (!ok)
    return absl::InvalidArgumentError(
        "exoview-uploader-id must be 1 to 64 characters of [A-Za-z0-9._:-]");
  return id;
}
}  // namespace

class ExoviewServer::Service final : public v1::Exoview::Service {
 public:
  Service(const ServerConfig& config, ModelStore* store, Pipeline* pipeline,
          const std::atomic<bool>* shutting_down, const UdpPoseInput* udp,
          std::unique_ptr<Authorizer> auth, Durability* durability)
      : config_(config), store_(store), pipeline_(pipeline), shutting_down_(shutting_down),
        udp_(udp), auth_(std::move(auth)), dur_(durability) {
    // Method 0 of exoview.v1.Exoview is Upload: served on raw bytes (see Upload below).
    MarkMethodStreamed(
        0, new grpc::internal::BidiStreamingHandler<Service, grpc::ByteBuffer, grpc::ByteBuffer>(
               [](Service* s, grpc::ServerContext* ctx,
                  grpc::ServerReaderWriter<grpc::ByteBuffer, grpc::ByteBuffer>* stream) {
                 return s->Upload(ctx, stream);
               },
               this));
  }

  void set_delta_log(const DeltaLog* log) { delta_log_ = log; }

  ~Service() {
    {
      std::lock_guard lock(watch_mu_);
      stop_watchdog_ = true;
    }
    watch_cv_.notify_all();
    if (watchdog_.joinable()) watchdog_.join();
  }

  // Upload reads raw bytes (the handler of method 0 is replaced in the constructor) so that a
  // message that does not parse as a Frame ends the stream with INVALID_ARGUMENT and a reason,
  // instead of looking like a clean end of stream (gRPC's typed Read() returns false for both).
  grpc::Status Upload(grpc::ServerContext* ctx,
                      grpc::ServerReaderWriter<grpc::ByteBuffer, grpc::ByteBuffer>* stream) {
    auto who = Authorize(*ctx, Rpc::kUpload);
    if (!who.ok()) return ToGrpc(who.status());
    if (!TakeSlot(&upload_streams_, config_.max_upload_streams)) {
      refused_uploads_.fetch_add(1);
      return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                          absl::StrCat("too many upload streams: the limit is max_upload_streams = ",
                                       config_.max_upload_streams));
    }
    ScopeExit release_slot{[this] { upload_streams_.fetch_sub(1); }};
    Watch watch(ctx, config_.upload_idle_timeout_s);
    WatchGuard watch_guard(this, &watch);
    const std::string client = who->empty() ? PeerHost(ctx->peer()) : *who;
    // A named uploader (call header exoview-uploader-id) gets resent frames de-duplicated.
    auto uploader_id = UploaderId(*ctx);
    if (!uploader_id.ok()) return ToGrpc(uploader_id.status());
    const std::string uploader =
        uploader_id->empty() ? std::string() : (who->empty() ? *uploader_id : *who + "/" + *uploader_id);
    FrameJournal* journal = dur_->journal.get();
    IngestOptions io = config_.ingest;
    io.decode.pose_required = udp_ == nullptr;
    IngestStream ingest(io);
    UploadStreamLog stream_log(ctx->peer(), config_.log_rejections_per_s);
    grpc::ByteBuffer in;
    uint64_t messages = 0;
    for (;;) {
      watch.blocked_since_ns.store(SteadyNowNs());  // idle until the next message
      const bool got = stream->Read(&in);
      watch.blocked_since_ns.store(0);
      if (!got) break;
      const size_t wire_bytes = in.Length();
      v1::Frame msg;
      if (grpc::Status ps = grpc::SerializationTraits<v1::Frame>::Deserialize(&in, &msg);
          !ps.ok()) {
        rejected_.fetch_add(1);
        const std::string reason =
            absl::StrCat("message ", messages + 1, " of the stream (", wire_bytes,
                         " bytes) does not parse as an exoview.v1.Frame: ", ps.error_message());
        log_->warn("upload from {} ended: {}", ctx->peer(), reason);
        return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, reason);
      }
      ++messages;
      received_.fetch_add(1);
      const int64_t t0 = SteadyNowNs();
      v1::Ack ack;
      ack.set_sequence(msg.sequence());
      const uint64_t durable_seq = journal && !uploader.empty() ? dur_->DurableSequence(uploader) : 0;
      if (shutting_down_->load()) {
        Reject(absl::UnavailableError("server is shutting down"), &ack);
      } else if (journal && !uploader.empty() && msg.sequence() <= durable_seq) {
        // A frame resent after a reconnect that the server already holds on disk: acked again,
        // not applied again.
        ack.set_status(v1::Ack::ACCEPTED);
        ack.set_code(v1::Ack::OK);
        ack.set_durable(true);
        ack.set_reason(absl::StrCat("duplicate: sequence ", msg.sequence(), " of uploader ",
                                    uploader, " is already durable (up to ", durable_seq,
                                    "); not applied again"));
        dur_->duplicates.fetch_add(1);
        accepted_.fetch_add(1);
      } else if (journal && journal->bytes() + wire_bytes + 4096 > journal->max_bytes()) {
        dur_->journal_full.fetch_add(1);
        if (dur_->request_checkpoint) dur_->request_checkpoint();
        Reject(absl::ResourceExhaustedError(absl::StrCat(
                   "journal full: ", journal->bytes(), " bytes not yet covered by a checkpoint, "
                   "journal_max_bytes = ", journal->max_bytes(), "; retry after the checkpoint")),
               &ack);
      } else if (auto frame = ingest.Admit(msg, wire_bytes); !frame.ok()) {
        Reject(frame.status(), &ack);
      } else if (absl::Status pose = FillPoseFromUdp(msg, &*frame); !pose.ok()) {
        Reject(pose, &ack);
      } else if (absl::Status held = ledger_->Acquire(client, FrameBytes(*frame)); !held.ok()) {
        inflight_rejections_.fetch_add(1);
        Reject(held, &ack);
      } else {
        const size_t bytes = FrameBytes(*frame);
        ingest.Commit(*frame);  // only a frame the server takes moves the stream's marks
        // The frame's bytes count against its client until the pipeline lets go of it.
        std::shared_ptr<InflightLedger> ledger = ledger_;
        auto pf = std::shared_ptr<PipelineFrame>(new PipelineFrame,
                                                 [ledger, client, bytes](PipelineFrame* p) {
                                                   delete p;
                                                   ledger->Release(client, bytes);
                                                 });
        pf->frame = *std::move(frame);
        pf->received_ns = t0;
        pf->uploader = uploader;
        // The journal record: the frame as received, with the pose it got from UDP if any.
        std::string record;
        if (journal) {
          if (!msg.has_world_from_cam()) PoseToProto(pf->frame.world_from_cam, msg.mutable_world_from_cam());
          record = msg.SerializeAsString();
        }
        const uint64_t sequence = pf->frame.sequence;
        Pipeline::Admission admission;
        uint64_t lsn = 0;
        if (journal) {
          std::lock_guard lock(dur_->submit_mu);
          lsn = pf->lsn = dur_->next_lsn++;
          admission = pipeline_->Submit(std::move(pf));
        } else {
          admission = pipeline_->Submit(std::move(pf));
        }
        if (admission == Pipeline::Admission::kAccepted) {
          ack.set_status(v1::Ack::ACCEPTED);
          ack.set_code(v1::Ack::OK);
          accepted_.fetch_add(1);
          if (journal) {
            // Durable before the ack leaves: the writer thread commits every record queued
            // while its previous fdatasync ran (group commit).
            JournalRecord r;
            r.lsn = lsn;
            r.sequence = sequence;
            r.uploader = uploader;
            r.frame = std::move(record);
            auto ticket = journal->Append(r);
            absl::Status durable = ticket.ok() ? journal->WaitDurable(*ticket) : ticket.status();
            if (durable.ok()) {
              ack.set_durable(true);
              dur_->NoteDurable(uploader, sequence);
            } else {
              dur_->not_durable.fetch_add(1);
              ack.set_reason(absl::StrCat("accepted but not durable: ", durable.message()));
              log_->error("frame {} from {}: accepted but not durable: {}", sequence, ctx->peer(),
                          std::string(durable.message()));
            }
            if (journal->bytes() > journal->max_bytes() / 2 && dur_->request_checkpoint)
              dur_->request_checkpoint();
          }
        } else {
          ack.set_status(v1::Ack::DROPPED);
          ack.set_code(v1::Ack::RESOURCE_EXHAUSTED);
          ack.set_reason("overload: planning queue full, candidate dropped");
          dropped_.fetch_add(1);
        }
      }
      ack.set_model_version(store_->version());
      stream_log.Record(ack);
      grpc::ByteBuffer out;
      bool own = false;
      if (!grpc::SerializationTraits<v1::Ack>::Serialize(ack, &out, &own).ok()) break;
      if (!stream->Write(out)) break;
    }
    if (watch.fired.load())
      return grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED,
                          absl::StrCat("upload stream idle for more than upload_idle_timeout_s = ",
                                       config_.upload_idle_timeout_s, " s"));
    return grpc::Status::OK;
  }

  grpc::Status Subscribe(grpc::ServerContext* ctx, const v1::SubscribeRequest* req,
                         grpc::ServerWriter<v1::Delta>* writer) override {
    if (auto who = Authorize(*ctx, Rpc::kSubscribe); !who.ok()) return ToGrpc(who.status());
    if (!TakeSlot(&subscriber_calls_, config_.max_subscribers)) {
      refused_subscribers_.fetch_add(1);
      return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                          absl::StrCat("too many subscribers: the limit is max_subscribers = ",
                                       config_.max_subscribers));
    }
    ScopeExit release_slot{[this] { subscriber_calls_.fetch_sub(1); }};
    Watch watch(ctx, config_.subscriber_write_timeout_s);
    WatchGuard watch_guard(this, &watch);
    auto sub = store_->Subscribe(req->last_version(), req->last_model_epoch());
    const std::string peer = ctx->peer();  // "unknown" once the call is cancelled
    log_->info("subscriber connected: peer={} last_version={}", peer, req->last_version());
    uint64_t deltas = 0, bytes = 0;
    bool write_failed = false;
    while (!write_failed && !ctx->IsCancelled() && !shutting_down_->load()) {
      for (const DeltaPtr& d : sub->NextForWire(100)) {
        watch.blocked_since_ns.store(SteadyNowNs());  // a client that does not read blocks here
        const bool written = writer->Write(*d);
        watch.blocked_since_ns.store(0);
        if (!written) {
          write_failed = true;
          break;
        }
        ++deltas;
        bytes += d->ByteSizeLong();
        bytes_published_.fetch_add(d->ByteSizeLong());
      }
    }
    const char* end = watch.fired.load()      ? "not reading: subscriber_write_timeout_s passed"
                      : ctx->IsCancelled()     ? "cancelled by the client"
                      : write_failed           ? "write failed"
                                               : "server shutting down";
    log_->info("subscriber disconnected: peer={} deltas={} bytes={} ({})", peer, deltas, bytes,
               end);
    return grpc::Status::OK;
  }

  grpc::Status GetStats(grpc::ServerContext* ctx, const v1::StatsRequest*,
                        v1::Stats* out) override {
    if (auto who = Authorize(*ctx, Rpc::kGetStats); !who.ok()) return ToGrpc(who.status());
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
    auto& c = *out->mutable_counters();
    c["server.upload_streams"] = upload_streams_.load();
    c["server.subscriber_calls"] = subscriber_calls_.load();
    c["server.refused_uploads"] = static_cast<double>(refused_uploads_.load());
    c["server.refused_subscribers"] = static_cast<double>(refused_subscribers_.load());
    c["server.timed_out_calls"] = static_cast<double>(timed_out_calls_.load());
    c["server.inflight_rejections"] = static_cast<double>(inflight_rejections_.load());
    c["server.denied_calls"] = static_cast<double>(denied_calls_.load());
    c["store.snapshot_bytes"] = static_cast<double>(s.snapshot_bytes);
    c["store.log_deltas"] = static_cast<double>(s.log_deltas);
    c["store.log_bytes"] = static_cast<double>(s.log_bytes);
    // glibc heap: live bytes vs free bytes the arenas hold (RSS growth: live data or fragmentation)
    if (const process::HeapUsage h = process::ReadHeapUsage(); h.known) {
      c["process.heap_in_use_bytes"] = static_cast<double>(h.in_use_bytes);
      c["process.heap_free_bytes"] = static_cast<double>(h.free_bytes);
    }
    c["journal.applied_lsn"] = static_cast<double>(store_->applied_lsn());
    if (udp_) {
      c["udp.received"] = static_cast<double>(udp_->received());
      c["udp.malformed"] = static_cast<double>(udp_->malformed());
      c["udp.unauthenticated"] = static_cast<double>(udp_->unauthenticated());
      c["udp.replayed"] = static_cast<double>(udp_->replayed());
      c["udp.rejected_future"] = static_cast<double>(udp_->rejected_future());
      c["udp.rejected_past"] = static_cast<double>(udp_->rejected_past());
      c["udp.rejected_backwards"] = static_cast<double>(udp_->rejected_backwards());
      c["udp.rebased"] = static_cast<double>(udp_->rebased());
    }
    if (FrameJournal* j = dur_->journal.get()) {
      const FrameJournal::Counters jc = j->counters();
      c["journal.appends"] = static_cast<double>(jc.appends);
      c["journal.groups"] = static_cast<double>(jc.groups);
      c["journal.bytes"] = static_cast<double>(jc.bytes);
      c["journal.segments"] = static_cast<double>(jc.segments);
      c["journal.segments_dropped"] = static_cast<double>(jc.segments_dropped);
      c["journal.sync_ms_mean"] = jc.groups ? jc.sync_ns_total * 1e-6 / jc.groups : 0.0;
      c["journal.sync_ms_max"] = jc.sync_ns_max * 1e-6;
      c["journal.duplicates"] = static_cast<double>(dur_->duplicates.load());
      c["journal.replayed"] = static_cast<double>(dur_->replayed.load());
      c["journal.replay_skipped"] = static_cast<double>(dur_->replay_skipped.load());
      c["journal.not_durable"] = static_cast<double>(dur_->not_durable.load());
      c["journal.full_rejections"] = static_cast<double>(dur_->journal_full.load());
    }
    for (const auto& [name, p] : store_->Uploaders()) {
      auto* u = out->add_uploaders();
      u->set_uploader(name);
      u->set_applied_max_sequence(p.applied_max_sequence);
      u->set_applied_frames(p.applied_frames);
      u->set_double_applied(p.double_applied);
    }
    if (completion_) {
      std::map<std::string, double> m;
      completion_->AddCounters(&m);
      for (const auto& [k, v] : m) c[k] = v;
    }
    if (delta_log_) {
      std::map<std::string, double> m;
      delta_log_->AddCounters(&m);
      for (const auto& [k, v] : m) c[k] = v;
    }
    return grpc::Status::OK;
  }

  void SetCompletion(CompletionStage* completion) { completion_ = completion; }

  // Scene completion at a viewer's camera (issue 18 item 4; completion_stage.h): viewer right.
  grpc::Status CompleteView(grpc::ServerContext* ctx, const v1::CompleteViewRequest* req,
                            v1::CompleteViewReply* out) override {
    auto who = Authorize(*ctx, Rpc::kCompleteView);
    if (!who.ok()) return ToGrpc(who.status());
    if (!completion_)
      return grpc::Status(grpc::StatusCode::UNIMPLEMENTED,
                          "scene completion is disabled on this server (config completion = false)");
    auto reply = [&]() -> absl::StatusOr<v1::CompleteViewReply> {
      CompletionRequest r;
      EXO_ASSIGN_OR_RETURN(r.camera, IntrinsicsFromProto(req->camera()));
      if (!req->has_local_from_cam())
        return absl::InvalidArgumentError("local_from_cam (the viewer's scene-local pose) is required");
      EXO_ASSIGN_OR_RETURN(r.local_from_cam, PoseFromProto(req->local_from_cam()));
      r.max_side_px = req->max_side_px();
      r.who = who->empty() ? ctx->peer() : *who;
      return completion_->Complete(r);
    }();
    if (!reply.ok()) return ToGrpc(reply.status());
    *out = *std::move(reply);
    return grpc::Status::OK;
  }

  void SetInpainting(RegionRegistry* regions, InpaintingStage* stage,
                     std::function<void()> regions_changed) {
    regions_ = regions;
    inpainting_ = stage;
    regions_changed_ = std::move(regions_changed);
  }

  // InpaintFusion regions (SPEC §7). Marking and clearing: operator or admin.
  grpc::Status MarkRegion(grpc::ServerContext* ctx, const v1::MarkRegionRequest* req,
                          v1::MarkRegionReply* out) override {
    auto who = Authorize(*ctx, Rpc::kMarkRegion);
    if (!who.ok()) return ToGrpc(who.status());
    if (!regions_) return NoInpainting();
    auto status = [&]() -> absl::Status {
      EXO_ASSIGN_OR_RETURN(const PinholeCamera camera, IntrinsicsFromProto(req->camera()));
      if (req->has_world_from_cam() == req->has_local_from_cam())
        return absl::InvalidArgumentError(
            "give exactly one pose: world_from_cam (the live camera's frame) or local_from_cam "
            "(a viewer's window, scene-local)");
      Rigid3d local_from_cam;
      if (req->has_local_from_cam()) {
        EXO_ASSIGN_OR_RETURN(local_from_cam, PoseFromProto(req->local_from_cam()));
      } else {
        EXO_ASSIGN_OR_RETURN(const Rigid3d world_from_cam, PoseFromProto(req->world_from_cam()));
        const std::optional<LocalOrigin> origin = store_->Origin();
        if (!origin)
          return absl::FailedPreconditionError(
              "no scene yet: upload frames before marking a region");
        local_from_cam = origin->ToLocal(world_from_cam);
      }
      std::vector<glm::dvec2> stroke;
      stroke.reserve(std::min(req->stroke_size(), 8192));
      for (const auto& p : req->stroke()) {
        if (stroke.size() >= 8192) break;
        stroke.push_back({p.x(), p.y()});
      }
      if (req->stroke_size() > 8192)
        return absl::InvalidArgumentError("the stroke has more than 8192 points");
      EXO_ASSIGN_OR_RETURN(*out->mutable_region(),
                           regions_->Mark(stroke, camera, local_from_cam, req->radius_px(),
                                          req->depth_tolerance_m(), req->label(), *who));
      return absl::OkStatus();
    }();
    if (!status.ok()) {
      log_->info("MarkRegion from {} refused: {}", ctx->peer(), std::string(status.message()));
      return ToGrpc(status);
    }
    log_->info("region {} marked by {} ({} voxels, {} px)", out->region().region_id(),
               who->empty() ? ctx->peer() : *who, out->region().num_voxels(),
               out->region().labelled_pixels());
    if (regions_changed_) regions_changed_();
    return grpc::Status::OK;
  }

  grpc::Status ListRegions(grpc::ServerContext* ctx, const v1::ListRegionsRequest*,
                           v1::ListRegionsReply* out) override {
    if (auto who = Authorize(*ctx, Rpc::kListRegions); !who.ok()) return ToGrpc(who.status());
    if (!regions_) return NoInpainting();
    const std::string status = inpainting_ ? inpainting_->status() : std::string();
    for (auto& r : regions_->List()) {
      r.set_inpaint_status(status);
      *out->add_regions() = std::move(r);
    }
    return grpc::Status::OK;
  }

  grpc::Status ClearRegion(grpc::ServerContext* ctx, const v1::ClearRegionRequest* req,
                           v1::ClearRegionReply* out) override {
    if (auto who = Authorize(*ctx, Rpc::kMarkRegion); !who.ok()) return ToGrpc(who.status());
    if (!regions_) return NoInpainting();
    auto n = regions_->Clear(req->region_id());
    if (!n.ok()) return ToGrpc(n.status());
    out->set_cleared(*n);
    // The inpainted views were made for the old set of regions: withdrawn; the stage makes new
    // keyframes for the regions that remain (a keyframe in flight is discarded).
    if (inpainting_) out->set_views_removed(inpainting_->Withdraw());
    if (regions_changed_) regions_changed_();
    return grpc::Status::OK;
  }

  // The live DR view (issue 18): the newest composited frame, as long as the client reads.
  grpc::Status WatchDrView(grpc::ServerContext* ctx, const v1::WatchDrViewRequest* req,
                           grpc::ServerWriter<v1::DrViewFrame>* writer) override {
    if (auto who = Authorize(*ctx, Rpc::kSubscribe); !who.ok()) return ToGrpc(who.status());
    if (!inpainting_) return NoInpainting();
    if (req->jpeg_quality() < 0 || req->jpeg_quality() > 100)
      return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "jpeg_quality must be in [0, 100]");
    if (!TakeSlot(&subscriber_calls_, config_.max_subscribers)) {
      refused_subscribers_.fetch_add(1);
      return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                          absl::StrCat("too many subscribers: the limit is max_subscribers = ",
                                       config_.max_subscribers));
    }
    ScopeExit release_slot{[this] { subscriber_calls_.fetch_sub(1); }};
    inpainting_->AddLiveWatcher(1);
    ScopeExit unwatch{[this] { inpainting_->AddLiveWatcher(-1); }};
    uint64_t last = 0;
    while (!ctx->IsCancelled() && !shutting_down_->load()) {
      auto f = inpainting_->WaitLiveFrame(last, 0.1);
      if (!f) continue;
      last = f->index;
      v1::DrViewFrame m;
      m.set_index(f->index);
      m.set_sequence(f->sequence);
      m.set_timestamp_s(f->timestamp_s);
      PoseToProto(f->world_from_cam, m.mutable_world_from_cam());
      m.set_width(f->color.width());
      m.set_height(f->color.height());
      if (req->raw()) {
        m.set_color_rgb(f->color.data(), f->color.size());
      } else {
        auto jpeg = EncodeJpeg(f->color, req->jpeg_quality() ? req->jpeg_quality() : 90);
        if (!jpeg.ok()) return ToGrpc(jpeg.status());
        m.set_color_jpeg(jpeg->data(), jpeg->size());
      }
      m.set_composited(f->composited);
      m.set_roi_px(f->roi_px);
      m.set_compose_ms(f->compose_ms);
      m.set_latency_ms(f->latency_ms);
      if (!writer->Write(m)) break;
    }
    return grpc::Status::OK;
  }

  // For the control service (same tokens, same counters and log lines).
  absl::StatusOr<std::string> AuthorizeCall(const grpc::ServerContext& ctx, Rpc rpc) {
    return Authorize(ctx, rpc);
  }

 private:
  static grpc::Status NoInpainting() {
    return grpc::Status(grpc::StatusCode::UNIMPLEMENTED,
                        "inpainting is disabled on this server (config inpainting = false)");
  }
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
    return CheckFrame(*frame, config_.ingest.decode.limits);
  }

  // The one place every RPC is authorized: the principal's name ("" without auth), or
  // UNAUTHENTICATED / PERMISSION_DENIED.
  absl::StatusOr<std::string> Authorize(const grpc::ServerContext& ctx, Rpc rpc) {
    if (!auth_) return std::string();
    std::optional<std::string> header;
    const auto& md = ctx.client_metadata();
    if (auto it = md.find("authorization"); it != md.end())
      header = std::string(it->second.data(), it->second.size());
    auto p = auth_->Check(header, rpc);
    if (!p.ok()) {
      denied_calls_.fetch_add(1);
      log_->warn("{} from {} refused: {}", RpcName(rpc), ctx.peer(), std::string(p.status().message()));
      return p.status();
    }
    return absl::StrCat(RoleName(p->role), ":", p->name);
  }
  static grpc::Status ToGrpc(const absl::Status& s) {
    return grpc::Status(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
  }

  // A call that can block on its peer (a Write to a subscriber that does not read, a Read from an
  // idle uploader): the watchdog cancels it once it has been blocked longer than `limit_s`.
  struct Watch {
    Watch(grpc::ServerContext* c, double limit) : ctx(c), limit_s(limit) {}
    grpc::ServerContext* ctx;
    double limit_s;                          // 0 = never
    std::atomic<int64_t> blocked_since_ns{0};  // 0 = not blocked
    std::atomic<bool> fired{false};
  };
  struct WatchGuard {
    WatchGuard(Service* s, Watch* w) : service(s), watch(w) { service->AddWatch(watch); }
    ~WatchGuard() { service->RemoveWatch(watch); }
    Service* service;
    Watch* watch;
  };
  void AddWatch(Watch* w) {
    if (w->limit_s <= 0) return;
    std::lock_guard lock(watch_mu_);
    watches_.insert(w);
    if (!watchdog_.joinable()) watchdog_ = std::thread([this] { WatchdogLoop(); });
  }
  void RemoveWatch(Watch* w) {
    std::lock_guard lock(watch_mu_);
    watches_.erase(w);
  }
  void WatchdogLoop() {
    std::unique_lock lock(watch_mu_);
    while (!watch_cv_.wait_for(lock, std::chrono::milliseconds(100),
                               [this] { return stop_watchdog_; })) {
      const int64_t now = SteadyNowNs();
      for (Watch* w : watches_) {
        const int64_t since = w->blocked_since_ns.load();
        if (since == 0 || w->fired.load() || (now - since) * 1e-9 < w->limit_s) continue;
        w->fired.store(true);
        timed_out_calls_.fetch_add(1);
        log_->warn("cancelling a call from {}: blocked on its peer for more than {} s",
                   w->ctx->peer(), w->limit_s);
        w->ctx->TryCancel();
      }
    }
  }

  const ServerConfig& config_;
  ModelStore* store_;
  Pipeline* pipeline_;
  RegionRegistry* regions_ = nullptr;
  InpaintingStage* inpainting_ = nullptr;
  CompletionStage* completion_ = nullptr;
  std::function<void()> regions_changed_;
  const std::atomic<bool>* shutting_down_;
  const UdpPoseInput* udp_;
  const DeltaLog* delta_log_ = nullptr;
  std::shared_ptr<spdlog::logger> log_ = log::Get("server");
  std::atomic<uint64_t> received_{0}, accepted_{0}, rejected_{0}, dropped_{0}, bytes_published_{0};
  std::unique_ptr<Authorizer> auth_;
  Durability* dur_;
  std::atomic<uint64_t> denied_calls_{0};
  std::atomic<int> upload_streams_{0}, subscriber_calls_{0};
  std::atomic<uint64_t> refused_uploads_{0}, refused_subscribers_{0}, timed_out_calls_{0},
      inflight_rejections_{0};
  std::shared_ptr<InflightLedger> ledger_ =
      std::make_shared<InflightLedger>(config_.max_client_inflight_bytes);
  std::mutex watch_mu_;
  std::condition_variable watch_cv_;
  std::unordered_set<Watch*> watches_;
  bool stop_watchdog_ = false;
  std::thread watchdog_;
};

ExoviewServer::ExoviewServer(const ServerConfig& config)
    : config_(config), durability_(std::make_unique<Durability>()) {}

ExoviewServer::~ExoviewServer() { Shutdown(); }

absl::Status ExoviewServer::Start() {
  EXO_RETURN_IF_ERROR(config_.Validate());
  store_ = std::make_unique<ModelStore>(config_.store);
  std::string pipeline_state;  // of the checkpoint (Pipeline::SaveState)
  if (config_.enable_inpainting)
    regions_ = std::make_shared<RegionRegistry>(config_.regions, store_.get());
  if (!config_.checkpoint_path.empty()) {
    // The newest generation, or the previous one (path.prev) when the newest is missing or does
    // not parse (a truncated file must not stop the server from starting).
    const std::string prev = config_.checkpoint_path + ".prev";
    v1::Checkpoint c;
    std::string loaded;
    for (const std::string& path : {config_.checkpoint_path, prev}) {
      if (!std::filesystem::exists(path)) continue;
      std::ifstream in(path, std::ios::binary);
      v1::Checkpoint candidate;
      if (in && candidate.ParseFromIstream(&in) && candidate.format() == 1) {
        c = std::move(candidate);
        loaded = path;
        break;
      }
      log::Get("server")->error(
          "checkpoint {} is corrupt or truncated (does not parse); trying the previous "
          "generation {}",
          path, prev);
    }
    if (loaded.empty() && (std::filesystem::exists(config_.checkpoint_path) ||
                           std::filesystem::exists(prev)))
      return absl::DataLossError(absl::StrCat("cannot parse checkpoint ", config_.checkpoint_path,
                                              " nor its previous generation ", prev));
    if (!loaded.empty()) {
      pipeline_state = std::move(*c.mutable_pipeline_state());
      EXO_RETURN_IF_ERROR(store_->RestoreCheckpoint(c));
      if (regions_) EXO_RETURN_IF_ERROR(regions_->Restore(c));
      restored_version_ = checkpoint_version_ = c.version();
      if (regions_) checkpoint_regions_generation_ = regions_->generation();
      log::Get("server")->info("restored checkpoint {} at version {} ({} views, {} regions)",
                               loaded, c.version(), store_->GetSummary().num_views,
                               c.regions_size());
    }
  }
  // The delta log (SPEC §15): memory, or JetStream (which may replay versions the checkpoint
  // missed into the store before anything is served).
  // With the frame journal, the checkpoint + the journal are the model's history (every durable
  // frame past the checkpoint is replayed from the journal below, exactly once): an external log
  // that holds versions past the checkpoint is reconciled to it, not replayed (delta_log.h).
  // Without a checkpoint and with an empty journal (a new volume) the external log, if any, is
  // the only copy of the scene and is adopted.
  std::unique_ptr<FrameJournal> journal;
  FrameJournal::OpenReport journal_report;
  if (config_.journal_enabled()) {
    FrameJournalOptions jo;
    jo.dir = config_.journal_directory();
    jo.max_bytes = config_.journal_max_bytes;
    jo.segment_bytes = config_.journal_segment_bytes;
    EXO_ASSIGN_OR_RETURN(journal, FrameJournal::Open(jo, &journal_report));
  }
  const bool store_is_authority =
      journal && (store_->version() > 0 || journal_report.records > 0);
  EXO_ASSIGN_OR_RETURN(delta_log_, MakeDeltaLog(config_.delta_log));
  EXO_RETURN_IF_ERROR(delta_log_->Open(store_.get(), store_is_authority));
  // The stages after the checkpoint and the log replay: a restarted stage sees the restored model.
  if (config_.enable_completion && config_.completion.completion.use_vertex_color)
    coloured_chunks_ = std::make_shared<ObservedChunks>();
  EXO_ASSIGN_OR_RETURN(auto stages, MakeStages(config_, regions_, store_.get(), &inpainting_,
                                               observed_chunks_, coloured_chunks_));
  pipeline_ = std::make_unique<Pipeline>(config_.pipeline, store_.get(), std::move(stages));
  // The pipeline's state at the checkpoint (scene set-up, TSDF, planner): the journal replay and
  // the next frames continue exactly as an uninterrupted server would have (issue 20).
  if (!pipeline_state.empty()) {
    absl::StatusOr<std::string> raw = DecompressState(pipeline_state);
    if (absl::Status s = raw.ok() ? pipeline_->RestoreState(*raw) : raw.status(); !s.ok()) {
      log::Get("server")->error("checkpoint: the pipeline state is not usable ({}); the stages "
                                "rebuild from the stored views instead",
                                std::string(s.message()));
      pipeline_state.clear();
      observed_chunks_->Clear();  // what the failed restore put there (control has not started)
      if (coloured_chunks_) coloured_chunks_->Clear();
      EXO_ASSIGN_OR_RETURN(auto fresh, MakeStages(config_, regions_, store_.get(), &inpainting_,
                                                  observed_chunks_, coloured_chunks_));
      pipeline_ = std::make_unique<Pipeline>(config_.pipeline, store_.get(), std::move(fresh));
    }
  }
  // The scene set-up of a restored model without pipeline state (checkpoint and/or replayed log).
  if (pipeline_state.empty() && store_->has_scene()) {
    const v1::SceneParams scene = store_->scene();
    const auto& o = scene.origin_in_world();
    LocalOrigin origin;
    origin.origin_in_world = {o.x(), o.y(), o.z()};
    if (config_.pipeline.model.cell_m > 0 && scene.cell_size_m() != config_.pipeline.model.cell_m)
      return absl::FailedPreconditionError("checkpoint: cell_size_m differs from the config");
    pipeline_->RestoreOrigin(origin, scene.cell_size_m());
  }
  restored_version_ = store_->version();
  if (journal) EXO_RETURN_IF_ERROR(ReplayJournal(std::move(journal), journal_report));
  if (!config_.checkpoint_path.empty() &&
      (config_.checkpoint_interval_s > 0 || durability_->journal)) {
    durability_->request_checkpoint = [this] {
      std::lock_guard lock(checkpoint_mu_);
      checkpoint_requested_ = true;
      checkpoint_cv_.notify_all();
    };
    checkpoint_thread_ = std::thread([this] {
      std::unique_lock lock(checkpoint_mu_);
      // Every checkpoint_interval_s (0: only when the journal asks for one, and at shutdown).
      const auto interval = std::chrono::duration<double>(
          config_.checkpoint_interval_s > 0 ? config_.checkpoint_interval_s : 3600.0);
      while (!checkpoint_cv_.wait_for(lock, interval, [this] {
        return shutting_down_.load() || checkpoint_requested_;
      }) || !shutting_down_.load()) {
        checkpoint_requested_ = false;
        lock.unlock();
        if (auto s = WriteCheckpoint(); !s.ok())
          log::Get("server")->error("checkpoint: {}", std::string(s.message()));
        lock.lock();
      }
    });
  }
  if (config_.udp_pose_port >= 0) {
    std::string key;
    if (!config_.udp_pose_key_file.empty()) {
      EXO_ASSIGN_OR_RETURN(key, ReadPoseKeyFile(config_.udp_pose_key_file));
    } else if (!absl::StartsWith(config_.udp_pose_address, "127.") &&
               config_.udp_pose_address != "::1" && !config_.allow_insecure_remote) {
      return absl::FailedPreconditionError(absl::StrCat(
          "refusing unauthenticated UDP poses on ", config_.udp_pose_address,
          ": give udp_pose_key_file (HMAC-SHA256 datagrams, docs/security.md), or "
          "allow_insecure_remote=true"));
    }
    EXO_ASSIGN_OR_RETURN(udp_, UdpPoseInput::Start(config_.udp_pose_address, config_.udp_pose_port,
                                                   4096, key, config_.udp_pose_time));
    log::Get("server")->info("UDP poses on {}:{}{}", config_.udp_pose_address, udp_->port(),
                             key.empty() ? " (plain datagrams, not authenticated)"
                                         : " (HMAC-SHA256 authenticated, replay-protected)");
  }
  std::unique_ptr<Authorizer> auth;
  if (!config_.auth_tokens_file.empty()) {
    EXO_ASSIGN_OR_RETURN(auth, Authorizer::FromFile(config_.auth_tokens_file));
    log::Get("server")->info("bearer tokens required: {} principals from {}", auth->size(),
                             config_.auth_tokens_file);
  }
  EXO_ASSIGN_OR_RETURN(std::shared_ptr<grpc::ServerCredentials> creds, MakeServerCredentials());
  service_ = std::make_unique<Service>(config_, store_.get(), pipeline_.get(), &shutting_down_,
                                       udp_.get(), std::move(auth), durability_.get());
  service_->set_delta_log(delta_log_.get());
  if (config_.enable_completion) {
    CompletionStageOptions co = config_.completion;
    co.publish = config_.publish;
    EXO_ASSIGN_OR_RETURN(completion_, CompletionStage::Create(co, store_.get(), coloured_chunks_));
    service_->SetCompletion(completion_.get());
  }
  service_->SetInpainting(regions_.get(), inpainting_, [this] {
    if (auto s = WriteCheckpoint(true); !s.ok())
      log::Get("server")->error("checkpoint: {}", std::string(s.message()));
  });
  if (config_.control.enabled()) {
    // The same tokens and the same one check as the modeling service.
    Service* svc = service_.get();
    EXO_ASSIGN_OR_RETURN(control_, ControlServiceHost::Start(
                                       config_.control, store_.get(),
                                       [svc](const grpc::ServerContext& ctx, Rpc rpc) {
                                         return svc->AuthorizeCall(ctx, rpc);
                                       },
                                       observed_chunks_));
  }
  grpc::EnableDefaultHealthCheckService(true);
  // Server reflection: grpcurl-style tools list exoview.v1.Exoview and fetch its descriptors.
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(config_.listen, creds, &port_);
  // Keepalive (docs/security.md): ping idle connections, drop the ones that do not answer; allow
  // client pings no more often than every 10 s (more is a ping flood: the connection is closed).
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS,
                             static_cast<int>(config_.keepalive_time_s * 1000));
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS,
                             static_cast<int>(config_.keepalive_timeout_s * 1000));
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MIN_RECV_PING_INTERVAL_WITHOUT_DATA_MS, 10000);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MAX_PING_STRIKES, 2);
  // Threads of the synchronous server: one per open call, bounded (beyond: RESOURCE_EXHAUSTED).
  grpc::ResourceQuota quota("exoview_server");
  quota.SetMaxThreads(config_.max_upload_streams + config_.max_subscribers + 64);
  builder.SetResourceQuota(quota);
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
  completion_.reset();  // no CompleteView call is left (queued ones are refused)
  if (pipeline_) pipeline_->Stop();  // every admitted frame is processed before we return
  if (delta_log_) delta_log_->Close();  // publishes what the pipeline committed (bounded wait)
  udp_.reset();
  {
    std::lock_guard lock(checkpoint_mu_);
    checkpoint_cv_.notify_all();
  }
  if (checkpoint_thread_.joinable()) checkpoint_thread_.join();
  if (store_ && !config_.checkpoint_path.empty())
    if (auto s = WriteCheckpoint(); !s.ok())
      log::Get("server")->error("checkpoint: {}", std::string(s.message()));
  durability_->request_checkpoint = nullptr;
  durability_->journal.reset();
}

absl::Status ExoviewServer::ReplayJournal(std::unique_ptr<FrameJournal> journal,
                                          const FrameJournal::OpenReport& rep) {
  auto log = log::Get("server");
  for (const std::string& cut : rep.cuts)
    log->warn("journal: torn or corrupt tail cut (never replayed): {}", cut);
  Durability& d = *durability_;
  for (const auto& [name, p] : store_->Uploaders()) d.NoteDurable(name, p.applied_max_sequence);
  const uint64_t applied = store_->applied_lsn();
  // Replay what the checkpoint does not cover through the same pipeline, in lsn order, blocking
  // (a replayed frame is never dropped). The ingest checks run again: a record the current
  // limits refuse is skipped and counted.
  FrameDecodeOptions decode = config_.ingest.decode;
  decode.pose_required = true;  // the journal holds the pose the frame was taken with
  const int64_t t0 = SteadyNowNs();
  EXO_RETURN_IF_ERROR(journal->ForEach(applied, [&](JournalRecord r) -> absl::Status {
    v1::Frame msg;
    absl::StatusOr<Frame> frame = msg.ParseFromString(r.frame)
                                      ? FrameFromProto(msg, decode)
                                      : absl::DataLossError("does not parse as a Frame");
    d.NoteDurable(r.uploader, r.sequence);
    if (!frame.ok()) {
      d.replay_skipped.fetch_add(1);
      log->error("journal: record lsn {} skipped: {}", r.lsn, std::string(frame.status().message()));
      return absl::OkStatus();
    }
    auto pf = std::make_shared<PipelineFrame>();
    pf->frame = *std::move(frame);
    pf->received_ns = SteadyNowNs();
    pf->lsn = r.lsn;
    pf->uploader = std::move(r.uploader);
    pipeline_->Submit(std::move(pf), /*block=*/true);
    d.replayed.fetch_add(1);
    return absl::OkStatus();
  }));
  d.next_lsn = std::max(rep.max_lsn, applied) + 1;
  log->info("journal {}: {} segments, {} records, checkpoint covers lsn <= {}; replayed {} frames "
            "({} skipped) in {:.3f} s; next lsn {}",
            config_.journal_directory(), rep.segments, rep.records, applied, d.replayed.load(), d.replay_skipped.load(),
            (SteadyNowNs() - t0) * 1e-9, d.next_lsn);
  d.journal = std::move(journal);
  journal_dropped_upto_ = applied;
  return absl::OkStatus();
}

absl::Status ExoviewServer::WriteCheckpoint(bool force) {
  if (config_.checkpoint_path.empty() || !store_) return absl::OkStatus();
  std::lock_guard write_lock(checkpoint_write_mu_);
  const uint64_t regions_generation = regions_ ? regions_->generation() : 0;
  if (!force && store_->version() == checkpoint_version_ &&
      store_->ledger_changes() == checkpoint_ledger_ &&
      regions_generation == checkpoint_regions_generation_)
    return absl::OkStatus();  // unchanged
  FrameJournal* journal = durability_ ? durability_->journal.get() : nullptr;
  // Records appended from now on go to a new segment; the closed ones are deleted once a
  // checkpoint that covers them is on disk (see below).
  if (journal) journal->Rotate();
  // The model and the pipeline's state at one frame: admission pauses until every admitted frame
  // went through every stage (Pipeline::Quiesce); the file is written after it resumes.
  uint64_t ledger = 0;
  v1::Checkpoint c;
  std::string state_raw;  // compressed after admission resumed
  auto snapshot = [&] {
    ledger = store_->ledger_changes();
    c = store_->MakeCheckpoint(config_.checkpoint_max_log_bytes);
    if (!pipeline_) return;
    absl::StatusOr<std::string> state = pipeline_->SaveState();
    if (state.ok()) {
      state_raw = *std::move(state);
    } else if (!pipeline_state_warned_.exchange(true)) {
      log::Get("server")->warn("checkpoint without the pipeline's state ({}): a restart rebuilds "
                               "the planner from the stored views and starts a new TSDF",
                               std::string(state.status().message()));
    }
  };
  const int64_t quiesce_t0 = SteadyNowNs();
  int64_t paused_ns = 0;
  const bool quiesced = pipeline_ && pipeline_->Quiesce(config_.checkpoint_quiesce_s, [&] {
    snapshot();
    paused_ns = SteadyNowNs() - quiesce_t0;
  });
  if (!quiesced) {
    if (pipeline_)
      log::Get("server")->warn("checkpoint: the pipeline did not drain within {} s; written "
                               "without its state",
                               config_.checkpoint_quiesce_s);
    ledger = store_->ledger_changes();
    c = store_->MakeCheckpoint(config_.checkpoint_max_log_bytes);
  }
  if (!state_raw.empty()) {
    absl::StatusOr<std::string> z = CompressState(state_raw);
    if (z.ok()) c.set_pipeline_state(*std::move(z));
    else log::Get("server")->warn("checkpoint without the pipeline's state: {}",
                                  std::string(z.status().message()));
  }
  if (regions_) regions_->ToCheckpoint(&c);
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
  // Atomic: a reader (a restarted server) sees the old or the new file, never a partial one. The
  // previous generation is kept as path.prev (the fallback when the newest does not parse).
  // (A crash between the two renames leaves only path.prev, which the start also reads.)
  if (std::filesystem::exists(config_.checkpoint_path) &&
      std::rename(config_.checkpoint_path.c_str(), (config_.checkpoint_path + ".prev").c_str()) !=
          0)
    return absl::UnavailableError(absl::StrCat("cannot keep the previous checkpoint generation of ",
                                               config_.checkpoint_path));
  if (std::rename(tmp.c_str(), config_.checkpoint_path.c_str()) != 0)
    return absl::UnavailableError(absl::StrCat("cannot rename ", tmp));
  {
    const std::string dir = std::filesystem::absolute(config_.checkpoint_path).parent_path().string();
    const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
    const bool synced = fd >= 0 && ::fsync(fd) == 0;
    if (fd >= 0) ::close(fd);
    if (!synced) return absl::UnavailableError(absl::StrCat("cannot fsync ", dir));
  }
  log::Get("server")->debug(
      "checkpoint: version {}, {} bytes, pipeline state {} -> {} bytes, admission paused {:.1f} ms",
      c.version(), c.ByteSizeLong(), state_raw.size(), c.pipeline_state().size(),
      paused_ns * 1e-6);
  checkpoint_version_ = c.version();
  checkpoint_regions_generation_ = regions_generation;
  checkpoint_ledger_ = ledger;
  // The journal keeps what the previous generation (path.prev, the fallback when this file does
  // not parse) does not cover: segments go once the older of the two checkpoints covers them.
  if (journal) {
    journal->DropCovered(journal_dropped_upto_);
    journal_dropped_upto_ = c.applied_lsn();
  }
  return absl::OkStatus();
}

absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> ExoviewServer::MakeServerCredentials()
    const {
  auto log = log::Get("server");
  if (config_.tls_cert.empty()) {
    if (!IsLoopback(config_.listen) && !config_.allow_insecure_remote)
      return absl::FailedPreconditionError(absl::StrCat(
          "refusing plain text on ", config_.listen,
          ": not a loopback address; give --tls_cert and --tls_key (deploy/make_certs.sh makes a "
          "local CA), or --allow_insecure_remote=true for a trusted network"));
    log->warn("**** PLAIN TEXT on {}: no TLS, no authentication; anyone who can connect may "
              "upload, subscribe and read stats. Demo/loopback only (docs/security.md) ****",
              config_.listen);
    return grpc::InsecureServerCredentials();
  }
  EXO_ASSIGN_OR_RETURN(auto creds, SslServerCredentialsFromFiles(config_.tls_cert, config_.tls_key,
                                                                 config_.tls_client_ca));
  log->info("TLS on {}{}", config_.listen,
            config_.tls_client_ca.empty() ? "" : " with required client certificates (mutual TLS)");
  return creds;
}

int ExoviewServer::udp_pose_port() const { return udp_ ? udp_->port() : -1; }

void ExoviewServer::Wait() {
  if (server_) server_->Wait();
}

}  // namespace exo
