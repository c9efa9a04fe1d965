#include "server/service/delta_log.h"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <thread>

#include "common/log/log.h"
#ifdef EXOVIEW_HAS_NATS
#include "server/service/jetstream.h"
#endif

namespace exo {

absl::Status DeltaLogOptions::Validate() const {
  if (kind != "memory" && kind != "jetstream")
    return absl::InvalidArgumentError(
        absl::StrCat("delta_log '", kind, "': must be 'memory' or 'jetstream'"));
  if (nats_replicas < 1 || nats_replicas > 5)
    return absl::InvalidArgumentError("nats_replicas must be 1..5");
  if (!(snapshot_interval_s > 0)) return absl::InvalidArgumentError("nats_snapshot_interval_s must be > 0");
  if (kind == "jetstream" && !JetStreamAvailable())
    return absl::UnimplementedError(
        "delta_log=jetstream: this exoview_server was built without libnats (apt-get install "
        "libnats-dev, then reconfigure)");
  return absl::OkStatus();
}

#ifdef EXOVIEW_HAS_NATS
bool JetStreamAvailable() { return true; }

namespace {

// Publishes the store's deltas to the scene's stream from one thread, in version order (each
// publish expects the stream to end at the previous version, so sequence = version), and writes
// a snapshot every snapshot_interval_s when the model changed. The store's own bounded log is
// the publish queue: nothing is copied, and a NATS outage longer than that log holds is a gap
// (a snapshot is then written and the stream moved up to it).
class JetStreamDeltaLog final : public DeltaLog {
 public:
  explicit JetStreamDeltaLog(const DeltaLogOptions& o) : options_(o) {}
  ~JetStreamDeltaLog() override { Close(); }
  const char* kind() const override { return "jetstream"; }

  absl::Status Open(ModelStore* store, bool store_is_authority) override {
    store_ = store;
    JetStreamSceneOptions so;
    so.url = options_.nats_url;
    so.scene = options_.scene;
    so.replicas = options_.nats_replicas;
    so.max_stream_bytes = options_.max_stream_bytes;
    so.connect_timeout_s = options_.connect_timeout_s;
    EXO_ASSIGN_OR_RETURN(js_, JetStreamScene::Connect(so, /*create=*/true));
    EXO_ASSIGN_OR_RETURN(StreamState s, js_->DeltaStreamState());
    const uint64_t c = store->version();
    log_->info("delta log: JetStream stream {} holds versions {}..{} ({} bytes); the store is at "
               "version {}", js_->stream(), s.first_seq, s.last_seq, s.bytes, c);
    bool need_snapshot = false;
    if (s.last_seq > c && store_is_authority) {
      // Reconciliation with the frame journal: the store (checkpoint + the journal it replays
      // next) is the history; the stream's versions c+1..last are abandoned. Version last+1 is
      // never published, so a relay that applied some of them meets a gap and resyncs from the
      // snapshot below instead of joining two histories.
      EXO_RETURN_IF_ERROR(CheckSameHistory(c, s.first_seq));
      const uint64_t next = s.last_seq + 2;
      EXO_RETURN_IF_ERROR(js_->PurgeDeltasBelow(next));
      EXO_ASSIGN_OR_RETURN(StreamState after, js_->DeltaStreamState());
      if (after.last_seq != next - 1)
        return absl::FailedPreconditionError(absl::StrCat(
            "delta log: could not move stream ", js_->stream(), " up to version ", next - 1,
            " (it ends at ", after.last_seq, ")"));
      EXO_RETURN_IF_ERROR(store->SkipVersionsTo(next - 1));
      abandoned_ = s.last_seq - c;
      log_->warn("delta log: the stream held versions {}..{} past the checkpoint's {}; abandoned "
                 "(the frame journal replays their frames once), the model continues at version "
                 "{} with a snapshot; relays resync from it",
                 c + 1, s.last_seq, c, next - 1);
      need_snapshot = true;
    } else if (s.last_seq > c) {
      // The stream is ahead of the checkpoint (the server died after publishing more): the stream
      // is the newer history; replay it so versions and epochs continue where viewers are.
      if (c + 1 < s.first_seq) {
        if (c != 0)
          return absl::DataLossError(absl::StrCat(
              "delta log: the stream starts at version ", s.first_seq,
              " but the checkpoint is at ", c, "; the versions between are in neither"));
        EXO_ASSIGN_OR_RETURN(auto snap, js_->ReadSnapshot());
        if (!snap || snap->version() + 1 < s.first_seq)
          return absl::DataLossError(absl::StrCat("delta log: the stream starts at version ",
                                                  s.first_seq, " and no snapshot reaches it"));
        EXO_RETURN_IF_ERROR(store->RestoreCheckpoint(*snap));
        log_->info("delta log: restored the stream's snapshot of version {}", snap->version());
      }
      EXO_RETURN_IF_ERROR(CheckSameHistory(store->version(), s.first_seq));
      const uint64_t from = store->version();
      for (uint64_t v = from + 1; v <= s.last_seq; ++v) {
        EXO_ASSIGN_OR_RETURN(v1::Delta d, js_->GetDelta(v));
        EXO_RETURN_IF_ERROR(store->ReplayDelta(d));
      }
      replayed_ = s.last_seq - from;
      log_->info("delta log: replayed versions {}..{} from the stream", from + 1, s.last_seq);
    } else if (s.last_seq < c) {
      // The stream is behind (a new or wiped NATS): it continues at the store's version.
      EXO_RETURN_IF_ERROR(js_->PurgeDeltasBelow(c + 1));
      EXO_ASSIGN_OR_RETURN(StreamState after, js_->DeltaStreamState());
      if (after.last_seq != c)
        return absl::FailedPreconditionError(absl::StrCat(
            "delta log: could not move stream ", js_->stream(), " up to version ", c,
            " (it ends at ", after.last_seq, ")"));
      log_->warn("delta log: the stream ended at version {} < the checkpoint's {}; moved it up "
                 "(viewers behind resync by snapshot)", s.last_seq, c);
      need_snapshot = true;
    } else {
      EXO_RETURN_IF_ERROR(CheckSameHistory(c, s.first_seq));
    }
    published_.store(store->version());
    if (need_snapshot || store->version() > 0) EXO_RETURN_IF_ERROR(Snapshot());
    thread_ = std::thread([this] { Run(); });
    return absl::OkStatus();
  }

  uint64_t durable_version() const override { return published_.load(); }

  void Close() override {
    if (!thread_.joinable()) return;
    {
      std::lock_guard lock(mu_);
      closing_ = true;  // Run drains what the store holds (bounded) before it stops
    }
    cv_.notify_all();
    thread_.join();
  }

  void AddCounters(std::map<std::string, double>* out) const override {
    (*out)["delta_log.published_version"] = static_cast<double>(published_.load());
    (*out)["delta_log.snapshot_version"] = static_cast<double>(snapshot_version_.load());
    (*out)["delta_log.snapshots"] = static_cast<double>(snapshots_.load());
    (*out)["delta_log.publish_retries"] = static_cast<double>(retries_.load());
    (*out)["delta_log.replayed"] = static_cast<double>(replayed_);
    (*out)["delta_log.gaps"] = static_cast<double>(gaps_.load());
    (*out)["delta_log.abandoned"] = static_cast<double>(abandoned_);
    (*out)["delta_log.unconditional_publishes"] = static_cast<double>(unconditional_.load());
    (*out)["delta_log.bytes_published"] = static_cast<double>(bytes_published_.load());
  }

 private:
  // The stream's delta at `version` must be from the store's history (same epoch).
  absl::Status CheckSameHistory(uint64_t version, uint64_t first_seq) {
    if (version == 0 || version < first_seq) return absl::OkStatus();
    EXO_ASSIGN_OR_RETURN(v1::Delta d, js_->GetDelta(version));
    const uint64_t mine = store_->EpochAt(version);
    if (mine != 0 && d.model_epoch() != mine)
      return absl::FailedPreconditionError(absl::StrCat(
          "delta log: stream ", js_->stream(), " holds version ", version, " of epoch ",
          d.model_epoch(), " but the checkpoint's is of epoch ", mine,
          ": the stream belongs to another history of this scene (wrong scene name, or a "
          "checkpoint from another deployment)"));
    return absl::OkStatus();
  }

  absl::Status Snapshot() {
    const v1::Checkpoint c = store_->MakeCheckpoint(0);
    EXO_ASSIGN_OR_RETURN(SnapshotManifest m, js_->WriteSnapshot(c));
    snapshot_version_.store(m.version);
    bytes_published_.fetch_add(m.bytes);
    snapshots_.fetch_add(1);
    last_snapshot_ = std::chrono::steady_clock::now();
    log_->info("delta log: snapshot of version {} ({} bytes, {} chunks)", m.version, m.bytes,
               m.chunks);
    return absl::OkStatus();
  }

  bool Closing() {
    std::lock_guard lock(mu_);
    return closing_;
  }

  void Run() {
    std::chrono::steady_clock::time_point close_deadline{};
    for (;;) {
      const bool closing = Closing();
      if (closing && close_deadline == std::chrono::steady_clock::time_point{})
        close_deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
      if (closing && (published_.load() >= store_->version() ||
                      std::chrono::steady_clock::now() > close_deadline))
        break;
      auto batch = store_->DeltasAfter(published_.load(), 256, closing ? 0 : 200);
      if (!batch.ok()) {
        // Gap: the store's log dropped versions NATS never got. Snapshot, then move the stream.
        gaps_.fetch_add(1);
        log_->error("delta log: {}; writing a snapshot and moving the stream up",
                    std::string(batch.status().message()));
        const uint64_t v = store_->version();
        if (auto s = js_->PurgeDeltasBelow(v + 1); !s.ok()) {
          log_->error("delta log: {}", std::string(s.message()));
          Backoff();
          continue;
        }
        published_.store(v);
        if (auto s = Snapshot(); !s.ok()) log_->error("delta log: {}", std::string(s.message()));
        continue;
      }
      for (const DeltaPtr& d : *batch) {
        absl::Status s;
        while (!(s = js_->PublishDelta(*d)).ok()) {
          if (s.code() == absl::StatusCode::kFailedPrecondition ||
              s.code() == absl::StatusCode::kResourceExhausted || s.code() == absl::StatusCode::kInternal) {
            log_->critical("delta log: {}; publishing stops (relays no longer follow this server)",
                           std::string(s.message()));
            return;
          }
          retries_.fetch_add(1);
          if (retries_.load() % 20 == 1)
            log_->warn("delta log: {} (retrying)", std::string(s.message()));
          if (Closing() && std::chrono::steady_clock::now() > close_deadline &&
              close_deadline != std::chrono::steady_clock::time_point{})
            return;
          Backoff();
        }
        published_.store(d->version());
        bytes_published_.fetch_add(d->ByteSizeLong());
        unconditional_.store(js_->unconditional_publishes());
      }
      if (published_.load() > snapshot_version_.load() &&
          std::chrono::steady_clock::now() - last_snapshot_ >
              std::chrono::duration<double>(options_.snapshot_interval_s))
        if (auto s = Snapshot(); !s.ok()) log_->warn("delta log: {}", std::string(s.message()));
    }
    if (published_.load() > snapshot_version_.load())
      if (auto s = Snapshot(); !s.ok()) log_->warn("delta log: {}", std::string(s.message()));
  }

  void Backoff() {
    std::unique_lock lock(mu_);
    cv_.wait_for(lock, std::chrono::milliseconds(200));
  }

  const DeltaLogOptions options_;
  ModelStore* store_ = nullptr;
  std::unique_ptr<JetStreamScene> js_;
  std::shared_ptr<spdlog::logger> log_ = log::Get("server");
  std::thread thread_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool closing_ = false;
  std::atomic<uint64_t> published_{0}, snapshot_version_{0}, snapshots_{0}, retries_{0}, gaps_{0},
      bytes_published_{0};  // deltas + snapshots sent to JetStream
  uint64_t replayed_ = 0;
  uint64_t abandoned_ = 0;
  std::atomic<uint64_t> unconditional_{0};  // publishes after a purge (nats-server 2.9)  // stream versions past the checkpoint given up at Open
  std::chrono::steady_clock::time_point last_snapshot_{};
};

}  // namespace
#else
bool JetStreamAvailable() { return false; }
#endif

absl::StatusOr<std::unique_ptr<DeltaLog>> MakeDeltaLog(const DeltaLogOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  if (options.kind == "memory") return std::unique_ptr<DeltaLog>(new MemoryDeltaLog);
#ifdef EXOVIEW_HAS_NATS
  EXO_RETURN_IF_ERROR(ValidateSceneName(options.scene));
  return std::unique_ptr<DeltaLog>(new JetStreamDeltaLog(options));
#else
  return absl::UnimplementedError("delta_log=jetstream: built without libnats");
#endif
}

}  // namespace exo
