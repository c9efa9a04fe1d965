// Render client session: subscribes to the server's deltas from the local store's version,
// applies them to a LocalStore, and optionally journals every applied delta to a file so a
// restarted viewer replays its store and resumes from its last version (only the missed deltas
// are sent). Records bytes, delta counts, snapshots and frame-to-delta receive times.
#pragma once

#include <atomic>
#include <cstdint>
#include <fstream>
#include <functional>
#include <memory>
#include <mutex>
#include <string>

#include "client/store/local_store.h"
#include "common/status.h"
#include "proto/exoview.pb.h"

namespace grpc {
class Channel;
}

namespace exo {

struct SyncOptions {
  // Stop once the local version equals the server's, the server's pipeline has processed every
  // accepted frame, and nothing changed for `settle_ms`.
  bool until_synced = true;
  int settle_ms = 400;
  uint64_t min_server_frames = 0;  // ...and the server has received at least this many frames
  double max_seconds = 60.0;
  std::string client_name = "viewer";
};

struct SessionStats {
  uint64_t deltas = 0;
  uint64_t bytes = 0;           // serialized delta bytes received
  uint64_t mesh_bytes = 0;      // ... of which proxy mesh chunks (MeshChunkUpserted, snapshot batches)
  uint64_t view_bytes = 0;      // ... of which views (ViewAdded / ViewUpdated)
  uint64_t mesh_chunks = 0;     // MeshChunkUpserted / MeshChunkBatch deltas received
  uint64_t snapshots = 0;
  uint64_t resumed_from = 0;    // version passed to Subscribe
  uint64_t replayed = 0;        // deltas replayed from the journal at start
};

class ViewerSession {
 public:
  // `journal_path` empty = no persistence.
  static absl::StatusOr<std::unique_ptr<ViewerSession>> Open(std::shared_ptr<grpc::Channel> channel,
                                                             const std::string& journal_path);
  ~ViewerSession();
  // Subscribes and applies deltas until the stop condition, Stop(), or max_seconds.
  absl::Status Sync(const SyncOptions& options);
  void Stop() { stop_.store(true); }

  // Called (under the session lock) after each applied delta with its steady-clock receive time.
  void SetOnDelta(std::function<void(const v1::Delta&, int64_t recv_ns)> f) { on_delta_ = std::move(f); }

  // The store must not be read while Sync runs on another thread unless under lock().
  const LocalStore& store() const { return store_; }
  std::mutex& lock() { return mu_; }
  const SessionStats& stats() const { return stats_; }
  // Server's GetStats (for digests and reports).
  absl::StatusOr<v1::Stats> ServerStats() const;

 private:
  ViewerSession() = default;
  absl::Status Replay();
  absl::Status Journal(const v1::Delta& d);

  std::shared_ptr<grpc::Channel> channel_;
  std::string journal_path_;
  std::ofstream journal_;
  LocalStore store_;
  SessionStats stats_;
  std::mutex mu_;
  std::atomic<bool> stop_{false};
  std::function<void(const v1::Delta&, int64_t)> on_delta_;
};

}  // namespace exo
