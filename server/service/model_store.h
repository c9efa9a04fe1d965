// The server's versioned model as clients see it, the bounded delta log and the subscription
// cursors of the publisher. Every mutation bumps the model version by one and appends one Delta
// to the log; the log is bounded (count and bytes) and compacts by dropping its oldest entries,
// since the current model itself is the snapshot. A subscriber is a cursor into the log: a slow
// subscriber only lags, it never blocks a mutation or other subscribers; when it falls behind the
// log (or lags more than `max_subscriber_lag`) it is switched to a snapshot resync.
// Snapshots are shared, not copied: every view and mesh chunk is held once, as the immutable
// Delta that a snapshot sends (reference-counted; an update replaces it copy-on-write), and the
// snapshot of a version is built once and handed to every subscriber that needs it. Inside a
// snapshot a part's `version` is the version of its last change (SnapshotBegin/End carry the
// snapshot's version).
// Thread-safe. No gRPC here: the service layer writes what Next() returns.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <unordered_map>
#include <vector>

#include "common/lumigraph/model.h"
#include "common/status.h"
#include "proto/exoview.pb.h"
#include "proto/frame_proto.h"
#include "proto/model_proto.h"

namespace exo {

using DeltaPtr = std::shared_ptr<const v1::Delta>;

struct ModelStoreOptions {
  size_t max_log_deltas = 4096;
  size_t max_log_bytes = size_t{64} << 20;
  size_t max_subscriber_lag = 2048;   // deltas behind the head before a forced resync
  // On resume, send a snapshot instead of the missed deltas when it is fewer bytes. Off: resume
  // with deltas whenever the log still holds them.
  bool snapshot_when_cheaper = true;
  // Snapshots on the wire (Subscription::NextForWire): the mesh chunks in MeshChunkBatch deltas
  // of up to this many uncompressed bytes each, one zstd frame (level below) per batch; 0 sends
  // each chunk as its own MeshChunkUpserted (a client that predates the batch needs that).
  size_t snapshot_chunk_batch_bytes = size_t{1} << 20;
  int snapshot_chunk_batch_level = 6;
  // A replica (exoview_relay): holds a copy of another store's history, fed by ReplayDelta and
  // RestoreCheckpoint(..., /*replica=*/true); it has no epoch of its own and never commits.
  bool replica = false;
  absl::Status Validate() const;
};

class ModelStore;

// Tags every delta committed by this thread while alive with the source frame's timestamp.
class ScopedDeltaSource {
 public:
  explicit ScopedDeltaSource(double timestamp_s);
  ~ScopedDeltaSource();

 private:
  double previous_;
};

// One subscriber's cursor. Only the thread that serves the subscriber calls Next().
class Subscription {
 public:
  // Blocks until there is something to send, `timeout_ms` elapsed (empty result), or Close().
  // Returns either a batch of log deltas or a whole snapshot (SnapshotBegin ... SnapshotEnd).
  std::vector<DeltaPtr> Next(int timeout_ms);
  // Next() as a gRPC edge sends it: a snapshot's mesh chunks packed into MeshChunkBatch deltas
  // (ModelStoreOptions::snapshot_chunk_batch_bytes), outside the store's lock, packed once per
  // snapshot version for every subscriber that needs it. Log deltas are passed through.
  std::vector<DeltaPtr> NextForWire(int timeout_ms);
  void Close();
  uint64_t sent_version() const { return sent_version_; }
  uint64_t snapshots() const { return snapshots_; }

 private:
  friend class ModelStore;
  Subscription(ModelStore* store, uint64_t from_version, bool force_snapshot)
      : store_(store), sent_version_(from_version), force_snapshot_(force_snapshot) {}
  ModelStore* store_;
  uint64_t sent_version_;  // everything <= this has been handed out
  bool force_snapshot_;
  bool closed_ = false;
  uint64_t snapshots_ = 0;
};

class ModelStore {
 public:
  explicit ModelStore(const ModelStoreOptions& options = {});
  ~ModelStore();

  // Mutations. Each returns the new model version.
  uint64_t SetSceneParams(const LocalOrigin& origin, double cell_size_m);
  uint64_t AddView(v1::ViewAdded view);          // replaces a view of the same id
  absl::StatusOr<uint64_t> UpdateView(ViewId id, const Rigid3d& local_from_cam, float exposure);
  absl::StatusOr<uint64_t> RemoveView(ViewId id);
  // Replaces the reference lists of the given cells (empty list = cell removed).
  uint64_t SetCellRefs(const std::vector<std::pair<CellId, std::vector<ViewId>>>& cells);
  // `wire` picks the chunk's encoding (proto/frame_proto.h MeshWireOptions); the digest covers
  // the mesh as the clients decode it.
  // `wire_bytes`, when given, receives the chunk's size on the wire (the MeshChunkUpserted).
  uint64_t UpsertChunk(uint64_t chunk_id, uint64_t chunk_version, const TriangleMesh& mesh,
                       const MeshWireOptions& wire = {}, size_t* wire_bytes = nullptr);
  absl::StatusOr<uint64_t> RemoveChunk(uint64_t chunk_id);

  // Ledger of applied frames (the frame journal, issue 20): the pipeline brackets the last
  // stage of every journaled frame with BeginApply / EndApply, so a checkpoint (which waits for
  // no frame to be half-applied by that stage) holds either all of a frame's views or none, and
  // the lsn and the uploader's sequence that came with them. `uploader` "" = anonymous stream
  // (only the lsn is kept). A frame whose lsn or (uploader, sequence) is not above the ledger's
  // counts as double_applied (a journal replay bug; the crash test asserts 0).
  struct UploaderProgress {
    uint64_t applied_max_sequence = 0, applied_frames = 0, double_applied = 0, last_lsn = 0;
  };
  static constexpr size_t kMaxUploaders = 4096;  // beyond: the least recently updated goes
  void BeginApply();
  void EndApply(uint64_t lsn, const std::string& uploader, uint64_t sequence);
  uint64_t applied_lsn() const;
  std::map<std::string, UploaderProgress> Uploaders() const;
  uint64_t ledger_changes() const;  // bumped by every EndApply

  // Checkpoint (SPEC §12): the model as published + at most `max_log_bytes` of the log tail,
  // and the applied-frame ledger.
  v1::Checkpoint MakeCheckpoint(size_t max_log_bytes) const;
  // Restores a checkpoint into an empty store (version 0): versions continue from it. A replica
  // store takes the checkpoint's lineage as it is (no epoch of its own after it).
  absl::Status RestoreCheckpoint(const v1::Checkpoint& checkpoint);
  // Applies a delta committed by another store (the modeling server, read back from an external
  // delta log, server/service/delta_log.h) with its own version, epoch and source timestamp:
  // `delta.version()` must be version() + 1. A replica takes every delta this way; a server takes
  // them only before it commits anything of its own (the replay of a log that is ahead of its
  // checkpoint at start), its own epoch then begins after the replayed versions. Snapshot
  // markers are refused; a delta that does not apply (e.g. an update of an unknown view) is
  // DATA_LOSS and changes nothing.
  absl::Status ReplayDelta(const v1::Delta& delta);
  // Moves a server's version up to `version` with no content change (the reconciliation of an
  // external delta log that holds versions this store abandons, delta_log.h): only before its
  // own epoch committed anything. The versions in between count as this store's epoch (a client
  // holding one of them from the abandoned history resyncs by snapshot) and the log is emptied
  // (no delta joins the two histories).
  absl::Status SkipVersionsTo(uint64_t version);
  // The log entries after `version` (at most `max`), waiting up to `timeout_ms` for one (CloseAll()
  // ends the wait; entries are still returned after it). Empty when nothing came; DATA_LOSS when the log no longer holds version + 1
  // (compacted away): the reader has lost deltas and must resync from a snapshot.
  absl::StatusOr<std::vector<DeltaPtr>> DeltasAfter(uint64_t version, size_t max, int timeout_ms);
  bool closed() const;
  bool has_scene() const;
  v1::SceneParams scene() const;
  // The published views (for a restarted planner), ordered by id.
  std::vector<std::shared_ptr<const v1::ViewAdded>> Views() const;
  std::vector<CellId> CellIds() const;
  // The published reference lists R(b_k) (scene completion renders the model as clients do).
  std::unordered_map<CellId, std::vector<ViewId>> CellRefs() const;
  // The published coverage per cell (τ/τ_max in whole percent; cells never given one absent).
  std::unordered_map<CellId, uint8_t> CellCoverage() const;
  // Mutation: SetCellRefs with the cells' coverage (CellCoverage: τ/τ_max in whole percent,
  // clamped to 100) in the same delta; either list may be empty. Returns the new version.
  uint64_t SetCellRefs(const std::vector<std::pair<CellId, std::vector<ViewId>>>& cells,
                       const std::vector<std::pair<CellId, uint8_t>>& coverage);
  // The published mesh chunks (shared parts; MeshFromProto turns them into meshes) and the scene
  // origin (nullopt before the first frame): what region marking renders its depth from.
  std::vector<std::shared_ptr<const v1::MeshChunkUpserted>> Chunks() const;
  std::optional<LocalOrigin> Origin() const;

  // Subscribe from the client's last applied (version, epoch): only the missed deltas, or a
  // snapshot when the log no longer holds them, when they would cost more bytes than a
  // snapshot, when the client claims a version from the future, or when the client's state is
  // not on this store's history (its epoch is not the one that produced `last_version` here,
  // e.g. a server restarted from a checkpoint older than the client and produced the same
  // version numbers again with other content). last_version 0 needs no epoch.
  std::shared_ptr<Subscription> Subscribe(uint64_t last_version, uint64_t last_epoch);

  // Model epochs: every store starts a new random epoch (non-zero); RestoreCheckpoint continues
  // the checkpoint's history and starts a new epoch after its version. EpochAt(v) is the epoch
  // that produced version v (0 for v = 0 or a version older than the kept history).
  static constexpr size_t kMaxLineage = 64;
  uint64_t epoch() const;
  uint64_t EpochAt(uint64_t version) const;
  // Wakes every subscription (shutdown); later Next() calls return empty.
  void CloseAll();

  struct Summary {
    uint64_t version = 0;
    uint64_t digest = 0;
    uint32_t num_views = 0, num_cells = 0, num_chunks = 0;
    uint64_t log_first_version = 0;
    uint64_t snapshot_bytes = 0;
    uint64_t log_deltas = 0, log_bytes = 0;  // the delta log's size against its bounds
    uint32_t subscribers = 0;
    uint64_t snapshots_sent = 0;
  };
  Summary GetSummary() const;
  uint64_t version() const;
  bool has_view(ViewId id) const;

 private:
  friend class Subscription;
  uint64_t CommitLocked(v1::Delta delta);          // sets version, appends, compacts, notifies
  void AppendLogLocked(DeltaPtr delta);             // appends, compacts, notifies
  // SnapshotBegin, model, SnapshotEnd: built once per version, shared by every subscriber.
  std::shared_ptr<const std::vector<DeltaPtr>> SnapshotLocked() const;
  size_t SnapshotBytesLocked() const;
  // The snapshot `parts` (SnapshotBegin ... SnapshotEnd) with their chunks batched; takes only
  // wire_mu_ (the packing runs beside ingest, not under mu_).
  std::vector<DeltaPtr> PackSnapshotForWire(std::vector<DeltaPtr> parts) const;
  uint64_t DigestLocked() const;
  uint64_t EpochAtLocked(uint64_t version) const;
  absl::Status ApplyModelDeltaLocked(const v1::Delta& d);  // restore: state only, no commit

  const ModelStoreOptions options_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  bool closed_ = false;
  uint64_t version_ = 0;
  // Model as published.
  bool has_scene_ = false;
  v1::SceneParams scene_;
  // Each view / chunk as its snapshot part (a Delta holding view_added / mesh_chunk_upserted).
  std::map<ViewId, DeltaPtr> views_;
  std::map<ViewId, ViewDigestRecord> view_records_;
  std::unordered_map<CellId, std::vector<ViewId>> cell_refs_;
  std::unordered_map<CellId, uint8_t> cell_coverage_;  // CellCoverage.tau_percent
  std::map<uint64_t, DeltaPtr> chunks_;
  mutable std::shared_ptr<const std::vector<DeltaPtr>> snapshot_;  // of snapshot_version_
  mutable uint64_t snapshot_version_ = ~uint64_t{0};
  // The last snapshot as packed for the wire, keyed by its SnapshotEnd's (version, epoch).
  mutable std::mutex wire_mu_;
  mutable std::shared_ptr<const std::vector<DeltaPtr>> wire_snapshot_;
  mutable uint64_t wire_snapshot_version_ = 0, wire_snapshot_epoch_ = 0;
  std::map<uint64_t, ChunkDigestRecord> chunk_records_;
  size_t view_bytes_ = 0, chunk_bytes_ = 0;
  // Delta log: versions (log_.front()->version() .. version_).
  std::deque<DeltaPtr> log_;
  size_t log_bytes_ = 0;
  int subscribers_ = 0;
  uint64_t snapshots_sent_ = 0;
  // Epoch history, oldest first; lineage_[i].id produced versions (start, next start].
  struct EpochSpan {
    uint64_t id;
    uint64_t start_version;
  };
  std::vector<EpochSpan> lineage_;
  // Applied-frame ledger.
  bool applying_ = false;
  mutable std::condition_variable apply_cv_;
  uint64_t applied_lsn_ = 0, ledger_changes_ = 0;
  std::map<std::string, UploaderProgress> uploaders_;
  uint64_t own_epoch_ = 0;  // this store's epoch (0 for a replica)
};

}  // namespace exo
