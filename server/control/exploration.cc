#include "server/control/exploration.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <queue>

#include "common/hilbert.h"

namespace exo::control {
namespace {

double DistanceQuality(double d, double d_max, double sigma) {
  const double e = d - d_max;
  return std::exp(-(e * e) / (2 * sigma * sigma));
}

}  // namespace

void ExplorationPlanner::Observe(const OccupancyGrid& grid, const ImageF& depth_m,
                                 const PinholeCamera& camera, const Rigid3d& frame_from_cam,
                                 int stride) {
  if (depth_m.empty()) return;
  stride = std::max(1, stride);
  const double sx = static_cast<double>(camera.width) / depth_m.width();
  const double sy = static_cast<double>(camera.height) / depth_m.height();
  // Solid angle of one sample; a cell face of cell_m² at distance d spans face/d² of it.
  const double sample_sr = (sx * stride / camera.fx) * (sy * stride / camera.fy);
  const double face = grid.options().cell_m * grid.options().cell_m;
  struct Hits {
    double samples = 0, g_sum = 0, d_sum = 0;
    glm::dvec3 dir{0.0};  // sum of the directions sample -> camera
  };
  std::unordered_map<size_t, Hits> hits;
  for (int y = stride / 2; y < depth_m.height(); y += stride)
    for (int x = stride / 2; x < depth_m.width(); x += stride) {
      const float z = depth_m.at(x, y);
      if (!(z > 0) || !std::isfinite(z)) continue;
      const glm::dvec2 uv((x + 0.5) * sx - 0.5, (y + 0.5) * sy - 0.5);
      const glm::dvec3 p = frame_from_cam * camera.Unproject(uv, z);
      const glm::ivec3 c = grid.CellOf(p);
      if (!grid.InGrid(c) || grid.At(c) != Occupancy::kOccupied) continue;
      const double d = glm::length(p - frame_from_cam.translation);
      Hits& h = hits[grid.Index(c)];
      h.samples += 1;
      h.g_sum += DistanceQuality(d, options_.d_max_m, options_.sigma_m);
      h.d_sum += d;
      h.dir += frame_from_cam.translation - p;
    }
  for (const auto& [i, h] : hits) {
    Cell& c = cells_[i];
    const double len = glm::length(h.dir);
    if (!(len > 0)) continue;
    const glm::dvec3 dir = h.dir / len;
    // φ_p = g · ψ_vis / ψ_total (3.13, 3.14) at the samples' mean distance.
    const double d = std::max(0.1, h.d_sum / h.samples);
    const double expected = std::max(1.0, face / (d * d) / sample_sr);
    const double phi_p = std::min(1.0, (h.g_sum / h.samples) * h.samples / expected);
    const double phi = options_.lambda * DirectionalNovelty(c, dir) +
                       (1 - options_.lambda) * phi_p;
    c.tau = std::min(options_.tau_max, c.tau + phi);
    if (static_cast<int>(c.refs.size()) < options_.r_max) c.refs.push_back(glm::vec3(dir));
  }
}

void ExplorationPlanner::TakeDecisionState(const ExplorationPlanner& copy) {
  tried_ = copy.tried_;
  sweep_ = copy.sweep_;
  sweep_reversed_ = copy.sweep_reversed_;
  swept_ = copy.swept_;
  sweep_retried_ = copy.sweep_retried_;
  last_sweep_ = copy.last_sweep_;
  last_sweep_goal_ = copy.last_sweep_goal_;
  climb_turns_ = copy.climb_turns_;
  climb_done_ = copy.climb_done_;
  looks_ = copy.looks_;
  look_misses_ = copy.look_misses_;
  last_look_ = copy.last_look_;
  last_look_place_ = copy.last_look_place_;
}

double ExplorationPlanner::DirectionalNovelty(const Cell& c, const glm::dvec3& dir) const {
  if (c.refs.empty()) return 1.0;  // SPEC §4 erratum 1
  double gamma = -1;
  for (const glm::vec3& r : c.refs) gamma = std::max(gamma, glm::dot(dir, glm::dvec3(r)));
  const double t = 1.0 - 2.0 / options_.r_max;
  const double phi_max = 2 * t * t - 1;  // Tammes bound (3.9)
  return std::clamp((1.0 - gamma) / (1.0 - phi_max), 0.0, 1.0);
}

double ExplorationPlanner::Tau(size_t i) const {
  auto it = cells_.find(i);
  return it == cells_.end() ? 0.0 : it->second.tau;
}

std::vector<float> ExplorationPlanner::Distances(const SafeFlight& safe,
                                                 const glm::dvec3& from) const {
  const OccupancyGrid& g = safe.grid();
  constexpr float kInf = std::numeric_limits<float>::infinity();
  std::vector<float> dist(g.num_cells(), kInf);
  // A drone whose own cell is not clear (unknown just above or below it: a level camera never
  // sees there) starts from its nearest permitted point, as SafeFlight::Plan does.
  glm::dvec3 start = from;
  if (!safe.Permitted(from)) {
    auto c = safe.Clamp(from);
    if (!c.ok()) return dist;
    start = *c;
  }
  const glm::ivec3 s = g.CellOf(start);
  if (!g.InGrid(s)) return dist;
  using Item = std::pair<float, size_t>;
  std::priority_queue<Item, std::vector<Item>, std::greater<Item>> open;
  dist[g.Index(s)] = static_cast<float>(glm::length(start - from));
  open.push({dist[g.Index(s)], g.Index(s)});
  const double cell = g.options().cell_m;
  while (!open.empty()) {
    const auto [d, i] = open.top();
    open.pop();
    if (d > dist[i]) continue;
    const glm::ivec3 c = g.CellOfIndex(i);
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          if (!dx && !dy && !dz) continue;
          const glm::ivec3 q = c + glm::ivec3(dx, dy, dz);
          if (!g.InGrid(q) || !g.IsClear(q) || !safe.InZones(g.CentreOf(q))) continue;
          const float nd =
              d + static_cast<float>(std::sqrt(double(dx * dx + dy * dy + dz * dz)) * cell);
          const size_t qi = g.Index(q);
          if (nd < dist[qi]) {
            dist[qi] = nd;
            open.push({nd, qi});
          }
        }
  }
  return dist;
}

double ExplorationPlanner::Gain(const OccupancyGrid& grid, const Setpoint& pose,
                                const SceneFrame& frame, double pitch,
                                double* unknown_part) const {
  const double step = 0.5 * grid.options().cell_m;
  const double goal = options_.tau_goal > 0 ? options_.tau_goal : options_.tau_max;
  double gain = 0, unknown = 0;
  for (int iy = 0; iy < options_.rays_y; ++iy)
    for (int ix = 0; ix < options_.rays_x; ++ix) {
      const double a = (ix + 0.5) / options_.rays_x - 0.5, b = (iy + 0.5) / options_.rays_y - 0.5;
      const double yaw = pose.yaw - a * options_.hfov_rad;
      const double elev = pitch - b * options_.vfov_rad;
      const glm::dvec3 dir = std::cos(elev) * frame.Heading(yaw) + std::sin(elev) * frame.up;
      for (double t = step; t <= options_.range_m; t += step) {
        const glm::ivec3 c = grid.CellOf(pose.position + t * dir);
        if (!grid.InGrid(c)) break;
        const Occupancy o = grid.At(c);
        if (o == Occupancy::kFree) continue;
        const double area = options_.area_weight ? (t * t) / (options_.d_max_m * options_.d_max_m)
                                                 : 1.0;
        if (o == Occupancy::kUnknown) {
          gain += area * options_.unknown_gain;
          unknown += area * options_.unknown_gain;
        } else {
          auto it = cells_.find(grid.Index(c));
          const double tau = it == cells_.end() ? 0.0 : it->second.tau;
          const double novelty = it == cells_.end() ? 1.0 : DirectionalNovelty(it->second, -dir);
          gain += area * std::clamp((goal - tau) / goal, 0.0, 1.0) *
                  (options_.lambda * novelty +
                   (1 - options_.lambda) * DistanceQuality(t, options_.d_max_m, options_.sigma_m));
        }
        break;
      }
    }
  if (unknown_part) *unknown_part = unknown;
  return gain;
}

std::optional<NextView> ExplorationPlanner::Autonomous(const SafeFlight& safe,
                                                       const glm::dvec3& from,
                                                       const SceneFrame& frame) {
  // The last sweep point proposed was not reached (its route was dropped, or it timed out):
  // it is flown again, once.
  if (last_sweep_ >= 0 && !sweep_retried_[last_sweep_] &&
      glm::length(from - last_sweep_goal_) > options_.sweep_climb_tolerance_m) {
    swept_[last_sweep_] = false;
    sweep_retried_[last_sweep_] = true;
  }
  last_sweep_ = -1;
  // The last look (sweep_climb) was not reached: it does not count as a look, up to a limit.
  if (last_look_ >= 0 && glm::length(from - last_look_place_) > options_.sweep_climb_tolerance_m) {
    if (!looks_[last_look_].empty()) looks_[last_look_].pop_back();
    ++look_misses_[last_look_];
  }
  last_look_ = -1;
  const OccupancyGrid& g = safe.grid();
  const std::vector<float> dist = Distances(safe, from);
  std::vector<size_t> reachable;
  for (size_t i = 0; i < dist.size(); ++i)
    if (std::isfinite(dist[i]) && dist[i] >= options_.min_goal_distance_m) reachable.push_back(i);
  if (reachable.empty()) return std::nullopt;
  std::optional<NextView> best;
  for (int k = 0; k < options_.candidates; ++k) {
    const size_t i =
        reachable[std::uniform_int_distribution<size_t>(0, reachable.size() - 1)(rng_)];
    for (int y = 0; y < options_.yaws; ++y)
      for (double pitch : options_.pitches) {
        NextView v;
        v.pose = Setpoint{g.CentreOf(g.CellOfIndex(i)), WrapAngle(2 * kPi * y / options_.yaws)};
        v.pitch = pitch;
        v.path_m = dist[i];
        v.gain = Gain(g, v.pose, frame, pitch, &v.gain_unknown);
        v.score = v.gain / (v.path_m + options_.travel_offset_m);
        if (v.gain > 0 && (!best || v.score > best->score)) best = v;
      }
  }
  if (!options_.sweep.empty() &&
      (!best || best->gain_unknown > options_.sweep_unknown_share * best->gain))
    if (auto s = NextSweepView(safe, from, frame, dist)) {
      if (best) {  // what the coverage-driven choice saw (the decision log's unknown share)
        s->gain = best->gain;
        s->gain_unknown = best->gain_unknown;
      }
      return s;
    }
  return best;
}

std::optional<NextView> ExplorationPlanner::NextSweepView(const SafeFlight& safe,
                                                          const glm::dvec3& from,
                                                          const SceneFrame& frame,
                                                          const std::vector<float>& dist) {
  const OccupancyGrid& g = safe.grid();
  const size_t n = options_.sweep.size();
  if (swept_.size() != n) {
    // The sweep starts at its end nearer to the drone (horizontally).
    swept_.assign(n, false);
    sweep_retried_.assign(n, false);
    looks_.assign(n, {});
    look_misses_.assign(n, 0);
    sweep_ = options_.sweep;
    sweep_reversed_ = glm::length(frame.Horizontal(sweep_.back() - from)) <
                      glm::length(frame.Horizontal(sweep_.front() - from));
    if (sweep_reversed_) std::reverse(sweep_.begin(), sweep_.end());
  }

  // The up axis's cell step (the frame's up is one of the grid's axes in practice; the column
  // is walked along whichever axis is closest to it).
  glm::ivec3 up_step(0);
  {
    const glm::dvec3 u = frame.up;
    int a = 0;
    for (int k = 1; k < 3; ++k)
      if (std::abs(u[k]) > std::abs(u[a])) a = k;
    up_step[a] = u[a] > 0 ? 1 : -1;
  }
  const double tol = options_.sweep_climb_tolerance_m;
  if (options_.sweep_climb && !climb_done_) {
    // Climb first while the sweep's altitude is out of reach (see ExploreOptions).
    size_t k0 = 0;
    while (k0 < n && swept_[k0]) ++k0;
    if (k0 < n) {
      const double want = frame.Height(sweep_[k0]);
      double top = -std::numeric_limits<double>::infinity();
      for (size_t i = 0; i < dist.size(); ++i)
        if (std::isfinite(dist[i])) top = std::max(top, frame.Height(g.CentreOf(g.CellOfIndex(i))));
      if (top < want - tol) {
        if (auto v = ClimbView(safe, from, frame, dist, k0)) return v;
      } else {
        climb_done_ = true;
      }
    }
  }
  for (size_t k = 0; k < n; ++k) {
    if (swept_[k]) continue;
    glm::ivec3 c = g.CellOf(sweep_[k]);
    // Down the column from the sweep point to the first reachable cell.
    std::optional<size_t> hit;
    const int span = 2 * std::max({g.dims().x, g.dims().y, g.dims().z});
    for (int steps = 0; steps < span; ++steps, c -= up_step) {
      if (!g.InGrid(c)) continue;  // above the grid (or below it: the loop ends)
      const size_t i = g.Index(c);
      if (std::isfinite(dist[i])) {
        hit = i;
        break;
      }
    }
    const double want = frame.Height(sweep_[k]);
    // Below the sweep's altitude (or none): look at the point first (sweep_climb).
    if (options_.sweep_climb &&
        (!hit || frame.Height(g.CentreOf(g.CellOfIndex(*hit))) < want - tol))
      if (auto v = LookView(safe, frame, dist, k)) return v;
    if (!hit || dist[*hit] < options_.min_goal_distance_m) {
      if (hit) swept_[k] = true;  // already there
      continue;
    }
    NextView v;
    const glm::dvec3 p = g.CentreOf(g.CellOfIndex(*hit));
    const glm::dvec3 along = k + 1 < n ? sweep_[k + 1] - sweep_[k] : p - from;
    v.pose = Setpoint{p, glm::length(frame.Horizontal(along)) > 1e-6 ? frame.YawOf(along)
                                                                     : frame.YawOf(p - from)};
    v.pitch = options_.sweep_pitch;
    // Along the sweep's altitude the camera may look down on the way too (sweep_travel_pitch).
    if (!std::isnan(options_.sweep_travel_pitch) && frame.Height(from) >= want - tol &&
        frame.Height(p) >= want - tol)
      v.travel_pitch = options_.sweep_travel_pitch;
    if (frame.Height(p) >= want - tol) v.pass_m = options_.sweep_pass_m;
    // Passing through: facing the leg flown (as the fly-over does), not the next one.
    if (v.pass_m > 0 && glm::length(frame.Horizontal(p - from)) > 1.0)
      v.pose.yaw = frame.YawOf(p - from);
    if (options_.sweep_climb_face_centre && frame.Height(p) >= want - tol &&
        frame.Height(from) < want - tol) {
      // A climb up to the sweep's altitude: face the centre of the points still to fly (see
      // ExploreOptions).
      glm::dvec3 centre(0.0);
      int m = 0;
      for (size_t j = k + 1; j < n; ++j)
        if (!swept_[j]) {
          centre += sweep_[j];
          ++m;
        }
      if (m > 0 && glm::length(frame.Horizontal(centre / double(m) - p)) > 1.0)
        v.pose.yaw = frame.YawOf(centre / double(m) - p);
    }
    v.path_m = dist[*hit];
    v.sweep_index = static_cast<int>(sweep_reversed_ ? n - 1 - k : k);
    swept_[k] = true;
    last_sweep_ = static_cast<int>(k);
    last_sweep_goal_ = p;
    return v;
  }
  return std::nullopt;
}

std::optional<NextView> ExplorationPlanner::LookView(const SafeFlight& safe,
                                                     const SceneFrame& frame,
                                                     const std::vector<float>& dist, size_t k) {
  // The reachable cell with the shortest flight (there, then straight on to the point) from
  // which sweep point k lies within the camera's view at a pitch in [0, sweep_climb_pitch] and
  // within range. Its frames observe the air along the line of sight, which the sweep then
  // flies. At most two looks per point, from places at least 2 m apart.
  const OccupancyGrid& g = safe.grid();
  std::vector<glm::dvec3>& looked = looks_[k];
  if (looked.size() >= 2 || look_misses_[k] >= options_.sweep_look_misses) return std::nullopt;
  const glm::dvec3 toward = sweep_[k];
  const double max_elev = options_.sweep_climb_pitch + 0.5 * options_.vfov_rad - 0.05;
  const double max_range = options_.range_m - 1.0;
  std::optional<size_t> look;
  double look_cost = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < dist.size(); ++i) {
    if (!std::isfinite(dist[i])) continue;
    const glm::dvec3 p = g.CentreOf(g.CellOfIndex(i));
    const glm::dvec3 d = toward - p;
    const double len = glm::length(d);
    if (len > max_range || len < 1e-6) continue;
    if (std::atan2(glm::dot(d, frame.up), glm::length(frame.Horizontal(d))) > max_elev) continue;
    bool again = false;
    for (const glm::dvec3& q : looked) again |= glm::length(q - p) < 2.0;
    if (again) continue;
    const double cost = dist[i] + len;
    if (cost < look_cost) {
      look_cost = cost;
      look = i;
    }
  }
  if (!look) return std::nullopt;
  const glm::dvec3 p = g.CentreOf(g.CellOfIndex(*look));
  looked.push_back(p);
  last_look_ = static_cast<int>(k);
  last_look_place_ = p;
  const glm::dvec3 d = toward - p;
  NextView v;
  v.climb = true;
  v.dwell_s = options_.sweep_look_dwell_s;
  v.pose = Setpoint{p, frame.YawOf(d)};
  v.pitch = std::clamp(std::atan2(glm::dot(d, frame.up), glm::length(frame.Horizontal(d))), 0.0,
                       options_.sweep_climb_pitch);
  v.path_m = dist[*look];
  return v;
}

std::optional<NextView> ExplorationPlanner::ClimbView(const SafeFlight& safe,
                                                      const glm::dvec3& from,
                                                      const SceneFrame& frame,
                                                      const std::vector<float>& dist, size_t k) {
  // 1. A look at the sweep point (LookView).
  if (auto v = LookView(safe, frame, dist, k)) return v;
  const OccupancyGrid& g = safe.grid();
  const glm::dvec3 toward = sweep_[k];
  NextView v;
  v.climb = true;
  v.dwell_s = options_.sweep_look_dwell_s;
  // 2. No such place: the most height per metre of flight, looking up toward the point.
  const double h0 = frame.Height(from);
  std::optional<size_t> best;
  double best_score = 0;
  for (size_t i = 0; i < dist.size(); ++i) {
    if (!std::isfinite(dist[i]) || dist[i] < options_.min_goal_distance_m) continue;
    const double dh = frame.Height(g.CentreOf(g.CellOfIndex(i))) - h0;
    if (dh < g.options().cell_m) continue;  // at least a cell higher
    const double score = dh / (dist[i] + options_.travel_offset_m);
    if (score > best_score) {
      best_score = score;
      best = i;
    }
  }
  v.pitch = v.travel_pitch = options_.sweep_climb_pitch;
  if (best) {
    climb_turns_ = 0;
    const glm::dvec3 p = g.CentreOf(g.CellOfIndex(*best));
    const glm::dvec3 ahead = frame.Horizontal(toward - p);
    v.pose = Setpoint{p, glm::length(ahead) > 1e-6 ? frame.YawOf(ahead) : frame.YawOf(p - from)};
    v.path_m = dist[*best];
    v.score = best_score;
    return v;
  }
  // 3. The top of the air seen so far: turn in place looking up, a quarter turn at a time.
  if (++climb_turns_ > 4) {
    climb_done_ = true;
    return std::nullopt;
  }
  v.pose = Setpoint{from, WrapAngle(frame.YawOf(frame.Horizontal(toward - from)) +
                                    kPi / 2 * (climb_turns_ - 1))};
  return v;
}

std::optional<NextView> ExplorationPlanner::NearestFrontier(const SafeFlight& safe,
                                                            const glm::dvec3& from,
                                                            const SceneFrame& frame) {
  const OccupancyGrid& g = safe.grid();
  const std::vector<float> dist = Distances(safe, from);
  std::vector<size_t> order;
  for (size_t i = 0; i < dist.size(); ++i)
    if (std::isfinite(dist[i]) && dist[i] >= options_.min_goal_distance_m) order.push_back(i);
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return dist[a] < dist[b]; });
  const int r = static_cast<int>(std::ceil(options_.frontier_reach_m / g.options().cell_m));
  double lowest = 0, highest = 0;
  if (!options_.pitches.empty()) {
    lowest = *std::min_element(options_.pitches.begin(), options_.pitches.end());
    highest = *std::max_element(options_.pitches.begin(), options_.pitches.end());
  }
  for (size_t i : order) {
    if (tried_.count(i)) continue;
    const glm::ivec3 c = g.CellOfIndex(i);
    glm::dvec3 towards(0.0);
    int unknown = 0;
    for (int dz = -r; dz <= r; ++dz)
      for (int dy = -r; dy <= r; ++dy)
        for (int dx = -r; dx <= r; ++dx) {
          const glm::ivec3 q = c + glm::ivec3(dx, dy, dz);
          if (!g.InGrid(q) || g.At(q) != Occupancy::kUnknown) continue;
          if (!safe.InZones(g.CentreOf(q))) continue;
          // A frontier cell: unknown next to known free space (not unknown behind a wall).
          bool next_to_free = false;
          for (const glm::ivec3& n :
               {glm::ivec3(1, 0, 0), glm::ivec3(-1, 0, 0), glm::ivec3(0, 1, 0),
                glm::ivec3(0, -1, 0), glm::ivec3(0, 0, 1), glm::ivec3(0, 0, -1)})
            if (g.At(q + n) == Occupancy::kFree) next_to_free = true;
          if (!next_to_free) continue;
          // Only unknown space the camera can look at from here (at one of its pitches) counts.
          const double h = glm::length(frame.Horizontal(glm::dvec3(dx, dy, dz)));
          const double v = glm::dot(glm::dvec3(dx, dy, dz), frame.up);
          const double elev = std::atan2(v, h);
          if (h == 0 || elev < lowest - 0.5 * options_.vfov_rad ||
              elev > highest + 0.5 * options_.vfov_rad)
            continue;
          ++unknown;
          towards += glm::dvec3(dx, dy, dz);
        }
    if (unknown == 0) continue;
    NextView v;
    v.pose = Setpoint{g.CentreOf(c), frame.YawOf(towards)};
    // The pitch candidate closest to the frontier's mean elevation.
    const double elev = std::atan2(glm::dot(towards, frame.up),
                                   glm::length(frame.Horizontal(towards)));
    if (!options_.pitches.empty()) v.pitch = options_.pitches.front();
    for (double p : options_.pitches)
      if (std::abs(p - elev) < std::abs(v.pitch - elev)) v.pitch = p;
    v.path_m = dist[i];
    v.gain = unknown;
    v.score = unknown / (v.path_m + options_.travel_offset_m);
    tried_.insert(i);
    return v;
  }
  return std::nullopt;
}

}  // namespace exo::control

namespace exo::control {

std::vector<glm::dvec3> HilbertSweep(const glm::dvec3& lo, const glm::dvec3& hi, double altitude,
                                     const SceneFrame& frame, int order, double inset) {
  // The box's extent along the frame's two horizontal axes.
  glm::dvec2 a(std::numeric_limits<double>::infinity()), b(-a);
  for (int corner = 0; corner < 8; ++corner) {
    const glm::dvec3 c((corner & 1) ? hi.x : lo.x, (corner & 2) ? hi.y : lo.y,
                       (corner & 4) ? hi.z : lo.z);
    const glm::dvec2 h(glm::dot(c, frame.e1), glm::dot(c, frame.e2));
    a = glm::min(a, h);
    b = glm::max(b, h);
  }
  const double in = inset * std::min(b.x - a.x, b.y - a.y);
  const int n = 1 << std::max(0, order);
  std::vector<glm::dvec3> out;
  out.reserve(static_cast<size_t>(n) * n);
  for (const glm::dvec2& p : HilbertCurve(order)) {
    const double u = p.x, w = p.y;
    const double e1 = a.x + in + u * (b.x - a.x - 2 * in), e2 = a.y + in + w * (b.y - a.y - 2 * in);
    out.push_back(e1 * frame.e1 + e2 * frame.e2 + altitude * frame.up);
  }
  return out;
}

}  // namespace exo::control
