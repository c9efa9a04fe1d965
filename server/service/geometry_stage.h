// Pipeline stage "geometry" (SPEC §3): the online model's geometry half (server/core
// OnlineGeometry: TSDF integration, chunk extraction) on its own thread. Each frame's
// GeometryUpdate goes to the planning stage through a GeometryHandoff (one entry per frame, in
// order, so the planner applies exactly the updates of the frames up to the one it plans: the
// server's decisions do not depend on thread timing). Re-meshed chunks are published as
// MeshChunkUpserted/Removed deltas; a chunk that already exists on the clients is only
// re-published when its triangle count changed by more than `republish_change_fraction` or its
// last publication is older than `republish_interval_s` of stream time (fusion noise would otherwise re-send
// the whole visible proxy every few frames: the steady-state bandwidth target of SPEC §10), or
// as a refresh when fusion has converged it further (republish_extraction_factor), under a
// bandwidth budget (refresh_budget_kbps).
#pragma once

#include <cmath>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>

#include "server/core/online_model.h"
#include "server/service/inpainted_proxy.h"
#include "server/service/pipeline.h"

namespace exo {

struct GeometryStageOptions {
  double republish_change_fraction = 0.2;
  // Seconds of the stream's own time (frame timestamps), not of the server's clock: the
  // publications are a function of the frames alone (issue 20: a restarted server replaying its
  // journal at full speed publishes what an uninterrupted one did).
  double republish_interval_s = 60.0;
  // Issue 15: a chunk's first meshes come from one or two noisy frames and move as fusion
  // converges, while its triangle count hardly changes; held back by the rules above, the clients
  // rendered the stale surface (on 7-Scenes the viewer's proxy covered 87.6 % of the held-out
  // pixels against 92.9 % for the same TSDF's final mesh, SSIM 0.7545 vs 0.7854). A chunk is
  // therefore due for a refresh whenever the number of times it was re-extracted (frames fused
  // into it) has grown by this factor since its last publication: O(log frames) refreshes per
  // chunk, frequent while the surface is young, rare once converged. 0 = off. Fold 9, store
  // 100: off 0.7545 / coverage 0.876; factor 2: 0.7738 / 0.914; 1.5: 0.7776 / 0.920.
  double republish_extraction_factor = 1.5;
  // ... while the chunk is young: no refresh once a publication held this many extractions
  // (fold 9: 1.5 capped at 32 gave 0.7695, at 64 0.7708, uncapped 0.7776).
  int republish_extraction_max = 1 << 30;
  // Due refreshes are sent under a budget (a token bucket in the frames' own time, so the
  // server's output does not depend on thread timing): at most this many kbit of refreshed
  // chunks per second of the stream, bursts up to `refresh_burst_s` seconds of it, the chunks
  // whose extraction count grew most since their last publication first. A due chunk that does
  // not fit waits (its newest mesh is kept) and goes out when tokens have accrued. New chunks
  // and structural changes (> republish_change_fraction) are not budgeted. 0 = unlimited.
  // Without the budget the refresh multiplied the steady-state proxy bytes (service_bench
  // --distinct=300 --long=900 --max=0, plain float meshes: 2.2 -> 34 Mbit/s). 7-Scenes, store
  // 100, folds 0/2/4/6/8, compact meshes (tools/product_eval.py, load 6-9): SSIM 0.7738 at 1000,
  // 0.7782 at 2000, 0.7809 at 4000 (ten folds: unlimited, plain 0.7804; off 0.7574);
  // the viewer's mesh bytes 4.6 / 5.7 / 6.6 MB (fold 9 off: 3.5 MB compact, 9.6 MB plain).
  // Session 12 (format-3 chunks with the LOD, refreshes charged their real wire bytes; ten folds,
  // store 100, admission_block so that no frame is dropped on the loaded machine): SSIM 0.7785 /
  // 0.7788 / 0.7787 at 500 / 1000 / 2000, viewer 7.45 / 7.64 / 7.73 MB: the budget no longer
  // buys quality above 500, so 1000 (SPEC §10's steady state is <= 1 Mbit/s in all).
  double refresh_budget_kbps = 1000.0;
  // Session 13: structural changes of chunks the clients already have (triangle count changed by
  // more than republish_change_fraction) go through the same bucket, ahead of the growth
  // refreshes, instead of out at once; new chunks are never held back. Then the mesh bytes are
  // bounded by the new chunks plus the budget. Off by default: at 1 Mbit/s it holds back the
  // modelling phase's structural changes (service_bench, admission_block: the initial sync's mesh
  // 3.28 -> 2.76 MB, i.e. staler) and the steady state then drains that backlog at the full
  // budget (mesh 2.77 -> 3.14 MB over 30 s); docs/service.md "Cell references packed".
  bool budget_structural = false;
  double refresh_burst_s = 2.0;
  // A due chunk whose surface has hardly moved since its publication is not re-sent (its
  // extraction count is taken as published, so it waits for the next growth step): moved = the
  // mean distance of its vertices to the nearest published vertex, in voxels (a converged
  // surface re-extracted from the same TSDF moves by a fraction of a millimetre; a surface
  // fusion is still pulling moves by millimetres). 0 = re-send every due chunk.
  double refresh_min_move_voxels = 0.1;
  // The clients' proxy LOD (geometry/mesh_lod.h): each published chunk is simplified by
  // quadric edge collapse with the chunk's open boundary locked, moving the surface by at most
  // this many voxels; the server keeps the full mesh for fusion and planning. 0 = publish the
  // full-resolution chunk. 7-Scenes store 100, ten folds, idle machine (tools/product_eval.py,
  // 30 Hz, 0 dropped): 0 / 0.25 / 0.5 voxel: SSIM 0.7791 / 0.7786 / 0.7780, proxy at the viewer
  // 114k / 43k / 39k triangles, viewer bytes 9.87 / 8.52 / 8.35 MB (docs/service.md "The
  // clients' proxy LOD"; the chunk borders, locked, bound what a larger error can remove).
  double publish_lod_error_voxels = 0.25;
  // Position step of the published chunks on the wire, in voxels (MeshWireOptions::step_m; 0 =
  // 16 bits over each chunk's bounding box, format 1/2). 1/32 voxel (0.6 mm at 2 cm) moves a
  // vertex by at most 0.3 mm per coordinate, far under the LOD's bound; on the 7-Scenes proxy it
  // sends 30 % fewer bytes than format 2 (benchmark/mesh_wire_bench: 394 -> 277 kB).
  double publish_step_voxels = 1.0 / 32.0;
  // Load shedding (issue 15: "every real frame accepted at 30 Hz"): TSDF fusion is the costliest
  // stage (~30 ms of a 7-Scenes frame's ~42 ms CPU), so when the machine cannot keep up the
  // admission queue fills and frames are DROPPED, i.e. lost as view candidates too. Instead,
  // while at least this fraction of the stage's input queue is waiting, a frame is not fused
  // (its view is still planned; the proxy is built from its neighbours, which at 30 Hz see the
  // same surfaces), at most `shed_max_run` frames in a row. 0 = never shed (deterministic runs).
  double shed_backlog_fraction = 0.5;
  int shed_max_run = 2;
  // InpaintFusion's labelled proxy (issue 18, geometry/inpainted_surface.h; only with an
  // InpaintedProxyLink, i.e. with the inpainting stage): the marked regions are carved from the
  // chunks the clients get and the inpainted keyframes' depth fills them (L_IP voxels only);
  // the planner keeps the observed proxy. The ROI is the label voxels grown by this many TSDF
  // voxels. false = the clients get the observed proxy (the object stays in it).
  bool inpaint_fuse = true;
  int inpaint_carve_margin_voxels = 1;
  absl::Status Validate() const {
    if (inpaint_carve_margin_voxels < 0 || inpaint_carve_margin_voxels > 16)
      return absl::InvalidArgumentError("inpaint_carve_margin_voxels must be in [0, 16]");
    if (!(shed_backlog_fraction >= 0.0 && shed_backlog_fraction <= 1.0))
      return absl::InvalidArgumentError("shed_backlog_fraction must be in [0, 1]");
    if (shed_max_run < 1 || shed_max_run > 100)
      return absl::InvalidArgumentError("shed_max_run must be in [1, 100]");
    if (!(republish_change_fraction >= 0.0))
      return absl::InvalidArgumentError("republish_change_fraction must be >= 0");
    if (!(republish_extraction_factor == 0.0 || republish_extraction_factor > 1.0))
      return absl::InvalidArgumentError("republish_extraction_factor must be 0 (off) or > 1");
    if (!(refresh_budget_kbps >= 0.0) || !std::isfinite(refresh_budget_kbps))
      return absl::InvalidArgumentError("refresh_budget_kbps must be >= 0 (0 = unlimited)");
    if (!(refresh_min_move_voxels >= 0.0 && refresh_min_move_voxels <= 100.0))
      return absl::InvalidArgumentError("refresh_min_move_voxels must be in [0, 100]");
    if (!(publish_lod_error_voxels >= 0.0 && publish_lod_error_voxels <= 10.0))
      return absl::InvalidArgumentError("publish_lod_error_voxels must be in [0, 10]");
    if (!(publish_step_voxels >= 0.0 && publish_step_voxels <= 1.0))
      return absl::InvalidArgumentError("publish_step_voxels must be in [0, 1] (0 = 16 bits per chunk box)");
    if (!(refresh_burst_s > 0.0 && refresh_burst_s <= 600.0))
      return absl::InvalidArgumentError("refresh_burst_s must be in (0, 600]");
    if (republish_extraction_max < 1)
      return absl::InvalidArgumentError("republish_extraction_max must be >= 1");
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
    std::shared_ptr<GeometryHandoff> handoff = nullptr,
    std::shared_ptr<InpaintedProxyLink> inpainted = nullptr,
    std::shared_ptr<ObservedChunks> coloured = nullptr);  // every chunk, full res + colours

}  // namespace exo
