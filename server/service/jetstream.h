// NATS JetStream layout of one scene's published model (libnats, the C client nats.c):
//   stream  EXOVIEW_<scene>       subject exoview.<scene>.deltas    one Delta per message,
//                                                                   stream sequence = model version
//   stream  EXOVIEW_<scene>_SNAP  subject exoview.<scene>.snapshot  a snapshot = a serialized
//                                                                   v1::Checkpoint (model + epoch
//                                                                   lineage, no log) in chunks
//   KV      EXOVIEW_<scene>       key snapshot                      where the newest snapshot is
//                                                                   (version, first chunk, chunks)
// Written by the modeling server (JetStreamDeltaLog), read by exoview_relay. Not thread-safe: one
// JetStreamScene per thread.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "common/status.h"
#include "proto/exoview.pb.h"
#include "proto/frame_proto.h"

namespace exo {

struct JetStreamSceneOptions {
  std::string url = "nats://127.0.0.1:4222";
  std::string scene = "default";
  int replicas = 1;
  uint64_t max_stream_bytes = uint64_t{4} << 30;
  double connect_timeout_s = 10.0;  // keeps retrying the connection this long
};

// Scene names become stream and subject names: letters, digits, '-' and '_' only.
absl::Status ValidateSceneName(const std::string& scene);

struct StreamState {
  uint64_t first_seq = 0, last_seq = 0, msgs = 0, bytes = 0;
};

struct SnapshotManifest {
  uint64_t version = 0;
  uint64_t first_seq = 0;  // of its first chunk in the snapshot stream
  uint64_t chunks = 0;
  uint64_t bytes = 0;
};

class JetStreamScene {
 public:
  // Connects (retrying up to connect_timeout_s). `create` = make the streams and the KV bucket
  // when missing (the server); a relay only binds and gets NOT_FOUND until they exist.
  static absl::StatusOr<std::unique_ptr<JetStreamScene>> Connect(const JetStreamSceneOptions& o,
                                                                 bool create);
  ~JetStreamScene();

  absl::StatusOr<StreamState> DeltaStreamState();
  // The delta of `version` (stream sequence), NOT_FOUND when the stream does not hold it.
  absl::StatusOr<v1::Delta> GetDelta(uint64_t version);
  // Publishes a delta as sequence delta.version(): the stream must end at version - 1
  // (FAILED_PRECONDITION naming both when it does not, e.g. a second server on the scene).
  absl::Status PublishDelta(const v1::Delta& delta);
  // Moves an empty or shorter stream's next sequence up to `next_seq` (purges everything below).
  absl::Status PurgeDeltasBelow(uint64_t next_seq);

  // Snapshot: chunks, then the manifest, then older snapshots purged.
  absl::StatusOr<SnapshotManifest> WriteSnapshot(const v1::Checkpoint& checkpoint);
  // The newest snapshot; nullopt when none was written.
  absl::StatusOr<std::optional<v1::Checkpoint>> ReadSnapshot();

  // Ordered push consumer of the delta stream from `first_version`: `on_delta` for each message
  // in sequence order, until it returns false or `keep_going` says stop (polled every 200 ms).
  absl::Status Follow(uint64_t first_version,
                      const std::function<bool(const v1::Delta&)>& on_delta,
                      const std::function<bool()>& keep_going);

  const std::string& stream() const { return stream_; }
  // Publishes that went without the expected-last-sequence check (after a purge, see
  // PublishDelta).
  uint64_t unconditional_publishes() const { return unconditional_; }
  int64_t max_payload() const;

 private:
  JetStreamScene() = default;
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::string stream_, snap_stream_, subject_, snap_subject_, bucket_;
  uint64_t unconditional_ = 0;
  bool expect_unreliable_ = false;  // the server's expected-last-sequence mark went stale
};

}  // namespace exo
