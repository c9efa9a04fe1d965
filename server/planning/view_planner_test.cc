#include "server/planning/view_planner.h"

#include <cmath>
#include <limits>
#include <iostream>
#include <map>
#include <random>
#include <set>
#include <tuple>

#include <gtest/gtest.h>

#include "absl/strings/match.h"

#include "server/planning/coverage.h"

namespace exo::planning {
namespace {

// A real (tiny) cell-id buffer: rays of a pinhole camera cast onto the ground plane z = 0, each
// hit pixel labelled with the cell of the hit point. Stands in for the proxy rasterizer.
std::vector<uint64_t> GroundPlaneCellIds(const PinholeCamera& cam, const Rigid3d& local_from_cam,
                                         const CellGrid& grid, double extent_m = 1e9) {
  std::vector<uint64_t> ids(static_cast<size_t>(cam.width) * cam.height, kNoCell);
  const glm::dmat3 r = local_from_cam.RotationMatrix();
  const glm::dvec3 c = local_from_cam.translation;
  for (int v = 0; v < cam.height; ++v)
    for (int u = 0; u < cam.width; ++u) {
      const glm::dvec3 ray = r * cam.RayZ1({double(u), double(v)});
      if (!(std::abs(ray.z) > 1e-12)) continue;
      const double t = -c.z / ray.z;
      if (!(t > 0)) continue;
      const glm::dvec3 p = c + t * ray;
      if (std::abs(p.x) > extent_m || std::abs(p.y) > extent_m) continue;
      ids[static_cast<size_t>(v) * cam.width + u] = grid.IdOf(p);
    }
  return ids;
}

// Camera at `centre` looking at `target` (OpenCV axes: z forward, y down), with world up +z.
Rigid3d LookAt(const glm::dvec3& centre, const glm::dvec3& target) {
  const glm::dvec3 z = glm::normalize(target - centre);
  glm::dvec3 up(0, 0, 1);
  if (std::abs(glm::dot(up, z)) > 0.99) up = glm::dvec3(0, 1, 0);
  const glm::dvec3 x = glm::normalize(glm::cross(z, up));
  const glm::dvec3 y = glm::cross(z, x);
  Rigid3d t;
  t.rotation = glm::normalize(glm::quat_cast(glm::dmat3(x, y, z)));
  t.translation = centre;
  return t;
}

Candidate MakeCandidate(ViewId id, const glm::dvec3& centre, const glm::dvec3& target,
                        const CellGrid& grid, size_t bytes = 1000, double extent_m = 1e9) {
  Candidate c;
  c.id = id;
  c.local_from_cam = LookAt(centre, target);
  c.id_camera = PinholeCamera::FromFov(40, 30, 1.0);
  const auto ids = GroundPlaneCellIds(c.id_camera, c.local_from_cam, grid, extent_m);
  c.cells = CountCellPixels(ids.data(), ids.size());
  c.bytes = bytes;
  return c;
}

// Options where only the pose rule of kFirst decides: cells of 1 m saturate at once (τ_max 0.05)
// and the coverage guard is off (the dispersion tests below).
PlannerOptions PoseRuleOptions(size_t max_views) {
  PlannerOptions o;
  o.max_views = max_views;
  o.cell_size_m = 1.0;
  o.tau_max = 0.05;  // cells saturate: the pose terms decide
  o.dispersion = PlannerOptions::Dispersion::kFirst;
  o.dispersion_guard = 1e9;  // no coverage guard: the dispersion rule alone
  o.dispersion_guard_relative = 0;
  return o;
}

// ---- coverage math ----

TEST(Coverage, TammesBound) {
  EXPECT_DOUBLE_EQ(TammesMaxCos(2), -1.0);   // two views: opposite directions
  EXPECT_DOUBLE_EQ(TammesMaxCos(4), -0.5);
  EXPECT_NEAR(TammesMaxCos(16), 2 * 0.875 * 0.875 - 1, 1e-15);
}

// Guard: erratum 2 (R_max <= 1). Without it 1 - φ_d^max = 0 and φ_d is NaN (0/0) or Inf.
TEST(Coverage, RMaxOneNeverDividesByZero) {
  const glm::dvec3 dir(0, 0, 1);
  const std::vector<glm::dvec3> refs = {dir};
  const double phi = DirectionalCoverage(dir, refs, 1);
  EXPECT_TRUE(std::isfinite(phi));
  EXPECT_EQ(phi, 0.0);
}

TEST(Coverage, RMaxTwoWorks) {
  const glm::dvec3 dir(0, 0, 1);
  const std::vector<glm::dvec3> same = {dir}, opposite = {-dir}, side = {glm::dvec3(1, 0, 0)};
  EXPECT_DOUBLE_EQ(DirectionalCoverage(dir, same, 2), 0.0);
  EXPECT_DOUBLE_EQ(DirectionalCoverage(dir, opposite, 2), 1.0);
  EXPECT_DOUBLE_EQ(DirectionalCoverage(dir, side, 2), 0.5);  // (1 - 0) / (1 - (-1))
}

// Guard: erratum 1. (3.8) as printed gives φ_d^min = 1, i.e. φ_d = 0, for an empty R(b_k).
TEST(Coverage, EmptyReferenceSetIsMaximallyNovel) {
  const glm::dvec3 dir(0, 0, 1);
  EXPECT_EQ(PhiDMinPrinted(dir, {}), 1.0);  // the printed equation
  EXPECT_EQ(DirectionalCoverage(dir, {}, 16), 1.0);
}

// Guard: φ_p clamp. A cell whose known area is tiny but which fills many pixels (ψ_vis > ψ_total).
TEST(Coverage, PsiVisAboveTotalIsClamped) {
  const double psi_total = PsiTotal(1e-6, 0.25, 2.0, 1e-4, 0.1);
  EXPECT_DOUBLE_EQ(psi_total, 1.0);  // floor of one pixel
  const double phi_p = PositionalCoverage(0.9, 500.0, psi_total);
  EXPECT_EQ(phi_p, 1.0);
  EXPECT_DOUBLE_EQ(PositionalCoverage(0.5, 10.0, 40.0), 0.125);
}

TEST(Coverage, PsiTotalGuardsZeroDistance) {
  const double t = PsiTotal(0.25, 0.25, 0.0, 1e-4, 0.25);
  EXPECT_TRUE(std::isfinite(t));
  EXPECT_DOUBLE_EQ(t, 0.25 / (0.25 * 0.25) / 1e-4);
}

// ---- options ----

TEST(PlannerOptions, RMaxOneRejectedTwoAccepted) {
  PlannerOptions o;
  o.r_max = 1;
  EXPECT_FALSE(ViewPlanner::Create(o).ok());
  EXPECT_NE(std::string(o.Validate().message()).find("erratum 2"), std::string::npos);
  o.r_max = 2;
  EXPECT_TRUE(ViewPlanner::Create(o).ok());
  for (auto mutate : std::vector<std::function<void(PlannerOptions&)>>{
           [](PlannerOptions& p) { p.lambda = -0.1; },
           [](PlannerOptions& p) { p.sigma_m = 0; },
           [](PlannerOptions& p) { p.tau_max = std::nan(""); },
           [](PlannerOptions& p) { p.cell_size_m = 0; },
           [](PlannerOptions& p) { p.max_views = 0; },
           [](PlannerOptions& p) { p.delta_tau_sum = -1; }}) {
    PlannerOptions p;
    mutate(p);
    EXPECT_FALSE(p.Validate().ok());
  }
}

TEST(PlannerOptions, ForSceneDerivesCellSizeAndDistance) {
  const PlannerOptions o = PlannerOptions::ForScene(20.0, 3.0);
  EXPECT_DOUBLE_EQ(o.cell_size_m, 0.5);
  EXPECT_DOUBLE_EQ(o.d_max_m, 3.0);
  EXPECT_DOUBLE_EQ(PlannerOptions::ForScene(1000.0, 3.0).cell_size_m, 1.0);
  EXPECT_DOUBLE_EQ(PlannerOptions::ForScene(2.0, 3.0).cell_size_m, 0.3);
  EXPECT_TRUE(o.Validate().ok());
}

// ---- planner ----

TEST(ViewPlanner, CountCellPixels) {
  const std::vector<uint64_t> ids = {5, 5, kNoCell, 7, 5, 7, 7, kNoCell};
  const auto c = CountCellPixels(ids.data(), ids.size());
  ASSERT_EQ(c.size(), 2u);
  EXPECT_EQ(c[0].cell, 5u);
  EXPECT_EQ(c[0].pixels, 3u);
  EXPECT_EQ(c[1].cell, 7u);
  EXPECT_EQ(c[1].pixels, 3u);
}

TEST(ViewPlanner, FirstViewCoverageUsesErratum1) {
  PlannerOptions o;
  o.lambda = 1.0;  // directional only
  auto p = ViewPlanner::Create(o).value();
  const CellId cell = p.grid().IdOf({0.1, 0.1, 0.1});
  EXPECT_DOUBLE_EQ(p.CoverageOf({0, 0, 3}, cell, 10, 1e-4), 1.0);
}

// Guard d -> 0: a camera inside the cell it sees claims no coverage (and never NaN).
// Issue 22: (3.6) as printed credits a duplicate of a stored view (same pose: φ_d = 0) with its
// positional term, so a hovering camera's copies are accepted until τ_max; the novelty-weighted
// form (novelty_positional) gives a duplicate no gain, keeps a cell's first view's φ, and still
// accepts a view from a new direction.
TEST(ViewPlanner, NoveltyWeightedPositionalTermRejectsDuplicates) {
  for (bool novelty : {false, true}) {
    PlannerOptions o;
    o.cell_size_m = 1.0;
    o.lambda = 0.4;
    o.novelty_positional = novelty;
    auto p = ViewPlanner::Create(o);
    ASSERT_TRUE(p.ok());
    const CellGrid grid = p->grid();
    const glm::dvec3 eye(0, -3, 2), target(0, 0, 0);
    auto first = p->Consider(MakeCandidate(1, eye, target, grid));
    ASSERT_TRUE(first.ok());
    EXPECT_TRUE(first->accepted);
    const double tau_first = p->tau_sum();
    auto dup = p->Consider(MakeCandidate(2, eye, target, grid));
    ASSERT_TRUE(dup.ok());
    if (novelty) {
      EXPECT_FALSE(dup->accepted) << dup->reason;
      EXPECT_NEAR(dup->gain, 0.0, 1e-9);
    } else {
      EXPECT_TRUE(dup->accepted);
      EXPECT_GT(dup->gain, 0.05 * tau_first);  // (1 - λ) φ_p of every cell again (11 % here)
    }
    // A view from the opposite side is new in direction: accepted either way.
    auto other = p->Consider(MakeCandidate(3, glm::dvec3(0, 3, 2), target, grid));
    ASSERT_TRUE(other.ok());
    EXPECT_TRUE(other->accepted);
    EXPECT_NEAR(p->RecomputeTauSum(), p->tau_sum(), 1e-6);
  }
  // The first view of a cell is scored the same by both forms (φ_d = 1).
  PlannerOptions a, b;
  a.cell_size_m = b.cell_size_m = 1.0;
  b.novelty_positional = true;
  auto pa = ViewPlanner::Create(a), pb = ViewPlanner::Create(b);
  ASSERT_TRUE(pa.ok() && pb.ok());
  auto ca = pa->Consider(MakeCandidate(1, glm::dvec3(1, -4, 3), glm::dvec3(0), pa->grid()));
  auto cb = pb->Consider(MakeCandidate(1, glm::dvec3(1, -4, 3), glm::dvec3(0), pb->grid()));
  ASSERT_TRUE(ca.ok() && cb.ok());
  EXPECT_GT(ca->tau_sum, 0.0);
  EXPECT_DOUBLE_EQ(ca->tau_sum, cb->tau_sum);
}

// Issue 15 / 22: with the τ clamp saturated, the thesis' planner stops following the camera; with
// dispersion a full store spreads over the camera poses without losing coverage, and an exact
// duplicate pose is not stored.
TEST(ViewPlanner, DispersionSpreadsASaturatedStoreWithoutLosingCoverage) {
  auto min_pair = [](const std::vector<glm::dvec3>& c) {
    double m = 1e300;
    for (size_t i = 0; i < c.size(); ++i)
      for (size_t j = i + 1; j < c.size(); ++j) m = std::min(m, glm::length(c[i] - c[j]));
    return m;
  };
  double span[2] = {0, 0}, spread[2] = {0, 0};
  for (bool disp : {false, true}) {
    PlannerOptions o;
    o.cell_size_m = 1.0;
    o.tau_max = 0.05;  // every cell saturates with its first view
    o.max_views = 4;
    o.dispersion = disp ? PlannerOptions::Dispersion::kTies : PlannerOptions::Dispersion::kOff;
    auto p = ViewPlanner::Create(o);
    ASSERT_TRUE(p.ok());
    const CellGrid grid = p->grid();
    const glm::dvec3 target(0, 0, 0);
    std::map<ViewId, glm::dvec3> centre;
    ViewId id = 1;
    // A hovering camera: four poses within 3 mm fill the store.
    for (int i = 0; i < 4; ++i, ++id) {
      const glm::dvec3 eye(0.001 * i, -3, 2);
      auto d = p->Consider(MakeCandidate(id, eye, target, grid, 1000, 2.0));
      ASSERT_TRUE(d.ok());
      if (d->accepted) centre[id] = eye;
    }
    // The same pose again is a duplicate: never stored.
    auto dup = p->Consider(MakeCandidate(id++, glm::dvec3(0, -3, 2), target, grid, 1000, 2.0));
    ASSERT_TRUE(dup.ok());
    EXPECT_FALSE(dup->accepted) << dup->reason;
    // Then the camera moves along x, seeing the same (saturated) cells.
    for (int i = 1; i <= 6; ++i, ++id) {
      const glm::dvec3 eye(0.5 * (i % 2 ? i : -i), -3, 2);
      const double before = p->tau_sum();
      auto d = p->Consider(MakeCandidate(id, eye, target, grid, 1000, 2.0));
      ASSERT_TRUE(d.ok());
      if (!d->accepted) continue;
      EXPECT_GE(d->tau_sum, before - 1e-9) << "a dispersion swap lost coverage: " << d->reason;
      for (ViewId r : d->removed) centre.erase(r);
      centre[id] = eye;
      EXPECT_LE(p->num_views(), o.max_views);
    }
    std::vector<glm::dvec3> cs;
    for (const auto& [v, c] : centre) cs.push_back(c);
    ASSERT_EQ(cs.size(), p->num_views());
    spread[disp] = min_pair(cs);
    for (const glm::dvec3& c : cs) span[disp] = std::max(span[disp], std::abs(c.x));
    EXPECT_NEAR(p->RecomputeTauSum(), p->tau_sum(), 1e-6);
  }
  EXPECT_LT(span[0], 0.01);    // the thesis' form keeps only the hover's poses
  EXPECT_GT(span[1], 1.9);     // dispersion: the store follows the camera (x to ±3 m) ...
  EXPECT_GT(spread[1], 0.9);   // ... and its poses are spread (none of the hover's cluster left
                               // but one)
}

TEST(ViewPlanner, CameraInsideCell) {
  PlannerOptions o;
  o.cell_size_m = 1.0;
  auto p = ViewPlanner::Create(o).value();
  const CellId cell = PackCell({0, 0, 0});
  const double at_centre = p.CoverageOf({0.5, 0.5, 0.5}, cell, 100, 1e-4);
  EXPECT_TRUE(std::isfinite(at_centre));
  EXPECT_EQ(at_centre, 0.0);
  EXPECT_EQ(p.CoverageOf({0.2, 0.7, 0.4}, cell, 100, 1e-4), 0.0);  // inside, off-centre
  EXPECT_GT(p.CoverageOf({0.5, 0.5, 2.5}, cell, 100, 1e-4), 0.0);  // outside: coverage
  // A candidate sitting inside a cell it "sees": finite τ_sum, that cell gets no reference.
  Candidate c;
  c.id = 1;
  c.local_from_cam.translation = {0.5, 0.5, 0.5};
  c.id_camera = PinholeCamera::FromFov(40, 30, 1.0);
  c.cells = {{cell, 1200}, {PackCell({0, 0, 3}), 50}};
  c.bytes = 10;
  auto d = p.Consider(c).value();
  EXPECT_TRUE(std::isfinite(p.tau_sum()));
  EXPECT_TRUE(p.Refs(cell).empty());
  EXPECT_TRUE(d.accepted);
  EXPECT_EQ(p.Refs(PackCell({0, 0, 3})), std::vector<ViewId>{1});
}

TEST(ViewPlanner, PsiVisAboveTotalBoundsPerViewCoverage) {
  PlannerOptions o;
  o.lambda = 0.0;  // positional only
  o.d_max_m = 2.0;
  o.cell_size_m = 1.0;
  auto p = ViewPlanner::Create(o).value();
  const CellId cell = PackCell({0, 0, 0});
  ASSERT_TRUE(p.SetCellArea(cell, 1e-4).ok());  // underestimated area
  const double phi = p.CoverageOf({0.5, 0.5, 2.5}, cell, 5000, 1e-4);
  EXPECT_LE(phi, 1.0);
  EXPECT_DOUBLE_EQ(phi, 1.0);  // g = 1 at d = d_max, ψ_vis/ψ_total clamped
  EXPECT_FALSE(p.SetCellArea(cell, std::nan("")).ok());
  EXPECT_FALSE(p.SetCellArea(cell, -1.0).ok());
}

TEST(ViewPlanner, BadInputIsAnErrorAndChangesNothing) {
  auto p = ViewPlanner::Create({}).value();
  const CellGrid& g = p.grid();
  Candidate ok = MakeCandidate(1, {0, 0, 3}, {0, 0, 0}, g);
  Candidate nan_pose = ok;
  nan_pose.local_from_cam.translation.x = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(p.Consider(nan_pose).ok());
  Candidate bad_rot = ok;
  bad_rot.local_from_cam.rotation = glm::dquat(std::nan(""), 0, 0, 0);
  EXPECT_FALSE(p.Consider(bad_rot).ok());
  Candidate bad_cam = ok;
  bad_cam.id_camera.fx = 0;
  EXPECT_FALSE(p.Consider(bad_cam).ok());
  EXPECT_EQ(p.num_views(), 0u);
  EXPECT_EQ(p.tau_sum(), 0.0);
  ASSERT_TRUE(p.Consider(ok).value().accepted);
  EXPECT_FALSE(p.Consider(ok).ok());  // duplicate id
}

TEST(ViewPlanner, GrazingViewGetsLittlePositionalCoverage) {
  PlannerOptions o;
  o.lambda = 0.0;
  o.cell_size_m = 1.0;
  o.d_max_m = 3.0;
  auto p = ViewPlanner::Create(o).value();
  const CellGrid& g = p.grid();
  // Same distance to the target cell, looking straight down vs. at a grazing 3 degrees.
  const glm::dvec3 target(0.5, 0.5, 0.0);
  const double a = 3.0 * M_PI / 180.0;
  const Candidate top = MakeCandidate(1, target + glm::dvec3(0, 0, 3), target, g);
  const Candidate graze =
      MakeCandidate(2, target + glm::dvec3(3 * std::cos(a), 0, 3 * std::sin(a)), target, g);
  const CellId cell = g.IdOf(target);
  auto pixels = [&](const Candidate& c) {
    for (auto& cp : c.cells)
      if (cp.cell == cell) return double(cp.pixels);
    return 0.0;
  };
  const double sr = top.id_camera.PixelSolidAngle();
  const double phi_top = p.CoverageOf(top.local_from_cam.translation, cell, pixels(top), sr);
  const double phi_graze =
      p.CoverageOf(graze.local_from_cam.translation, cell, pixels(graze), sr);
  EXPECT_GT(phi_top, 0.5);
  EXPECT_TRUE(std::isfinite(phi_graze));
  EXPECT_LT(phi_graze, 0.15 * phi_top);  // ~sin(3°) of the footprint
}

// Invariants of the bookkeeping, checked after every step of a long stream.
void CheckInvariants(const ViewPlanner& p, const PlannerOptions& o) {
  ASSERT_LE(p.num_views(), o.max_views);
  ASSERT_LE(p.bytes(), o.max_bytes);
  const auto ids = p.ViewIds();
  const std::set<ViewId> stored(ids.begin(), ids.end());
  for (const auto& [cell, refs] : p.CellRefs()) {
    ASSERT_LE(refs.size(), size_t(o.r_max));
    for (ViewId r : refs) ASSERT_TRUE(stored.count(r)) << "reference to an evicted view";
    ASSERT_EQ(std::set<ViewId>(refs.begin(), refs.end()).size(), refs.size());
  }
}

// A long stream over a 12 m x 12 m ground plane; store bounded by count and bytes with
// variable frame sizes; incremental τ_sum must equal a from-scratch recomputation.
// Both dispersion modes on a random stream with the byte bound binding (several victims per
// candidate): bounds and τ bookkeeping hold, a dispersion swap never loses more coverage than
// its guard (kTies: none; kFirst: dispersion_guard, absolute or relative), and the incremental
// nearest-neighbour bookkeeping survives removals from outside.
TEST(ViewPlanner, DispersionLongStreamKeepsBoundsAndGuard) {
  using D = PlannerOptions::Dispersion;
  struct Mode {
    D mode;
    double guard, guard_rel;
    bool unique = false;
  };
  for (const Mode m : {Mode{D::kTies, 0.5, 0}, Mode{D::kFirst, 0.5, 0}, Mode{D::kFirst, 0, 0.65},
                       Mode{D::kFirst, 1e9, 0}, Mode{D::kFirst, 0, 0.65, true},
                       Mode{D::kFirst, 0.2, 0, true}}) {
    PlannerOptions o;
    o.max_views = 12;
    o.max_bytes = 12 * 1000;
    o.r_max = 4;
    o.cell_size_m = 1.0;
    o.d_max_m = 3.0;
    o.tau_max = 0.3;  // saturates after a few views: ties and dispersion swaps happen
    o.delta_tau_sum = 0.01;
    o.dispersion = m.mode;
    o.dispersion_guard = m.guard;
    o.dispersion_guard_relative = m.guard_rel;
    o.dispersion_guard_unique = m.unique;
    auto p = ViewPlanner::Create(o).value();
    // The cells some stored view observes (= a non-empty R(b_k)).
    auto observed = [&p] {
      std::set<CellId> out;
      for (const auto& [cell, refs] : p.CellRefs()) out.insert(cell);
      return out;
    };
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-6, 6), h(1.5, 5.0);
    std::uniform_int_distribution<int> sz(600, 2500);
    int spread = 0;
    std::vector<std::pair<glm::dvec3, glm::dvec3>> past;  // (target, centre)
    for (ViewId id = 1; id <= 300; ++id) {
      glm::dvec3 target(u(rng), u(rng), 0);
      glm::dvec3 centre = target + glm::dvec3(u(rng) * 0.5, u(rng) * 0.5, h(rng));
      if (id > 20 && id % 2 == 0) {  // every other frame revisits an earlier place (saturation)
        const auto& [t, c] = past[std::uniform_int_distribution<size_t>(0, past.size() - 1)(rng)];
        target = t;
        centre = c + glm::dvec3(u(rng), u(rng), u(rng)) * 0.05;
      }
      past.emplace_back(target, centre);
      const double before = p.tau_sum();
      const size_t n_before = p.num_views();
      const double guard =
          m.guard_rel > 0 ? m.guard_rel * before / double(std::max<size_t>(1, n_before)) : m.guard;
      const std::set<CellId> seen_before = m.unique ? observed() : std::set<CellId>{};
      auto d = p.Consider(MakeCandidate(id, centre, target, p.grid(), size_t(sz(rng)), 6.0));
      ASSERT_TRUE(d.ok()) << d.status();
      if (d->accepted && absl::StrContains(d->reason, "dispersion")) {
        ++spread;
        if (m.unique) {
          // Unique guard: the cells left with no stored view, net of the cells the candidate
          // observes first, at Sat(φ of a cell's only view) = τ_max = 0.3 each (φ >= λ = 0.5).
          const std::set<CellId> seen_after = observed();
          int lost = 0, added = 0;
          for (CellId c : seen_before) lost += !seen_after.count(c);
          for (CellId c : seen_after) added += !seen_before.count(c);
          EXPECT_GE(o.tau_max * (added - lost), -guard - 1e-9) << d->reason;
        } else if (m.mode == D::kTies) {
          EXPECT_GE(d->gain, -1e-9) << d->reason;
        } else {
          EXPECT_GE(d->gain, -guard - 1e-9) << d->reason;
        }
      }
      CheckInvariants(p, o);
      ASSERT_NEAR(p.tau_sum(), p.RecomputeTauSum(), 1e-9 * (1 + p.tau_sum())) << "step " << id;
      if (id % 50 == 0 && p.num_views() > 1) ASSERT_TRUE(p.Remove(p.ViewIds().front()).ok());
    }
    EXPECT_GT(spread, 0) << "mode " << int(m.mode) << ": no dispersion decision was exercised";
  }
}

// Density-weighted dispersion (dispersion_weight_exponent): a camera that passes a 22 m line
// fast but lingers on 2 of its metres for 70 % of the stream. Min-distance (α = 0) spreads the
// store evenly over the line (~1 view in 2 m); every-N keeps views in proportion to time (~8.6 of
// 12 there); the weighted store lies between, and its frames are closer to their nearest stored
// view on average (the k-median objective). Every frame's weight is kept (they sum to the frames
// offered).
TEST(ViewPlanner, DensityWeightedDispersionKeepsMoreViewsWhereTheCameraLingers) {
  std::vector<double> xs;
  for (double x = 0; x < 10; x += 0.25) xs.push_back(x);
  for (int i = 0; i < 200; ++i) xs.push_back(10 + 0.01 * i);
  for (double x = 12; x <= 22; x += 0.25) xs.push_back(x);
  const size_t store = 12;
  int lingering[2] = {0, 0};
  double mean_error[2] = {0, 0};
  for (int weighted : {0, 1}) {
    PlannerOptions o = PoseRuleOptions(store);
    o.dispersion_weight_exponent = weighted ? 0.5 : 0.0;
    auto p = ViewPlanner::Create(o).value();
    std::map<ViewId, double> x_of;
    ViewId id = 1;
    for (double x : xs) {
      const glm::dvec3 eye(x, 0, 2);
      auto d = p.Consider(MakeCandidate(id, eye, eye + glm::dvec3(1, 0, -1), p.grid()));
      ASSERT_TRUE(d.ok()) << d.status();
      if (d->accepted) x_of[id] = x;
      for (ViewId r : d->removed) x_of.erase(r);
      ++id;
    }
    ASSERT_EQ(p.num_views(), store);
    double weights = 0;
    for (ViewId v : p.ViewIds()) {
      weights += p.ViewWeight(v);
      EXPECT_GT(p.ViewWeight(v), 0.0);
      if (x_of.at(v) >= 10 && x_of.at(v) < 12) ++lingering[weighted];
    }
    if (weighted)  // (β = 0 keeps no weights: every view 1)
      EXPECT_NEAR(weights, double(xs.size()), 1e-9) << "the weights must sum to the frames offered";
    else
      EXPECT_EQ(weights, double(store));
    for (double x : xs) {
      double best = 1e300;
      for (const auto& [v, sx] : x_of) best = std::min(best, std::abs(sx - x));
      mean_error[weighted] += best / double(xs.size());
    }
  }
  // dispersion_weight_after: the plain distance until the stream has offered more than T
  // frames per view of capacity, so a T beyond the stream's length is min-distance exactly.
  {
    PlannerOptions o = PoseRuleOptions(store);
    o.dispersion_weight_exponent = 0.5;
    o.dispersion_weight_after = double(xs.size()) / double(store) + 1;  // never reached
    auto p = ViewPlanner::Create(o).value();
    int in_linger = 0;
    std::map<ViewId, double> x_of;
    ViewId id = 1;
    for (double x : xs) {
      const glm::dvec3 eye(x, 0, 2);
      auto d = p.Consider(MakeCandidate(id, eye, eye + glm::dvec3(1, 0, -1), p.grid())).value();
      if (d.accepted) x_of[id] = x;
      for (ViewId r : d.removed) x_of.erase(r);
      ++id;
    }
    for (const auto& [v, x] : x_of) in_linger += x >= 10 && x < 12;
    EXPECT_EQ(in_linger, lingering[0]) << "before the switch the store is min-distance's";
    o.dispersion_weight_after = -1;
    EXPECT_FALSE(o.Validate().ok());
  }
  // dispersion_weight_until: the weighting ends after U frames per view; an end before the
  // first candidate is min-distance exactly, one beyond the stream the weighted store exactly.
  for (double until : {1e-9, double(xs.size()) / double(store) + 1}) {
    PlannerOptions o = PoseRuleOptions(store);
    o.dispersion_weight_exponent = 0.5;
    o.dispersion_weight_until = until;
    auto p = ViewPlanner::Create(o).value();
    std::map<ViewId, double> x_of;
    ViewId id = 1;
    for (double x : xs) {
      const glm::dvec3 eye(x, 0, 2);
      auto d = p.Consider(MakeCandidate(id, eye, eye + glm::dvec3(1, 0, -1), p.grid())).value();
      if (d.accepted) x_of[id] = x;
      for (ViewId r : d.removed) x_of.erase(r);
      ++id;
    }
    int in_linger = 0;
    for (const auto& [v, x] : x_of) in_linger += x >= 10 && x < 12;
    EXPECT_EQ(in_linger, until < 1 ? lingering[0] : lingering[1]) << "until " << until;
    o.dispersion_weight_after = until;  // the end must come after the start
    EXPECT_FALSE(o.Validate().ok());
  }
  const double every_n = double(store) * 200.0 / double(xs.size());  // ~8.6
  EXPECT_LE(lingering[0], 2) << "min-distance is uniform over the line";
  EXPECT_GE(lingering[1], lingering[0] + 2) << "the weighted store keeps more views where the camera lingers";
  EXPECT_LT(lingering[1], every_n - 1) << "... but fewer than every-N";
  EXPECT_LT(mean_error[1], mean_error[0]) << "frames are nearer their nearest stored view";
  std::cout << "lingering views: min-distance " << lingering[0] << ", weighted " << lingering[1]
            << ", every-N " << every_n << "; mean frame-to-store distance " << mean_error[0]
            << " -> " << mean_error[1] << " m\n";
}

// dispersion_keep_nearest: the store's closest pair is A (x = 0) and B (x = 1); C lies at 5. A
// candidate at x = -1.5 is farther from its nearest view (A, 1.5) than the pair's distance, so it
// is stored and one of the pair leaves. The default removes the one in the more crowded place
// (A: its nearest other view, the candidate counted, is 1.5 away; B's is 2.5); with the option the
// candidate's nearest (A) stays and B leaves, as in the min-distance baseline.
TEST(ViewPlanner, KeepNearestChoosesWhichViewOfTheClosestPairLeaves) {
  for (bool keep_nearest : {false, true}) {
    PlannerOptions o = PoseRuleOptions(3);
    o.dispersion_keep_nearest = keep_nearest;
    auto p = ViewPlanner::Create(o).value();
    ViewId id = 1;
    for (double x : {0.0, 1.0, 5.0}) {
      const glm::dvec3 eye(x, 0, 2);
      auto d = p.Consider(MakeCandidate(id++, eye, eye + glm::dvec3(1, 0, -1), p.grid()));
      ASSERT_TRUE(d.ok()) << d.status();
      ASSERT_TRUE(d->accepted) << d->reason;
    }
    const glm::dvec3 eye(-1.5, 0, 2);
    auto d = p.Consider(MakeCandidate(4, eye, eye + glm::dvec3(1, 0, -1), p.grid()));
    ASSERT_TRUE(d.ok()) << d.status();
    ASSERT_TRUE(d->accepted) << d->reason;
    ASSERT_EQ(d->removed.size(), 1u);
    EXPECT_EQ(d->removed[0], keep_nearest ? ViewId(2) : ViewId(1))
        << (keep_nearest ? "the candidate's nearest view (A) must stay"
                         : "the view in the more crowded place (A) must leave");
    EXPECT_EQ(p.num_views(), 3u);
  }
}

// The scenario of the turn-weight tests: store A (x = 0), A turned by θ about the vertical and
// C (x = 5), then offer a candidate 0.5 m behind A. Expects whether it is stored (replacing one
// view of the turned pair) and that the store keeps 3 views.
void ExpectTurnedPairThenDisplaced(const PlannerOptions& o, double theta, bool accepted) {
  auto p = ViewPlanner::Create(o).value();
  const glm::dvec3 a(0, 0, 2), c(5, 0, 2);
  for (const auto& [id, eye, dir] :
       {std::tuple{ViewId(1), a, glm::dvec3(1, 0, -1)},
        std::tuple{ViewId(2), a, glm::dvec3(std::cos(theta), std::sin(theta), -1)},
        std::tuple{ViewId(3), c, glm::dvec3(1, 0, -1)}}) {
    auto d = p.Consider(MakeCandidate(id, eye, eye + dir, p.grid()));
    ASSERT_TRUE(d.ok()) << d.status();
    ASSERT_TRUE(d->accepted) << d->reason;
  }
  const glm::dvec3 eye(-0.5, 0, 2);
  auto d = p.Consider(MakeCandidate(4, eye, eye + glm::dvec3(1, 0, -1), p.grid()));
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(d->accepted, accepted) << d->reason;
  if (accepted) {
    ASSERT_EQ(d->removed.size(), 1u);
    EXPECT_TRUE(d->removed[0] == 1 || d->removed[0] == 2) << d->removed[0];
  }
  EXPECT_EQ(p.num_views(), 3u);
}

// dispersion_rotation_scale s: a turn of θ counts as s · d_max · θ metres in the pose distance.
// Store A (x = 0), A' (A turned by 0.4 rad about the vertical) and C (x = 5), d_max = 2: the
// closest pair is A-A' at 0.8 m (s = 1) or 0.2 m (s = 0.25). A candidate displaced 0.5 m from A
// is rejected at s = 1 (the turned view counts as more distinct than the displacement) and stored
// at s = 0.25, replacing one view of the turned pair; dispersion_m_per_rad > 0 wins over s.
TEST(ViewPlanner, RotationScaleWeighsATurnAgainstADisplacement) {
  struct Case {
    double scale, m_per_rad;
    bool accepted;
  };
  for (const Case& k : {Case{1.0, 0.0, false}, Case{0.25, 0.0, true}, Case{0.25, 2.0, false},
                        Case{1.0, 0.5, true}}) {
    PlannerOptions o = PoseRuleOptions(3);
    o.d_max_m = 2.0;
    o.dispersion_rotation_scale = k.scale;
    o.dispersion_m_per_rad = k.m_per_rad;
    ASSERT_TRUE(o.Validate().ok());
    SCOPED_TRACE(testing::Message() << "scale " << k.scale << " m_per_rad " << k.m_per_rad);
    ExpectTurnedPairThenDisplaced(o, 0.4, k.accepted);
  }
  PlannerOptions bad;
  for (double s : {0.0, -0.5, 1.5, std::numeric_limits<double>::quiet_NaN()}) {
    bad.dispersion_rotation_scale = s;
    EXPECT_FALSE(bad.Validate().ok()) << s;
  }
}

// dispersion_turn_overlap_rad φ (session 16): a turn within φ counts at the reduced weight s, the
// rest at the full one. Store A (x = 0), A' (A turned by θ about the vertical) and C (x = 5),
// d_max = 2, φ = 0.6 rad, s = 0.25. A small turn (θ = 0.4 < φ) makes A-A' 0.2 m apart instead of
// 0.8, so a candidate displaced 0.5 m from A is stored, replacing one view of the turned pair (at
// φ = 0 it is rejected, the rule since session 9). A large turn (θ = 1.2 > φ) costs
// 2 (0.25 × 0.6 + 0.6) = 1.5 m: the turned view stays and the displaced candidate is rejected.
TEST(ViewPlanner, TurnOverlapWeighsTurnsWithinTheFieldOfViewLess) {
  struct Case {
    double theta, overlap;
    bool accepted;
  };
  for (const Case& k : {Case{0.4, 0.0, false}, Case{0.4, 0.6, true}, Case{1.2, 0.6, false},
                        Case{1.2, 0.0, false}}) {
    PlannerOptions o = PoseRuleOptions(3);
    o.d_max_m = 2.0;
    o.dispersion_turn_overlap_rad = k.overlap;
    o.dispersion_turn_overlap_scale = 0.25;
    ASSERT_TRUE(o.Validate().ok());
    SCOPED_TRACE(testing::Message() << "theta " << k.theta << " overlap " << k.overlap);
    ExpectTurnedPairThenDisplaced(o, k.theta, k.accepted);
  }
  PlannerOptions bad;
  for (double phi : {-0.1, 4.0, std::numeric_limits<double>::quiet_NaN()}) {
    bad.dispersion_turn_overlap_rad = phi;
    EXPECT_FALSE(bad.Validate().ok()) << phi;
  }
  bad = PlannerOptions{};
  for (double s : {0.0, 1.5, std::numeric_limits<double>::quiet_NaN()}) {
    bad.dispersion_turn_overlap_rad = 0.5;
    bad.dispersion_turn_overlap_scale = s;
    EXPECT_FALSE(bad.Validate().ok()) << s;
  }
}

// dispersion_turn_axis (session 16): the turn between two views is the angle between their
// optical axes, so a roll about the axis (the same rays, the image turned) is no turn, and a yaw
// counts about θ cos(pitch). Store A (x = 0), B (A's pose turned, `offset` away) and C (x = 5),
// d_max = 2. A candidate displaced 0.5 m from A (A's orientation) is stored only when A-B is
// closer than 0.5 m:
//  - B = A rolled by 0.6 rad, 0.3 m away: 0.3 + 2 × 0.6 = 1.5 m by the full angle, 0.3 m by the
//    axes (stored);
//  - B = A yawed by 0.4 rad looking 45° down, 0.3 m away: 0.3 + 2 × 0.28 = 0.86 m by the axes
//    (rejected);
//  - B = A yawed by 0.4 rad looking 63° down (cos 0.45), same centre: 2 × 0.18 = 0.36 m by the
//    axes (stored) against 0.8 m by the full angle (rejected).
TEST(ViewPlanner, TurnAxisIgnoresRollAndWeighsYawByPitch) {
  struct Case {
    glm::dvec3 dir;
    double yaw, roll, offset;
    bool axis, accepted;
  };
  for (const Case& k : {Case{{1, 0, -1}, 0.0, 0.6, 0.3, false, false},
                        Case{{1, 0, -1}, 0.0, 0.6, 0.3, true, true},
                        Case{{1, 0, -1}, 0.4, 0.0, 0.3, true, false},
                        Case{{1, 0, -2}, 0.4, 0.0, 0.0, false, false},
                        Case{{1, 0, -2}, 0.4, 0.0, 0.0, true, true}}) {
    PlannerOptions o = PoseRuleOptions(3);
    o.d_max_m = 2.0;
    o.dispersion_turn_axis = k.axis;
    ASSERT_TRUE(o.Validate().ok());
    auto p = ViewPlanner::Create(o).value();
    const glm::dvec3 a(0, 0, 2), b(k.offset, 0, 2), c(5, 0, 2);
    ASSERT_TRUE(p.Consider(MakeCandidate(1, a, a + k.dir, p.grid()))->accepted);
    // B: the same direction yawed about the vertical, then rolled about its own axis.
    const glm::dvec3 yawed(k.dir.x * std::cos(k.yaw), k.dir.x * std::sin(k.yaw), k.dir.z);
    Candidate bc = MakeCandidate(2, b, b + yawed, p.grid());
    bc.local_from_cam.rotation =
        glm::normalize(bc.local_from_cam.rotation * glm::angleAxis(k.roll, glm::dvec3(0, 0, 1)));
    const auto ids = GroundPlaneCellIds(bc.id_camera, bc.local_from_cam, p.grid(), 1e9);
    bc.cells = CountCellPixels(ids.data(), ids.size());
    auto db = p.Consider(bc);
    ASSERT_TRUE(db.ok()) << db.status();
    ASSERT_TRUE(db->accepted) << db->reason;
    ASSERT_TRUE(p.Consider(MakeCandidate(3, c, c + k.dir, p.grid()))->accepted);
    const glm::dvec3 eye(-0.5, 0, 2);
    auto d = p.Consider(MakeCandidate(4, eye, eye + k.dir, p.grid()));
    ASSERT_TRUE(d.ok()) << d.status();
    SCOPED_TRACE(testing::Message() << "yaw " << k.yaw << " roll " << k.roll << " axis " << k.axis);
    EXPECT_EQ(d->accepted, k.accepted) << d->reason;
    if (k.accepted) {
      ASSERT_EQ(d->removed.size(), 1u);
      EXPECT_TRUE(d->removed[0] == 1 || d->removed[0] == 2) << d->removed[0];
    }
    EXPECT_EQ(p.num_views(), 3u);
  }
}

// dispersion_recency ρ: a full store's candidate replaces the most redundant view when its
// distance to its nearest stored view exceeds (1 - ρ) x the victim's (ρ = 0: strictly larger).
// Store A (x = 0), B (x = 1), C (x = 5), closest pair distance 1; a candidate 0.95 from A is
// rejected at ρ = 0 and stored at ρ = 0.1, one 0.85 from A is rejected at both.
// dispersion_drop_older: of the closest pair the older view leaves. B is stored first here, so
// the crowding rule removes A (its second neighbour, the candidate, is nearer) and the option B.
TEST(ViewPlanner, RecencyToleranceAndDropOlderDecideNearTies) {
  struct Case {
    double recency;
    bool drop_older;
    double candidate_x;
    bool accepted;
    ViewId removed;
  };
  for (const Case& k : {Case{0.0, false, -0.95, false, 0}, Case{0.1, false, -0.95, true, 2},
                        Case{0.1, false, -0.85, false, 0}, Case{0.0, false, -1.5, true, 2},
                        Case{0.0, true, -1.5, true, 1}, Case{0.1, true, -0.95, true, 1}}) {
    PlannerOptions o = PoseRuleOptions(3);
    o.dispersion_recency = k.recency;
    o.dispersion_drop_older = k.drop_older;
    auto p = ViewPlanner::Create(o).value();
    ViewId id = 1;
    for (double x : {1.0, 0.0, 5.0}) {  // B (id 1), A (id 2), C (id 3)
      const glm::dvec3 eye(x, 0, 2);
      auto d = p.Consider(MakeCandidate(id++, eye, eye + glm::dvec3(1, 0, -1), p.grid()));
      ASSERT_TRUE(d.ok()) << d.status();
      ASSERT_TRUE(d->accepted) << d->reason;
    }
    const glm::dvec3 eye(k.candidate_x, 0, 2);
    auto d = p.Consider(MakeCandidate(4, eye, eye + glm::dvec3(1, 0, -1), p.grid()));
    ASSERT_TRUE(d.ok()) << d.status();
    SCOPED_TRACE(testing::Message() << "recency " << k.recency << " drop_older " << k.drop_older
                                    << " candidate x " << k.candidate_x);
    EXPECT_EQ(d->accepted, k.accepted) << d->reason;
    if (k.accepted) {
      ASSERT_EQ(d->removed.size(), 1u);
      EXPECT_EQ(d->removed[0], k.removed);
    }
    EXPECT_EQ(p.num_views(), 3u);
  }
  PlannerOptions bad;
  for (double r : {-0.1, 0.6, std::numeric_limits<double>::quiet_NaN()}) {
    bad.dispersion_recency = r;
    EXPECT_FALSE(bad.Validate().ok()) << r;
  }
}

// dispersion_time_steps (session 15): time as a dimension of the dispersion's pose distance. A
// camera passes a 20 m line at 0.25 m per frame but stands (1 mm jitter) at x = 10 for 200 frames;
// store 12, cells saturated and no guard (the pose rule alone). Pose only (κ = 0), the standing
// stretch is one place and keeps at most 2 views; with κ = 1 its 200 frames are as far apart as
// the camera's mean step times their ids, so it keeps several. The unit is measured, not set: the
// same stream scaled ×3 in space (cells too) keeps the same frames. Invalid κ is refused.
TEST(ViewPlanner, TimeStepsSpreadALingeringStretchAndAreScaleFree) {
  std::vector<double> xs;
  for (double x = 0; x < 10; x += 0.25) xs.push_back(x);
  for (int i = 0; i < 200; ++i) xs.push_back(10 + 0.001 * (i % 2));
  for (double x = 10.25; x <= 20; x += 0.25) xs.push_back(x);
  auto run = [&](double kappa, double scale) {
    PlannerOptions o;
    o.max_views = 12;
    o.cell_size_m = 1.0 * scale;
    o.d_max_m = 2.0 * scale;
    o.tau_max = 0.05;  // cells saturate: the pose terms decide
    o.dispersion = PlannerOptions::Dispersion::kFirst;
    o.dispersion_guard = 1e9;
    o.dispersion_guard_relative = 0;
    o.dispersion_time_steps = kappa;
    auto p = ViewPlanner::Create(o).value();
    ViewId id = 1;
    for (double x : xs) {
      const glm::dvec3 eye = glm::dvec3(x, 0, 2) * scale;
      auto d = p.Consider(MakeCandidate(id++, eye, eye + glm::dvec3(1, 0, -1) * scale, p.grid()));
      EXPECT_TRUE(d.ok()) << d.status();
    }
    EXPECT_EQ(p.num_views(), 12u);
    std::vector<ViewId> ids = p.ViewIds();
    std::sort(ids.begin(), ids.end());
    return ids;
  };
  auto standing = [&](const std::vector<ViewId>& ids) {
    int n = 0;
    for (ViewId v : ids) n += v > 40 && v <= 240;  // ids 41..240: the 200 standing frames
    return n;
  };
  const auto pose_only = run(0.0, 1.0), timed = run(1.0, 1.0);
  EXPECT_LE(standing(pose_only), 2);
  EXPECT_GE(standing(timed), 4) << "the standing stretch keeps views spread over its time";
  EXPECT_LT(standing(timed), 12) << "the line is still covered";
  EXPECT_EQ(run(1.0, 3.0), timed) << "the time unit follows the stream's own speed";
  PlannerOptions bad;
  for (double k : {-0.5, std::numeric_limits<double>::infinity()}) {
    bad.dispersion_time_steps = k;
    EXPECT_FALSE(bad.Validate().ok()) << k;
  }
}

// dispersion_time_arc (session 16): the time term's clock is the travelled pose path. The line
// of the test above, but the camera stands at x = 10 for 200 frames either perfectly still (a
// synthetic stream's stop: one image repeated) or shaking in yaw by ±1° per frame (a hand-held
// camera: 7-Scenes turns ~1° per frame while dwelling). The id clock spreads views over both
// stops; the arc clock keeps at most 2 where nothing moves and spreads them where the camera
// shakes. A planner restored from its state mid-stand (the travelled path included) ends with
// the same store as one that never stopped.
TEST(ViewPlanner, TimeArcClockRunsOnlyWhileTheCameraMoves) {
  auto stream = [](double shake_deg) {
    std::vector<std::pair<glm::dvec3, glm::dvec3>> poses;  // eye, target
    auto add = [&](double x, double yaw_deg) {
      const double a = glm::radians(yaw_deg);
      const glm::dvec3 eye(x, 0, 2);
      poses.push_back({eye, eye + glm::dvec3(std::cos(a), std::sin(a), -1)});
    };
    for (double x = 0; x < 10; x += 0.25) add(x, 0);
    for (int i = 0; i < 200; ++i) add(10, shake_deg * (i % 2 == 0 ? 1 : -1));
    for (double x = 10.25; x <= 20; x += 0.25) add(x, 0);
    return poses;
  };
  auto options = [](bool arc) {
    PlannerOptions o = PoseRuleOptions(12);  // d_max_m: the default 2 m
    o.dispersion_time_steps = 1.0;
    o.dispersion_time_arc = arc;
    return o;
  };
  // restart_at > 0: the planner's state is saved after that many frames and loaded into a new one.
  auto run = [&](bool arc, double shake_deg, size_t restart_at = 0) {
    auto p = ViewPlanner::Create(options(arc)).value();
    ViewId id = 1;
    for (const auto& [eye, target] : stream(shake_deg)) {
      if (restart_at > 0 && id == restart_at + 1) {
        StateWriter w;
        p.SaveState(&w);
        p = ViewPlanner::Create(options(arc)).value();
        StateReader r(w.str());
        EXPECT_TRUE(p.LoadState(&r).ok());
      }
      auto d = p.Consider(MakeCandidate(id++, eye, target, p.grid()));
      EXPECT_TRUE(d.ok()) << d.status();
    }
    EXPECT_EQ(p.num_views(), 12u);
    std::vector<ViewId> ids = p.ViewIds();
    std::sort(ids.begin(), ids.end());
    return ids;
  };
  auto standing = [](const std::vector<ViewId>& ids) {
    int n = 0;
    for (ViewId v : ids) n += v > 40 && v <= 240;
    return n;
  };
  EXPECT_GE(standing(run(false, 0.0)), 4) << "the id clock runs while the camera stands still";
  EXPECT_LE(standing(run(true, 0.0)), 2) << "the arc clock stops with the camera";
  const auto shaking = run(true, 1.0);
  EXPECT_GE(standing(shaking), 4) << "a shaking camera's path keeps growing";
  EXPECT_LT(standing(shaking), 12) << "the line is still covered";
  EXPECT_EQ(run(true, 1.0, 140), shaking) << "the travelled path survives a restart";
}

// dispersion_time_auto_ref (session 16): the time term waits for the caller's measurement of
// the stream's time-correlated error (SetTimeScale). Unmeasured it is off (the stand keeps at most
// 2 views, as pose only); at scale 1 it is κ as set (the stand is spread); scales are clamped to
// [0, 1]; the scale survives a restart.
TEST(ViewPlanner, TimeAutoScaleFollowsTheMeasurement) {
  std::vector<double> xs;
  for (double x = 0; x < 10; x += 0.25) xs.push_back(x);
  for (int i = 0; i < 200; ++i) xs.push_back(10 + 0.001 * (i % 2));
  for (double x = 10.25; x <= 20; x += 0.25) xs.push_back(x);
  PlannerOptions o = PoseRuleOptions(12);  // d_max_m: the default 2 m
  o.dispersion_time_steps = 1.0;
  o.dispersion_time_auto_ref = 0.001;
  auto run = [&](double scale) {
    auto p = ViewPlanner::Create(o).value();
    EXPECT_EQ(p.time_scale(), 0.0);
    if (scale >= 0) p.SetTimeScale(scale);
    ViewId id = 1;
    for (double x : xs) {
      const glm::dvec3 eye(x, 0, 2);
      EXPECT_TRUE(p.Consider(MakeCandidate(id++, eye, eye + glm::dvec3(1, 0, -1), p.grid())).ok());
    }
    int n = 0;
    for (ViewId v : p.ViewIds()) n += v > 40 && v <= 240;
    return std::make_pair(n, p.time_scale());
  };
  EXPECT_LE(run(-1).first, 2) << "unmeasured: off";
  EXPECT_GE(run(1.0).first, 4) << "measured time-correlated error: κ as set";
  EXPECT_EQ(run(7.0).second, 1.0);
  EXPECT_EQ(run(-1).second, 0.0);
  auto p = ViewPlanner::Create(o).value();
  p.SetTimeScale(0.5);
  StateWriter w;
  p.SaveState(&w);
  auto q = ViewPlanner::Create(o).value();
  StateReader r(w.str());
  ASSERT_TRUE(q.LoadState(&r).ok());
  EXPECT_EQ(q.time_scale(), 0.5);
  PlannerOptions bad;
  bad.dispersion_time_auto_ref = -1;
  EXPECT_FALSE(bad.Validate().ok());
}

// observe_zero_coverage: a yaw pan from one centre. The second frame's direction to every cell
// the first already references is the first's, so its φ there is 0. Without the option it never
// observes those cells: they are not published with it and, once the first frame has left, R(b_k)
// has no view there although the stored second frame sees them (the replay of the pre-selection
// over the stored views would take it). With the option it observes them at φ = 0: τ_sum and the
// decisions are the same, the published references include it, and after the first frame leaves
// R(b_k) is rebuilt with it (docs/planning.md "Session 14").
TEST(ViewPlanner, ObserveZeroCoverageKeepsAPansFramesAsObservers) {
  double tau[2] = {0, 0};
  for (bool observe : {false, true}) {
    PlannerOptions o;
    o.max_views = 8;
    o.cell_size_m = 1.0;
    o.lambda = 1.0;  // the product's φ = φ_d
    o.observe_zero_coverage = observe;
    auto p = ViewPlanner::Create(o).value();
    const glm::dvec3 eye(0.3, 0.4, 3.0);
    const Candidate first = MakeCandidate(1, eye, eye + glm::dvec3(1.0, 0.0, -3.0), p.grid());
    const Candidate second = MakeCandidate(2, eye, eye + glm::dvec3(1.6, 0.5, -3.0), p.grid());
    ASSERT_TRUE(p.Consider(first)->accepted);
    // The cells both frames see where the second's φ is exactly 0 (its direction duplicates).
    std::vector<CellId> zero;
    const double sr = second.id_camera.PixelSolidAngle();
    for (const CellPixelCount& c : second.cells)
      if (!p.Refs(c.cell).empty() && p.CoverageOf(eye, c.cell, c.pixels, sr) == 0.0 &&
          p.grid().CoordOf(eye) != UnpackCell(c.cell))
        zero.push_back(c.cell);
    ASSERT_GE(zero.size(), 3u) << "the frames must share cells at φ = 0";
    auto d = p.Consider(second);
    ASSERT_TRUE(d.ok()) << d.status();
    ASSERT_TRUE(d->accepted) << d->reason << " (it sees cells the first does not)";
    tau[observe] = p.tau_sum();
    for (CellId cell : zero) {
      const std::vector<ViewId> pub = p.PublishedRefs(cell);
      const bool published = std::find(pub.begin(), pub.end(), ViewId(2)) != pub.end();
      EXPECT_EQ(published, observe) << "cell " << cell;
      EXPECT_EQ(p.Refs(cell), std::vector<ViewId>{1}) << "a φ = 0 view is no reference";
    }
    ASSERT_TRUE(p.Remove(1).ok());
    for (CellId cell : zero)
      EXPECT_EQ(p.Refs(cell), observe ? std::vector<ViewId>{2} : std::vector<ViewId>{})
          << "cell " << cell << ": R(b_k) after the first frame left";
    EXPECT_NEAR(p.tau_sum(), p.RecomputeTauSum(), 1e-9);
  }
  EXPECT_DOUBLE_EQ(tau[0], tau[1]) << "observing at φ = 0 must not change τ";
}

TEST(ViewPlanner, LongStreamRespectsBoundsAndIncrementalTauSumIsExact) {
  PlannerOptions o;
  o.max_views = 12;
  o.max_bytes = 12 * 1000;  // byte bound binds before the count bound for large frames
  o.r_max = 4;
  o.cell_size_m = 1.0;
  o.d_max_m = 3.0;
  o.sigma_m = 2.0;
  o.tau_max = 1.5;
  o.delta_tau_sum = 0.01;
  auto p = ViewPlanner::Create(o).value();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-6, 6), h(1.5, 5.0);
  std::uniform_int_distribution<int> sz(600, 2500);
  int accepted = 0, evictions = 0;
  std::set<CellId> seen_cells;
  size_t byte_sum_check = 0;
  std::map<ViewId, size_t> bytes_of;
  std::map<ViewId, Candidate> candidates;
  for (ViewId id = 1; id <= 400; ++id) {
    const glm::dvec3 target(u(rng), u(rng), 0);
    const glm::dvec3 centre = target + glm::dvec3(u(rng) * 0.5, u(rng) * 0.5, h(rng));
    Candidate c = MakeCandidate(id, centre, target, p.grid(), size_t(sz(rng)), 6.0);
    for (auto& cp : c.cells) seen_cells.insert(cp.cell);
    candidates.emplace(id, c);
    auto d = p.Consider(c);
    ASSERT_TRUE(d.ok()) << d.status();
    if (d->accepted) {
      ++accepted;
      evictions += int(d->removed.size());
      bytes_of[id] = c.bytes;
      for (ViewId r : d->removed) bytes_of.erase(r);
      EXPECT_GT(d->gain, o.delta_tau_sum);
      EXPECT_FALSE(d->changed_cells.empty());
    }
    CheckInvariants(p, o);
    byte_sum_check = 0;
    for (auto& [v, b] : bytes_of) byte_sum_check += b;
    ASSERT_EQ(p.bytes(), byte_sum_check);
    ASSERT_NEAR(p.tau_sum(), p.RecomputeTauSum(), 1e-9 * (1 + p.tau_sum())) << "step " << id;
  }
  EXPECT_GT(accepted, 20);
  EXPECT_GT(evictions, 5);
  // R(b_k) is the pre-selection replayed over the views stored now, in acceptance order,
  // whatever was evicted on the way (guard: RebuildRefs after evictions; the old refill from the
  // best remaining observer fails this): a fresh planner that accepts every stored view in id
  // order (τ_max huge, Δτ_sum 0, room for all) must end with the same references in every cell.
  {
    PlannerOptions fo = o;
    fo.max_views = 1000;
    fo.max_bytes = size_t{1} << 40;
    fo.tau_max = 1e30;
    fo.delta_tau_sum = 0;
    auto fresh = ViewPlanner::Create(fo).value();
    for (ViewId id : p.ViewIds()) {
      auto d = fresh.Consider(candidates.at(id));
      ASSERT_TRUE(d.ok());
      ASSERT_TRUE(d->accepted);
    }
    size_t cells_checked = 0;
    for (const auto& [cell, refs] : p.CellRefs()) {
      std::vector<ViewId> a = refs, b = fresh.Refs(cell);
      std::sort(a.begin(), a.end());
      std::sort(b.begin(), b.end());
      EXPECT_EQ(a, b) << "cell " << cell;
      ++cells_checked;
    }
    EXPECT_EQ(fresh.CellRefs().size(), cells_checked);
    EXPECT_GT(cells_checked, 20u);
  }
  // Bookkeeping grows with observed cells, not frames.
  EXPECT_LE(p.num_cells(), seen_cells.size());
  EXPECT_LT(p.BookkeepingBytes(), 200000u);
}

// The baseline policies in the planner (issue 15 / 22: the product path can run them): the store
// holds exactly the views the baseline selector alone keeps, at every frame; the planner's
// bookkeeping (τ, the references replayed over the stored views) stays exact; a checkpoint
// continues the same stream; a state of another policy is refused.
TEST(ViewPlanner, BaselinePoliciesKeepTheSelectorsStoreWithExactReferences) {
  using P = PlannerOptions::Policy;
  for (P policy : {P::kMinDistance, P::kEveryN, P::kEveryNOnline}) {
    SCOPED_TRACE(PolicyName(int(policy)));
    PlannerOptions o;
    o.max_views = 12;
    o.r_max = 4;
    o.cell_size_m = 1.0;
    o.d_max_m = 3.0;
    o.policy = policy;
    o.baseline_m_per_rad = 1.5;
    o.baseline_stream_frames = 300;
    auto p = ViewPlanner::Create(o).value();
    std::unique_ptr<OnlineSelector> alone;
    if (policy == P::kMinDistance) alone = std::make_unique<MinDistanceSelector>(12, 1.5);
    if (policy == P::kEveryN) alone = std::make_unique<LengthAwareEveryN>(12, 300);
    if (policy == P::kEveryNOnline) alone = std::make_unique<ProgressiveEveryN>(12);
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-6, 6), h(1.5, 5.0);
    std::map<ViewId, Candidate> candidates;
    std::string saved;
    std::vector<int64_t> kept_at_save;
    int accepted = 0;
    for (ViewId id = 1; id <= 300; ++id) {
      const glm::dvec3 target(u(rng), u(rng), 0);
      const glm::dvec3 centre = target + glm::dvec3(u(rng) * 0.5, u(rng) * 0.5, h(rng));
      Candidate c = MakeCandidate(id, centre, target, p.grid(), 1000, 6.0);
      candidates.emplace(id, c);
      alone->Offer(id, c.local_from_cam);
      auto d = p.Consider(c);
      ASSERT_TRUE(d.ok()) << d.status();
      accepted += d->accepted;
      // The planner's store is the selector's (the views a progressive thinning dropped leave
      // with the next kept frame, so compare at kept frames).
      if (d->accepted) {
        std::vector<int64_t> ids;
        for (ViewId v : p.ViewIds()) ids.push_back(v);
        std::sort(ids.begin(), ids.end());
        ASSERT_EQ(ids, alone->Selected()) << "frame " << id;
      }
      ASSERT_LE(p.num_views(), o.max_views);
      ASSERT_NEAR(p.tau_sum(), p.RecomputeTauSum(), 1e-9 * (1 + p.tau_sum()));
      if (id == 150) {
        StateWriter w;
        p.SaveState(&w);
        saved = w.str();
        kept_at_save = alone->Selected();
      }
    }
    EXPECT_GE(accepted, 12);  // every_n: exactly 12 of 300, evenly
    // References: the pre-selection replayed over the stored views in id order.
    {
      PlannerOptions fo = o;
      fo.policy = P::kCoverage;
      fo.max_views = 1000;
      fo.tau_max = 1e30;
      fo.delta_tau_sum = 0;
      auto fresh = ViewPlanner::Create(fo).value();
      for (ViewId id : p.ViewIds()) ASSERT_TRUE(fresh.Consider(candidates.at(id))->accepted);
      for (const auto& [cell, refs] : p.CellRefs()) {
        std::vector<ViewId> a = refs, b = fresh.Refs(cell);
        std::sort(a.begin(), a.end());
        std::sort(b.begin(), b.end());
        EXPECT_EQ(a, b) << "cell " << cell;
      }
    }
    // Restored at frame 150, the rest of the stream gives the same store.
    auto q = ViewPlanner::Create(o).value();
    StateReader r(saved);
    ASSERT_TRUE(q.LoadState(&r).ok());
    for (ViewId id = 151; id <= 300; ++id) ASSERT_TRUE(q.Consider(candidates.at(id)).ok());
    EXPECT_EQ(q.ViewIds().size(), p.ViewIds().size());
    std::vector<ViewId> a = q.ViewIds(), b = p.ViewIds();
    std::sort(a.begin(), a.end());
    std::sort(b.begin(), b.end());
    EXPECT_EQ(a, b);
    // Another policy's state is a clear error.
    PlannerOptions other = o;
    other.policy = policy == P::kMinDistance ? P::kEveryNOnline : P::kMinDistance;
    auto x = ViewPlanner::Create(other).value();
    StateReader r2(saved);
    const absl::Status st = x.LoadState(&r2);
    EXPECT_FALSE(st.ok());
    EXPECT_TRUE(absl::StrContains(st.message(), "policy")) << st;
  }
  PlannerOptions bad;
  bad.policy = PlannerOptions::Policy::kEveryN;  // the length-aware oracle needs the length
  EXPECT_FALSE(ViewPlanner::Create(bad).ok());
}

// Exact victim choice on a hand-computable case. Cells: A = (0,0,0), B = (5,0,0), C = (10,0,0)
// (cell size 1). Three views with fixed coverage via λ = 1 and distinct directions.
TEST(ViewPlanner, VictimIsTheViewWhoseRemovalLosesLeast) {
  PlannerOptions o;
  o.max_views = 2;
  o.lambda = 1.0;     // φ = φ_d: 1 for the first view of a cell
  o.tau_max = 1.0;    // a second view of the same cell adds nothing
  o.delta_tau_sum = 0.1;
  o.cell_size_m = 1.0;
  auto p = ViewPlanner::Create(o).value();
  const PinholeCamera cam = PinholeCamera::FromFov(40, 30, 1.0);
  auto cand = [&](ViewId id, std::vector<glm::ivec3> cells, glm::dvec3 centre) {
    Candidate c;
    c.id = id;
    c.local_from_cam.translation = centre;
    c.id_camera = cam;
    for (auto& k : cells) c.cells.push_back({PackCell(k), 10});
    c.bytes = 1;
    return c;
  };
  // View 1 from +y sees A, B; view 2 from +z sees B (new direction: φ_d = 1, τ_B saturates) and C.
  ASSERT_TRUE(p.Consider(cand(1, {{0, 0, 0}, {5, 0, 0}}, {0.5, 20.5, 0.5})).value().accepted);
  ASSERT_TRUE(p.Consider(cand(2, {{5, 0, 0}, {10, 0, 0}}, {0.5, 0.5, 20.5})).value().accepted);
  EXPECT_NEAR(p.tau_sum(), 3.0, 1e-6);
  // Full. Candidate 3 sees A from the opposite side (φ_d = 1) and a new cell D: evicting 1
  // loses nothing that 3 doesn't cover (A re-covered by 3, B still covered by 2); evicting 2
  // loses C.
  auto d = p.Consider(cand(3, {{0, 0, 0}, {15, 0, 0}}, {0.5, -19.5, 0.5})).value();
  ASSERT_TRUE(d.accepted);
  EXPECT_EQ(d.removed, std::vector<ViewId>{1});
  EXPECT_NEAR(d.gain, 1.0, 1e-6);
  EXPECT_NEAR(p.tau_sum(), 4.0, 1e-6);
  // A duplicate of 3 (same direction to A and D as the reference 3) gains nothing: rejected.
  auto dup = p.Consider(cand(4, {{0, 0, 0}, {15, 0, 0}}, {0.5, -19.5, 0.5})).value();
  EXPECT_FALSE(dup.accepted);
  EXPECT_EQ(p.ViewIds(), (std::vector<ViewId>{2, 3}));
  // B lost view 1 from its references and was refilled from its remaining observer (view 2).
  EXPECT_EQ(p.Refs(PackCell({5, 0, 0})), std::vector<ViewId>{2});
}

// Session 11 (docs/planning.md): φ is frozen at acceptance, so a cell's first view holds its
// φ_d = 1 and a later view from nearly the same pose ~0. Two views 1 cm apart (1 first saw A,
// 2 first saw B, and A and B are seen by other stored views too) then each "lose" 6 τ on removal
// and the τ guard keeps both, evicting a view 20 m from every other one instead. The
// unique-coverage guard counts only the cells a removal leaves with no stored view: it thins the
// pair, keeps every cell observed, and still keeps a cell's only view (E).
TEST(ViewPlanner, UniqueCoverageGuardThinsAPairTheFrozenTauGuardKeeps) {
  const PinholeCamera cam = PinholeCamera::FromFov(40, 30, 1.0);
  auto cand = [&](ViewId id, std::vector<std::pair<int, int>> rows, glm::dvec3 centre) {
    Candidate c;
    c.id = id;
    c.local_from_cam.translation = centre;
    c.id_camera = cam;
    for (auto [y, n] : rows)  // n cells (0..n-1, y, 0)
      for (int x = 0; x < n; ++x) c.cells.push_back({PackCell({x, y, 0}), 10});
    c.bytes = 1;
    return c;
  };
  constexpr int kA = 0, kB = 2, kC = 4, kD = -10, kE = 8;
  struct Case {
    bool unique;
    double guard, guard_rel;
    bool e;  // view 1 also sees E, which no other view sees
    // dispersion_guard_unique_after: candidate 5 is the 5th offered, 4 views of capacity: 1.0
    // switches to the unique guard before it (5 > 4), 2.0 does not (5 <= 8).
    double after = 0.0;
  };
  for (const Case k : {Case{false, 0, 0.65, false}, Case{true, 0, 0.65, false},
                       Case{false, 0, 0.65, true}, Case{true, 0.5, 0, true},
                       Case{false, 0, 0.65, false, 1.0}, Case{false, 0, 0.65, false, 2.0}}) {
    SCOPED_TRACE(::testing::Message() << "unique " << k.unique << " guard " << k.guard << " rel "
                                      << k.guard_rel << " E " << k.e << " after " << k.after);
    const bool unique = k.unique || (k.after > 0 && k.after < 1.25);
    PlannerOptions o;
    o.max_views = 4;
    o.lambda = 1.0;  // φ = φ_d: 1 for a cell's first view, ~0 for one from the same direction
    o.cell_size_m = 1.0;
    o.dispersion = PlannerOptions::Dispersion::kFirst;
    o.dispersion_guard = k.guard;
    o.dispersion_guard_relative = k.guard_rel;
    o.dispersion_guard_unique = k.unique;
    o.dispersion_guard_unique_after = k.after;
    auto p = ViewPlanner::Create(o).value();
    std::vector<std::pair<int, int>> rows1 = {{kA, 6}};
    if (k.e) rows1.push_back({kE, 3});
    const std::map<ViewId, glm::dvec3> centres = {{1, {0.5, 20.5, 0.5}},  // sees A (+E)
                                                  {2, {0.51, 20.5, 0.5}},  // 1 cm away: A, B
                                                  {3, {0.5, 0.5, 20.5}},   // from above: B, C
                                                  {4, {0.5, 0.5, 40.5}},   // behind 3: C
                                                  {5, {0.5, -19.5, 0.5}}};  // other side: A, D
    ASSERT_TRUE(p.Consider(cand(1, rows1, centres.at(1))).value().accepted);
    ASSERT_TRUE(p.Consider(cand(2, {{kA, 6}, {kB, 6}}, centres.at(2))).value().accepted);
    ASSERT_TRUE(p.Consider(cand(3, {{kB, 6}, {kC, 6}}, centres.at(3))).value().accepted);
    ASSERT_TRUE(p.Consider(cand(4, {{kC, 6}}, centres.at(4))).value().accepted);
    const double tau_before = p.tau_sum();
    auto d = p.Consider(cand(5, {{kA, 6}, {kD, 3}}, centres.at(5))).value();
    ASSERT_TRUE(d.accepted) << d.reason;
    ASSERT_EQ(d.removed.size(), 1u);
    const ViewId victim = d.removed[0];
    const auto ids = p.ViewIds();
    const std::set<ViewId> stored(ids.begin(), ids.end());
    if (!unique) {
      // The frozen-τ guard: 1 and 2 each hold 6 τ > 0.65 x mean τ, 3 holds 12; only 4 (whose C
      // cells 3 saw first) is a permitted victim, although it is 20 m from every other view.
      EXPECT_EQ(victim, 4u);
      EXPECT_TRUE(stored.count(1) && stored.count(2));
    } else if (!k.e) {
      // Unique coverage: no view holds a cell alone; the 1 cm pair is thinned.
      EXPECT_TRUE(victim == 1 || victim == 2) << victim;
      double min_pair = 1e300;
      for (ViewId a : ids)
        for (ViewId b : ids)
          if (a < b) min_pair = std::min(min_pair, glm::length(centres.at(a) - centres.at(b)));
      EXPECT_GT(min_pair, 19.0);
    } else {
      // E is 1's alone (3 cells > guard 0.5): 2, the other view of the pair, goes.
      EXPECT_EQ(victim, 2u);
      for (int x = 0; x < 3; ++x) EXPECT_EQ(p.Refs(PackCell({x, kE, 0})), std::vector<ViewId>{1});
    }
    // Every cell any view saw is still observed by a stored view under the unique guard.
    if (unique)
      for (auto [y, n] : std::vector<std::pair<int, int>>{{kA, 6}, {kB, 6}, {kC, 6}, {kD, 3}})
        for (int x = 0; x < n; ++x) EXPECT_FALSE(p.Refs(PackCell({x, y, 0})).empty()) << x << "," << y;
    EXPECT_EQ(p.num_views(), 4u);
    EXPECT_NEAR(p.tau_sum(), p.RecomputeTauSum(), 1e-9);
    EXPECT_GT(p.tau_sum(), tau_before);  // 5 added D and a second direction of A
  }
  PlannerOptions bad;
  bad.dispersion_guard_unique_after = -1.0;
  EXPECT_FALSE(bad.Validate().ok());
  bad.dispersion_guard_unique_after = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(bad.Validate().ok());
}

TEST(ViewPlanner, PreSelectionKeepsAtMostRMaxReferences) {
  PlannerOptions o;
  o.r_max = 2;
  o.max_views = 10;
  o.delta_tau_sum = 0.0;
  o.tau_max = 100;
  o.cell_size_m = 1.0;
  auto p = ViewPlanner::Create(o).value();
  const CellId cell = PackCell({0, 0, 0});
  const PinholeCamera cam = PinholeCamera::FromFov(40, 30, 1.0);
  for (ViewId id = 1; id <= 5; ++id) {
    const double a = id * 1.1;
    Candidate c;
    c.id = id;
    c.local_from_cam.translation = glm::dvec3(0.5 + 3 * std::cos(a), 0.5 + 3 * std::sin(a), 2.5);
    c.id_camera = cam;
    c.cells = {{cell, 50u * id}};
    c.bytes = 1;
    ASSERT_TRUE(p.Consider(c).ok());
    EXPECT_LE(p.Refs(cell).size(), 2u);
  }
  EXPECT_EQ(p.Refs(cell).size(), 2u);
}

// Published references (what clients render with): R(b_k) when render_refs_max = 0; every
// stored observer when there are at most max(render_refs_max, r_max); otherwise R(b_k) plus a
// farthest-point spread of the other observers' camera centres. Observers that leave are gone.
TEST(ViewPlanner, PublishedRefsAreTheObserversUpToTheCap) {
  const CellId cell = PackCell({0, 0, 0});
  const PinholeCamera cam = PinholeCamera::FromFov(40, 30, 1.0);
  auto run = [&](int render_refs_max, int views) {
    PlannerOptions o;
    o.r_max = 2;
    o.render_refs_max = render_refs_max;
    o.max_views = 100;
    o.delta_tau_sum = 0.0;  // accept every view with a positive gain (each covers the cell)
    o.tau_max = 1000;
    o.cell_size_m = 1.0;
    auto p = ViewPlanner::Create(o).value();
    // Cameras along a line x = 0..views-1 at 3 m height, all seeing the one cell.
    for (ViewId id = 1; id <= ViewId(views); ++id) {
      Candidate c;
      c.id = id;
      c.local_from_cam.translation = glm::dvec3(double(id - 1), 0.5, 3.0);
      c.id_camera = cam;
      c.cells = {{cell, 50u}};
      c.bytes = 1;
      auto d = p.Consider(c);
      EXPECT_TRUE(d.ok() && d->accepted);
      // Every accepted view changes the cell's published list once it is the observers.
      if (render_refs_max > 0) {
        EXPECT_TRUE(std::binary_search(d->changed_cells.begin(), d->changed_cells.end(), cell));
      }
    }
    return p;
  };
  {
    auto p = run(0, 6);
    EXPECT_EQ(p.PublishedRefs(cell), p.Refs(cell));
    EXPECT_EQ(p.PublishedRefs(cell).size(), 2u);
  }
  {
    auto p = run(8, 6);  // 6 observers <= 8: all of them, R(b_k) among them
    const auto pub = p.PublishedRefs(cell);
    EXPECT_EQ(pub, (std::vector<ViewId>{1, 2, 3, 4, 5, 6}));
    for (ViewId r : p.Refs(cell)) EXPECT_NE(std::find(pub.begin(), pub.end(), r), pub.end());
    EXPECT_EQ(p.CellPublishedRefs().at(cell), pub);
    // A removed view leaves the list and the cell is reported changed.
    auto changed = p.Remove(3).value();
    EXPECT_TRUE(std::binary_search(changed.begin(), changed.end(), cell));
    EXPECT_EQ(p.PublishedRefs(cell), (std::vector<ViewId>{1, 2, 4, 5, 6}));
  }
  {
    auto p = run(4, 21);  // 21 observers on a 20 m line, cap 4
    const auto pub = p.PublishedRefs(cell);
    ASSERT_EQ(pub.size(), 4u);
    const auto refs = p.Refs(cell);
    for (size_t i = 0; i < refs.size(); ++i) EXPECT_EQ(pub[i], refs[i]);  // R(b_k) first
    // The rest spread over the line: every camera of the path is within 7 m of a published one
    // (the first four would leave 17 m uncovered; farthest-point sampling is within 2x the best
    // cover of about 3 m).
    for (int x = 0; x <= 20; ++x) {
      double best = 1e9;
      for (ViewId v : pub) best = std::min(best, std::abs(double(v - 1) - x));
      EXPECT_LE(best, 7.0) << "camera at x = " << x;
    }
    EXPECT_EQ(p.PublishedRefs(cell), pub);  // deterministic
  }
  PlannerOptions bad;
  bad.render_refs_max = -1;
  EXPECT_FALSE(bad.Validate().ok());
}

// Scene 1e5 m from the origin: expressed in a local frame (LocalOrigin) the planner makes the
// same decisions as for the scene at the origin.
TEST(ViewPlanner, SceneFarFromOriginInLocalFrame) {
  PlannerOptions o;
  o.max_views = 6;
  o.cell_size_m = 1.0;
  o.d_max_m = 3.0;
  auto near = ViewPlanner::Create(o).value();
  auto far = ViewPlanner::Create(o).value();
  const glm::dvec3 offset(1e5, -1e5, 0);
  LocalOrigin origin{offset};
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-5, 5), h(2, 4);
  for (ViewId id = 1; id <= 60; ++id) {
    const glm::dvec3 t(u(rng), u(rng), 0), c = t + glm::dvec3(0.3, 0.2, h(rng));
    Candidate a = MakeCandidate(id, c, t, near.grid());
    // The far scene: world pose 1e5 m away, converted with the local origin.
    Rigid3d world_from_cam = a.local_from_cam;
    world_from_cam.translation += offset;
    Candidate b = a;
    b.local_from_cam = origin.ToLocal(world_from_cam);
    const auto da = near.Consider(a).value();
    const auto db = far.Consider(b).value();
    ASSERT_EQ(da.accepted, db.accepted) << id;
    ASSERT_EQ(da.removed, db.removed) << id;
  }
  EXPECT_NEAR(near.tau_sum(), far.tau_sum(), 1e-9);
}

}  // namespace
}  // namespace exo::planning
