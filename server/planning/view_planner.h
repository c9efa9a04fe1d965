// Online view planning in bounded memory (SPEC §4, thesis §3.1.2 and §3.1.4): decides for each
// incoming frame whether it enters the view store, which stored view it replaces when the store
// is full (bounded by view count AND bytes), and maintains per-cell reference lists R(b_k) of at
// most R_max views, the pre-selection a render client blends from.
//
// Bookkeeping (everything incremental, only the cells a candidate sees are touched):
//   per stored view i: its cells k with φ(F_i, b_k) > 0 (observe_zero_coverage: every cell it
//     sees, φ = 0 included), φ frozen when the view was accepted (the directional term depends
//     on R(b_k) at that time, as in the thesis);
//   per cell k: τ(F, b_k) = Σ_i φ(F_i, b_k) (3.15), the observers (views with φ > 0), R(b_k);
//   τ_sum(F) = Σ_k min(τ(F, b_k), τ_max) (3.16), kept as a running sum.
// Candidate test: accept iff τ_sum(F ∪ I) > τ_sum(F) + Δτ_sum. When full, every stored view is
// evaluated as a victim exactly (τ_sum(F ∪ I \ F_i) in O(|cells of F_i|) from a dense cell table;
// cheap enough that no "lowest-ranked" shortlist is needed: the shortlist of the thesis is the
// whole store); several victims are removed if the candidate needs more bytes than one frees.
// Pre-selection (§3.1.4): I joins R(b_k) when R has room (Δτ = 0) or replaces the reference with
// the smallest φ when φ_I - φ_v > Δτ. R(b_k) is always the pre-selection replayed over the views
// STORED NOW, in acceptance order (each φ against the references chosen before it): when a view
// leaves the store, the R(b_k) of its cells are rebuilt that way, so R does not depend on views
// that were evicted (patching the hole with the best remaining observer instead keeps
// references whose φ was judged against views long gone; measured in docs/evaluation.md).
#pragma once

#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include <glm/glm.hpp>

#include "common/camera.h"
#include "common/cells.h"
#include "common/image.h"
#include "common/lumigraph/model.h"
#include "common/rigid3.h"
#include "common/state_io.h"
#include "common/status.h"
#include "server/planning/online_baselines.h"

namespace exo::planning {

const char* PolicyName(int policy);  // PlannerOptions::Policy: "lumigraph", "min_distance", ...

struct PlannerOptions {
  int r_max = 16;                    // |R(b_k)| <= R_max; >= 2 (erratum 2)
  size_t max_views = 200;            // store capacity, views
  size_t max_bytes = size_t{1} << 30;  // store capacity, bytes (colour + depth + header)
  double lambda = 0.5;               // (3.6) directional vs positional
  double d_max_m = 2.0;              // ideal view distance of (3.11)
  double sigma_m = 2.0;              // σ of (3.11)
  double tau_max = 4.0;              // per-cell clamp of (3.16)
  double delta_tau_sum = 0.05;       // Δτ_sum: minimum gain for a candidate
  double delta_tau = 0.0;            // Δτ: minimum per-cell gain to replace a reference when full
  double cell_size_m = 0.5;          // q
  // The per-cell view references the clients render with ("published references"). 0: R(b_k)
  // itself (|R| <= r_max, the thesis' pre-selection). N > 0: every stored observer of the cell
  // (every stored view with φ > 0 there), at most max(N, r_max): R(b_k) first, then the other
  // observers by farthest-point sampling of their camera centres (spread over where the
  // cameras were). Issue 15: on real 7-Scenes data the R_max = 16 cap was the cause of "more
  // views hurt" (the stored frame next to a novel pose was often not among a cell's 16);
  // rendering every observer gains +0.04..+0.13 SSIM and makes quality grow with the store
  // (docs/evaluation.md). The planner's own objective τ still uses R(b_k) only.
  int render_refs_max = 64;
  // Issue 22: (3.6) as printed, φ = λ φ_d + (1 - λ) φ_p, credits the positional term of a view
  // that duplicates a reference (same place and direction, φ_d = 0), so a hovering or standing
  // camera fills the store with copies of one pose (docs/planning.md, "Issue 22"). true:
  // φ = φ_d (λ + (1 - λ) φ_p): the positional term counts in proportion to the view's directional
  // novelty (a cell's first view unchanged, a duplicate 0). false = the thesis' form.
  bool novelty_positional = false;
  // Saturation of a cell's τ in τ_sum (3.16). false: the thesis' hard clamp min(τ, τ_max).
  // true: S(τ) = τ_max (1 - exp(-τ / τ_max)), the same slope at 0 and the same ceiling, but
  // strictly increasing: a view over already saturated cells still has a (small) value, so the
  // victim search and the acceptance test do not meet exact ties (with the clamp every view
  // over saturated cells costs 0 to remove, and the oldest such view went first) and coverage
  // keeps spreading over the cells with the fewest observations (issue 15 / 22).
  bool soft_saturation = false;
  // Issue 15 / 22: pose dispersion. kTies: coverage first, pose dispersion among ties. The thesis' τ_sum saturates
  // (τ_max): once the cells are covered, every view over saturated cells costs 0 to remove and
  // a new view gains 0, so the store stops following the camera (ties went to the oldest view)
  // and its views bunch where the camera hovered. kTies:
  //  - victim ties (equal τ loss) go to the most redundant view: the smallest pose distance to
  //    its nearest neighbour in the store (the candidate included);
  //  - a candidate without enough coverage gain is still stored when it does not lose coverage
  //    and is farther from its nearest stored view than the victim is from its own: a full store
  //    then spreads over the camera poses like the min-distance policy, without giving up a
  //    cell's only views; while the store has room, a candidate that is not a duplicate of a
  //    stored pose (pose distance > dispersion_min) is stored.
  // Pose distance = |Δt| + m_per_rad · angle (dispersion_m_per_rad; 0: d_max_m, so a turn
  // counts as the displacement it causes at the typical viewing distance).
  // kFirst reverses the order: a full store keeps the min-distance rule (the candidate replaces
  // the most redundant view when it is farther from its nearest stored view than that view is
  // from its own), restricted to victims whose removal loses at most dispersion_guard of τ_sum
  // (so a cell's only views stay), and a candidate whose net τ gain exceeds dispersion_guard is
  // stored as well (new surface), replacing that same most redundant view.
  enum class Dispersion { kOff = 0, kTies = 1, kFirst = 2 };
  Dispersion dispersion = Dispersion::kOff;
  double dispersion_m_per_rad = 0.0;
  // dispersion_m_per_rad = 0: the turn's weight is this fraction of d_max_m (1: a turn counts as
  // the displacement it causes at the typical viewing distance). A turn about the camera centre
  // adds no parallax (the stored rays through the centre stay exact for every surface point both
  // views see): it only changes what is in view, which the other stored views fill; a displacement
  // does both. (0, 1] (docs/planning.md "Session 15").
  double dispersion_rotation_scale = 1.0;
  // > 0: a turn counts at dispersion_turn_overlap_scale of its weight up to this angle φ
  // (radians) and at its full weight beyond: turn(θ) = s·min(θ, φ) + max(0, θ − φ), × the metres
  // per radian above. Two views turned by less than about half the field of view still share
  // most of what they see, so one can stand in for the other's coverage and the store keeps
  // places rather than orientations; a turn beyond it brings other surfaces into view and costs
  // what it did. 0 = off (docs/planning.md "Session 16").
  double dispersion_turn_overlap_rad = 0.0;
  double dispersion_turn_overlap_scale = 0.5;  // s in (0, 1]
  // true: the turn between two views is the angle between their optical axes (camera +z) instead
  // of the full rotation angle: a roll about the axis keeps every ray the view holds (the image
  // only turns), so it does not make a view novel. A drone looking down at pitch p that yaws by
  // θ turns its axis by about θ cos p (and rolls its image by θ sin p): its pans count less the
  // steeper it looks down; a level camera's yaw counts in full (docs/planning.md "Session 16").
  bool dispersion_turn_axis = false;
  double dispersion_guard = 0.5;  // τ units (kFirst)
  // > 0: the guard is this fraction of the mean τ per stored view (τ_sum / n) instead.
  double dispersion_guard_relative = 0.0;
  // kFirst: what the guard measures. false: the τ_sum a removal loses, from the φ frozen at
  // acceptance. A cell's first view holds its φ_d = 1 and later views from nearby hold ~0, so
  // removing a view that first saw some cells "loses" them although other stored views still
  // see them; on a long stream nearly every view then exceeds the guard and the store keeps the
  // stream's first sightings instead of spreading (docs/planning.md, "Session 11"). true:
  // unique coverage: a removal loses only the cells it would leave with no stored observer (the
  // candidate counted), each valued at the φ the view would have as the cell's only view; a
  // candidate's gain is its φ over the cells no stored view observes.
  bool dispersion_guard_unique = false;
  // > 0: the unique-coverage guard from the moment the planner has been offered more than this
  // many candidates per view of capacity (max_views), the frozen-τ guard before. The frozen φ
  // describe the store while most of the references they were judged against are still stored
  // (short streams: the ten 7-Scenes folds offer <= 5.4 frames per view and the frozen-τ guard
  // wins there); on a long stream they are stale (docs/planning.md, "Session 11").
  double dispersion_guard_unique_after = 0.0;
  double dispersion_min = 1e-3;  // pose-distance units (m)
  // Density-weighted dispersion (kFirst / kTies; β = this option in [0, 0.95]; 0 = off, the
  // min-distance redundancy above). Each stored view carries a weight w = the number of stream
  // frames it stands for: 1 when stored, plus every candidate that is not stored (added to its
  // nearest stored view by pose distance) and the weight of every view evicted (added to its
  // nearest view left in the store); the weights sum to the candidates offered. w / d1 (d1 =
  // distance to the nearest stored view) estimates the frame density ρ around a view, and the
  // redundancy of a view becomes d1 × ρ^β = w^β d1^(1-β); a candidate's is its distance to its
  // nearest stored view u times ρ_u^β (it would stand for frames of u's neighbourhood). The
  // victim is the view of smallest redundancy and the candidate is stored when its own is
  // larger, so spacing × ρ^β evens out: the stored point density follows ρ^β, between
  // min-distance (β = 0: uniform over the poses) and every-N (β = 1: the time density of the
  // stream) — a place where the camera lingered keeps more views than one it passed once, and
  // held-out frames of the same stream fall where it lingered (issue 15 / 22). Quantisation
  // theory: the mean distance to the nearest stored view is smallest at β = D / (D + 1) for
  // poses of dimension D.
  double dispersion_weight_exponent = 0.0;
  // > 0: the density-weighted redundancy only once the planner has been offered more than this
  // many candidates per view of capacity (the weights are kept from the start); the plain
  // distance before. Ten 7-Scenes folds: the weighting wins at 10.8 frames per view (store 25)
  // and loses at 5.6 and 2.8 (stores 48, 95; docs/planning.md "Session 12").
  double dispersion_weight_after = 0.0;
  // > 0: the density-weighted redundancy only until the planner has been offered this many
  // candidates per view of capacity (must exceed dispersion_weight_after); the plain distance
  // after (the weights are still kept). 0: no end (docs/planning.md "Session 13").
  double dispersion_weight_until = 0.0;
  // kFirst / kTies: between views of equal redundancy (the two views of the store's closest
  // pair), the candidate's nearest stored view stays and the other leaves (the min-distance
  // baseline's rule); false: the one in the more crowded place leaves (second-neighbour
  // distance, the candidate counted). Diagnostic for the long drone stream (docs/planning.md
  // "Session 13").
  bool dispersion_keep_nearest = false;
  // kFirst / kTies, store full: the candidate replaces the most redundant view when its own
  // redundancy exceeds (1 - dispersion_recency) x the victim's (0: strictly larger, the
  // min-distance rule). Near-ties then go to the newer frame. In [0, 0.5] (docs/planning.md
  // "Session 14").
  double dispersion_recency = 0.0;
  // kFirst / kTies: between views of equal redundancy (the two views of the store's closest
  // pair) the older one (smaller id: the server numbers frames in arrival order) leaves, before
  // the keep-nearest and crowding rules (docs/planning.md "Session 14").
  bool dispersion_drop_older = false;
  // kFirst / kTies: time as a dimension of the dispersion's pose distance. Two views are apart
  // by their pose distance plus κ × |id_a − id_b| × s, s = the stream's mean pose step per frame
  // id so far (the server numbers frames in arrival order; each step capped at d_max_m), κ =
  // this option: two frames of a camera that lingers in one place are as far apart as κ times
  // the camera's typical motion over that time, so a lingering stretch keeps views spread over
  // its time, and a place revisited later is not a plain duplicate of the first visit. Real
  // poses and images carry errors correlated in time (pose drift, exposure, blur), so a
  // held-out 7-Scenes frame is rendered best from its neighbours in time, not only in pose
  // (docs/planning.md "Session 15"). Scale-free: s is measured, not set. 0 = pose only.
  double dispersion_time_steps = 0.0;
  // true: the larger of the pose distance and the time term instead of their sum, so frames of a
  // camera moving faster than κ·s are apart by their pose distance alone (the default's spread)
  // and only frames where the camera lingered are set apart by time.
  bool dispersion_time_max = false;
  // The time term's clock (session 16). false: frame ids (κ × |id_a − id_b| × s). true: the
  // camera's travelled pose path, κ × |arc_a − arc_b| with arc = the running sum of the pose
  // steps between consecutive candidates (each capped at d_max_m): frames of a camera that stands
  // perfectly still are apart by nothing (a synthetic stream's stop repeats one image), while a
  // hand-held camera that dwells keeps moving by its shake and pose noise (7-Scenes: ~1° per
  // frame, 30° summed over 30 frames against 3–19° net), so there the clock runs as time does.
  // Scale-free like the id clock: no s to measure.
  bool dispersion_time_arc = false;
  // The time term follows the stream's measured time-correlated error (session 16): > 0, the
  // effective κ is dispersion_time_steps × a scale the caller measures and sets (SetTimeScale;
  // core::OnlinePlanner: StreamDrift::TimeScale(this), 0 while the growth g of the stream's
  // depth disagreement from 1 to 15 frames apart is below half this, 1 from this on); until a
  // measurement arrives the time term is off. 0 = κ as set.
  double dispersion_time_auto_ref = 0.0;
  // Which stored views observe a cell (its published references when render_refs_max > 0, the
  // unique-coverage guard's count, the views R(b_k) is rebuilt from). false: the views with
  // φ > 0 at acceptance. A frame whose direction to the cell duplicates a reference's (a yaw
  // pan turns on one centre: every frame after the first gets φ_d = 0 on the cells the first
  // saw) then never observes those cells, even after the reference has left: the renderer
  // cannot use it there, and R(b_k) is not the pre-selection replayed over the stored views.
  // true: every cell the view sees (ψ_vis > 0, the camera outside it) is observed, at φ = 0
  // where φ is 0; τ and the acceptance test are unchanged (docs/planning.md "Session 14").
  bool observe_zero_coverage = false;

  // Which frames the store keeps (issues 15 / 22). kCoverage: the planner's own rules above.
  // The others are the online baselines of online_baselines.h deciding from the camera poses
  // alone (each frame offered once, in stream order); the planner then keeps its bookkeeping
  // and reference pre-selection for the views the baseline keeps, so a client renders a
  // baseline's store exactly as it renders the planner's, and the product path can measure
  // (or, for a stream type where a baseline wins, run) it. The view count bounds these stores;
  // a frame over the byte budget is not kept. Views a baseline drops while it does not keep the
  // frame (progressive every-N's thinning) leave with its next kept frame.
  //   kMinDistance: the closest stored pair loses a member to a frame farther from its nearest
  //     stored view (pose distance |Δt| + baseline_m_per_rad × angle);
  //   kEveryN: the length-aware oracle: baseline_stream_frames frames expected, min(L, capacity)
  //     of them kept evenly (frame k iff k = floor(j L / m));
  //   kEveryNOnline: progressive every-N (N doubles and every other view leaves when full).
  enum class Policy { kCoverage = 0, kMinDistance = 1, kEveryN = 2, kEveryNOnline = 3 };
  Policy policy = Policy::kCoverage;
  double baseline_m_per_rad = 1.0;
  int64_t baseline_stream_frames = 0;

  absl::Status Validate() const;

  // Defaults derived from the observed scene (SPEC §4: "cell size and d_max derived from the
  // observed scene, not hard-coded"): q = diameter/40 clamped to [0.3, 1.0] m (thesis: 30-100 cm
  // were best), d_max = the median camera-to-surface distance seen so far, σ = max(d_max, 0.1 ·
  // diameter).
  static PlannerOptions ForScene(double scene_diameter_m, double median_view_distance_m);
};

struct CellPixelCount {
  CellId cell = kNoCell;
  uint32_t pixels = 0;  // ψ_vis (3.12)
};

// Counts the pixels per cell of a cell-id buffer (kNoCell = background, ignored). Order: by
// first appearance. Works on any resolution; pair it with the camera of that resolution.
std::vector<CellPixelCount> CountCellPixels(const uint64_t* cell_ids, size_t count);

// ψ_vis from the frame's own depth instead of a render of the proxy: the centre pixel of every
// `stride` x `stride` block of `depth_m` is back-projected (local_from_depth) and labelled with
// its cell (invalid depth: background). The counts refer to `*id_camera` = depth_camera scaled to
// the block grid. Unlike a proxy render it does not depend on how much of the scene is fused yet.
// Errors: stride < 1 or larger than the image, depth size != camera size.
absl::StatusOr<std::vector<CellPixelCount>> CountDepthCellPixels(
    const ImageF& depth_m, const PinholeCamera& depth_camera, const Rigid3d& local_from_depth,
    const CellGrid& grid, int stride, PinholeCamera* id_camera);

struct Candidate {
  ViewId id = 0;
  Rigid3d local_from_cam;             // pose in the scene-local frame (double)
  PinholeCamera id_camera;            // intrinsics of the cell-id buffer that produced the counts:
                                      // A_px = id_camera.PixelSolidAngle() (reduced res ok)
  std::vector<CellPixelCount> cells;  // ψ_vis per visible cell
  size_t bytes = 0;                   // what storing this frame costs (StoredView::bytes())
  // Image quality of the frame in (0, 1] (e.g. FrameQuality's relative sharpness: a motion-
  // blurred frame < 1): every φ of the view is multiplied by it, so a blurred frame covers less
  // and a sharp one of the same place replaces it. 1 = the thesis' planner.
  double quality = 1.0;
  // A stored view offered again after a restart (core::OnlinePlanner::Readmit): a baseline
  // policy keeps it while it has room instead of counting it as a new frame of the stream.
  bool readmit = false;
};

struct Decision {
  bool accepted = false;
  std::string reason;                 // why (for logs / acks)
  double gain = 0.0;                  // τ_sum(after) - τ_sum(before), as evaluated
  std::vector<ViewId> removed;        // victims evicted to make room
  std::vector<CellId> changed_cells;  // cells whose published references changed (publisher
                                      // deltas: R(b_k), or the observers when
                                      // render_refs_max > 0), sorted
  double tau_sum = 0.0;               // τ_sum of the store after the decision
};

class ViewPlanner {
 public:
  // Options must be valid (use Create).
  static absl::StatusOr<ViewPlanner> Create(const PlannerOptions& options);

  // Evaluates one candidate frame and updates the store. Bad input (NaN pose, invalid camera,
  // duplicate id) is an error and changes nothing; a frame larger than the byte budget is a
  // rejection with a reason.
  absl::StatusOr<Decision> Consider(const Candidate& candidate);

  // Per-cell surface area A(b_k) from the proxy (geometry's CellAreas). Cells without a known
  // area use the face area A_cell (the upper bound of 3.13). Negative/NaN areas are an error.
  absl::Status SetCellArea(CellId cell, double area_m2);

  // Removes a stored view from outside the planner (e.g. refinement flagged it as a pose
  // outlier): its coverage leaves τ, references to it are refilled from the remaining observers.
  // Returns the cells whose R(b_k) changed (sorted); NotFound for an unknown id.
  absl::StatusOr<std::vector<CellId>> Remove(ViewId id);

  // The coverage φ(I, b_k) a candidate camera at `cam_centre_local` would get for `cell` with
  // `pixels` visible pixels of solid angle `pixel_sr`, against the current R(b_k). 0 for a
  // camera inside the cell (guard d -> 0). Exposed for tests and tools.
  double CoverageOf(const glm::dvec3& cam_centre_local, CellId cell, double pixels,
                    double pixel_sr, double quality = 1.0) const;

  const PlannerOptions& options() const { return options_; }
  const CellGrid& grid() const { return grid_; }
  double tau_sum() const { return tau_sum_; }
  size_t num_views() const { return views_.size(); }
  size_t bytes() const { return bytes_; }
  size_t num_cells() const { return cells_.size(); }
  bool HasView(ViewId id) const { return views_.count(id) > 0; }
  std::vector<ViewId> ViewIds() const;
  // τ(F, b_k) of a cell (0 if unknown), and R(b_k) (empty if unknown).
  double CellTau(CellId cell) const;
  std::vector<ViewId> Refs(CellId cell) const;
  // τ_sum recomputed from scratch from the stored per-view φ (for tests / drift checks).
  double RecomputeTauSum() const;
  // Every non-empty R(b_k).
  std::unordered_map<CellId, std::vector<ViewId>> CellRefs() const;
  // The references clients render with (options().render_refs_max): R(b_k) first, then other
  // observers; empty if the cell is unknown. Deterministic.
  std::vector<ViewId> PublishedRefs(CellId cell) const;
  // Every non-empty published list, e.g. to fill LumigraphModel::cell_refs.
  std::unordered_map<CellId, std::vector<ViewId>> CellPublishedRefs() const;
  // Approximate memory of the planner's own bookkeeping (bytes).
  size_t BookkeepingBytes() const;
  // The weight of a stored view (PlannerOptions::dispersion_weight_exponent > 0 with dispersion
  // on: the stream frames it stands for; otherwise 1); 0 if not stored.
  double ViewWeight(ViewId id) const;

  // Everything the planner decides from (views, cells, τ, areas, dispersion neighbours), for the
  // server's checkpoint (common/state_io.h); LoadState into a planner made with the same options
  // replaces it (error: truncated / corrupt state, nothing usable).
  void SaveState(StateWriter* w) const;
  // dispersion_time_auto_ref: the measured scale of the time term, in [0, 1] (clamped).
  void SetTimeScale(double scale);
  double time_scale() const { return time_scale_; }
  absl::Status LoadState(StateReader* r);

 private:
  explicit ViewPlanner(const PlannerOptions& options);

  struct Ref {
    ViewId view;
    float phi;
    glm::dvec3 dir;      // unit vector cell centre -> camera
    uint32_t pixels = 0; // ψ_vis
    double d = 0;        // |camera - cell centre|
    double g = 0;        // distance quality (3.11) at d
    double pixel_sr = 0; // A_px of the view's cell-id buffer
    double quality = 1;  // Candidate::quality
  };
  struct Cell {
    CellId id = kNoCell;
    double tau = 0.0;
    std::vector<Ref> observers;  // every stored view with φ > 0 for this cell
    std::vector<Ref> refs;       // R(b_k) ⊆ observers, |refs| <= r_max
  };
  struct Entry {
    int32_t cell;  // index into cells_
    float phi;
  };
  struct View {
    ViewId id;
    glm::dvec3 centre;
    glm::dquat rotation;
    size_t bytes;
    double pixel_sr = 0;            // A_px of the candidate's cell-id buffer
    double quality = 1;             // Candidate::quality
    std::vector<Entry> entries;
    std::vector<uint32_t> pixels;   // ψ_vis per entry (copied into the cell's Ref by AddView)
    double weight = 1.0;            // stream frames it stands for (dispersion_weight_exponent)
    double arc = 0.0;               // the travelled pose path at its arrival (dispersion_time_arc)
  };
  // An accepted decision's end: the stale cells' R(b_k) rebuilt (the candidate already added),
  // the victims and the changed cells (sorted, unique) recorded, τ_sum.
  void FinishAccepted(const std::vector<int32_t>& stale, std::vector<ViewId> victims, Decision* d);
  // A baseline policy's decision (PlannerOptions::policy != kCoverage) for a validated view.
  Decision ConsiderBaseline(const Candidate& cand, View view);
  std::unique_ptr<OnlineSelector> selector_;  // null for kCoverage
  double AreaOf(CellId cell) const;  // A(b_k), or A_cell when unknown
  // A cell's contribution to τ_sum: min(τ, τ_max), or the soft form (soft_saturation).
  double Sat(double tau) const;
  // φ_p (3.13-3.14) of a view at distance d with distance quality g and ψ_vis = pixels.
  double PositionalPart(double area_m2, double d, double g, double pixels, double pixel_sr) const;
  // φ of (3.6), or its novelty-weighted form (PlannerOptions::novelty_positional).
  double Phi(double phi_d, double phi_p) const;
  // The camera can observe the cell (not inside it): observe_zero_coverage.
  bool Observes(const glm::dvec3& cam, CellId cell) const;
  // Replays the pre-selection over the cell's current observers in acceptance order;
  // true if the set of references changed.
  bool RebuildRefs(int32_t cell);

  int32_t CellIndex(CellId id);  // creates the cell on first use
  void AddToCellTau(int32_t cell, double dphi);
  // Removes the view's coverage and observer entries; the cells whose R(b_k) lost it are appended
  // to `stale` (rebuild them with RebuildRefs once the store is final), every cell it observed to
  // `observed` when the published references are the observers.
  void RemoveView(ViewId id, std::vector<int32_t>* stale, std::vector<CellId>* observed);
  std::vector<ViewId> PublishedRefsOf(const Cell& c) const;
  void AddView(View view, std::vector<CellId>* changed);

  PlannerOptions options_;
  CellGrid grid_;
  double tau_sum_ = 0.0;
  size_t bytes_ = 0;
  std::unordered_map<ViewId, View> views_;
  std::unordered_map<CellId, int32_t> cell_index_;
  std::vector<Cell> cells_;
  std::unordered_map<CellId, double> areas_;
  std::vector<double> scratch_;      // per-cell pending τ change during victim search
  // Pose dispersion (options_.dispersion): each stored view's nearest and second-nearest other
  // stored view, kept up to date incrementally (O(n) per added view; a removal recomputes only
  // the views whose neighbour it was).
  double PoseDistance(const glm::dvec3& ca, const glm::dquat& qa, const glm::dvec3& cb,
                      const glm::dquat& qb) const;
  // A turn of `angle` radians in radians of full weight (dispersion_turn_overlap_rad).
  double TurnWeight(double angle) const;
  // ... plus the time term (dispersion_time_steps): the distance the dispersion rules use.
  double ViewDistance(const glm::dvec3& ca, const glm::dquat& qa, ViewId ida, double arca,
                      const glm::dvec3& cb, const glm::dquat& qb, ViewId idb, double arcb) const;
  double ViewDistance(const View& a, const View& b) const {
    return ViewDistance(a.centre, a.rotation, a.id, a.arc, b.centre, b.rotation, b.id, b.arc);
  }
  struct Nearest {
    double d1, d2;     // distances to the nearest and second-nearest other stored view
    ViewId id1, id2;   // those views (0 when none)
    void Offer(double d, ViewId id);
  };
  Nearest NearestOf(const View& v) const;  // from scratch, O(n)
  void NearestAdd(const View& v);          // v already in views_
  void NearestRemove(ViewId id);           // id already erased from views_
  std::unordered_map<ViewId, Nearest> nearest_;
  // dispersion_guard_unique: per-cell pending observer-count change during the victim search,
  // and the coverage a view alone holds (the cells it would leave unobserved).
  std::vector<int32_t> obs_scratch_;
  double UniqueLoss(const View& v) const;
  // Adds `weight` to the stored view nearest (pose distance) to the pose; none stored: dropped.
  void GiveWeight(const glm::dvec3& centre, const glm::dquat& rotation, ViewId id, double arc,
                  double weight);
  // A view's redundancy from its nearest-neighbour distance d1 and weight
  // (dispersion_weight_exponent β: d1 × (w / d1)^β; β = 0: d1).
  double WeightedSpacing(double d1, double weight) const;
  // The density-weighted redundancy is in force (dispersion_weight_exponent, _after).
  bool Weighted() const;
  uint64_t offered_ = 0;  // candidates that passed validation (dispersion_guard_unique_after)
  // dispersion_time_steps: the mean pose step per frame id over the valid candidates; the time
  // unit κ·s the nearest-neighbour cache was computed with (recomputed when s drifts by > 2 %).
  void TrackStep(const glm::dvec3& centre, const glm::dquat& rotation, ViewId id);
  bool has_last_ = false;
  glm::dvec3 last_centre_{0.0};
  glm::dquat last_rotation_{1.0, 0.0, 0.0, 0.0};
  ViewId last_id_ = 0;
  double step_sum_ = 0.0;
  uint64_t step_count_ = 0;
  double time_unit_ = 0.0;
  double arc_ = 0.0;  // dispersion_time_arc: the travelled pose path so far
  double time_scale_ = 1.0;  // SetTimeScale (0 until measured when dispersion_time_auto_ref > 0)
  double Kappa() const { return options_.dispersion_time_steps * time_scale_; }
  void RecomputeTimeUnit();
};

}  // namespace exo::planning
