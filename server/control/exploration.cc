#include "server/control/exploration.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <queue>

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
  if (swept_.size() != n) swept_.assign(n, false);
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
  for (size_t k = 0; k < n; ++k) {
    if (swept_[k]) continue;
    glm::ivec3 c = g.CellOf(options_.sweep[k]);
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
    if (!hit || dist[*hit] < options_.min_goal_distance_m) {
      if (hit) swept_[k] = true;  // already there
      continue;
    }
    NextView v;
    const glm::dvec3 p = g.CentreOf(g.CellOfIndex(*hit));
    const glm::dvec3 along = k + 1 < n ? options_.sweep[k + 1] - options_.sweep[k] : p - from;
    v.pose = Setpoint{p, glm::length(frame.Horizontal(along)) > 1e-6 ? frame.YawOf(along)
                                                                     : frame.YawOf(p - from)};
    v.pitch = options_.sweep_pitch;
    v.path_m = dist[*hit];
    v.sweep_index = static_cast<int>(k);
    swept_[k] = true;
    return v;
  }
  return std::nullopt;
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
