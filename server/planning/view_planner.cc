#include "server/planning/view_planner.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numbers>

#include "server/planning/coverage.h"

namespace exo::planning {
namespace {

constexpr int kMaxRMax = 64;
constexpr int kMaxRenderRefs = 1024;
// τ losses / gains closer than this are ties (a view over saturated cells: exactly 0).
constexpr double kTie = 1e-9;

bool Finite(const glm::dvec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

}  // namespace

absl::Status PlannerOptions::Validate() const {
  if (r_max < 2)
    return absl::InvalidArgumentError(absl::StrCat(
        "planner r_max must be >= 2 (R_max <= 1 makes the Tammes bound 1 - phi_d^max zero, "
        "SPEC §4 erratum 2), got ",
        r_max));
  if (r_max > kMaxRMax)
    return absl::InvalidArgumentError(absl::StrCat("planner r_max must be <= ", kMaxRMax));
  if (render_refs_max < 0 || render_refs_max > kMaxRenderRefs)
    return absl::InvalidArgumentError(absl::StrCat(
        "planner render_refs_max must be in [0, ", kMaxRenderRefs, "], got ", render_refs_max));
  if (max_views < 1) return absl::InvalidArgumentError("planner max_views must be >= 1");
  if (policy != Policy::kCoverage && policy != Policy::kMinDistance &&
      policy != Policy::kEveryN && policy != Policy::kEveryNOnline)
    return absl::InvalidArgumentError(absl::StrCat(
        "planner policy must be 0 (lumigraph), 1 (min_distance), 2 (every_n) or 3 "
        "(every_n_online), got ", int(policy)));
  if (!std::isfinite(baseline_m_per_rad) || baseline_m_per_rad < 0.0)
    return absl::InvalidArgumentError("planner baseline_m_per_rad must be finite and >= 0");
  if (policy == Policy::kEveryN && baseline_stream_frames < 1)
    return absl::InvalidArgumentError(
        "planner policy every_n (the length-aware oracle) needs the stream's length: set "
        "baseline_stream_frames (server key planner_baseline_stream_frames) > 0");
  if (max_bytes < 1) return absl::InvalidArgumentError("planner max_bytes must be >= 1");
  if (!std::isfinite(lambda) || lambda < 0.0 || lambda > 1.0)
    return absl::InvalidArgumentError(absl::StrCat("planner lambda must be in [0,1], got ", lambda));
  if (!std::isfinite(d_max_m) || d_max_m < 0.0)
    return absl::InvalidArgumentError("planner d_max_m must be finite and >= 0");
  if (!std::isfinite(sigma_m) || sigma_m <= 0.0)
    return absl::InvalidArgumentError("planner sigma_m must be finite and > 0");
  if (!std::isfinite(tau_max) || tau_max <= 0.0)
    return absl::InvalidArgumentError("planner tau_max must be finite and > 0");
  if (!std::isfinite(delta_tau_sum) || delta_tau_sum < 0.0)
    return absl::InvalidArgumentError("planner delta_tau_sum must be finite and >= 0");
  if (!std::isfinite(delta_tau) || delta_tau < 0.0)
    return absl::InvalidArgumentError("planner delta_tau must be finite and >= 0");
  if (!std::isfinite(cell_size_m) || cell_size_m <= 0.0)
    return absl::InvalidArgumentError("planner cell_size_m must be finite and > 0");
  if (!std::isfinite(dispersion_m_per_rad) || dispersion_m_per_rad < 0.0)
    return absl::InvalidArgumentError("planner dispersion_m_per_rad must be finite and >= 0");
  if (!(dispersion_rotation_scale > 0.0 && dispersion_rotation_scale <= 1.0))
    return absl::InvalidArgumentError("planner dispersion_rotation_scale must be in (0, 1]");
  if (!(std::isfinite(dispersion_turn_overlap_rad) && dispersion_turn_overlap_rad >= 0.0 &&
        dispersion_turn_overlap_rad <= std::numbers::pi) ||
      !(dispersion_turn_overlap_scale > 0.0 && dispersion_turn_overlap_scale <= 1.0))
    return absl::InvalidArgumentError(absl::StrCat(
        "planner dispersion_turn_overlap_rad must be in [0, pi] and dispersion_turn_overlap_scale "
        "in (0, 1], got ", dispersion_turn_overlap_rad, " and ", dispersion_turn_overlap_scale));
  if (dispersion != Dispersion::kOff && dispersion != Dispersion::kTies &&
      dispersion != Dispersion::kFirst)
    return absl::InvalidArgumentError(absl::StrCat(
        "planner dispersion must be 0 (off), 1 (ties) or 2 (first), got ", int(dispersion)));
  if (!std::isfinite(dispersion_guard_relative) || dispersion_guard_relative < 0.0)
    return absl::InvalidArgumentError("planner dispersion_guard_relative must be finite and >= 0");
  if (!std::isfinite(dispersion_guard) || dispersion_guard < 0.0)
    return absl::InvalidArgumentError("planner dispersion_guard must be finite and >= 0");
  if (!std::isfinite(dispersion_guard_unique_after) || dispersion_guard_unique_after < 0.0)
    return absl::InvalidArgumentError("planner dispersion_guard_unique_after must be finite and >= 0");
  if (!std::isfinite(dispersion_min) || dispersion_min < 0.0)
    return absl::InvalidArgumentError("planner dispersion_min must be finite and >= 0");
  if (!std::isfinite(dispersion_weight_exponent) || dispersion_weight_exponent < 0.0 ||
      dispersion_weight_exponent > 0.95 || !std::isfinite(dispersion_weight_after) ||
      dispersion_weight_after < 0.0 || !std::isfinite(dispersion_weight_until) ||
      dispersion_weight_until < 0.0 ||
      (dispersion_weight_until > 0.0 && dispersion_weight_until <= dispersion_weight_after))
    return absl::InvalidArgumentError(absl::StrCat(
        "planner dispersion_weight_exponent must be in [0, 0.95], dispersion_weight_after >= 0 "
        "and dispersion_weight_until 0 or > dispersion_weight_after, got ",
        dispersion_weight_exponent, ", ", dispersion_weight_after, " and ",
        dispersion_weight_until));
  if (!std::isfinite(dispersion_recency) || dispersion_recency < 0.0 || dispersion_recency > 0.5)
    return absl::InvalidArgumentError(absl::StrCat(
        "planner dispersion_recency must be in [0, 0.5], got ", dispersion_recency));
  if (!std::isfinite(dispersion_time_steps) || dispersion_time_steps < 0.0)
    return absl::InvalidArgumentError(absl::StrCat(
        "planner dispersion_time_steps must be finite and >= 0, got ",
        dispersion_time_steps));
  if (!std::isfinite(dispersion_time_auto_ref) || dispersion_time_auto_ref < 0.0)
    return absl::InvalidArgumentError(absl::StrCat(
        "planner dispersion_time_auto_ref must be finite and >= 0, got ",
        dispersion_time_auto_ref));
  return absl::OkStatus();
}

PlannerOptions PlannerOptions::ForScene(double scene_diameter_m, double median_view_distance_m) {
  PlannerOptions o;
  if (std::isfinite(scene_diameter_m) && scene_diameter_m > 0.0)
    o.cell_size_m = std::clamp(scene_diameter_m / 40.0, 0.3, 1.0);
  if (std::isfinite(median_view_distance_m) && median_view_distance_m > 0.0)
    o.d_max_m = median_view_distance_m;
  o.sigma_m = std::max(o.d_max_m, 0.1 * (std::isfinite(scene_diameter_m) ? scene_diameter_m : 0.0));
  return o;
}

std::vector<CellPixelCount> CountCellPixels(const uint64_t* cell_ids, size_t count) {
  std::vector<CellPixelCount> out;
  std::unordered_map<CellId, uint32_t> index;
  size_t i = 0;
  while (i < count) {
    const CellId id = cell_ids[i];
    size_t j = i + 1;
    while (j < count && cell_ids[j] == id) ++j;  // runs along rows are long
    if (id != kNoCell) {
      auto [it, inserted] = index.try_emplace(id, static_cast<uint32_t>(out.size()));
      if (inserted) out.push_back({id, 0});
      out[it->second].pixels += static_cast<uint32_t>(j - i);
    }
    i = j;
  }
  return out;
}

absl::StatusOr<std::vector<CellPixelCount>> CountDepthCellPixels(
    const ImageF& depth_m, const PinholeCamera& depth_camera, const Rigid3d& local_from_depth,
    const CellGrid& grid, int stride, PinholeCamera* id_camera) {
  if (depth_m.width() != depth_camera.width || depth_m.height() != depth_camera.height)
    return absl::InvalidArgumentError(absl::StrCat("depth image ", depth_m.width(), "x",
                                                   depth_m.height(), " does not match its camera ",
                                                   depth_camera.width, "x", depth_camera.height));
  const int w = stride >= 1 ? depth_m.width() / stride : 0;
  const int h = stride >= 1 ? depth_m.height() / stride : 0;
  if (w < 1 || h < 1)
    return absl::InvalidArgumentError(absl::StrCat("cell-id stride ", stride, " does not fit a ",
                                                   depth_m.width(), "x", depth_m.height(), " depth image"));
  std::vector<uint64_t> ids(static_cast<size_t>(w) * h, kNoCell);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const int dx = x * stride + stride / 2, dy = y * stride + stride / 2;
      const float z = depth_m.at(dx, dy);
      if (!(z > 0.0f) || !std::isfinite(z)) continue;
      ids[static_cast<size_t>(y) * w + x] =
          grid.IdOf(local_from_depth * depth_camera.Unproject({dx, dy}, z));
    }
  *id_camera = depth_camera.Scaled(w, h);
  return CountCellPixels(ids.data(), ids.size());
}

const char* PolicyName(int policy) {
  switch (static_cast<PlannerOptions::Policy>(policy)) {
    case PlannerOptions::Policy::kCoverage: return "lumigraph";
    case PlannerOptions::Policy::kMinDistance: return "min_distance";
    case PlannerOptions::Policy::kEveryN: return "every_n";
    case PlannerOptions::Policy::kEveryNOnline: return "every_n_online";
  }
  return "unknown";
}

ViewPlanner::ViewPlanner(const PlannerOptions& options) : options_(options) {
  grid_.cell_size_m = options.cell_size_m;
  if (options.dispersion_time_auto_ref > 0.0) time_scale_ = 0.0;  // until measured
  switch (options.policy) {
    case PlannerOptions::Policy::kCoverage: break;
    case PlannerOptions::Policy::kMinDistance:
      selector_ = std::make_unique<MinDistanceSelector>(options.max_views, options.baseline_m_per_rad);
      break;
    case PlannerOptions::Policy::kEveryN:
      selector_ = std::make_unique<LengthAwareEveryN>(options.max_views, options.baseline_stream_frames);
      break;
    case PlannerOptions::Policy::kEveryNOnline:
      selector_ = std::make_unique<ProgressiveEveryN>(options.max_views);
      break;
  }
}

absl::StatusOr<ViewPlanner> ViewPlanner::Create(const PlannerOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  return ViewPlanner(options);
}

absl::Status ViewPlanner::SetCellArea(CellId cell, double area_m2) {
  if (!std::isfinite(area_m2) || area_m2 < 0.0)
    return absl::InvalidArgumentError(absl::StrCat("cell area must be finite and >= 0, got ", area_m2));
  areas_[cell] = area_m2;
  return absl::OkStatus();
}

int32_t ViewPlanner::CellIndex(CellId id) {
  auto [it, inserted] = cell_index_.try_emplace(id, static_cast<int32_t>(cells_.size()));
  if (inserted) {
    cells_.push_back({});
    cells_.back().id = id;
  }
  return it->second;
}

double ViewPlanner::CoverageOf(const glm::dvec3& cam, CellId cell, double pixels,
                               double pixel_sr, double quality) const {
  if (cell == kNoCell || !(pixels > 0.0) || !(pixel_sr > 0.0) || !Finite(cam)) return 0.0;
  // Guard d -> 0 (SPEC §4, §11): a camera inside the cell has no defined direction to it and
  // the 1/d^2 footprint model does not apply: it claims no coverage of that cell.
  if (grid_.CoordOf(cam) == UnpackCell(cell)) return 0.0;
  const glm::dvec3 v = cam - grid_.Centre(cell);
  const double d = glm::length(v);
  if (!(d > 0.0)) return 0.0;
  const glm::dvec3 dir = v / d;

  std::array<glm::dvec3, kMaxRMax> ref_dirs;
  size_t n_refs = 0;
  if (auto it = cell_index_.find(cell); it != cell_index_.end())
    // A reference of lower image quality than the candidate does not make the candidate's
    // direction redundant (a sharp frame is novel over a blurred one of the same direction);
    // with every quality 1 (FrameQuality off) this is the thesis' R(b_k).
    for (const Ref& r : cells_[it->second].refs)
      if (r.quality >= quality) ref_dirs[n_refs++] = r.dir;
  const double phi_d = DirectionalCoverage(
      dir, std::span<const glm::dvec3>(ref_dirs.data(), n_refs), options_.r_max);
  const double g = DistanceQuality(d, options_.d_max_m, options_.sigma_m);
  return quality * Phi(phi_d, PositionalPart(AreaOf(cell), d, g, pixels, pixel_sr));
}

bool ViewPlanner::Observes(const glm::dvec3& cam, CellId cell) const {
  // CoverageOf's guards: a camera inside the cell has no direction to it.
  if (cell == kNoCell || !Finite(cam) || grid_.CoordOf(cam) == UnpackCell(cell)) return false;
  return glm::length(cam - grid_.Centre(cell)) > 0.0;
}

double ViewPlanner::Phi(double phi_d, double phi_p) const {
  if (options_.novelty_positional) return phi_d * Coverage(options_.lambda, 1.0, phi_p);
  return Coverage(options_.lambda, phi_d, phi_p);
}

double ViewPlanner::Sat(double tau) const {
  const double m = options_.tau_max;
  if (!options_.soft_saturation) return std::min(tau, m);
  return m * -std::expm1(-std::max(tau, 0.0) / m);
}

double ViewPlanner::AreaOf(CellId cell) const {
  const auto it = areas_.find(cell);
  return it != areas_.end() ? it->second : grid_.CellArea();
}

double ViewPlanner::PositionalPart(double area_m2, double d, double g, double pixels,
                                   double pixel_sr) const {
  const double psi_total = PsiTotal(area_m2, grid_.CellArea(), d, pixel_sr, 0.5 * grid_.cell_size_m);
  return PositionalCoverage(g, pixels, psi_total);
}

void ViewPlanner::AddToCellTau(int32_t cell, double dphi) {
  Cell& c = cells_[cell];
  const double old_clamped = Sat(c.tau);
  c.tau += dphi;
  if (c.observers.empty()) c.tau = 0.0;  // no drift once a cell is unobserved again
  tau_sum_ += Sat(c.tau) - old_clamped;
}

void ViewPlanner::AddView(View view, std::vector<CellId>* changed) {
  for (size_t i = 0; i < view.entries.size(); ++i) {
    const Entry& e = view.entries[i];
    Cell& c = cells_[e.cell];
    // The same d and direction CoverageOf computed for this view (the replay in RebuildRefs
    // reproduces its φ exactly).
    const glm::dvec3 v = view.centre - grid_.Centre(c.id);
    const double d = glm::length(v);
    const Ref ref{view.id, e.phi, v / d, view.pixels[i], d,
                  DistanceQuality(d, options_.d_max_m, options_.sigma_m), view.pixel_sr,
                  view.quality};
    c.observers.push_back(ref);
    AddToCellTau(e.cell, e.phi);
    if (options_.render_refs_max > 0) changed->push_back(c.id);  // its observers changed
    if (!(e.phi > 0.0f)) continue;  // observe_zero_coverage: observed, not a reference
    // Pre-selection (§3.1.4). τ(R ∪ I) - τ(R) = φ_I > 0 = Δτ while R has room.
    if (static_cast<int>(c.refs.size()) < options_.r_max) {
      c.refs.push_back(ref);
      changed->push_back(c.id);
    } else {
      // v_k = argmax_{F_j ∈ R} τ(R ∪ I \ F_j) = the reference with the smallest φ.
      auto victim = std::min_element(c.refs.begin(), c.refs.end(),
                                     [](const Ref& a, const Ref& b) { return a.phi < b.phi; });
      if (static_cast<double>(e.phi) - victim->phi > options_.delta_tau) {
        *victim = ref;
        changed->push_back(c.id);
      }
    }
  }
  bytes_ += view.bytes;
  const ViewId id = view.id;
  auto [it, inserted] = views_.emplace(id, std::move(view));
  if (options_.dispersion != PlannerOptions::Dispersion::kOff) NearestAdd(it->second);
}

double ViewPlanner::PoseDistance(const glm::dvec3& ca, const glm::dquat& qa,
                                 const glm::dvec3& cb, const glm::dquat& qb) const {
  const double mpr = options_.dispersion_m_per_rad > 0.0
                         ? options_.dispersion_m_per_rad
                         : options_.dispersion_rotation_scale * options_.d_max_m;
  // The rotation angle 2 acos(|q_a · q_b|) from the chord |q_a ∓ q_b| = 2 sin(α / 2) between
  // the unit quaternions (α = half the rotation angle): 4 asin(chord / 2), well conditioned for
  // nearly equal rotations, where acos near 1 loses half the digits.
  const double sign = glm::dot(qa, qb) < 0.0 ? -1.0 : 1.0;
  const double chord = glm::length(glm::dvec4(qa.w, qa.x, qa.y, qa.z) -
                                   sign * glm::dvec4(qb.w, qb.x, qb.y, qb.z));
  double angle = 4.0 * std::asin(std::min(1.0, 0.5 * chord));
  if (options_.dispersion_turn_axis) {
    // The angle between the optical axes, 2 asin(|a - b| / 2) (well conditioned near 0).
    const glm::dvec3 za = qa * glm::dvec3(0.0, 0.0, 1.0), zb = qb * glm::dvec3(0.0, 0.0, 1.0);
    angle = 2.0 * std::asin(std::min(1.0, 0.5 * glm::length(za - zb)));
  }
  return glm::length(ca - cb) + mpr * TurnWeight(angle);
}

double ViewPlanner::TurnWeight(double angle) const {
  // dispersion_turn_overlap_rad φ: a turn within the views' shared field of view at the reduced
  // weight s, the rest at the full one.
  const double phi = options_.dispersion_turn_overlap_rad;
  if (!(phi > 0.0)) return angle;
  const double s = options_.dispersion_turn_overlap_scale;
  return angle <= phi ? s * angle : s * phi + (angle - phi);
}

double ViewPlanner::ViewDistance(const glm::dvec3& ca, const glm::dquat& qa, ViewId ida,
                                 double arca, const glm::dvec3& cb, const glm::dquat& qb,
                                 ViewId idb, double arcb) const {
  const double pose = PoseDistance(ca, qa, cb, qb);
  double time = 0.0;
  if (options_.dispersion_time_arc) {
    time = Kappa() * std::abs(arca - arcb);
  } else {
    const double frames =
        ida > idb ? static_cast<double>(ida - idb) : static_cast<double>(idb - ida);
    time = time_unit_ * frames;
  }
  return options_.dispersion_time_max ? std::max(pose, time) : pose + time;
}

void ViewPlanner::TrackStep(const glm::dvec3& centre, const glm::dquat& rotation, ViewId id) {
  if (has_last_ && id <= last_id_) return;  // out of order: not a step of the stream
  if (has_last_) {
    double step = PoseDistance(last_centre_, last_rotation_, centre, rotation) /
                  static_cast<double>(id - last_id_);
    if (options_.d_max_m > 0.0) step = std::min(step, options_.d_max_m);  // a jump is not motion
    step_sum_ += step;
    ++step_count_;
    if (options_.dispersion_time_arc) {
      // The path between two candidates, each capped at d_max_m like the id clock's steps (a
      // jump is not motion).
      double path = PoseDistance(last_centre_, last_rotation_, centre, rotation);
      if (options_.d_max_m > 0.0) path = std::min(path, options_.d_max_m);
      arc_ += path;
    }
  }
  has_last_ = true;
  last_centre_ = centre;
  last_rotation_ = rotation;
  last_id_ = id;
  // The arc clock's distances do not drift: the nearest-neighbour cache stays valid.
  if (options_.dispersion_time_arc) return;
  RecomputeTimeUnit();
}

void ViewPlanner::RecomputeTimeUnit() {
  if (step_count_ == 0) return;
  const double unit = Kappa() * step_sum_ / static_cast<double>(step_count_);
  if (std::abs(unit - time_unit_) <= 0.02 * std::max(unit, time_unit_)) return;
  time_unit_ = unit;
  if (options_.dispersion != PlannerOptions::Dispersion::kOff)
    for (auto& [vid, n] : nearest_) n = NearestOf(views_.at(vid));
}

void ViewPlanner::SetTimeScale(double scale) {
  scale = std::isfinite(scale) ? std::clamp(scale, 0.0, 1.0) : 0.0;
  if (std::abs(scale - time_scale_) <= 0.02 * std::max(scale, time_scale_)) return;
  time_scale_ = scale;
  if (options_.dispersion_time_arc) {
    if (options_.dispersion != PlannerOptions::Dispersion::kOff)
      for (auto& [vid, n] : nearest_) n = NearestOf(views_.at(vid));
  } else {
    RecomputeTimeUnit();
  }
}

double ViewPlanner::UniqueLoss(const View& v) const {
  // The cells v would leave with no stored observer (obs_scratch_: the candidate and the chosen
  // victims), each at the φ v would have there as the cell's only view (φ_d = 1): its frozen φ
  // may be ~0 when a view that has left since was the reference it was judged against.
  double loss = 0.0;
  for (size_t i = 0; i < v.entries.size(); ++i) {
    const Entry& e = v.entries[i];
    const Cell& c = cells_[e.cell];
    if (static_cast<int64_t>(c.observers.size()) + obs_scratch_[e.cell] != 1) continue;
    const double d = glm::length(v.centre - grid_.Centre(c.id));
    const double g = DistanceQuality(d, options_.d_max_m, options_.sigma_m);
    loss += Sat(v.quality * Phi(1.0, PositionalPart(AreaOf(c.id), d, g, v.pixels[i], v.pixel_sr)));
  }
  return loss;
}

void ViewPlanner::GiveWeight(const glm::dvec3& centre, const glm::dquat& rotation, ViewId id_of,
                             double arc, double weight) {
  View* best = nullptr;
  double best_d = std::numeric_limits<double>::infinity();
  for (auto& [id, u] : views_) {
    const double d = ViewDistance(centre, rotation, id_of, arc, u.centre, u.rotation, u.id, u.arc);
    if (d < best_d || (d == best_d && best != nullptr && id < best->id)) {
      best_d = d;
      best = &u;
    }
  }
  if (best != nullptr) best->weight += weight;
}

bool ViewPlanner::Weighted() const {
  const double offered = static_cast<double>(offered_);
  const double capacity = static_cast<double>(options_.max_views);
  return options_.dispersion != PlannerOptions::Dispersion::kOff &&
         options_.dispersion_weight_exponent > 0.0 &&
         offered > options_.dispersion_weight_after * capacity &&
         (options_.dispersion_weight_until <= 0.0 ||
          offered <= options_.dispersion_weight_until * capacity);
}

double ViewPlanner::WeightedSpacing(double d1, double weight) const {
  const double beta = options_.dispersion_weight_exponent;
  if (!Weighted()) return d1;
  // d1 × (w / d1)^β = w^β d1^(1-β); d1 = ∞ (a single view) stays ∞.
  return std::pow(weight, beta) * std::pow(d1, 1.0 - beta);
}

double ViewPlanner::ViewWeight(ViewId id) const {
  const auto it = views_.find(id);
  return it == views_.end() ? 0.0 : it->second.weight;
}

void ViewPlanner::Nearest::Offer(double d, ViewId id) {
  if (d < d1) {
    d2 = d1;
    id2 = id1;
    d1 = d;
    id1 = id;
  } else if (d < d2) {
    d2 = d;
    id2 = id;
  }
}

ViewPlanner::Nearest ViewPlanner::NearestOf(const View& v) const {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  Nearest n{kInf, kInf, 0, 0};
  for (const auto& [id, u] : views_)
    if (id != v.id) n.Offer(ViewDistance(v, u), id);
  return n;
}

void ViewPlanner::NearestAdd(const View& v) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  Nearest n{kInf, kInf, 0, 0};
  for (const auto& [id, u] : views_) {
    if (id == v.id) continue;
    const double d = ViewDistance(v, u);
    n.Offer(d, id);
    nearest_.at(id).Offer(d, v.id);
  }
  nearest_[v.id] = n;
}

void ViewPlanner::NearestRemove(ViewId gone) {
  nearest_.erase(gone);
  for (auto& [id, n] : nearest_)
    if (n.id1 == gone || n.id2 == gone) n = NearestOf(views_.at(id));
}

void ViewPlanner::RemoveView(ViewId id, std::vector<int32_t>* stale,
                             std::vector<CellId>* observed) {
  auto it = views_.find(id);
  if (it == views_.end()) return;
  const View& view = it->second;
  for (const Entry& e : view.entries) {
    Cell& c = cells_[e.cell];
    std::erase_if(c.observers, [id](const Ref& r) { return r.view == id; });
    if (options_.render_refs_max > 0) observed->push_back(c.id);
    AddToCellTau(e.cell, -static_cast<double>(e.phi));
    if (std::any_of(c.refs.begin(), c.refs.end(), [id](const Ref& r) { return r.view == id; }))
      stale->push_back(e.cell);
  }
  bytes_ -= view.bytes;
  views_.erase(it);
  if (options_.dispersion != PlannerOptions::Dispersion::kOff) NearestRemove(id);
}

bool ViewPlanner::RebuildRefs(int32_t cell) {
  // Replays §3.1.4 over the observers in acceptance order (the order AddView appended them):
  // each φ is what CoverageOf gave that view against the references chosen before it.
  Cell& c = cells_[cell];
  const double area = AreaOf(c.id);
  std::array<ViewId, kMaxRMax> before;
  size_t n_before = 0;
  for (const Ref& r : c.refs) before[n_before++] = r.view;
  std::array<glm::dvec3, kMaxRMax> dirs;
  std::array<glm::dvec3, kMaxRMax> eligible;  // the references CoverageOf counted (quality)
  c.refs.clear();
  for (const Ref& o : c.observers) {
    size_t n_eligible = 0;
    for (size_t j = 0; j < c.refs.size(); ++j)
      if (c.refs[j].quality >= o.quality) eligible[n_eligible++] = dirs[j];
    const double phi_d = DirectionalCoverage(
        o.dir, std::span<const glm::dvec3>(eligible.data(), n_eligible), options_.r_max);
    const double phi =
        o.quality * Phi(phi_d, PositionalPart(area, o.d, o.g, o.pixels, o.pixel_sr));
    if (!(phi > 0.0)) continue;
    Ref r = o;
    r.phi = static_cast<float>(phi);
    if (static_cast<int>(c.refs.size()) < options_.r_max) {
      dirs[c.refs.size()] = r.dir;
      c.refs.push_back(r);
    } else {
      auto victim = std::min_element(c.refs.begin(), c.refs.end(),
                                     [](const Ref& a, const Ref& b) { return a.phi < b.phi; });
      if (phi - victim->phi > options_.delta_tau) {
        dirs[static_cast<size_t>(victim - c.refs.begin())] = r.dir;
        *victim = r;
      }
    }
  }
  if (c.refs.size() != n_before) return true;
  std::array<ViewId, kMaxRMax> after;
  for (size_t i = 0; i < c.refs.size(); ++i) after[i] = c.refs[i].view;
  std::sort(before.begin(), before.begin() + n_before);
  std::sort(after.begin(), after.begin() + n_before);
  return !std::equal(before.begin(), before.begin() + n_before, after.begin());
}

absl::StatusOr<std::vector<CellId>> ViewPlanner::Remove(ViewId id) {
  if (!views_.count(id)) return absl::NotFoundError(absl::StrCat("view ", id, " is not stored"));
  std::vector<int32_t> stale;
  std::vector<CellId> changed;
  if (selector_) selector_->Forget(id);
  RemoveView(id, &stale, &changed);
  for (int32_t k : stale)
    if (RebuildRefs(k)) changed.push_back(cells_[k].id);
  std::sort(changed.begin(), changed.end());
  changed.erase(std::unique(changed.begin(), changed.end()), changed.end());
  return changed;
}

absl::StatusOr<Decision> ViewPlanner::Consider(const Candidate& cand) {
  if (views_.count(cand.id))
    return absl::AlreadyExistsError(absl::StrCat("view ", cand.id, " is already in the store"));
  EXO_RETURN_IF_ERROR(cand.id_camera.Validate());
  EXO_RETURN_IF_ERROR(ValidateQuaternion(cand.local_from_cam.rotation));
  if (!Finite(cand.local_from_cam.translation))
    return absl::InvalidArgumentError("candidate pose translation is NaN or Inf");

  Decision d;
  if (cand.bytes > options_.max_bytes) {
    d.reason = absl::StrCat("frame of ", cand.bytes, " bytes exceeds the store budget of ",
                            options_.max_bytes, " bytes");
    d.tau_sum = tau_sum_;
    return d;
  }

  // φ(I, b_k) for every cell I sees (only these cells can change).
  const glm::dvec3 centre = cand.local_from_cam.translation;
  const double pixel_sr = cand.id_camera.PixelSolidAngle();
  if (!(cand.quality > 0.0) || !(cand.quality <= 1.0))
    return absl::InvalidArgumentError(
        absl::StrCat("candidate quality must be in (0, 1], got ", cand.quality));
  if (options_.dispersion_time_steps > 0.0)
    TrackStep(centre, cand.local_from_cam.rotation, cand.id);
  View view{cand.id, centre, cand.local_from_cam.rotation, cand.bytes, pixel_sr, cand.quality,
            {}, {}};
  view.arc = arc_;
  view.entries.reserve(cand.cells.size());
  view.pixels.reserve(cand.cells.size());
  for (const CellPixelCount& c : cand.cells) {
    if (c.cell == kNoCell || c.pixels == 0) continue;
    const double phi = CoverageOf(centre, c.cell, c.pixels, pixel_sr, cand.quality);
    // observe_zero_coverage: a cell the view sees with φ = 0 (its direction duplicates a
    // reference: another frame of a pan from the same centre) is still observed, at φ = 0.
    if (!(phi > 0.0) && !(options_.observe_zero_coverage && Observes(centre, c.cell))) continue;
    const int32_t idx = CellIndex(c.cell);
    // Duplicate cells in the input are merged (φ is not additive, keep the larger).
    auto dup = std::find_if(view.entries.begin(), view.entries.end(),
                            [idx](const Entry& e) { return e.cell == idx; });
    if (dup != view.entries.end()) {
      if (static_cast<float>(phi) > dup->phi) {
        dup->phi = static_cast<float>(phi);
        view.pixels[static_cast<size_t>(dup - view.entries.begin())] = c.pixels;
      }
    } else {
      view.entries.push_back({idx, static_cast<float>(phi)});
      view.pixels.push_back(c.pixels);
    }
  }
  if (selector_) return ConsiderBaseline(cand, std::move(view));
  if (std::none_of(view.entries.begin(), view.entries.end(),
                   [](const Entry& e) { return e.phi > 0.0f; })) {
    d.reason = "candidate covers no cell";
    d.tau_sum = tau_sum_;
    return d;
  }

  double gain = 0.0;
  for (const Entry& e : view.entries) {
    const double t = cells_[e.cell].tau;
    gain += Sat(t + e.phi) - Sat(t);
  }

  const bool first = options_.dispersion == PlannerOptions::Dispersion::kFirst;
  // kFirst's coverage guard in τ units: absolute, or relative to the mean τ per stored view.
  const double guard = options_.dispersion_guard_relative > 0.0
                           ? options_.dispersion_guard_relative * tau_sum_ /
                                 static_cast<double>(std::max<size_t>(1, views_.size()))
                           : options_.dispersion_guard;
  // Unique-coverage guard (kFirst): the candidate's φ over the cells no stored view observes,
  // minus what the victims alone observed (set when full).
  ++offered_;
  const bool guard_unique =
      first && (options_.dispersion_guard_unique ||
                (options_.dispersion_guard_unique_after > 0.0 &&
                 static_cast<double>(offered_) >
                     options_.dispersion_guard_unique_after * static_cast<double>(options_.max_views)));
  double unique_net = 0.0;
  if (guard_unique)
    for (const Entry& e : view.entries)
      if (cells_[e.cell].observers.empty()) unique_net += Sat(e.phi);
  std::vector<ViewId> victims;
  double victim_redundancy = 0.0;  // dispersion: the largest redundancy among the victims
  const bool full = views_.size() + 1 > options_.max_views ||
                    bytes_ + cand.bytes > options_.max_bytes;
  if (full) {
    // Exact victim search over the whole store: τ_sum(F ∪ I \ F_v) via a dense scratch of the
    // pending per-cell change s_k (φ_I added, chosen victims' φ removed).
    scratch_.assign(cells_.size(), 0.0);
    std::vector<uint8_t> touched_mark(cells_.size(), 0);
    std::vector<int32_t> touched;
    auto touch = [&](int32_t k, double ds) {
      scratch_[k] += ds;
      if (!touched_mark[k]) {
        touched_mark[k] = 1;
        touched.push_back(k);
      }
    };
    for (const Entry& e : view.entries) touch(e.cell, e.phi);
    // Unique-coverage guard: the pending change of each cell's observer count (the candidate
    // +1, chosen victims -1); a removal loses the cells only it would still observe.
    if (guard_unique) {
      obs_scratch_.assign(cells_.size(), 0);
      for (const Entry& e : view.entries) ++obs_scratch_[e.cell];
    }
    size_t count = views_.size() + 1;
    size_t bytes = bytes_ + cand.bytes;
    // Dispersion: a view's redundancy = pose distance to its nearest neighbour in the store
    // (smaller = more redundant). The two views of the closest pair tie: the one in the more
    // crowded place goes (the smaller distance to its second neighbour, the candidate counted),
    // so the store's smallest distance after the swap is as large as it can be; then the older.
    // Density-weighted (dispersion_weight_exponent β > 0): d1 × ρ^β with the frame density
    // ρ = w / d1 around the view.
    auto redundancy = [&](const View& v) { return WeightedSpacing(nearest_.at(v.id).d1, v.weight); };
    auto crowding = [&](const View& v) {
      return std::min(nearest_.at(v.id).d2,
                      ViewDistance(v, view));
    };
    // dispersion_keep_nearest: the candidate's nearest stored view (0: none / option off).
    ViewId keep = 0;
    if (options_.dispersion_keep_nearest) {
      double best_d = std::numeric_limits<double>::infinity();
      for (const auto& [vid, v] : views_) {
        const double dist = ViewDistance(v, view);
        if (dist < best_d) {
          best_d = dist;
          keep = vid;
        }
      }
    }
    auto more_redundant = [&](const View& v, double red, const View& b, double b_red) {
      if (red != b_red) return red < b_red;
      if (options_.dispersion_drop_older && v.id != b.id) return v.id < b.id;
      if (keep != 0 && (v.id == keep) != (b.id == keep)) return b.id == keep;
      const double cv = crowding(v), cb = crowding(b);
      if (cv != cb) return cv < cb;
      return v.id < b.id;
    };
    while (count > options_.max_views || bytes > options_.max_bytes) {
      const View* best = nullptr;
      double best_loss = -std::numeric_limits<double>::infinity();
      double best_red = 0.0;
      for (const auto& [vid, v] : views_) {
        if (std::find(victims.begin(), victims.end(), vid) != victims.end()) continue;
        double loss = 0.0;  // τ_sum change caused by removing v (<= 0)
        for (const Entry& e : v.entries) {
          const double t = cells_[e.cell].tau + scratch_[e.cell];
          loss += Sat(t - e.phi) - Sat(t);
        }
        if (guard_unique) loss = -UniqueLoss(v);  // what the unique-coverage guard counts
        if (first) {
          // Dispersion first: the most redundant view among those whose removal loses at most
          // dispersion_guard of τ (a cell's only views are kept); none such: the thesis' victim.
          const bool ok = loss >= -guard;
          const bool best_ok = best != nullptr && best_loss >= -guard;
          if (best == nullptr || (ok && !best_ok) || (!ok && !best_ok && loss > best_loss)) {
            best_loss = loss;
            best = &v;
            best_red = redundancy(v);
          } else if (ok && best_ok) {
            const double red = redundancy(v);
            if (more_redundant(v, red, *best, best_red)) {
              best_loss = loss;
              best = &v;
              best_red = red;
            }
          }
        } else if (options_.dispersion != PlannerOptions::Dispersion::kOff) {
          if (best == nullptr || loss > best_loss + kTie) {
            best_loss = loss;
            best = &v;
            best_red = redundancy(v);
          } else if (loss >= best_loss - kTie) {
            const double red = redundancy(v);
            if (more_redundant(v, red, *best, best_red)) {
              best_loss = std::max(best_loss, loss);
              best = &v;
              best_red = red;
            }
          }
        } else if (loss > best_loss || (loss == best_loss && best != nullptr && vid < best->id)) {
          best_loss = loss;
          best = &v;
        }
      }
      if (best == nullptr) break;  // cannot happen: bytes <= max_bytes once the store is empty
      victims.push_back(best->id);
      victim_redundancy = std::max(victim_redundancy, best_red);
      if (guard_unique) {
        unique_net += best_loss;
        for (const Entry& e : best->entries) --obs_scratch_[e.cell];
      }
      for (const Entry& e : best->entries) touch(e.cell, -static_cast<double>(e.phi));
      --count;
      bytes -= best->bytes;
    }
    gain = 0.0;
    for (int32_t k : touched) {
      const double t = cells_[k].tau;
      gain += Sat(t + scratch_[k]) - Sat(t);
    }
  }

  d.gain = gain;
  // Dispersion: not enough coverage gain, but the candidate spreads the store over the camera
  // poses without losing coverage (full: farther from its nearest stored view than the victim
  // from its own; room left: not a duplicate of a stored pose).
  bool spread = false;
  // Density-weighted dispersion: the candidate's nearest stored view u (victims included) and
  // the share of u's weight the candidate would take if stored: 1/2 for a duplicate of u (the
  // two split u's frames), falling as the candidate lies beyond u's own neighbour distance d1
  // (share = d1 / (2 (d1 + δ))); the weights stay consistent with the spacing, so a view next
  // to a heavy one is not credited with the heavy one's density.
  // Weights are kept whenever β > 0 (also before dispersion_weight_after switches them in);
  // β = 0 costs nothing extra.
  const bool track = options_.dispersion != PlannerOptions::Dispersion::kOff &&
                     options_.dispersion_weight_exponent > 0.0;
  const bool weighted = Weighted();
  double nearest = std::numeric_limits<double>::infinity();
  ViewId nearest_id = 0;
  double share = 0.0;
  if (track) {
    for (const auto& [vid, v] : views_) {
      const double dist = ViewDistance(v, view);
      if (dist < nearest || (dist == nearest && vid < nearest_id)) {
        nearest = dist;
        nearest_id = vid;
      }
    }
    if (weighted && nearest_id != 0) {
      const double d1 = nearest_.at(nearest_id).d1;
      share = std::isfinite(d1) ? 0.5 * d1 / (d1 + nearest) : 0.5;
      if (!std::isfinite(share)) share = 0.5;  // d1 = δ = 0
    }
  }
  const double accept_gain = first && full ? guard : options_.delta_tau_sum;
  const double min_gain = first ? -guard : -kTie;
  // What the guard tests: the τ gain, or (unique-coverage guard, store full) the net unique one.
  const double guard_gain = guard_unique && full ? unique_net : gain;
  if (options_.dispersion != PlannerOptions::Dispersion::kOff && !(guard_gain > accept_gain) &&
      guard_gain >= min_gain) {
    // As the min-distance policy: the candidate's nearest stored view (victims included, so a
    // candidate next to the victim does not just replace it) must be farther than the victim's.
    if (!track)
      for (const auto& [vid, v] : views_)
        nearest = std::min(nearest, ViewDistance(v, view));
    // Density-weighted: the candidate's own weight would be 1 + its share of u's frames.
    const double candidate_redundancy =
        weighted && nearest_id != 0
            ? WeightedSpacing(nearest, 1.0 + share * views_.at(nearest_id).weight)
            : nearest;
    spread = full ? candidate_redundancy > (1.0 - options_.dispersion_recency) * victim_redundancy
                  : nearest > options_.dispersion_min;
  }
  if (!(guard_gain > accept_gain) && !spread) {
    // The frame is represented by its nearest stored view (density-weighted dispersion).
    if (track) GiveWeight(view.centre, view.rotation, view.id, view.arc, view.weight);
    d.reason = full ? absl::StrCat("store full and no victim gains more than delta_tau_sum (best ",
                                   gain, ")")
                    : absl::StrCat("coverage gain ", gain, " <= delta_tau_sum ",
                                   options_.delta_tau_sum);
    d.tau_sum = tau_sum_;
    return d;
  }

  d.accepted = true;
  d.reason = spread ? (victims.empty() ? "accepted (pose dispersion)"
                                       : "accepted, replacing a more redundant view (pose dispersion)")
                    : (victims.empty() ? "accepted" : "accepted, replacing a victim");
  // Victims leave first; the cells whose R(b_k) lost a victim are rebuilt from the final store
  // (the candidate included), the others get the candidate by the incremental rule.
  std::vector<int32_t> stale;
  struct Gone {
    glm::dvec3 centre;
    glm::dquat rotation;
    ViewId id;
    double arc;
    double weight;
  };
  std::vector<Gone> gone;
  for (ViewId v : victims) {
    const View& g = views_.at(v);
    gone.push_back({g.centre, g.rotation, g.id, g.arc, g.weight});
    RemoveView(v, &stale, &d.changed_cells);
  }
  std::sort(stale.begin(), stale.end());
  stale.erase(std::unique(stale.begin(), stale.end()), stale.end());
  AddView(std::move(view), &d.changed_cells);
  // The frames a victim stood for move to its nearest view left (the candidate included).
  if (track)
    for (const Gone& g : gone) GiveWeight(g.centre, g.rotation, g.id, g.arc, g.weight);
  // ... and the candidate takes its share of the frames of its nearest view (if still stored).
  if (weighted && nearest_id != 0 && views_.count(nearest_id) && views_.count(cand.id)) {
    View& u = views_.at(nearest_id);
    const double moved = share * u.weight;
    u.weight -= moved;
    views_.at(cand.id).weight += moved;
  }
  FinishAccepted(stale, std::move(victims), &d);
  return d;
}

void ViewPlanner::FinishAccepted(const std::vector<int32_t>& stale, std::vector<ViewId> victims,
                                 Decision* d) {
  for (int32_t k : stale)
    if (RebuildRefs(k)) d->changed_cells.push_back(cells_[k].id);
  d->removed = std::move(victims);
  std::sort(d->changed_cells.begin(), d->changed_cells.end());
  d->changed_cells.erase(std::unique(d->changed_cells.begin(), d->changed_cells.end()),
                         d->changed_cells.end());
  d->tau_sum = tau_sum_;
}

Decision ViewPlanner::ConsiderBaseline(const Candidate& cand, View view) {
  Decision d;
  ++offered_;
  const char* name = PolicyName(int(options_.policy));
  // A stored view after a restart (its stream position is gone) is adopted while there is room.
  if (cand.readmit)
    selector_->Adopt(cand.id, cand.local_from_cam);
  else
    selector_->Offer(cand.id, cand.local_from_cam);
  const std::vector<int64_t> kept = selector_->Selected();
  const bool keep = std::binary_search(kept.begin(), kept.end(), int64_t(cand.id));
  if (!keep || bytes_ + cand.bytes > options_.max_bytes) {
    if (keep) selector_->Forget(cand.id);
    d.reason = keep ? absl::StrCat("store bytes ", bytes_, " + ", cand.bytes, " exceed ",
                                   options_.max_bytes, " (", name, " policy)")
                    : absl::StrCat("not kept by the ", name, " policy");
    d.tau_sum = tau_sum_;
    return d;
  }
  // Victims: the stored views the baseline no longer keeps (all of its drops since its last
  // kept frame).
  std::vector<ViewId> victims;
  for (const auto& [vid, v] : views_)
    if (!std::binary_search(kept.begin(), kept.end(), int64_t(vid))) victims.push_back(vid);
  std::sort(victims.begin(), victims.end());
  double gain = 0.0;
  for (const Entry& e : view.entries) {
    const double t = cells_[e.cell].tau;
    gain += Sat(t + e.phi) - Sat(t);
  }
  d.accepted = true;
  d.gain = gain;
  d.reason = victims.empty() ? absl::StrCat("accepted (", name, " policy)")
                             : absl::StrCat("accepted, replacing ", victims.size(), " view(s) (",
                                            name, " policy)");
  std::vector<int32_t> stale;
  for (ViewId v : victims) RemoveView(v, &stale, &d.changed_cells);
  std::sort(stale.begin(), stale.end());
  stale.erase(std::unique(stale.begin(), stale.end()), stale.end());
  AddView(std::move(view), &d.changed_cells);
  FinishAccepted(stale, std::move(victims), &d);
  return d;
}

std::vector<ViewId> ViewPlanner::ViewIds() const {
  std::vector<ViewId> ids;
  ids.reserve(views_.size());
  for (const auto& [id, v] : views_) ids.push_back(id);
  std::sort(ids.begin(), ids.end());
  return ids;
}

double ViewPlanner::CellTau(CellId cell) const {
  auto it = cell_index_.find(cell);
  return it == cell_index_.end() ? 0.0 : cells_[it->second].tau;
}

std::vector<ViewId> ViewPlanner::Refs(CellId cell) const {
  std::vector<ViewId> out;
  auto it = cell_index_.find(cell);
  if (it == cell_index_.end()) return out;
  for (const Ref& r : cells_[it->second].refs) out.push_back(r.view);
  return out;
}

double ViewPlanner::RecomputeTauSum() const {
  std::vector<double> tau(cells_.size(), 0.0);
  for (const auto& [id, v] : views_)
    for (const Entry& e : v.entries) tau[e.cell] += e.phi;
  double sum = 0.0;
  for (double t : tau) sum += Sat(t);
  return sum;
}

std::unordered_map<CellId, std::vector<ViewId>> ViewPlanner::CellRefs() const {
  std::unordered_map<CellId, std::vector<ViewId>> out;
  for (const Cell& c : cells_) {
    if (c.refs.empty()) continue;
    auto& v = out[c.id];
    for (const Ref& r : c.refs) v.push_back(r.view);
  }
  return out;
}

std::vector<ViewId> ViewPlanner::PublishedRefsOf(const Cell& c) const {
  std::vector<ViewId> out;
  if (options_.render_refs_max == 0) {
    for (const Ref& r : c.refs) out.push_back(r.view);
    return out;
  }
  const size_t cap = size_t(std::max(options_.render_refs_max, options_.r_max));
  if (c.observers.size() <= cap) {
    // Every observer (R(b_k) is a subset), in acceptance order.
    for (const Ref& r : c.observers) out.push_back(r.view);
    return out;
  }
  // R(b_k) first, then farthest-point sampling of the remaining observers' camera centres
  // (cell centre + d·dir): each pick maximises its distance to the nearest picked camera, so
  // the list keeps a camera near every part of the path that saw the cell. Ties: earlier
  // observer (deterministic).
  const glm::dvec3 centre = grid_.Centre(c.id);
  std::vector<glm::dvec3> pos(c.observers.size());
  std::vector<double> nearest(c.observers.size(), std::numeric_limits<double>::infinity());
  std::vector<char> taken(c.observers.size(), 0);
  for (size_t i = 0; i < c.observers.size(); ++i)
    pos[i] = centre + c.observers[i].d * c.observers[i].dir;
  auto take = [&](size_t i) {
    taken[i] = 1;
    out.push_back(c.observers[i].view);
    for (size_t j = 0; j < pos.size(); ++j) {
      const glm::dvec3 v = pos[j] - pos[i];
      nearest[j] = std::min(nearest[j], glm::dot(v, v));
    }
  };
  for (const Ref& r : c.refs)
    for (size_t i = 0; i < c.observers.size(); ++i)
      if (!taken[i] && c.observers[i].view == r.view) take(i);
  if (out.empty()) take(0);
  while (out.size() < cap) {
    size_t best = pos.size();
    for (size_t j = 0; j < pos.size(); ++j)
      if (!taken[j] && (best == pos.size() || nearest[j] > nearest[best])) best = j;
    if (best == pos.size()) break;
    take(best);
  }
  return out;
}

std::vector<ViewId> ViewPlanner::PublishedRefs(CellId cell) const {
  auto it = cell_index_.find(cell);
  if (it == cell_index_.end()) return {};
  return PublishedRefsOf(cells_[it->second]);
}

std::unordered_map<CellId, std::vector<ViewId>> ViewPlanner::CellPublishedRefs() const {
  std::unordered_map<CellId, std::vector<ViewId>> out;
  for (const Cell& c : cells_) {
    std::vector<ViewId> v = PublishedRefsOf(c);
    if (!v.empty()) out[c.id] = std::move(v);
  }
  return out;
}

void ViewPlanner::SaveState(StateWriter* w) const {
  w->Put<double>(tau_sum_);
  w->Put<uint64_t>(bytes_);
  w->Put<uint64_t>(offered_);
  PutUnordered(w, views_, [w](const View& v) {
    w->Put(v.id);
    w->Put(v.centre);
    w->Put(v.rotation);
    w->Put<uint64_t>(v.bytes);
    w->Put(v.pixel_sr);
    w->Put(v.quality);
    w->PutVec(v.entries);
    w->PutVec(v.pixels);
    w->Put(v.arc);
  });
  PutUnorderedPod(w, cell_index_);
  w->Put<uint64_t>(cells_.size());
  for (const Cell& c : cells_) {
    w->Put(c.id);
    w->Put(c.tau);
    w->PutVec(c.observers);
    w->PutVec(c.refs);
  }
  PutUnorderedPod(w, areas_);
  w->PutVec(scratch_);
  PutUnorderedPod(w, nearest_);
  w->PutVec(obs_scratch_);
  w->Put<uint8_t>(has_last_ ? 1 : 0);
  w->Put(last_centre_);
  w->Put(last_rotation_);
  w->Put(last_id_);
  w->Put(step_sum_);
  w->Put<uint64_t>(step_count_);
  w->Put(time_unit_);
  w->Put(arc_);
  w->Put(time_scale_);
  w->Put<int32_t>(static_cast<int32_t>(options_.policy));
  if (selector_) selector_->SaveState(w);
}

absl::Status ViewPlanner::LoadState(StateReader* r) {
  uint64_t bytes = 0, cells = 0;
  r->Get(&tau_sum_) && r->Get(&bytes) && r->Get(&offered_);
  bytes_ = bytes;
  GetUnordered(r, &views_, [r](View* v) {
    uint64_t b = 0;
    const bool ok = r->Get(&v->id) && r->Get(&v->centre) && r->Get(&v->rotation) &&
                    r->Get(&b) && r->Get(&v->pixel_sr) && r->Get(&v->quality) &&
                    r->GetVec(&v->entries) && r->GetVec(&v->pixels) && r->Get(&v->arc);
    v->bytes = b;
    return ok;
  }) && GetUnorderedPod(r, &cell_index_) && r->Count(&cells, sizeof(CellId) + sizeof(double));
  cells_.assign(r->ok() ? cells : 0, Cell{});
  for (Cell& c : cells_)
    if (!(r->Get(&c.id) && r->Get(&c.tau) && r->GetVec(&c.observers) && r->GetVec(&c.refs))) break;
  uint8_t has_last = 0;
  GetUnorderedPod(r, &areas_) && r->GetVec(&scratch_) && GetUnorderedPod(r, &nearest_) &&
      r->GetVec(&obs_scratch_) && r->Get(&has_last) && r->Get(&last_centre_) &&
      r->Get(&last_rotation_) && r->Get(&last_id_) && r->Get(&step_sum_) &&
      r->Get(&step_count_) && r->Get(&time_unit_) && r->Get(&arc_) &&
      r->Get(&time_scale_);
  has_last_ = has_last != 0;
  int32_t policy = -1;
  r->Get(&policy);
  EXO_RETURN_IF_ERROR(r->Status("view planner"));
  if (policy != static_cast<int32_t>(options_.policy))
    return absl::FailedPreconditionError(absl::StrCat(
        "view planner state was written with policy ", PolicyName(policy), ", this planner runs ",
        PolicyName(int(options_.policy))));
  if (selector_) EXO_RETURN_IF_ERROR(selector_->LoadState(r));
  // Every index must point into cells_ (a corrupt state must not crash a later Consider).
  for (const auto& [id, v] : views_)
    for (const Entry& e : v.entries)
      if (e.cell < 0 || static_cast<size_t>(e.cell) >= cells_.size())
        return absl::DataLossError("view planner state: an entry outside the cells");
  for (const auto& [id, i] : cell_index_)
    if (i < 0 || static_cast<size_t>(i) >= cells_.size())
      return absl::DataLossError("view planner state: a cell index outside the cells");
  if (scratch_.size() != cells_.size() && !scratch_.empty())
    scratch_.assign(cells_.size(), 0.0);
  return absl::OkStatus();
}

size_t ViewPlanner::BookkeepingBytes() const {
  size_t b = cells_.capacity() * sizeof(Cell) + cell_index_.size() * (sizeof(CellId) + 16) +
             areas_.size() * (sizeof(CellId) + sizeof(double) + 16);
  for (const Cell& c : cells_) b += (c.observers.capacity() + c.refs.capacity()) * sizeof(Ref);
  for (const auto& [id, v] : views_)
    b += sizeof(View) + v.entries.capacity() * sizeof(Entry) + v.pixels.capacity() * sizeof(uint32_t);
  return b;
}

}  // namespace exo::planning
