// Scene completion in the server (issue 18 item 4, second mode; SPEC §7): a viewer's
// CompleteView call lands here. The stage's own worker thread (one completion in flight, one
// waiting; RESOURCE_EXHAUSTED beyond; never on the ingest path) snapshots the published model
// (views, cell references, proxy chunks), runs the pure library (server/inpainting/completion.h:
// lumigraph render at the viewer's camera -> holes -> InpaintKeyframe), and publishes the result
// through the model store like every view, so every viewer gets it through deltas, resume and
// checkpoint:
//   - an inpainted view (ViewAdded.inpainted, labels = the holes), id in
//     [kCompletionViewIdBase, kCompletionViewIdEnd);
//   - where the holes had no proxy surface, a mesh chunk of the inpainted depth, id
//     kCompletionChunkBit | view id (TSDF chunk ids are packed cells, < 2^63).
// Observations are preferred (SPEC §7): every `refresh_period_s` the worker looks whether the
// observed part of the model (views that are not inpainted, chunks that are not completion
// chunks) changed; if so, each completion view's holes are found again (at most
// refresh_views_per_check views per period) without any completion
// view or chunk, its labels shrink to the holes that remain (republished under the same id, its
// depth taken from the proxy where the proxy now has a surface, its mesh chunk rebuilt) or, when
// fewer than min_hole_px remain, the view and its chunk are withdrawn.
// Planning, refinement, tracking never see these views (inpainted: the planner skips them, cells
// never reference them, frames are not touched); the drone control's map skips completion
// chunks. No gRPC here.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>

#include "common/status.h"
#include "proto/exoview.pb.h"
#include "proto/model_proto.h"
#include "server/inpainting/completion.h"
#include "server/service/model_store.h"
#include "server/service/observed_chunks.h"

namespace exo {

inline constexpr ViewId kCompletionViewIdBase = 0x60000000u;
inline constexpr ViewId kCompletionViewIdEnd = 0x70000000u;
inline constexpr uint64_t kCompletionChunkBit = uint64_t{1} << 63;
inline bool IsCompletionView(ViewId id) {
  return id >= kCompletionViewIdBase && id < kCompletionViewIdEnd;
}
inline bool IsCompletionChunk(uint64_t chunk_id) { return (chunk_id & kCompletionChunkBit) != 0; }

struct CompletionStageOptions {
  inpainting::CompletionOptions completion = [] {
    inpainting::CompletionOptions o;
    o.inpaint.num_threads = 1;  // one worker thread: ingest and the other stages keep the other core
    o.render.num_threads = 1;
    return o;
  }();
  int max_side_px = 640;      // default (and largest) longer side of a completion keyframe
  size_t max_views = 8;       // completion views kept (oldest withdrawn beyond)
  double refresh_period_s = 1.0;  // observations re-checked this often (0 = never)
  // ... at most this many completion views per period (a render each: bounded CPU while frames
  // arrive and every chunk update counts as a change).
  int refresh_views_per_check = 2;
  int refresh_min_px = 16;    // republish once this many hole pixels were observed since
  int nice = 5;               // the worker runs this much nicer than the server
  ViewEncodeOptions publish;
  absl::Status Validate() const;
};

struct CompletionRequest {
  PinholeCamera camera;
  Rigid3d local_from_cam;
  uint32_t max_side_px = 0;  // 0 = options.max_side_px
  std::string who;
};

class CompletionStage {
 public:
  // Starts the worker; the completion views of a restored model (checkpoint) are taken over.
  // `coloured` (may be null): the geometry stage's full-resolution chunks with their fused
  // vertex colours (observed_chunks.h), the colour guide of CompletionOptions::use_vertex_color
  // (the published chunks carry no colours).
  static absl::StatusOr<std::unique_ptr<CompletionStage>> Create(
      const CompletionStageOptions& options, ModelStore* store,
      std::shared_ptr<ObservedChunks> coloured = nullptr);
  virtual ~CompletionStage() = default;
  // Blocks the caller (an RPC thread) until the completion is published or refused. Errors:
  // INVALID_ARGUMENT (camera, pose, size), FAILED_PRECONDITION (no scene, nothing modelled in
  // view), RESOURCE_EXHAUSTED (one in flight and one waiting), UNAVAILABLE (shutting down).
  virtual absl::StatusOr<v1::CompleteViewReply> Complete(const CompletionRequest& request) = 0;
  // Re-checks every completion view against the observations now (on the worker; tests and
  // benchmarks): returns how many views were republished or withdrawn.
  virtual absl::StatusOr<int> RefreshNow() = 0;
  virtual void AddCounters(std::map<std::string, double>* counters) const = 0;
};

}  // namespace exo
