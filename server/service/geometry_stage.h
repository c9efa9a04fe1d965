// Pipeline stage "geometry" (SPEC §3): the online model's geometry half (server/core
// OnlineGeometry: TSDF integration, chunk extraction) on its own thread. Each frame's
// GeometryUpdate goes to the planning stage through a GeometryHandoff (one entry per frame, in
// order, so the planner applies exactly the updates of the frames up to the one it plans: the
// server's decisions do not depend on thread timing). Re-meshed chunks are published as
// MeshChunkUpserted/Removed deltas; a chunk that already exists on the clients is only
// re-published when its triangle count changed by more than `republish_change_fraction` or its
// last publication is older than `republish_interval_s` (fusion noise would otherwise re-send
// the whole visible proxy every few frames: the steady-state bandwidth target of SPEC §10).
#pragma once

#include <deque>
#include <memory>
#include <mutex>
#include <optional>

#include "server/core/online_model.h"
#include "server/service/pipeline.h"

namespace exo {

struct GeometryStageOptions {
  double republish_change_fraction = 0.2;
  double republish_interval_s = 60.0;
  absl::Status Validate() const {
    if (!(republish_change_fraction >= 0.0))
      return absl::InvalidArgumentError("republish_change_fraction must be >= 0");
    if (!(republish_interval_s >= 0.0))
      return absl::InvalidArgumentError("republish_interval_s must be >= 0");
    return absl::OkStatus();
  }
};

// Geometry -> planning, one GeometryUpdate per frame in frame order. Thread-safe.
class GeometryHandoff {
 public:
  void Push(core::GeometryUpdate update);
  // The update of the oldest frame not yet taken (the geometry stage handled a frame before the
  // planning stage receives it, so it is there); nullopt if none.
  std::optional<core::GeometryUpdate> Pop();

 private:
  std::mutex mu_;
  std::deque<core::GeometryUpdate> updates_;
};

absl::StatusOr<std::unique_ptr<PipelineStage>> MakeGeometryStage(
    const GeometryStageOptions& options, const core::OnlineModelOptions& model,
    std::shared_ptr<GeometryHandoff> handoff = nullptr);

}  // namespace exo
