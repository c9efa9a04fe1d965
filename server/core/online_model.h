// The online model of Exoview (SPEC §3-§4), one library for every caller: the server's pipeline
// stages (server/service) and exoview_eval's online policy (server/eval) drive this code, so what
// the evaluation measures is what the server runs.
//
// Data flow per frame (world pose; the scene-local origin and scales are fixed by the first frame):
//   OnlineGeometry::Integrate   TSDF integration (optionally at 1/k depth resolution) -> re-meshed
//                               mesh chunks every n frames (GeometryUpdate: chunks + removed ids)
//   OnlinePlanner::Apply        the update -> per-cell proxy areas A(b_k) (+ cell-id meshes)
//   OnlinePlanner::Plan         cell-id buffer (frame depth back-projected, or the proxy rendered)
//                               -> ViewPlanner::Consider -> HandOff: the view that enters the store
//                               (with its id), the views that leave, the cells whose R(b_k) changed
//   StoredViewOf                the accepted frame as a stored view (depth registered to colour)
// The two halves can run on two threads (the server does) and stay deterministic as long as the
// planner applies exactly the updates of frames <= the frame it plans (OnlineModel::Step does
// both in order on one thread).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "common/cells.h"
#include "common/frame.h"
#include "common/lumigraph/model.h"
#include "common/rigid3.h"
#include "common/status.h"
#include "server/geometry/cell_areas.h"
#include "server/geometry/scene_scale.h"
#include "server/geometry/tsdf_volume.h"
#include "server/planning/cell_id_proxy.h"
#include "server/planning/frame_quality.h"
#include "server/planning/stream_drift.h"
#include "server/planning/view_planner.h"

namespace exo::core {

// Every option of the online model. 0 for a scale option = chosen from the first frame
// (ChooseSceneSetup).
struct OnlineModelOptions {
  // ---- scene set-up ----
  double voxel_m =
      0.0;  // TSDF voxel; 0: clamp(D / 600, 0.02, 0.15), D = diameter of frame 0's surface
  double cell_m = 0.0;   // planner cell; 0: server/geometry/scene_scale.h rule (D / 16 in [0.3, 1])
  double d_max_m = 0.0;  // ideal view distance (3.11); 0: PlannerOptions::ForScene(D, median depth)
  double sigma_m = 0.0;  // σ of (3.11); 0: as d_max_m
  // ---- geometry ----
  double max_depth_m = 4.0;
  double min_depth_m = 0.1;
  int fuse_depth_downscale = 1;  // depth fused at 1/k resolution (nearest sample): speed knob
  int mesh_every_n_frames = 1;   // dirty chunks re-meshed every n-th fused frame
  int tsdf_threads = 2;
  // ---- planning ----
  int id_buffer_stride = 4;  // cell-id buffer = 1/stride of the frame (160x120 for 640x480)
  size_t max_views = 200;
  size_t max_bytes = size_t{1} << 30;
  int r_max = 16;
  // References per cell the clients render with (planning::PlannerOptions::render_refs_max):
  // 0 = R(b_k); N = every stored observer, at most max(N, r_max).
  int render_refs_max = 64;
  // (3.6) directional vs positional. 1 with pose dispersion (issue 15, ten 7-Scenes folds): the
  // positional term credits views close to a cell, which dispersion already spreads.
  double lambda = 1.0;
  double tau_max = 4.0;
  double delta_tau_sum = 0.05;
  bool novelty_positional = false;  // planning::PlannerOptions::novelty_positional (issue 22)
  bool soft_saturation = false;    // planning::PlannerOptions::soft_saturation
  // planning::PlannerOptions::dispersion / _m_per_rad (0: d_max) / _guard (issues 15 / 22).
  // Pose dispersion first, guarded by coverage relative to the mean τ per view (issues 15 / 22,
  // docs/planning.md "Pose dispersion").
  planning::PlannerOptions::Dispersion dispersion = planning::PlannerOptions::Dispersion::kFirst;
  // PlannerOptions::policy / baseline_m_per_rad / baseline_stream_frames: the coverage planner,
  // or an online baseline in the product path (issues 15 / 22; docs/planning.md "Session 17").
  planning::PlannerOptions::Policy policy = planning::PlannerOptions::Policy::kCoverage;
  double baseline_m_per_rad = 1.0;
  int64_t baseline_stream_frames = 0;
  double dispersion_m_per_rad = 0.0;
  double dispersion_rotation_scale = 1.0;  // PlannerOptions::dispersion_rotation_scale
  // PlannerOptions::dispersion_turn_overlap_rad / _scale (session 16; 0 = off).
  double dispersion_turn_overlap_rad = 0.0;
  double dispersion_turn_overlap_scale = 0.5;
  bool dispersion_turn_axis = false;  // PlannerOptions::dispersion_turn_axis (session 16)
  double dispersion_guard = 0.5;
  double dispersion_guard_relative = 0.65;
  // PlannerOptions::dispersion_guard_unique / _after (session 11): the frozen-τ guard while the
  // stream has offered <= 8 frames per view of capacity (the ten 7-Scenes folds: <= 5.4, where it
  // wins), the unique-coverage guard after (long streams, where the frozen τ are stale).
  bool dispersion_guard_unique = false;
  double dispersion_guard_unique_after = 8.0;
  // PlannerOptions::dispersion_weight_exponent (density-weighted dispersion; 0 = off).
  double dispersion_weight_exponent = 0.0;
  double dispersion_weight_after = 0.0;  // PlannerOptions::dispersion_weight_after
  double dispersion_weight_until = 0.0;  // PlannerOptions::dispersion_weight_until
  bool dispersion_keep_nearest = false;  // PlannerOptions::dispersion_keep_nearest
  double dispersion_recency = 0.0;       // PlannerOptions::dispersion_recency
  bool dispersion_drop_older = false;    // PlannerOptions::dispersion_drop_older
  // The time term (session 16 default): κ = 1, max form, on only where the stream's depth
  // disagreement grows by >= 0.1 % of the depth from 1 to 15 frames apart (time-correlated error:
  // 7-Scenes 0.26 %, synthetic streams < 0.01 %: there it stays off and the planner is the
  // pose-only one of session 15). docs/planning.md "Session 16 (lead)".
  double dispersion_time_steps = 1.0;     // PlannerOptions::dispersion_time_steps
  bool dispersion_time_max = true;        // PlannerOptions::dispersion_time_max
  bool dispersion_time_arc = false;       // PlannerOptions::dispersion_time_arc
  double dispersion_time_auto_ref = 0.001;  // PlannerOptions::dispersion_time_auto_ref; the
                                            // OnlinePlanner measures g (planning/stream_drift.h)
  // PlannerOptions::observe_zero_coverage (session 14): a view observes every cell it sees, also
  // where its φ is 0 (the frames of a yaw pan after the first), so R(b_k) and the published
  // references stay the pre-selection over the views stored now. Long drone stream +0.012 SSIM
  // at 50 / 100 / 200 views (6 of 6 seeds each); identical stores on the handheld stream and the
  // ten 7-Scenes folds (docs/planning.md "Session 14").
  bool observe_zero_coverage = true;
  // Relative sharpness of each frame as the planner's candidate quality (issue 15;
  // planning/frame_quality.h). gamma 0 = off.
  planning::FrameQualityOptions frame_quality;
  bool cell_areas = true;  // A(b_k) from the proxy; false: every cell the face area A_cell
  // Bandwidth governor: once the store is full at most this many candidates per second (frame
  // timestamps) reach the planner; 0 = off.
  double max_candidates_per_s_when_full = 0.0;
  // Cell ids from a render of the proxy (planning::CellIdRenderer, SPEC §4 as written) instead of
  // the frame's own depth; the depth is used while there is no proxy yet.
  bool id_from_proxy = false;
  double cellid_lod_m = -1.0;    // LOD cluster size; < 0: planning::DefaultCellIdLodM; 0: full mesh
  double cellid_lod_keep = 0.1;  // planning::CellIdRendererOptions::lod_keep_fraction
  double cellid_max_range_m = 0.0;  // 0: 2 x max_depth_m

  absl::Status Validate() const;
  bool IsValid() const { return Validate().ok(); }
};

// The scene parameters fixed once per scene.
struct SceneSetup {
  LocalOrigin origin;
  double diameter_m = 0.0;    // of the first frame's observed surface
  double view_depth_m = 0.0;  // median valid depth of the first frame
  double voxel_m = 0.02, cell_m = 0.5, d_max_m = 2.0, sigma_m = 2.0;
  SceneScale scale;  // scene_scale.h's values for diameter_m (before ForScene / overrides)
};

// The rule for a scene seen for the first time: origin = the first frame's camera centre; D from
// the bounds of the first frame fused alone (at voxel_m, or 0.02 m when automatic); every option
// left at 0 derived from D as documented on OnlineModelOptions. `restored_origin` /
// `restored_cell_m` (a server restarted from its checkpoint) win over the rule.
absl::StatusOr<SceneSetup> ChooseSceneSetup(const Frame& first, const OnlineModelOptions& options,
                                            std::optional<LocalOrigin> restored_origin = {},
                                            std::optional<double> restored_cell_m = {});

// What one integrated frame changed in the proxy.
struct GeometryUpdate {
  std::vector<MeshChunk> chunks;  // re-meshed chunks, newest version
  std::vector<uint64_t> removed;  // chunk ids that disappeared
  bool empty() const { return chunks.empty() && removed.empty(); }
};

// Registration -> integration -> chunk extraction.
class OnlineGeometry {
 public:
  static absl::StatusOr<std::unique_ptr<OnlineGeometry>> Create(const OnlineModelOptions& options,
                                                                const SceneSetup& setup);
  // A frame without depth changes nothing.
  absl::StatusOr<GeometryUpdate> Integrate(const Frame& frame);
  const TsdfVolume& volume() const { return volume_; }
  uint64_t fused() const { return fused_; }
  // Hash of the live chunks (id, version), 48 bits (exact in a double).
  uint64_t Digest() const;
  // The TSDF and the chunk bookkeeping, for the server's checkpoint (common/state_io.h): a
  // geometry made with the same options and set-up that loads it continues exactly as this one.
  void SaveState(StateWriter* w) const;
  absl::Status LoadState(StateReader* r);

 private:
  OnlineGeometry(const TsdfOptions& tsdf, const OnlineModelOptions& options,
                 const SceneSetup& setup);
  TsdfVolume volume_;
  OnlineModelOptions options_;
  SceneSetup setup_;
  uint64_t fused_ = 0;
  std::map<uint64_t, uint64_t> live_;  // chunk id -> version
};

// The proxy as the lumigraph renders it: the live mesh chunks of every GeometryUpdate so far.
class ProxyMesh {
 public:
  void Apply(const GeometryUpdate& update);
  void Set(MeshChunk chunk);
  // Every chunk concatenated (positions, indices; colours when every chunk has them).
  TriangleMesh All() const;
  const std::map<uint64_t, MeshChunk>& chunks() const { return chunks_; }
  size_t bytes() const;
  size_t triangles() const;

 private:
  std::map<uint64_t, MeshChunk> chunks_;
};

// One frame as the planner sees it (scene-local poses).
struct PlanFrame {
  Rigid3d local_from_cam;
  PinholeCamera camera;           // the colour camera (what a stored view shows)
  const ImageF* depth = nullptr;  // null: cell ids only from the proxy
  const ImageU8* color = nullptr;  // for the frame quality (null: quality 1)
  PinholeCamera depth_camera;
  Rigid3d local_from_depth;
  double timestamp_s = 0.0;
  size_t bytes = 0;  // stored size (colour + float depth + header)
  static PlanFrame Of(const Frame& frame, const LocalOrigin& origin);
};

// The planner's decision on one frame: what the view store must do.
struct HandOff {
  bool candidate = false;  // false: no depth and no proxy, or governed
  bool governed = false;
  bool accepted = false;
  ViewId id = 0;                // the frame's view id (kept when accepted)
  std::vector<ViewId> removed;  // views that leave the store
  std::vector<std::pair<CellId, std::vector<ViewId>>> cell_refs;  // new R(b_k) of changed cells
  double tau_sum = 0.0;
};

// Cell areas -> cell ids -> planning -> hand-off.
class OnlinePlanner {
 public:
  static absl::StatusOr<std::unique_ptr<OnlinePlanner>> Create(const OnlineModelOptions& options,
                                                               const SceneSetup& setup);
  // Applies a proxy change (areas; the cell-id meshes when id_from_proxy). A malformed chunk for
  // the cell-id renderer is skipped and counted; the areas are still applied.
  absl::Status Apply(const GeometryUpdate& update);
  // Plans one frame. View ids are 1 + the number of frames planned before (a frame skipped by
  // the governor or without depth still takes its number), so any caller that plans the same
  // frames gets the same ids.
  absl::StatusOr<HandOff> Plan(const PlanFrame& frame);
  // A view restored from a checkpoint, re-offered in id order (its depth gives the cell ids).
  absl::StatusOr<HandOff> Readmit(const StoredView& view);
  // Removes a stored view (e.g. a refinement outlier); the changed cells' new R(b_k).
  absl::StatusOr<std::vector<std::pair<CellId, std::vector<ViewId>>>> Remove(ViewId id);

  const planning::ViewPlanner& planner() const { return planner_; }
  const CellAreas& areas() const { return areas_; }
  const planning::CellIdRenderer* cell_id_renderer() const { return cell_ids_.get(); }
  const SceneSetup& setup() const { return setup_; }
  // Hash of the stored views (id, pose) and every R(b_k), 48 bits.
  uint64_t Digest() const;
  // Everything Plan decides from, for the server's checkpoint (common/state_io.h): a planner
  // made with the same options and set-up that loads it plans the next frames exactly as this
  // one. Unimplemented with id_from_proxy (the cell-id renderer's meshes are not saved).
  absl::Status SaveState(StateWriter* w) const;
  absl::Status LoadState(StateReader* r);
  struct Counters {
    uint64_t frames = 0, candidates = 0, accepted = 0, governed = 0, areas_set = 0;
    uint64_t ids_from_proxy = 0, cellid_update_errors = 0;
  };
  const Counters& counters() const { return counters_; }
  const planning::StreamDrift& drift() const { return drift_; }

 private:
  OnlinePlanner(planning::ViewPlanner planner, const OnlineModelOptions& options,
                const SceneSetup& setup, std::unique_ptr<planning::CellIdRenderer> cell_ids);
  absl::StatusOr<HandOff> Decide(planning::Candidate cand);
  std::vector<std::pair<CellId, std::vector<ViewId>>> RefsOf(
      const std::vector<CellId>& cells) const;

  planning::ViewPlanner planner_;
  OnlineModelOptions options_;
  SceneSetup setup_;
  CellAreas areas_;
  std::unique_ptr<planning::CellIdRenderer> cell_ids_;
  std::map<ViewId, Rigid3d> poses_;
  ViewId last_id_ = 0;
  double last_candidate_s_ = -1e300;
  planning::FrameQuality quality_;
  planning::StreamDrift drift_;  // dispersion_time_auto_ref
  Counters counters_;
};

// Cell-id pixel counts of a depth map (the frame's visible surface) at 1/stride resolution.
absl::StatusOr<planning::Candidate> CandidateFromDepth(ViewId id, const ImageF& depth,
                                                       const PinholeCamera& depth_camera,
                                                       const Rigid3d& local_from_depth,
                                                       const Rigid3d& local_from_cam,
                                                       const CellGrid& grid, int stride,
                                                       size_t bytes);

// Depth registered to the colour camera (z-depth in the colour frame, colour size): identity when
// depth is already registered, else a forward z-buffered warp (0 = no sample).
ImageF RegisterDepthToColor(const Frame& frame);

// An accepted frame as the view the store keeps (colour, registered depth, exposure).
StoredView StoredViewOf(const Frame& frame, ViewId id, const LocalOrigin& origin);

// Median of the valid (> 0, finite) depths (0 when none): the first frame's view distance.
double MedianDepth(const ImageF& depth);

// Both halves on one thread, in order (what exoview_eval's online policy runs).
class OnlineModel {
 public:
  static absl::StatusOr<std::unique_ptr<OnlineModel>> Create(const OnlineModelOptions& options,
                                                             const SceneSetup& setup);
  // Integrate, apply, plan.
  absl::StatusOr<HandOff> Step(const Frame& frame);
  OnlineGeometry& geometry() { return *geometry_; }
  OnlinePlanner& planner() { return *planner_; }
  const GeometryUpdate& last_update() const { return last_update_; }
  // ModelDigest(geometry().Digest(), planner().Digest()).
  uint64_t Digest() const;

 private:
  std::unique_ptr<OnlineGeometry> geometry_;
  std::unique_ptr<OnlinePlanner> planner_;
  GeometryUpdate last_update_;
};

// The model digest of a server or an eval run: one 48-bit value from the geometry and planner
// digests (the server publishes both halves as stats counters "geometry.digest" and
// "planning.digest"); hex for JSON.
uint64_t ModelDigest(uint64_t geometry_digest, uint64_t planner_digest);
std::string DigestHex(uint64_t digest);

}  // namespace exo::core
