// Where the published model's deltas go (SPEC §15). Every mutation of the ModelStore is one
// versioned, epoch-tagged Delta; a DeltaLog is what holds that sequence for readers other than
// the server's own subscribers:
//  - "memory" (the embedded default): the store's own bounded in-memory log is the only log; the
//    server serves every viewer itself. Nothing outside the process, no dependency.
//  - "jetstream": the deltas are also published to NATS JetStream (one stream per scene, model
//    version = stream sequence, periodic snapshots), where stateless exoview_relay processes read
//    them and serve the unchanged Subscribe API (server/relay). See docs/deploy.md.
// The interface is about published deltas only: which versions the log holds (the watermark a
// durable acknowledgement can wait on), not how frames are journaled.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>

#include "common/status.h"
#include "server/service/model_store.h"

namespace exo {

struct DeltaLogOptions {
  std::string kind = "memory";  // "memory" | "jetstream"
  // JetStream: server URL(s) (comma-separated), scene name (names the stream, the snapshot stream
  // and the KV bucket), stream replicas (3 in a cluster), seconds between snapshots, stream bound.
  std::string nats_url = "nats://127.0.0.1:4222";
  std::string scene = "default";
  int nats_replicas = 1;
  double snapshot_interval_s = 10.0;
  uint64_t max_stream_bytes = uint64_t{4} << 30;
  double connect_timeout_s = 10.0;
  absl::Status Validate() const;
};

class DeltaLog {
 public:
  virtual ~DeltaLog() = default;
  virtual const char* kind() const = 0;
  // Called once, before the server serves, with the store as restored from its checkpoint (or
  // empty). The log and the store are brought to one history, from then on every delta the
  // store commits goes to the log in version order. A log behind the store is moved up to the
  // store's version. A log ahead of the store (the server died after publishing more than its
  // checkpoint holds):
  //  - store_is_authority = false (no frame journal): the log is the newer history and is
  //    replayed into the store (ModelStore::ReplayDelta);
  //  - store_is_authority = true (the frame journal, issue 20, holds every durable frame past
  //    the checkpoint and will replay them): the log's versions past the checkpoint are
  //    abandoned, because replaying them AND the journal would apply those frames twice (the
  //    deltas carry no applied-frame ledger, and the log may end in the middle of a frame). The
  //    store skips to one version past the log's last (ModelStore::SkipVersionsTo), the log is
  //    purged up to there and a snapshot of the store is written: every follower of the log
  //    then meets a gap (that one version is never published), which is how a relay knows to
  //    resync from the snapshot; after it, every delta of the new epoch once, in order.
  virtual absl::Status Open(ModelStore* store, bool store_is_authority) = 0;
  // Highest model version the log holds (the store's version for "memory"; for "jetstream" the
  // last one the stream acknowledged).
  virtual uint64_t durable_version() const = 0;
  // Publishes what the store committed until now (bounded wait), then stops.
  virtual void Close() = 0;
  // Counters for GetStats ("delta_log.*").
  virtual void AddCounters(std::map<std::string, double>* out) const { (void)out; }
};

// The store's own in-memory log (no external log).
class MemoryDeltaLog final : public DeltaLog {
 public:
  const char* kind() const override { return "memory"; }
  absl::Status Open(ModelStore* store, bool) override {
    store_ = store;
    return absl::OkStatus();
  }
  uint64_t durable_version() const override { return store_ ? store_->version() : 0; }
  void Close() override {}

 private:
  ModelStore* store_ = nullptr;
};

// The log `options.kind` names; UNIMPLEMENTED for "jetstream" in a build without libnats.
absl::StatusOr<std::unique_ptr<DeltaLog>> MakeDeltaLog(const DeltaLogOptions& options);
bool JetStreamAvailable();

}  // namespace exo
