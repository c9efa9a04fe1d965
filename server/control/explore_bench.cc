// Exploration benchmark (issue 19 metrics): the simulated drone explores a synthetic scene from
// a start pose under one of three policies, its camera frames (every 0.5 s of flight) building
// the occupancy view it plans in:
//   autonomous  coverage-driven next view (ExplorationPlanner::Autonomous: expected τ gain per
//               metre of flight over reachable safe poses),
//   frontier    nearest frontier (the classic baseline),
//   scripted    the scene's scripted eye-height walk, waypoint after waypoint.
// Coverage is measured on the ground truth: the scene's surface cells (q = --coverage_cell_m,
// area-weighted) whose τ = Σ φ over the frames (SPEC §4: φ = λφ_d + (1−λ)φ_p, the first R_max
// views of a cell as its references) reaches τ_max/2. Prints one JSON line per policy: flight
// time and path length to 50 / 80 / 95 % coverage (null: not reached within --max_flight_s),
// final coverage, collisions with the ground-truth mesh, per-decision cost; over --runs seeded
// start poses.
// Scale: by default the metric and the planner use the apartment's values (0.5 m cells, d_max =
// σ = 2 m, 5 m carving range, 6 m planner range); --scene_scale true derives them from the scene
// (server/geometry/scene_scale.h, SPEC §4: cell size and d_max from the scene's diameter; the
// village: 1 m cells, d_max 13.8 m, σ 18.4 m) and sets the carving and planner range to d_max + σ
// (at most 30 m). Every run also reports the coverage under the other scale (`alt_`), so a flight
// can be read under both metrics.
// Outdoor scenes (a fly-over altitude) fly the scripted policy as the scene's Hilbert fly-over
// (synth::HilbertCurve at the fly-over altitude, camera pitched 40° down), indoor ones the walk.
// MSSIM over time (--mssim_every_s): the frames feed the product's view planner (planning::
// ViewPlanner, ψ_vis from the frame's depth, --store views); every that many seconds of flight the
// stored views are rendered by the CPU lumigraph renderer (the ground-truth mesh as the proxy, so
// the figure measures which views were collected, not the geometry) at --test_views held-out test
// poses (synth::MakeTestPoses, the same for every policy and run) and compared with the ground
// truth (SSIM on luma, mean over the poses).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <unordered_map>

#include "common/cells.h"
#include "common/cli/cli.h"
#include "common/drone/sim_drone.h"
#include "common/lumigraph/cpu_renderer.h"
#include "common/metrics/metrics.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/control/exploration.h"
#include "server/geometry/cell_areas.h"
#include "server/geometry/scene_scale.h"
#include "server/planning/coverage.h"
#include "server/planning/view_planner.h"

namespace {

using namespace exo;
using namespace exo::control;

struct CoverageCell {
  double area = 0, tau = 0;
  double area_by_class[3] = {0, 0, 0};  // facing up (floors, tops), down (ceiling), sideways
  std::vector<glm::dvec3> refs;
};

class GroundTruthCoverage {
 public:
  GroundTruthCoverage(const TriangleMesh& mesh, double q, double d_max, double sigma)
      : q_(q), d_max_(d_max), sigma_(sigma) {
    for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
      const glm::dvec3 a(mesh.positions[mesh.indices[t]]), b(mesh.positions[mesh.indices[t + 1]]),
          c(mesh.positions[mesh.indices[t + 2]]);
      const double area = 0.5 * glm::length(glm::cross(b - a, c - a));
      if (!(area > 0)) continue;
      const double len = std::max({glm::length(b - a), glm::length(c - a), glm::length(c - b)});
      const int n = std::max(1, static_cast<int>(std::ceil(len / (0.25 * q))));
      const double w = area / ((n + 1) * (n + 2) / 2.0);
      const double nz = glm::normalize(glm::cross(b - a, c - a)).z;
      const int cls = nz > 0.7 ? 0 : nz < -0.7 ? 1 : 2;
      class_total_[cls] += area;
      for (int i = 0; i <= n; ++i)
        for (int j = 0; i + j <= n; ++j) {
          CoverageCell& cc = cells_[Key(a + (b - a) * (double(i) / n) + (c - a) * (double(j) / n))];
          cc.area += w;
          cc.area_by_class[cls] += w;
        }
      total_ += area;
    }
  }
  CellId Key(const glm::dvec3& p) const { return PackCell(glm::ivec3(glm::floor(p / q_))); }
  void AddFrame(const ImageF& z, const PinholeCamera& cam, const Rigid3d& local_from_cam,
                int stride) {
    std::unordered_map<CellId, double> pixels;
    for (int y = stride / 2; y < z.height(); y += stride)
      for (int x = stride / 2; x < z.width(); x += stride) {
        const float d = z.at(x, y);
        if (!(d > 0) || !std::isfinite(d)) continue;
        pixels[Key(local_from_cam * cam.Unproject({x, y}, d))] += 1;
      }
    const double sample_sr = cam.PixelSolidAngle() * stride * stride;
    const glm::dvec3 eye = local_from_cam.translation;
    for (const auto& [k, n] : pixels) {
      auto it = cells_.find(k);
      if (it == cells_.end()) continue;
      CoverageCell& c = it->second;
      const glm::dvec3 centre = (glm::dvec3(UnpackCell(k)) + 0.5) * q_;
      const double d = glm::length(eye - centre);
      if (d < 1e-6) continue;
      const glm::dvec3 dir = (eye - centre) / d;
      const double phi_d = planning::DirectionalCoverage(dir, c.refs, 16);
      const double g = planning::DistanceQuality(d, d_max_, sigma_);
      const double psi_total = planning::PsiTotal(c.area, q_ * q_, d, sample_sr, 0.1);
      const double phi =
          planning::Coverage(0.4, phi_d, planning::PositionalCoverage(g, n, psi_total));
      c.tau = std::min(4.0, c.tau + phi);
      if (c.refs.size() < 16) c.refs.push_back(dir);
    }
  }
  // Per surface class (0 up, 1 down, 2 sideways): its share of the area and the fraction of it
  // in cells with τ >= tau.
  double ClassShare(int cls) const { return total_ > 0 ? class_total_[cls] / total_ : 0; }
  double ClassFraction(int cls, double tau) const {
    double a = 0;
    for (const auto& [k, c] : cells_)
      if (c.tau >= tau) a += c.area_by_class[cls];
    return class_total_[cls] > 0 ? a / class_total_[cls] : 0;
  }
  void Dump(FILE* f) const {
    for (const auto& [k, c] : cells_) {
      const glm::ivec3 i = UnpackCell(k);
      std::fprintf(f, "%d %d %d %.4f %.3f %.4f %.4f %.4f %zu\n", i.x, i.y, i.z, c.area, c.tau,
                   c.area_by_class[0], c.area_by_class[1], c.area_by_class[2], c.refs.size());
    }
  }
  // Where the uncovered area (τ < tau) sits in the planner's view: cells whose box holds an
  // occupied occupancy cell the planner still rates below tau ("known"), only occupied cells it
  // rates at or above tau ("planner_covered"), or no occupied cell at all ("unmodelled"; of
  // which "unmodelled_outside_grid": the box lies wholly outside the occupancy view); as
  // fractions of the whole surface area. `reachable_view`: of the "known" area, the part with a
  // clear cell within `view_m` of the cell's centre.
  nlohmann::json Gap(const OccupancyGrid& g, const ExplorationPlanner& p, double tau,
                     double view_m) const {
    double known = 0, covered = 0, unmodelled = 0, near_clear = 0, outside = 0;
    const int rv = static_cast<int>(std::ceil(view_m / g.options().cell_m));
    for (const auto& [k, c] : cells_) {
      if (c.tau >= tau) continue;
      const glm::dvec3 lo = glm::dvec3(UnpackCell(k)) * q_;
      const glm::ivec3 a = g.CellOf(lo + 1e-6), b = g.CellOf(lo + q_ - 1e-6);
      int occupied = 0, low = 0, in_grid = 0;
      for (int z = a.z; z <= b.z; ++z)
        for (int y = a.y; y <= b.y; ++y)
          for (int x = a.x; x <= b.x; ++x) {
            const glm::ivec3 q(x, y, z);
            if (!g.InGrid(q)) continue;
            ++in_grid;
            if (g.At(q) != Occupancy::kOccupied) continue;
            ++occupied;
            if (p.Tau(g.Index(q)) < tau) ++low;
          }
      if (occupied == 0) {
        unmodelled += c.area;
        if (in_grid == 0) outside += c.area;
      } else if (low == 0) {
        covered += c.area;
      } else {
        known += c.area;
        const glm::ivec3 m = g.CellOf(lo + 0.5 * q_);
        bool clear = false;
        for (int dz = -rv; dz <= rv && !clear; ++dz)
          for (int dy = -rv; dy <= rv && !clear; ++dy)
            for (int dx = -rv; dx <= rv && !clear; ++dx) {
              const glm::ivec3 q = m + glm::ivec3(dx, dy, dz);
              if (g.InGrid(q) && g.IsClear(q)) clear = true;
            }
        if (clear) near_clear += c.area;
      }
    }
    const double t = total_ > 0 ? total_ : 1;
    return {{"known_below", known / t},
            {"planner_covered", covered / t},
            {"unmodelled", unmodelled / t},
            {"unmodelled_outside_grid", outside / t},
            {"known_below_with_clear_cell_within_m", view_m},
            {"known_below_near_clear", near_clear / t}};
  }
  double Fraction(double tau) const {
    double a = 0;
    for (const auto& [k, c] : cells_)
      if (c.tau >= tau) a += c.area;
    return total_ > 0 ? a / total_ : 0;
  }

 private:
  double q_, d_max_, sigma_;
  double total_ = 0;
  double class_total_[3] = {0, 0, 0};
  std::unordered_map<CellId, CoverageCell> cells_;
};

// The metric's scale: ground-truth cell, d_max and σ of (3.11).
struct MetricScale {
  double cell_m = 0.5, d_max_m = 2.0, sigma_m = 2.0;
  nlohmann::json Json() const {
    return {{"cell_m", cell_m}, {"d_max_m", d_max_m}, {"sigma_m", sigma_m}};
  }
};

// Held-out test poses and their ground-truth images (the same for every policy and run).
struct TestSet {
  PinholeCamera camera;
  std::vector<Rigid3d> poses;
  std::vector<ImageU8> truth;
};

ImageU8 ToSrgb8(const ImageF& linear) {
  ImageU8 out(linear.width(), linear.height(), linear.channels());
  for (size_t k = 0; k < out.size(); ++k) out.data()[k] = synth::LinearToSrgb8(linear.data()[k]);
  return out;
}

struct RunConfig {
  std::string policy;
  uint64_t seed = 0;
  double max_flight_s = 180, cell_m = 0.15, dwell_s = 1.0, grid_margin_m = 0.5;
  double carve_range_m = 5.0;
  MetricScale metric, alt_metric;
  std::string dump_cells;
  ExploreOptions eo;
  bool no_return_is_free = false;
  bool sky_rule = false;  // missing depth carved by OccupancyGrid::SkyRule (a real sensor's)
  double sky_min_elevation_rad = -0.1;
  // Outdoor scenes: the autonomous mode falls back on the fly-over's path as a sweep
  // (ExploreOptions::sweep) while its best view's gain is mostly unknown space.
  bool sweep_fallback = false;
  // MSSIM over time: every this many seconds of flight (0: off), views kept by the planner.
  double mssim_every_s = 0;
  int store_views = 100;
  const TestSet* tests = nullptr;
};

struct RunResult {
  std::vector<std::pair<double, double>> curve;  // (flight s, coverage)
  std::vector<std::pair<double, double>> alt_curve;  // (flight s, coverage at the other scale)
  std::vector<std::pair<double, double>> mssim;  // (flight s, MSSIM at the test poses)
  size_t stored_views = 0;
  double mssim_cpu_s = 0;  // lumigraph renders at the test poses (not in decision_ms)
  double final_seen = 0;                         // area fraction with τ > 0
  std::vector<double> path_at;                   // path length at each curve sample
  uint64_t collisions = 0, decisions = 0, replans = 0;
  double decision_ms = 0, final_coverage = 0, path_m = 0;
  double class_share[3] = {0, 0, 0}, class_coverage[3] = {0, 0, 0}, class_seen[3] = {0, 0, 0};
  // Per decision (autonomous / frontier): what was chosen and how it ended.
  struct Decision {
    double t = 0, coverage = 0, gain = 0, gain_unknown = 0, path_m = 0;
    bool sweep = false;  // a point of the sweep fallback
    std::string kind;     // view | sweep | climb | none
    glm::dvec3 goal{0.0};
    std::string outcome;  // none | unreachable | reached | timeout | replanned | open
  };
  std::vector<Decision> log;
  nlohmann::json gap;  // GroundTruthCoverage::Gap at the end
};

// MSSIM of the store at the test poses (ground-truth mesh as the proxy).
double StoreMssim(const synth::SynthScene& scene, const planning::ViewPlanner& vp,
                  const std::map<ViewId, StoredView>& stored, const TestSet& tests) {
  LumigraphModel model;
  model.grid = vp.grid();
  MeshChunk chunk;
  chunk.id = 0;
  chunk.version = 1;
  chunk.mesh = scene.mesh;
  model.chunks[0] = std::move(chunk);
  for (const auto& [id, v] : stored) model.views[id] = v;
  model.cell_refs = vp.CellPublishedRefs();
  auto renderer = CpuLumigraphRenderer::Create(model, {});
  if (!renderer.ok()) return 0;
  double sum = 0;
  int n = 0;
  for (size_t i = 0; i < tests.poses.size(); ++i) {
    auto r = (*renderer)->Render(tests.camera, tests.poses[i]);
    if (!r.ok()) continue;
    auto ssim = Ssim(r->color, tests.truth[i]);
    if (!ssim.ok()) continue;
    sum += *ssim;
    ++n;
  }
  return n ? sum / n : 0;
}

double CpuSeconds() {
  return static_cast<double>(std::clock()) / CLOCKS_PER_SEC;
}

RunResult Run(const synth::SynthScene& scene, const RunConfig& rc) {
  const std::string& policy = rc.policy;
  const uint64_t seed = rc.seed;
  const double max_flight_s = rc.max_flight_s, cell_m = rc.cell_m, dwell_s = rc.dwell_s;
  ExploreOptions eo = rc.eo;
  RunResult out;
  std::mt19937_64 rng(seed);
  const SceneFrame frame = SceneFrame::ZUp();
  SafeFlightOptions so;
  so.zones = {{"navigable", scene.navigable.min, scene.navigable.max}};
  so.cell_m = cell_m;
  so.drone_radius_m = 0.2;
  so.region_fallback = false;
  so.grid_margin_m = rc.grid_margin_m;
  auto safe_or = SafeFlight::Create(so);
  EXO_CHECK(safe_or.ok());
  SafeFlight& safe = *safe_or;
  eo.seed = seed;
  if (rc.sweep_fallback && policy == "autonomous" && scene.flyover_altitude_m > 0) {
    // The scripted fly-over's path (below) as the autonomous mode's sweep fallback.
    // (the library's HilbertSweep, as the Control service builds it from its zones).
    eo.sweep = HilbertSweep(scene.navigable.min, scene.navigable.max, scene.flyover_altitude_m,
                            frame);
  }
  ExplorationPlanner planner(eo);
  SimDroneOptions dopt;
  SimDrone drone(dopt);
  const glm::dvec3 start = scene.walk_waypoints[std::uniform_int_distribution<size_t>(
      0, scene.walk_waypoints.size() - 1)(rng)];
  const double yaw0 = std::uniform_real_distribution<double>(-kPi, kPi)(rng);
  drone.Reset(start, yaw0);
  CollisionMonitor collisions(scene.mesh, dopt.radius_m);
  GroundTruthCoverage cov(scene.mesh, rc.metric.cell_m, rc.metric.d_max_m, rc.metric.sigma_m);
  GroundTruthCoverage alt(scene.mesh, rc.alt_metric.cell_m, rc.alt_metric.d_max_m,
                          rc.alt_metric.sigma_m);
  // The product's view planner over the same frames (MSSIM over time): ψ_vis from the frame's
  // depth, cell areas from the ground-truth mesh (the proxy the store is rendered with).
  std::optional<planning::ViewPlanner> vp;
  std::map<ViewId, StoredView> stored;
  if (rc.mssim_every_s > 0 && rc.tests) {
    planning::PlannerOptions po;
    po.cell_size_m = rc.metric.cell_m;
    po.d_max_m = rc.metric.d_max_m;
    po.sigma_m = rc.metric.sigma_m;
    po.lambda = scene.flyover_altitude_m > 0 ? 0.5 : 0.4;
    po.max_views = rc.store_views;
    auto p = planning::ViewPlanner::Create(po);
    EXO_CHECK(p.ok());
    vp.emplace(std::move(*p));
    CellAreas areas(vp->grid());
    MeshChunk chunk;
    chunk.mesh = scene.mesh;
    areas.UpdateChunk(chunk);
    for (const auto& [cell, a] : areas.areas()) (void)vp->SetCellArea(cell, a);
  }
  double next_mssim = rc.mssim_every_s;
  ViewId next_view = 1;
  // Outdoor scenes: the scripted policy is the Hilbert fly-over at the fly-over altitude (a
  // climb from the start first), the camera 40° down; indoor: the eye-height walk.
  const bool flyover = policy == "scripted" && scene.flyover_altitude_m > 0;
  std::vector<glm::dvec3> script = scene.walk_waypoints;
  if (flyover) {
    const glm::dvec3 lo = scene.navigable.min, hi = scene.navigable.max;
    const double inset = 0.15 * std::min(hi.x - lo.x, hi.y - lo.y);
    script.clear();
    for (const glm::dvec2& h : synth::HilbertCurve(3))
      script.push_back({lo.x + inset + h.x * (hi.x - lo.x - 2 * inset),
                        lo.y + inset + h.y * (hi.y - lo.y - 2 * inset), scene.flyover_altitude_m});
  }
  synth::RenderOptions ro;
  ro.width = 160;
  ro.height = 120;
  const PinholeCamera cam = ro.Camera();

  std::vector<glm::dvec3> route;
  size_t wp = 0;
  double goal_yaw = yaw0, route_start = 0, arrived_at = -1;
  // Camera gimbal: pitch (+ up) towards the goal's on the last leg, level while travelling,
  // at most 1.5 rad/s.
  double goal_pitch = 0, cam_pitch = 0, travel_pitch = 0, goal_pass_m = 0, goal_dwell_s = dwell_s;
  size_t script_index = 0;
  glm::dvec3 prev = start;
  double next_frame = 0;
  bool finished = false;
  const int steps = static_cast<int>(max_flight_s * dopt.rate_hz);
  for (int i = 0; i < steps && !finished; ++i) {
    const double t = drone.state().timestamp_s;
    const DroneState s = drone.state();
    if (t >= next_frame) {
      next_frame += 0.5;
      const Rigid3d pose = synth::LookAt(
          s.position, s.position + std::cos(cam_pitch) * frame.Heading(s.yaw) +
                          std::sin(cam_pitch) * frame.up);
      ImageF z;
      auto colour = synth::RenderLinear(scene, pose, ro, &z);
      if (colour.ok()) {
        // The drone's own volume is free; the frame carves the rest.
        OccupancyGrid& g = safe.grid();
        const glm::ivec3 c = g.CellOf(s.position);
        const int r = static_cast<int>(std::ceil(dopt.radius_m / cell_m));
        for (int dz = -r; dz <= r; ++dz)
          for (int dy = -r; dy <= r; ++dy)
            for (int dx = -r; dx <= r; ++dx)
              if (glm::length(glm::dvec3(dx, dy, dz)) * cell_m <= dopt.radius_m)
                g.Set(c + glm::ivec3(dx, dy, dz), Occupancy::kFree);
        if (rc.sky_rule) {  // a real sensor's rule for missing depth (OccupancyGrid::SkyRule)
          OccupancyGrid::SkyRule sky;
          sky.up = frame.up;
          sky.color = &*colour;
          sky.min_elevation_rad = rc.sky_min_elevation_rad;
          g.CarveDepth(z, cam, pose, 2, rc.carve_range_m, sky);
        } else {
          g.CarveDepth(z, cam, pose, 2, rc.carve_range_m, rc.no_return_is_free);
        }
        planner.Observe(g, z, cam, pose, 2);
        cov.AddFrame(z, cam, pose, 2);
        alt.AddFrame(z, cam, pose, 2);
        if (vp) {
          planning::Candidate c;
          c.id = next_view++;
          c.local_from_cam = pose;
          auto cells = planning::CountDepthCellPixels(z, cam, pose, vp->grid(), 2, &c.id_camera);
          if (cells.ok()) {
            c.cells = std::move(*cells);
            c.bytes = size_t(cam.width) * cam.height * 7 + sizeof(StoredView);
            auto d = vp->Consider(c);
            if (d.ok() && d->accepted) {
              for (ViewId v : d->removed) stored.erase(v);
              StoredView sv;
              sv.id = c.id;
              sv.camera = cam;
              sv.local_from_cam = pose;
              sv.color = ToSrgb8(*colour);
              sv.depth_m = z;
              stored[c.id] = std::move(sv);
            }
          }
        }
      }
      out.curve.emplace_back(t, cov.Fraction(2.0));
      out.alt_curve.emplace_back(t, alt.Fraction(2.0));
      if (vp && t + 1e-9 >= next_mssim) {
        const double c0 = CpuSeconds();
        out.mssim.emplace_back(next_mssim, StoreMssim(scene, *vp, stored, *rc.tests));
        out.mssim_cpu_s += CpuSeconds() - c0;
        next_mssim += rc.mssim_every_s;
      }
      out.path_at.push_back(out.path_m);
      if (out.curve.back().second >= 0.95 && !vp) break;
      // A route that crosses newly found obstacles is dropped.
      if (!route.empty()) {
        glm::dvec3 a = s.position;
        for (size_t k = wp; k < route.size(); ++k) {
          if (!safe.SegmentPermitted(a, route[k]) && policy != "scripted") {
            route.clear();
            ++out.replans;
            break;
          }
          a = route[k];
        }
      }
    }
    // Decide when idle: spin first, then the policy.
    // A point to pass through (a sweep point, ExploreOptions::sweep_pass_m): there once within
    // that distance, no hover.
    const bool at_goal =
        !route.empty() && wp + 1 == route.size() &&
        (goal_pass_m > 0 ? glm::length(s.position - route.back()) < goal_pass_m
                         : glm::length(s.position - route.back()) < 0.15 &&
                               std::abs(WrapAngle(s.yaw - goal_yaw)) < 0.1 &&
                               std::abs(cam_pitch - goal_pitch) < 0.05);
    // At the goal the drone hovers `dwell_s` (frames keep coming: τ grows from the chosen view).
    if (at_goal && arrived_at < 0) arrived_at = t;
    if (!at_goal) arrived_at = -1;
    const bool dwelt = at_goal && t - arrived_at >= (goal_pass_m > 0 ? 0.0 : goal_dwell_s);
    if (route.empty() || dwelt || t - route_start > 30) {
      if (!out.log.empty() && out.log.back().outcome == "open")
        out.log.back().outcome = dwelt ? "reached" : route.empty() ? "replanned" : "timeout";
      arrived_at = -1;
      route_start = t;
      goal_pitch = 0;
      travel_pitch = 0;
      goal_pass_m = 0;
      goal_dwell_s = dwell_s;
      if (t < 4.0) {  // initial look-around: four quarter turns in place
        route = {start};
        wp = 0;
        goal_yaw = WrapAngle(yaw0 + kPi / 2 * (1 + std::floor(t)));
      } else if (policy == "scripted") {
        glm::dvec3 target = script[script_index % script.size()];
        // The fly-over climbs above the start before its first leg.
        if (flyover && s.position.z < scene.flyover_altitude_m - 0.5)
          target = {s.position.x, s.position.y, scene.flyover_altitude_m};
        else
          ++script_index;
        route = {target};
        wp = 0;
        const glm::dvec3 dir = target - s.position;
        goal_yaw = glm::length(glm::dvec2(dir.x, dir.y)) > 0.3 ? frame.YawOf(dir) : s.yaw;
        goal_pitch = flyover ? -glm::radians(40.0) : 0.0;
        if (!out.log.empty() && out.log.back().outcome == "open") out.log.back().outcome = "reached";
        RunResult::Decision dl;  // the script's waypoints, for --trace_decisions
        dl.t = t;
        dl.coverage = out.curve.empty() ? 0 : out.curve.back().second;
        dl.goal = target;
        dl.kind = "script";
        dl.outcome = "open";
        out.log.push_back(dl);
      } else {
        const auto t0 = std::chrono::steady_clock::now();
        std::optional<NextView> v = policy == "autonomous"
                                        ? planner.Autonomous(safe, s.position, frame)
                                        : planner.NearestFrontier(safe, s.position, frame);
        std::optional<Route> r;
        if (v) {
          auto plan = safe.Plan(s.position, v->pose.position);
          if (plan.ok()) r = *plan;
        }
        out.decision_ms +=
            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                .count();
        ++out.decisions;
        RunResult::Decision dl;
        dl.t = t;
        dl.coverage = out.curve.empty() ? 0 : out.curve.back().second;
        if (v) {
          dl.gain = v->gain;
          dl.gain_unknown = v->gain_unknown;
          dl.path_m = v->path_m;
          dl.sweep = v->sweep_index >= 0;
          dl.kind = v->climb ? "climb" : dl.sweep ? "sweep" : "view";
          dl.goal = v->pose.position;
        }
        dl.outcome = !v ? "none" : r ? "open" : "unreachable";
        out.log.push_back(dl);
        if (!v) {
          finished = true;  // nothing left to explore
        } else if (r) {
          route = r->waypoints;
          wp = 0;
          goal_yaw = v->pose.yaw;
          goal_pitch = v->pitch;
          travel_pitch = v->travel_pitch;
          goal_pass_m = v->pass_m;
          if (v->dwell_s >= 0) goal_dwell_s = v->dwell_s;
        } else {
          route = {s.position};  // unreachable this time: turn and look again
          wp = 0;
          goal_yaw = WrapAngle(s.yaw + kPi / 2);
        }
      }
    }
    while (wp + 1 < route.size() && glm::length(s.position - route[wp]) < 0.15) ++wp;
    const bool last = wp + 1 == route.size();
    const double want_pitch = last ? goal_pitch : travel_pitch, max_step = 1.5 / dopt.rate_hz;
    cam_pitch += std::clamp(want_pitch - cam_pitch, -max_step, max_step);
    drone.Receive({route[wp], last ? goal_yaw : frame.YawOf(route[wp] - s.position)}, t);
    const DroneState& n = drone.Step();
    collisions.Update(n.position);
    out.path_m += glm::length(n.position - prev);
    prev = n.position;
  }
  if (policy != "scripted") out.gap = cov.Gap(safe.grid(), planner, 2.0, 2.5);
  out.collisions = collisions.collisions();
  out.final_coverage = out.curve.empty() ? 0 : out.curve.back().second;
  out.final_seen = cov.Fraction(1e-9);
  // MSSIM checkpoints not reached (a run that ended early): the store as it ended.
  while (vp && next_mssim <= max_flight_s + 1e-9) {
    const double c0 = CpuSeconds();
    out.mssim.emplace_back(next_mssim, StoreMssim(scene, *vp, stored, *rc.tests));
    out.mssim_cpu_s += CpuSeconds() - c0;
    next_mssim += rc.mssim_every_s;
  }
  out.stored_views = stored.size();
  if (!rc.dump_cells.empty()) {  // the last run's cells win
    FILE* f = std::fopen(rc.dump_cells.c_str(), "w");
    if (f) {
      cov.Dump(f);
      std::fclose(f);
    }
  }
  for (int c = 0; c < 3; ++c) {
    out.class_share[c] = cov.ClassShare(c);
    out.class_coverage[c] = cov.ClassFraction(c, 2.0);
    out.class_seen[c] = cov.ClassFraction(c, 1e-9);
  }
  return out;
}

// One line per run: the plateau is the first time after which coverage rose by less than 2
// points up to the end; decisions before and after it are summarised by outcome, share of the
// chosen gain from unknown space, and repeats (a goal within 0.3 m of an earlier goal).
void PrintRun(const std::string& scene, const std::string& policy, uint64_t seed,
              const RunResult& res, bool trace, const std::vector<double>& levels) {
  nlohmann::json j;
  j["bench"] = "explore_run";
  j["scene"] = scene;
  j["policy"] = policy;
  j["seed"] = seed;
  j["final_coverage"] = res.final_coverage;
  j["final_seen"] = res.final_seen;
  j["collisions"] = res.collisions;
  double t80 = -1, plateau = 0;
  for (const auto& [t, c] : res.curve)
    if (c >= 0.8) {
      t80 = t;
      break;
    }
  for (const auto& [t, c] : res.curve)
    if (res.final_coverage - c < 0.02) {
      plateau = t;
      break;
    }
  j["t80_s"] = t80 >= 0 ? nlohmann::json(t80) : nlohmann::json(nullptr);
  // Flight time and path length to each --levels level (null: not reached).
  nlohmann::json to_s = nlohmann::json::object(), to_m = nlohmann::json::object();
  for (double level : levels) {
    char buf[32];
    std::snprintf(buf, sizeof(buf), "%g", std::round(level * 1000) / 10);
    to_s[buf] = nullptr;
    to_m[buf] = nullptr;
    for (size_t k = 0; k < res.curve.size(); ++k)
      if (res.curve[k].second >= level) {
        to_s[buf] = res.curve[k].first;
        to_m[buf] = res.path_at[k];
        break;
      }
  }
  j["flight_s_to"] = to_s;
  j["path_m_to"] = to_m;
  j["path_m"] = res.path_m;
  j["plateau_s"] = plateau;
  j["flight_s"] = res.curve.empty() ? 0 : res.curve.back().first;
  auto summarise = [&](bool after) {
    std::map<std::string, int> outcomes;
    int n = 0, repeats = 0, mostly_unknown = 0, sweeps = 0;
    double gain = 0, unknown = 0, path = 0, goal_z = 0;
    std::vector<glm::dvec3> goals;
    for (const auto& d : res.log) {
      if ((d.t >= plateau) != after) continue;
      ++n;
      ++outcomes[d.outcome];
      sweeps += d.sweep;
      if (d.outcome == "none") continue;
      gain += d.gain;
      unknown += d.gain_unknown;
      path += d.path_m;
      goal_z += d.goal.z;
      if (d.gain_unknown > 0.5 * d.gain) ++mostly_unknown;
      for (const auto& g : goals)
        if (glm::length(g - d.goal) < 0.3) {
          ++repeats;
          break;
        }
      goals.push_back(d.goal);
    }
    nlohmann::json s;
    s["decisions"] = n;
    s["outcomes"] = outcomes;
    s["mean_gain"] = n ? gain / n : 0;
    s["unknown_share_of_gain"] = gain > 0 ? unknown / gain : 0;
    s["mostly_unknown"] = mostly_unknown;
    s["sweep_points"] = sweeps;
    s["repeated_goals"] = repeats;
    s["mean_path_m"] = n ? path / n : 0;
    s["mean_goal_z_m"] = n ? goal_z / n : 0;
    return s;
  };
  j["before_plateau"] = summarise(false);
  j["after_plateau"] = summarise(true);
  j["uncovered_in_planner_view"] = res.gap;
  j["final_coverage_alt"] = res.alt_curve.empty() ? 0 : res.alt_curve.back().second;
  nlohmann::json m = nlohmann::json::object();
  for (const auto& [t, v] : res.mssim) m[std::to_string(static_cast<int>(std::lround(t)))] = v;
  j["mssim_at_s"] = m;
  j["stored_views"] = res.stored_views;
  if (trace) {  // every decision: [t, coverage, goal x, y, z, kind, outcome]
    nlohmann::json d = nlohmann::json::array();
    for (const auto& l : res.log)
      d.push_back({std::round(l.t * 10) / 10, std::round(l.coverage * 1000) / 1000,
                   std::round(l.goal.x * 10) / 10, std::round(l.goal.y * 10) / 10,
                   std::round(l.goal.z * 10) / 10, l.kind, l.outcome});
    j["decisions"] = d;
  }
  std::printf("%s\n", j.dump().c_str());
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Exploration benchmark: coverage-driven next view vs nearest frontier vs scripted.",
               "exoview_explore_bench"};
  exo::cli::Setup(app);
  std::string scene_name = "apartment";
  std::vector<std::string> policies = {"autonomous", "frontier", "scripted"};
  int runs = 3;
  uint64_t seed0 = 1000;
  double dwell_s = 1.0;
  double max_flight_s = 180, coverage_cell_m = 0.5, cell_m = 0.15;
  app.add_option("--scene", scene_name, "apartment | village");
  app.add_option("--policies", policies, "autonomous, frontier, scripted")->delimiter(',');
  app.add_option("--runs", runs, "seeded start poses per policy")->check(CLI::PositiveNumber);
  app.add_option("--max_flight_s", max_flight_s, "flight time per run")->check(CLI::PositiveNumber);
  app.add_option("--coverage_cell_m", coverage_cell_m, "ground-truth surface cell")
      ->check(CLI::PositiveNumber);
  app.add_option("--cell_m", cell_m, "occupancy cell")->check(CLI::PositiveNumber);
  ExploreOptions eo;
  eo.tau_goal = 2.0;              // the coverage threshold τ_max/2
  eo.pitches = {-0.5, 0.0, 0.5};  // a gimbal: ±29° (the camera's vertical FOV is ±25°)
  app.add_option("--unknown_gain", eo.unknown_gain,
                 "autonomous: gain of a ray ending in unknown space");
  app.add_option("--travel_offset_m", eo.travel_offset_m,
                 "autonomous: score = gain / (path + this)");
  app.add_option("--candidates", eo.candidates, "autonomous: candidate positions per decision");
  app.add_option("--range_m", eo.range_m, "autonomous: frustum ray length in the gain");
  app.add_option("--tau_goal", eo.tau_goal,
                 "autonomous: a cell's weight is (tau_goal - tau)/tau_goal (0: tau_max)");
  app.add_option("--area_weight", eo.area_weight,
                 "autonomous: weight a ray's gain by (distance/d_max)^2");
  app.add_option("--pitches", eo.pitches,
                 "camera gimbal pitch candidates, rad (+ up); 0 = a level camera")
      ->delimiter(',');
  double grid_margin_m = SafeFlightOptions{}.grid_margin_m;
  app.add_option("--grid_margin_m", grid_margin_m,
                 "occupancy view beyond the navigable box (0: the box only, session 10)")
      ->check(CLI::NonNegativeNumber);
  bool no_return_is_free = false;
  app.add_option("--sky_is_free", no_return_is_free,
                 "pixels without depth (the renderer's sky) carve free space to 5 m; off: they "
                 "carve nothing and the sky inside the navigable box stays unknown");
  bool sweep_fallback = false;
  bool sky_rule = false;
  app.add_option("--sky_rule", sky_rule,
                 "pixels without depth carve free space only where they look like sky (above "
                 "the horizon, nothing measured above them in the image column, bright and "
                 "blue: OccupancyGrid::SkyRule, a rule for real sensors); overrides --sky_is_free");
  double sky_min_elevation_rad = -0.1;
  app.add_option("--sky_min_elevation_rad", sky_min_elevation_rad,
                 "--sky_rule: the lowest ray elevation a missing depth is taken as sky at (rad)");
  app.add_option("--sweep_fallback", sweep_fallback,
                 "outdoor scenes: the autonomous mode flies the fly-over's path as a sweep while "
                 "its best view's gain is mostly (> 90 %) unknown space (ExploreOptions::sweep)");
  app.add_option("--sweep_climb", eo.sweep_climb,
                 "with --sweep_fallback: climb to the sweep's altitude first, looking up "
                 "(ExploreOptions::sweep_climb; session 15)");
  app.add_option("--sweep_travel_pitch", eo.sweep_travel_pitch,
                 "with --sweep_fallback: camera pitch (rad) while travelling between sweep points "
                 "at the sweep's altitude (default: level)");
  app.add_option("--sweep_climb_face_centre", eo.sweep_climb_face_centre,
                 "autonomous + sweep: on a climb up to a sweep point the camera faces the centre "
                 "of the points still to fly (false: the leg, session 15)");
  app.add_option("--sweep_pitch", eo.sweep_pitch,
                 "autonomous + sweep: camera pitch at the sweep's points (rad, + up)");
  app.add_option("--sweep_pass_m", eo.sweep_pass_m,
                 "with --sweep_fallback: sweep points at the sweep's altitude are passed through "
                 "within this distance, not hovered at (0: hovered at, dwell_s)");
  app.add_option("--sweep_look_misses", eo.sweep_look_misses,
                 "with --sweep_fallback: unreached looks at one sweep point before it gets no "
                 "more (ExploreOptions::sweep_look_misses)");
  app.add_option("--sweep_look_dwell_s", eo.sweep_look_dwell_s,
                 "with --sweep_fallback: the hover at a look before a climb, s (< 0: dwell_s)");
  bool per_run = false;
  app.add_option("--per_run", per_run,
                 "also print one line per run (bench explore_run): coverage, decisions before and "
                 "after the plateau (what the planner picked once coverage stopped growing), "
                 "where the uncovered area sits in the planner's view");
  bool trace_decisions = false;
  app.add_option("--trace_decisions", trace_decisions,
                 "with --per_run: list every decision (time, coverage, goal, kind, outcome)");
  std::string dump_cells;
  app.add_option("--dump_cells", dump_cells,
                 "write the last run's ground-truth cells (x y z area tau area_up area_down "
                 "area_side refs, cell indices at --coverage_cell_m) to this file");
  app.add_option("--dwell_s", dwell_s, "hover this long at each goal before the next decision");
  app.add_option("--seed0", seed0, "first run's seed (runs use seed0, seed0 + 1, ...)");
  bool scene_scale = false;
  app.add_option("--scene_scale", scene_scale,
                 "derive the metric's cell, d_max and sigma and the planner's d_max, sigma and "
                 "range (= carving range = d_max + sigma, at most 30 m) from the scene's diameter "
                 "(scene_scale.h); false: the apartment's 0.5 m cells, d_max = sigma = 2 m, "
                 "5 m carving and 6 m planner range");
  double carve_range_m = 0;
  app.add_option("--carve_range_m", carve_range_m,
                 "depth beyond this carves nothing (0: 5 m, or the planner range with "
                 "--scene_scale)")
      ->check(CLI::NonNegativeNumber);
  double mssim_every_s = 0;
  int test_views = 12, store_views = 100;
  app.add_option("--mssim_every_s", mssim_every_s,
                 "MSSIM of the planner's store at the held-out test poses every this many "
                 "seconds of flight (0: off)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--test_views", test_views, "held-out test poses (160x120)")
      ->check(CLI::PositiveNumber);
  app.add_option("--store", store_views, "views the view planner keeps (MSSIM)")
      ->check(CLI::PositiveNumber);
  std::vector<double> levels = {0.5, 0.8, 0.95};
  app.add_option("--levels", levels,
                 "coverage levels to report flight time and path to (fractions of the surface "
                 "area)")
      ->delimiter(',');
  int visible_poses = 0;
  app.add_option("--visible_poses", visible_poses,
                 "estimate how much of the surface can be seen at all: render this many random "
                 "poses in the navigable free space (0.3 m from solids, pitch -90..+30 deg), "
                 "print the area fraction they see (bench explore_visible) and run nothing else")
      ->check(CLI::NonNegativeNumber);
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  for (const auto& p : policies)
    if (p != "autonomous" && p != "frontier" && p != "scripted") {
      std::fprintf(stderr, "exoview_explore_bench: unknown policy '%s'\n", p.c_str());
      return 2;
    }
  auto kind = synth::ParseSceneKind(scene_name);
  if (!kind.ok()) {
    std::fprintf(stderr, "exoview_explore_bench: %s\n",
                 std::string(kind.status().message()).c_str());
    return 2;
  }
  auto scene = synth::MakeScene(*kind, synth::SceneOptions{});
  if (!scene.ok()) return 1;
  MetricScale fixed_scale;
  fixed_scale.cell_m = coverage_cell_m;
  const SceneScale derived = DeriveSceneScale(scene->bounds.min, scene->bounds.max);
  MetricScale scene_derived{derived.cell_size_m, derived.d_max_m, derived.sigma_m};
  if (visible_poses > 0) {
    const MetricScale m = scene_scale ? scene_derived : fixed_scale;
    GroundTruthCoverage vis(scene->mesh, m.cell_m, m.d_max_m, m.sigma_m);
    std::mt19937_64 rng(99);
    auto uni = [&](double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); };
    synth::RenderOptions ro;
    ro.width = 160;
    ro.height = 120;
    const PinholeCamera cam = ro.Camera();
    const SceneFrame frame = SceneFrame::ZUp();
    const auto& nb = scene->navigable;
    int done = 0;
    for (int tries = 0; done < visible_poses && tries < 100 * visible_poses; ++tries) {
      const glm::dvec3 p(uni(nb.min.x, nb.max.x), uni(nb.min.y, nb.max.y),
                         uni(nb.min.z, nb.max.z));
      if (!scene->IsFree(p, 0.3)) continue;
      const double yaw = uni(-kPi, kPi), pitch = uni(-kPi / 2 + 1e-3, 0.52);
      const Rigid3d pose = synth::LookAt(
          p, p + std::cos(pitch) * frame.Heading(yaw) + std::sin(pitch) * frame.up);
      ImageF z;
      if (!synth::RenderLinear(*scene, pose, ro, &z).ok()) continue;
      vis.AddFrame(z, cam, pose, 2);
      ++done;
    }
    nlohmann::json j;
    j["bench"] = "explore_visible";
    j["scene"] = scene_name;
    j["poses"] = done;
    j["metric"] = m.Json();
    j["visible_fraction"] = vis.Fraction(1e-9);
    const char* cls_name[3] = {"up", "down", "side"};
    for (int c = 0; c < 3; ++c)
      j["visible_" + std::string(cls_name[c])] = {{"area_share", vis.ClassShare(c)},
                                                  {"visible", vis.ClassFraction(c, 1e-9)}};
    std::printf("%s\n", j.dump().c_str());
    return 0;
  }
  RunConfig base;
  base.max_flight_s = max_flight_s;
  base.cell_m = cell_m;
  base.dwell_s = dwell_s;
  base.grid_margin_m = grid_margin_m;
  base.no_return_is_free = no_return_is_free;
  base.sky_rule = sky_rule;
  base.sky_min_elevation_rad = sky_min_elevation_rad;
  base.sweep_fallback = sweep_fallback;
  base.dump_cells = dump_cells;
  base.metric = scene_scale ? scene_derived : fixed_scale;
  base.alt_metric = scene_scale ? fixed_scale : scene_derived;
  if (scene_scale) {
    eo.d_max_m = derived.d_max_m;
    eo.sigma_m = derived.sigma_m;
    if (app.count("--range_m") == 0) eo.range_m = std::min(30.0, derived.d_max_m + derived.sigma_m);
  }
  base.carve_range_m = carve_range_m > 0 ? carve_range_m : scene_scale ? eo.range_m : 5.0;
  base.eo = eo;
  base.mssim_every_s = mssim_every_s;
  base.store_views = store_views;
  TestSet tests;
  if (mssim_every_s > 0) {
    synth::RenderOptions tro;
    tro.width = 160;
    tro.height = 120;
    tests.camera = tro.Camera();
    synth::TestPoseOptions tpo;
    tpo.count = test_views;
    tpo.seed = 7;
    auto poses = synth::MakeTestPoses(*scene, tests.camera, tpo);
    if (!poses.ok()) {
      std::fprintf(stderr, "exoview_explore_bench: %s\n",
                   std::string(poses.status().message()).c_str());
      return 1;
    }
    tests.poses = *poses;
    for (const Rigid3d& p : tests.poses) {
      auto lin = synth::RenderLinear(*scene, p, tro);
      if (!lin.ok()) return 1;
      tests.truth.push_back(ToSrgb8(*lin));
    }
    base.tests = &tests;
  }
  for (const std::string& policy : policies) {
    nlohmann::json j;
    j["bench"] = "explore";
    j["scene"] = scene_name;
    j["policy"] = policy;
    j["runs"] = runs;
    j["max_flight_s"] = max_flight_s;
    std::map<size_t, std::vector<double>> time_to, path_to;
    std::vector<double> final_cov, final_seen, dec_ms, cls_share[3], cls_cov[3], cls_seen[3];
    uint64_t collisions = 0, replans = 0, decisions = 0;
    std::map<int, std::vector<double>> cov_at;  // coverage at every 30 s of flight
    std::map<int, std::vector<double>> alt_at, mssim_at;
    std::vector<double> final_alt, mssim_cpu;
    std::vector<int> reached(levels.size(), 0);
    for (int r = 0; r < runs; ++r) {
      RunConfig rc = base;
      rc.policy = policy;
      rc.seed = seed0 + r;
      const RunResult res = Run(*scene, rc);
      final_alt.push_back(res.alt_curve.empty() ? 0 : res.alt_curve.back().second);
      for (const auto& [t, v] : res.mssim) mssim_at[static_cast<int>(std::lround(t))].push_back(v);
      mssim_cpu.push_back(res.mssim_cpu_s);
      for (int s30 = 30; s30 <= max_flight_s + 1e-9; s30 += 30) {
        double c = res.alt_curve.empty() ? 0 : res.alt_curve.back().second;
        for (const auto& [ft, fc] : res.alt_curve)
          if (ft <= s30) c = fc;
          else break;
        alt_at[s30].push_back(c);
      }
      if (per_run) PrintRun(scene_name, policy, seed0 + r, res, trace_decisions, levels);
      final_seen.push_back(res.final_seen);
      collisions += res.collisions;
      replans += res.replans;
      decisions += res.decisions;
      for (int s30 = 30; s30 <= max_flight_s + 1e-9; s30 += 30) {
        double c = res.curve.empty() ? 0 : res.curve.back().second;  // stopped early: final
        for (const auto& [ft, fc] : res.curve)
          if (ft <= s30) c = fc;
          else break;
        cov_at[s30].push_back(c);
      }
      final_cov.push_back(res.final_coverage);
      for (int c = 0; c < 3; ++c) {
        cls_share[c].push_back(res.class_share[c]);
        cls_cov[c].push_back(res.class_coverage[c]);
        cls_seen[c].push_back(res.class_seen[c]);
      }
      if (res.decisions) dec_ms.push_back(res.decision_ms / res.decisions);
      for (size_t l = 0; l < levels.size(); ++l)
        for (size_t k = 0; k < res.curve.size(); ++k)
          if (res.curve[k].second >= levels[l]) {
            time_to[l].push_back(res.curve[k].first);
            path_to[l].push_back(res.path_at[k]);
            ++reached[l];
            break;
          }
    }
    auto mean = [](const std::vector<double>& v) -> nlohmann::json {
      if (v.empty()) return nullptr;
      double s = 0;
      for (double x : v) s += x;
      return s / v.size();
    };
    for (size_t l = 0; l < levels.size(); ++l) {
      // 0.8 -> "80", 0.668 -> "66.8"
      char buf[32];
      std::snprintf(buf, sizeof(buf), "%g", std::round(levels[l] * 1000) / 10);
      const std::string k = buf;
      j["runs_reaching_" + k] = reached[l];
      j["mean_flight_s_to_" + k] = mean(time_to[l]);
      j["mean_path_m_to_" + k] = mean(path_to[l]);
      // The spread over the runs that reached the level: min, max, standard deviation.
      for (const auto& [name, v] : {std::pair{"flight_s", &time_to[l]}, std::pair{"path_m", &path_to[l]}}) {
        if (v->empty()) continue;
        const double m = *mean(*v).get_ptr<const double*>();
        double ss = 0;
        for (double x : *v) ss += (x - m) * (x - m);
        j[std::string(name) + "_spread_to_" + k] = {
            {"min", *std::min_element(v->begin(), v->end())},
            {"max", *std::max_element(v->begin(), v->end())},
            {"sd", v->size() > 1 ? std::sqrt(ss / (v->size() - 1)) : 0.0}};
      }
    }
    j["mean_final_coverage"] = mean(final_cov);
    j["mean_final_seen"] = mean(final_seen);
    // Final coverage (τ >= τ_max/2) and seen (τ > 0) per surface class, with its area share.
    const char* cls_name[3] = {"up", "down", "side"};
    for (int c = 0; c < 3; ++c)
      j["surface_" + std::string(cls_name[c])] = {{"area_share", mean(cls_share[c])},
                                                  {"coverage", mean(cls_cov[c])},
                                                  {"seen", mean(cls_seen[c])}};
    j["unknown_gain"] = eo.unknown_gain;
    j["travel_offset_m"] = eo.travel_offset_m;
    j["pitches"] = eo.pitches;
    j["range_m"] = eo.range_m;
    j["tau_goal"] = eo.tau_goal;
    j["area_weight"] = eo.area_weight;
    j["seed0"] = seed0;
    j["dwell_s"] = dwell_s;
    j["grid_margin_m"] = grid_margin_m;
    j["sky_is_free"] = no_return_is_free;
    j["sky_rule"] = sky_rule;
    j["sky_min_elevation_rad"] = sky_min_elevation_rad;
    j["sweep_fallback"] = sweep_fallback;
    j["sweep_climb"] = eo.sweep_climb;
    j["sweep_pass_m"] = eo.sweep_pass_m;
    j["sweep_pitch"] = eo.sweep_pitch;
    j["sweep_climb_face_centre"] = eo.sweep_climb_face_centre;
    j["sweep_look_dwell_s"] = eo.sweep_look_dwell_s;
    j["sweep_look_misses"] = eo.sweep_look_misses;
    j["sweep_travel_pitch"] = std::isnan(eo.sweep_travel_pitch)
                                  ? nlohmann::json(nullptr)
                                  : nlohmann::json(eo.sweep_travel_pitch);
    j["collisions"] = collisions;
    j["replans"] = replans;
    j["decisions"] = decisions;
    nlohmann::json curve = nlohmann::json::object();
    for (const auto& [s30, v] : cov_at) curve[std::to_string(s30)] = mean(v);
    j["mean_coverage_at_s"] = curve;
    j["mean_decision_ms"] = mean(dec_ms);
    j["metric"] = base.metric.Json();
    j["scene_scale"] = scene_scale;
    j["d_max_m"] = base.eo.d_max_m;
    j["sigma_m"] = base.eo.sigma_m;
    j["carve_range_m"] = base.carve_range_m;
    j["cell_m"] = cell_m;
    // The same flights under the other scale's metric (see the header comment).
    j["alt_metric"] = base.alt_metric.Json();
    j["alt_mean_final_coverage"] = mean(final_alt);
    nlohmann::json alt_curve = nlohmann::json::object();
    for (const auto& [s30, v] : alt_at) alt_curve[std::to_string(s30)] = mean(v);
    j["alt_mean_coverage_at_s"] = alt_curve;
    if (mssim_every_s > 0) {
      nlohmann::json mc = nlohmann::json::object();
      for (const auto& [t, v] : mssim_at) mc[std::to_string(t)] = mean(v);
      j["mean_mssim_at_s"] = mc;
      j["test_views"] = tests.poses.size();
      j["store"] = store_views;
      j["mssim_proxy"] = "ground-truth mesh";
      j["mean_mssim_cpu_s_per_run"] = mean(mssim_cpu);
    }
    std::printf("%s\n", j.dump().c_str());
    std::fflush(stdout);
  }
  return 0;
}
