// The render client's local copy of the lumigraph model: applies the server's versioned deltas
// (exoview.v1.Delta) to an exo::LumigraphModel with decoded views, tracks the last applied
// version (what the client passes to Subscribe when it reconnects) and computes the same model
// digest as the server (proto/model_proto.h) so equality can be checked end to end.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "common/lumigraph/model.h"
#include "common/status.h"
#include "proto/exoview.pb.h"
#include "proto/model_proto.h"

namespace exo {

class LocalStore {
 public:
  // Applies one delta. Snapshot deltas (SnapshotBegin ... SnapshotEnd) replace the model; the
  // version advances only when the snapshot is complete, so a client interrupted mid-snapshot
  // resumes from its previous consistent version. A delta for a version already applied is an
  // error (FailedPrecondition), as is a gap in versions outside a snapshot.
  absl::Status Apply(const v1::Delta& delta);

  const LumigraphModel& model() const { return model_; }
  uint64_t version() const { return model_.version; }
  // Server epoch of the last applied delta (or of the snapshot): sent with version() on
  // Subscribe so a restarted server can tell whether the client's state is on its history.
  uint64_t epoch() const { return epoch_; }
  uint64_t Digest() const;
  bool in_snapshot() const { return in_snapshot_; }
  uint64_t deltas_applied() const { return deltas_applied_; }
  uint64_t snapshots_applied() const { return snapshots_applied_; }

 private:
  absl::Status ApplyKind(const v1::Delta& delta, LumigraphModel* model,
                         std::map<ViewId, ViewDigestRecord>* views,
                         std::map<uint64_t, ChunkDigestRecord>* chunks);

  LumigraphModel model_;
  std::map<ViewId, ViewDigestRecord> view_records_;
  std::map<uint64_t, ChunkDigestRecord> chunk_records_;
  // Snapshot being received (swapped in at SnapshotEnd).
  bool in_snapshot_ = false;
  LumigraphModel pending_;
  std::map<ViewId, ViewDigestRecord> pending_views_;
  std::map<uint64_t, ChunkDigestRecord> pending_chunks_;
  uint64_t deltas_applied_ = 0, snapshots_applied_ = 0;
  uint64_t epoch_ = 0;
};

// Defensive client (issue 20): why a received view cannot be rendered (non-finite or
// non-positive exposure, invalid intrinsics, images that do not match them, a side above 16384,
// a rotation that is not a unit quaternion, a non-finite position); OK when it can.
absl::Status CheckRenderableView(const StoredView& view);
// A copy of `model` without the views a renderer cannot use (nullopt, no copy, when every view is
// usable); each skipped view is described in `skipped` ("view 16: exposure ..."). Cell
// references to a skipped view are dropped too.
std::optional<LumigraphModel> WithoutUnusableViews(const LumigraphModel& model,
                                                   std::vector<std::string>* skipped);

}  // namespace exo
