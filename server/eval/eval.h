// Evaluation benchmark of the modeling core (SPEC §9): streams RGB-D frames of a synthetic scene
// (village / apartment, fly-over / walk) or of a real sequence (7-Scenes redkitchen, every 10th
// frame held out) through the real pipeline (sparse TSDF proxy -> cell areas -> cell-id buffer
// -> online ViewPlanner), and compares the resulting lumigraph (CPU renderer, SPEC §6) with
// ground truth at test poses: MSSIM / PSNR / coverage via common/metrics, next to the speed of
// integration and planning and the memory of store and geometry.
//
// Selection policies compared on the same input and the same store budget:
//   kOnline        the thesis' online planner (SPEC §4), its per-cell pre-selection R(b_k)
//   kOfflineGreedy greedy maximisation of the same τ_sum objective over ALL frames, seen at once
//                  with the final proxy (lazy greedy; the upper bound the online planner chases)
//   kEveryN        keep every N-th frame, N = frames / store: knows the stream's length, so an
//                  ORACLE row, not an online policy (JSON "online":0)
//   kMinDistance   online dispersion: when full, a frame replaces one view of the closest pair
//                  if its nearest-view pose distance exceeds that pair's distance
//   kAll           every frame (unbounded store)
// Issue 22 online baselines (server/planning/online_baselines.h; they never know the length):
//   kEveryNOnline  every-N with progressive decimation (keep every frame until full, then drop
//                  every other kept frame and double N)
//   kReservoir     reservoir sampling, seeded (PolicyConfig::policy_seed)
//   kKeyframe      SLAM keyframes: InpaintFusion ||I - M_i^-1 M_k||_F > 0.7 to the last keyframe
//                  (translation in units of Source::metres_per_rad); when full the threshold
//                  grows x1.5 and the kept keyframes are re-thinned with it
// Baselines get their per-cell references R(b_k) from the same pre-selection rule as the
// planner (R_max cap, fed the selected views in frame order); an "uncapped" variant references
// every selected view that sees the cell in the final proxy (unbounded R). A further baseline, the per-vertex averaged colour of the
// TSDF mesh (KinectFusion class), is reported once per run (policy "vertex_color").
//
// Synthetic stored views are re-rendered from their pose when evaluated (deterministic,
// exposure 1, no noise), so the stream keeps only poses and cell counts per frame.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "common/lumigraph/blend_math.h"
#include "common/status.h"

namespace exo::eval {

// kOnlineFinalAreas (diagnostic, not a product policy): the online rules run in stream order
// after the stream, with every cell's area A(b_k) taken from the FINAL proxy from the first frame
// on (the same per-frame cell ids as the online policy) - the online planner without the growing
// proxy's areas.
enum class Policy { kOnline, kOfflineGreedy, kEveryN, kMinDistance, kAll, kVertexColor,
                    kOnlineFinalAreas, kEveryNOnline, kReservoir, kKeyframe };
const char* PolicyName(Policy p);
// Whether the policy could run on a stream of unknown length, one frame at a time (every_n and
// offline_greedy cannot: they are oracles).
bool PolicyIsOnline(Policy p);
// Baselines whose stored views get the fair pre-selection (or uncapped) references.
bool PolicyIsBaseline(Policy p);
enum class ProxyKind { kTsdf, kGroundTruth };

// One store configuration evaluated on the shared stream.
struct PolicyConfig {
  Policy policy = Policy::kOnline;
  int store = 200;              // views (and bytes = store x one frame)
  int r_max = 16;
  double lambda = -1;           // planner λ; < 0: 0.5 fly-over, 0.4 walk / real
  double delta_tau_sum = -1;    // < 0: planner default
  double tau_max = -1;          // < 0: planner default
  double cell_m = 0;            // 0: scene-scale rule (server/geometry/scene_scale.h)
  int test_views = -1;          // < 0: all test poses of the run
  // Baselines only (every_n, min_distance, all): how R(b_k) is built from the selected views.
  //   false (default, fair): the planner's own per-cell pre-selection (§3.1.4, R_max cap, same
  //          d_max/σ/λ/cell), fed the selected views in frame order, so only the CHOICE of
  //          stored views differs from the online policy;
  //   true  ("uncapped"): every selected view that sees the cell in the final proxy.
  bool uncapped_refs = false;
  double blend_lambda = -1;  // blend (3.5) lambda; < 0: BlendOptions (the product default)
  int render_refs_max = 64;  // planning::PlannerOptions::render_refs_max (0 = R(b_k) only)
  // Every planner of this config (online, offline greedy, the baselines' pre-selection) gets no
  // proxy areas: A(b_k) = the face area A_cell for every cell (the planner's rule for an unknown
  // area), instead of the TSDF proxy's CellAreas.
  bool face_areas = false;
  std::string tag;              // free label copied into the JSON ("sweep":"store" ...)
  uint64_t policy_seed = 1;     // reservoir sampling's seed
  // Issue 22: planners of this config use φ = φ_d (λ + (1 - λ) φ_p) (PlannerOptions::
  // novelty_positional); exoview_eval's policy "online_novelty" = online with this on.
  bool novelty_positional = false;
  // planning::PlannerOptions::soft_saturation; policy option "soft=1".
  bool soft_saturation = false;
  // planning::PlannerOptions::dispersion / dispersion_m_per_rad; policy options "disp=1",
  // "mpr=V".
  // -1: the product's default (core::OnlineModelOptions), as every unset planner option.
  int dispersion = -1;  // 0 off, 1 ties, 2 first
  double dispersion_m_per_rad = -1;
  double dispersion_rotation_scale = -1;  // policy option "drs=V"
  double dispersion_turn_overlap_deg = -1;   // policy option "dfo=DEG" (0 = off)
  double dispersion_turn_overlap_scale = -1; // policy option "dfs=V"
  int dispersion_turn_axis = -1;             // policy option "dax=0|1"
  double dispersion_guard = -1;           // policy option "dg=V"
  double dispersion_guard_relative = -1;  // policy option "dgr=V"
  int dispersion_guard_unique = -1;       // policy option "dgu=0|1"
  double dispersion_guard_unique_after = -1;  // policy option "dgua=V"
  double dispersion_weight_exponent = -1;     // policy option "dwe=V"
  double dispersion_weight_after = -1;        // policy option "dwa=V"
  double dispersion_weight_until = -1;        // policy option "dwu=V"
  int dispersion_keep_nearest = -1;           // policy option "dkn=0|1"
  double dispersion_recency = -1;             // policy option "drc=V"
  int dispersion_drop_older = -1;             // policy option "ddo=0|1"
  double dispersion_time_steps = -1;          // policy option "dtk=V"
  int dispersion_time_max = -1;               // policy option "dtm=0|1"
  int dispersion_time_arc = -1;               // policy option "dta=0|1"
  double dispersion_time_auto_ref = -1;       // policy option "dtr=V"
  int observe_zero_coverage = -1;             // policy option "ozc=0|1"
  // Online policy only, diagnostic (policy option "rpl=1"): the online planner's final store
  // rendered with the references the baselines get (the pre-selection replayed over the stored
  // views in frame order) instead of the planner's own: separates which views are stored from
  // which views each cell references (docs/planning.md "Session 15").
  bool replay_refs = false;

  // OnlineModelOptions::frame_quality.gamma; policy option "sharp=G" (0 = off).
  double sharp_gamma = 0.0;
  double keyframe_threshold = 0.7;  // kKeyframe: InpaintFusion's ||I - M_i^-1 M_k||_F
  // Issue 15: blend options of this config's renders (lambda still from `lambda`); unset = the
  // run's. Lets one stream compare blend variants on the same stores.
  std::optional<blend::BlendOptions> blend;
  // Issue 15 attribution (7-Scenes only): each test view rendered with its own depth map as
  // the proxy (attribution.h MeshFromDepth) instead of the TSDF mesh: isolates proxy error.
  bool own_depth_proxy = false;
};

struct Quality {
  double mssim = 0, psnr = 0, coverage = 0;
  double mssim_covered = 0;     // SSIM over covered pixels only (masked), mean over views
  double surface = 0;           // fraction of pixels where the proxy was hit (rest: sky/void)
  // mssim / psnr are of the frame the product shows (uncovered pixels filled by FillHoles, the
  // renderers' default since session 5); *_unfilled of the frame without the fill (sessions 1-4).
  double mssim_unfilled = 0, psnr_unfilled = 0;
  // Issue 15: MS-SSIM (Wang 2003) and GMSD (Xue 2014) of the filled frame (common/metrics/
  // perceptual.h), mean over views; NaN when the test image is too small for 5-scale MS-SSIM.
  double ms_ssim = 0, gmsd = 0;
  // Issue 15 attribution: SSIM / PSNR after per-channel gains fitted to the ground truth over
  // the covered pixels (attribution.h FitGainToReference): the global exposure/WB share.
  double mssim_gain_fit = 0, psnr_gain_fit = 0;
  int views = 0;
};

struct ConfigResult {
  PolicyConfig config;
  Quality quality;
  double integrate_ms_median = 0, integrate_ms_p95 = 0;
  double plan_ms_median = 0, plan_ms_p95 = 0;    // cell-id render + Consider, per input frame
  double consider_ms_median = 0;                 // Consider only
  double render_ms_median = 0;                   // CPU lumigraph render per test view
  size_t store_views = 0, store_bytes = 0, geometry_bytes = 0, planner_bytes = 0;
  size_t accepted = 0;
  size_t max_refs = 0;                           // largest |R(b_k)| the renderer was given
  double tau_sum = 0;                            // τ_sum of the selection (final proxy, see .cc)
  double mean_refs = 0;                          // mean |R(b_k)| over cells with references
  double plan_cpu_ms_median = 0, plan_cpu_ms_p95 = 0;  // thread CPU ms of plan (online only)
  // Process CPU ms per input frame of integrate (TSDF integrate on its worker threads + dirty
  // extraction + cell areas; the cell-id LOD update excluded, as in integrate_ms_*).
  double integrate_cpu_ms_median = 0, integrate_cpu_ms_p95 = 0;
  size_t proxy_triangles = 0;                    // triangles of the final proxy mesh
  // Online: the stream's depth disagreement 1 and 15 frames apart (planning/stream_drift.h; 0
  // when not measured) and the time term's final scale.
  double drift_near = 0, drift_far = 0, time_scale = 1;
  std::string test_poses;                        // label of the test pose set ("scene", ...)
  std::vector<int> selected;                     // stored input frame indices (stream order)
  // Online policy: digests of the core's model (server/core ModelDigest), the same values the
  // server publishes as stats counters "geometry.digest" / "planning.digest" for the same frames.
  uint64_t model_digest = 0, geometry_digest = 0, planner_digest = 0;
  // Per test view (only with per_view diagnostics on): SSIM; distance (m), angle between the
  // optical axes (deg) and stream index of the nearest stored view; the fraction of the view's
  // cell-id pixels whose R(b_k) contains that nearest view.
  // per_view_coverage: the fraction of the view's pixels the blend covered (before the hole fill).
  std::vector<double> per_view_ssim, per_view_coverage, per_view_near_m, per_view_near_deg, per_view_near_frame,
      per_view_ref_hit;
  std::string json;                              // the printed line
};

// Where synthetic test poses come from.
enum class TestPoseMode {
  kSceneWide,      // synth::MakeTestPoses: anywhere in the navigable region, eye level and
                   // elevated, >= 90 % geometry in view (independent of the input trajectory)
  kNearTrajectory  // a random input pose moved by up to 10 % of the scene diameter (horizontal),
                   // +-2 m / +-0.3 m vertical (fly-over / walk), yaw +-45 deg, pitch +-10 deg,
                   // free space and >= 90 % geometry in view: novel views in the input's range
};

// How d_max and σ of (3.11) are chosen (the cell size always follows scene_scale.h).
enum class ScaleMode {
  kBounds,     // server/geometry/scene_scale.h: d_max = clamp(0.15 D, 1, 50), σ = clamp(0.2 D, .5, 50)
  kViewDepth,  // PlannerOptions::ForScene: d_max = median valid depth of the first frame (the
               // distance the operator actually views the surface from), σ = max(d_max, 0.1 D)
  kServer      // the server's rule, core::ChooseSceneSetup on the first frame: as kViewDepth, but
               // D (hence the cell size and σ) from the first frame's fused surface, not the scene
               // bounds. The 7-Scenes path always uses ChooseSceneSetup, so there it = kViewDepth.
};
// "bounds" | "depth" | "server"; false for another name.
bool ParseScaleMode(std::string_view name, ScaleMode* out);
const char* ScaleModeName(ScaleMode m);

// Where ψ_vis (3.12) of a frame comes from.
enum class CellIdSource {
  kProxy,      // a render of the current proxy (planning::CellIdRenderer, SPEC §4 as written)
  kFrameDepth  // the frame's own depth, back-projected (the server's default, planning_stage.cc)
};
const char* CellIdSourceName(CellIdSource s);

struct SynthRunOptions {
  std::string scene = "village";   // village | apartment
  std::string traj = "flyover";    // flyover | walk | drone | handheld (issue 22)
  int frames = 600;
  // drone / handheld: the stream's seed (synth::TrajectoryOptions::seed); < 0: scene_seed.
  int64_t traj_seed = -1;
  ProxyKind proxy = ProxyKind::kTsdf;
  double voxel_m = 0;              // 0: scene diameter / 640 clamped to [0.02, 0.12]
  int id_width = 160, id_height = 120;   // cell-id buffer resolution
  int frame_width = 640, frame_height = 480;
  int test_views = 200, test_width = 320, test_height = 240;
  uint64_t test_seed = 7;
  // synth::SceneOptions::seed: furniture / house placement and textures (1 = the scene of every
  // earlier run). Independent input replicates of the same protocol; a seed other than 1 is
  // appended to the JSON dataset name ("apartment/walk/seed2").
  uint64_t scene_seed = 1;
  TestPoseMode test_pose_mode = TestPoseMode::kSceneWide;
  // Several test pose sets evaluated on the same stream and stores (one JSON line per config and
  // set); empty = {test_pose_mode}.
  std::vector<TestPoseMode> test_pose_modes;
  double walk_look_around_deg = -1;  // walk yaw-sweep amplitude; < 0: synth's default (20 deg)
  bool per_view = false;             // per-test-view diagnostics in the JSON (ConfigResult)
  ScaleMode scale_mode = ScaleMode::kBounds;
  // Cell-id buffers (planning::CellIdRenderer) from a vertex-clustered LOD of the proxy
  // (planning::ClusterSimplify) with clusters of this fraction of the cell size; 0 = the full
  // TSDF mesh; < 0 (default) = planning::DefaultCellIdLodM (0.5 x cell, at most 4 x voxel).
  double cellid_lod_frac = -1;
  // > 0: cell-id LOD cluster size in metres, wins over cellid_lod_frac (a LOD held fixed while
  // the voxel size is swept).
  double cellid_lod_m = 0;
  // A chunk keeps its cell-id LOD while its triangle count stays within this fraction of the
  // count the LOD was built from (planning::CellIdRendererOptions::lod_keep_fraction; 0 = rebuild
  // for every new chunk version). Village 200 frames: 0.1 cuts planning CPU 14.0 -> 10.2 ms at
  // -0.0006 MSSIM (docs/evaluation.md).
  double cellid_lod_keep = 0.1;
  // ψ_vis from the frame's depth (the server's default; since session 4) or a proxy render.
  CellIdSource cell_ids = CellIdSource::kFrameDepth;
  blend::BlendOptions blend;       // lambda is overridden per config
  bool vertex_color_baseline = true;
  std::vector<PolicyConfig> configs;
  // Called with each JSON line as soon as it is ready (may be empty).
  std::function<void(const std::string&)> emit;
  // Directory to write render/GT/coverage PNGs of the first test views of the first config
  // ("" = none), and how many.
  std::string dump_dir;
  int dump_views = 0;
  absl::Status Validate() const;
};

absl::StatusOr<std::vector<ConfigResult>> RunSynthetic(const SynthRunOptions& options);

struct SevenScenesRunOptions {
  std::string dir;                 // .../7scenes-redkitchen
  int max_frames = 0;              // 0 = all
  int hold_out_every = 10;
  // Frame i is held out when i % hold_out_every == holdout_offset (issue 15: the ten folds
  // j = 0..9); < 0: hold_out_every - 1 (frames 9, 19, ..., the split of every earlier run).
  int holdout_offset = -1;
  // Depth registered to colour (common/datasets rgbd_registration; colour camera K and pose).
  bool register_depth = true;
  double voxel_m = 0;              // 0: the online model's rule (server/core ChooseSceneSetup)
  double max_depth_m = 4.0;
  int id_width = 160, id_height = 120;
  int test_width = 640, test_height = 480;
  // Ground truth at a reduced test size: false = nearest sample (the eval's historical smoke
  // resample), true = box average over the integer factor (what tools/product_eval compares
  // against: the anti-aliased reference).
  bool test_box = false;
  ScaleMode scale_mode = ScaleMode::kViewDepth;
  double cellid_lod_frac = -1;     // see SynthRunOptions
  double cellid_lod_m = 0;         // see SynthRunOptions
  double cellid_lod_keep = 0.1;    // see SynthRunOptions
  CellIdSource cell_ids = CellIdSource::kFrameDepth;  // see SynthRunOptions
  bool per_view = false;           // see SynthRunOptions
  blend::BlendOptions blend;
  bool vertex_color_baseline = true;
  std::vector<PolicyConfig> configs;
  std::function<void(const std::string&)> emit;
  std::string dump_dir;
  int dump_views = 0;
};

struct SevenScenesReport {
  std::vector<ConfigResult> results;
  int held_out = 0;             // every hold_out_every-th frame
  int dropped_duplicates = 0;   // held-out frames whose colour is byte-identical to an input frame
  int ingested = 0;
};
absl::StatusOr<SevenScenesReport> RunSevenScenes(const SevenScenesRunOptions& options);

}  // namespace exo::eval
