#include "server/control/safe_flight.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <queue>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"

namespace exo::control {
namespace {

std::string Fmt(const glm::dvec3& p) {
  return absl::StrFormat("(%.2f, %.2f, %.2f)", p.x, p.y, p.z);
}

}  // namespace

absl::StatusOr<Zone> ParseZone(const std::string& text) {
  Zone z;
  absl::string_view body = absl::StripAsciiWhitespace(text);
  if (const size_t colon = body.find(':'); colon != absl::string_view::npos) {
    z.name = std::string(absl::StripAsciiWhitespace(body.substr(0, colon)));
    body = body.substr(colon + 1);
  }
  const std::vector<std::string> parts = absl::StrSplit(body, ',');
  if (parts.size() != 6)
    return absl::InvalidArgumentError(absl::StrCat(
        "zone '", text, "': expected name:minx,miny,minz,maxx,maxy,maxz (6 numbers), got ",
        parts.size()));
  double v[6];
  for (int i = 0; i < 6; ++i)
    if (!absl::SimpleAtod(absl::StripAsciiWhitespace(parts[i]), &v[i]) || !std::isfinite(v[i]))
      return absl::InvalidArgumentError(
          absl::StrCat("zone '", text, "': '", parts[i], "' is not a number"));
  z.min = {v[0], v[1], v[2]};
  z.max = {v[3], v[4], v[5]};
  if (!(z.max.x > z.min.x && z.max.y > z.min.y && z.max.z > z.min.z))
    return absl::InvalidArgumentError(absl::StrCat("zone '", text, "': max must exceed min"));
  return z;
}

absl::Status SafeFlightOptions::Validate() const {
  if (zones.empty())
    return absl::InvalidArgumentError("safe flight: at least one zone is required");
  for (const Zone& z : zones)
    if (!(z.max.x > z.min.x && z.max.y > z.min.y && z.max.z > z.min.z))
      return absl::InvalidArgumentError(absl::StrCat("safe flight: zone '", z.name, "' is empty"));
  if (!(cell_m > 0)) return absl::InvalidArgumentError("safe flight: cell_m must be > 0");
  if (!(drone_radius_m >= 0)) return absl::InvalidArgumentError("safe flight: drone_radius_m < 0");
  return absl::OkStatus();
}

absl::StatusOr<SafeFlight> SafeFlight::Create(const SafeFlightOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  OccupancyOptions o;
  o.min = options.zones[0].min;
  o.max = options.zones[0].max;
  for (const Zone& z : options.zones) {
    o.min = glm::min(o.min, z.min);
    o.max = glm::max(o.max, z.max);
  }
  o.cell_m = options.cell_m;
  o.drone_radius_m = options.drone_radius_m;
  o.inflate_unknown = options.inflate_unknown;
  EXO_ASSIGN_OR_RETURN(OccupancyGrid grid, OccupancyGrid::Create(o));
  return SafeFlight(options, std::move(grid));
}

bool SafeFlight::InZones(const glm::dvec3& p) const {
  for (const Zone& z : options_.zones)
    if (z.Contains(p)) return true;
  return false;
}

bool SafeFlight::CellPermitted(const glm::ivec3& c) const {
  return grid_.IsClear(c) && InZones(grid_.CentreOf(c));
}

bool SafeFlight::Permitted(const glm::dvec3& p) const {
  if (!InZones(p)) return false;
  if (UsingRegions()) return true;
  return grid_.IsClear(p);
}

bool SafeFlight::SegmentPermitted(const glm::dvec3& a, const glm::dvec3& b) const {
  const double len = glm::length(b - a);
  const int n = std::max(1, static_cast<int>(std::ceil(len / (0.25 * options_.cell_m))));
  for (int i = 0; i <= n; ++i)
    if (!Permitted(a + (b - a) * (static_cast<double>(i) / n))) return false;
  return true;
}

absl::StatusOr<glm::dvec3> SafeFlight::Clamp(const glm::dvec3& p) const {
  if (Permitted(p)) return p;
  // The nearest point of the zones (exact "nearest border" when that point is permitted).
  glm::dvec3 best_zone = options_.zones[0].Nearest(p);
  for (const Zone& z : options_.zones) {
    const glm::dvec3 q = z.Nearest(p);
    if (glm::length(q - p) < glm::length(best_zone - p)) best_zone = q;
  }
  if (Permitted(best_zone)) return best_zone;
  if (UsingRegions())  // a point on a zone face is in the zone
    return absl::InternalError("safe flight: zone clamp failed");
  // The nearest clear cell centre.
  const std::vector<uint8_t>& clear = grid_.ClearMask();
  double best = std::numeric_limits<double>::infinity();
  std::optional<glm::dvec3> out;
  for (size_t i = 0; i < clear.size(); ++i) {
    if (!clear[i]) continue;
    const glm::dvec3 c = grid_.CentreOf(grid_.CellOfIndex(i));
    const double d = glm::length(c - p);
    if (d < best && InZones(c)) {
      best = d;
      out = c;
    }
  }
  if (!out)
    return absl::NotFoundError(
        "safe flight: no permitted point: no known free space inside the zones yet");
  return *out;
}

absl::StatusOr<Route> SafeFlight::Plan(const glm::dvec3& from, const glm::dvec3& to) const {
  if (UsingRegions()) return PlanRegions(from, to);
  Route route;
  route.requested = to;
  EXO_ASSIGN_OR_RETURN(route.target, Clamp(to));
  route.clamped = glm::length(route.target - to) > 1e-9;
  glm::dvec3 start = from;
  if (!Permitted(from)) {
    EXO_ASSIGN_OR_RETURN(start, Clamp(from));
    route.start_snapped = true;
  }
  const glm::ivec3 s = grid_.CellOf(start), g = grid_.CellOf(route.target);
  std::vector<glm::dvec3> cells_path;
  if (s != g) {
    const size_t n = grid_.num_cells();
    constexpr float kInf = std::numeric_limits<float>::infinity();
    std::vector<float> cost(n, kInf);
    std::vector<int64_t> parent(n, -1);
    std::vector<uint8_t> closed(n, 0);
    using Item = std::pair<float, int64_t>;
    std::priority_queue<Item, std::vector<Item>, std::greater<Item>> open;
    const double cell = grid_.options().cell_m;
    auto h = [&](const glm::ivec3& c) {
      return static_cast<float>(glm::length(glm::dvec3(c - g)) * cell);
    };
    const int64_t si = static_cast<int64_t>(grid_.Index(s));
    const int64_t gi = static_cast<int64_t>(grid_.Index(g));
    cost[si] = 0;
    open.push({h(s), si});
    bool found = false;
    while (!open.empty()) {
      const auto [f, i] = open.top();
      open.pop();
      if (closed[i]) continue;
      closed[i] = 1;
      ++route.expanded;
      if (i == gi) {
        found = true;
        break;
      }
      const glm::ivec3 c = grid_.CellOfIndex(static_cast<size_t>(i));
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            if (!dx && !dy && !dz) continue;
            const glm::ivec3 q = c + glm::ivec3(dx, dy, dz);
            if (!grid_.InGrid(q)) continue;
            const int64_t qi = static_cast<int64_t>(grid_.Index(q));
            if (closed[qi] || !CellPermitted(q)) continue;
            const float nc =
                cost[i] + static_cast<float>(std::sqrt(double(dx * dx + dy * dy + dz * dz)) * cell);
            if (nc < cost[qi]) {
              cost[qi] = nc;
              parent[qi] = i;
              open.push({nc + h(q), qi});
            }
          }
    }
    if (!found)
      return absl::NotFoundError(absl::StrCat(
          "safe flight: no path through known free space from ", Fmt(start), " to ",
          Fmt(route.target), " (", route.expanded,
          " cells reachable; the target's free space is not connected to the drone's)"));
    for (int64_t i = parent[gi]; i >= 0 && i != si; i = parent[i])
      cells_path.push_back(grid_.CentreOf(grid_.CellOfIndex(static_cast<size_t>(i))));
    std::reverse(cells_path.begin(), cells_path.end());
  }
  // Line-of-sight shortcuts over [start, cells..., target].
  std::vector<glm::dvec3> pts;
  pts.push_back(start);
  pts.insert(pts.end(), cells_path.begin(), cells_path.end());
  pts.push_back(route.target);
  size_t i = 0;
  if (route.start_snapped) route.waypoints.push_back(start);
  while (i + 1 < pts.size()) {
    size_t j = pts.size() - 1;
    while (j > i + 1 && !SegmentPermitted(pts[i], pts[j])) --j;
    route.waypoints.push_back(pts[j]);
    i = j;
  }
  if (route.waypoints.empty()) route.waypoints.push_back(route.target);
  glm::dvec3 prev = from;
  for (const auto& w : route.waypoints) {
    route.length_m += glm::length(w - prev);
    prev = w;
  }
  return route;
}

absl::StatusOr<Route> SafeFlight::PlanRegions(const glm::dvec3& from, const glm::dvec3& to) const {
  Route route;
  route.regions = true;
  route.requested = to;
  EXO_ASSIGN_OR_RETURN(route.target, Clamp(to));
  route.clamped = glm::length(route.target - to) > 1e-9;
  glm::dvec3 start = from;
  if (!InZones(from)) {
    EXO_ASSIGN_OR_RETURN(start, Clamp(from));
    route.start_snapped = true;
    route.waypoints.push_back(start);
  }
  auto zone_of = [&](const glm::dvec3& p) {
    for (size_t k = 0; k < options_.zones.size(); ++k)
      if (options_.zones[k].Contains(p)) return static_cast<int>(k);
    return -1;
  };
  const int za = zone_of(start), zb = zone_of(route.target);
  // Breadth-first search over zones; portals join every zone that contains them.
  const int nz = static_cast<int>(options_.zones.size());
  std::vector<int> prev_zone(nz, -2), via(nz, -1);
  std::queue<int> q;
  prev_zone[za] = -1;
  q.push(za);
  while (!q.empty() && prev_zone[zb] == -2) {
    const int z = q.front();
    q.pop();
    for (size_t p = 0; p < options_.portals.size(); ++p) {
      if (!options_.zones[z].Contains(options_.portals[p], 1e-6)) continue;
      for (int k = 0; k < nz; ++k)
        if (prev_zone[k] == -2 && options_.zones[k].Contains(options_.portals[p], 1e-6)) {
          prev_zone[k] = z;
          via[k] = static_cast<int>(p);
          q.push(k);
        }
    }
  }
  if (prev_zone[zb] == -2)
    return absl::NotFoundError(absl::StrCat("safe flight: no portal route from zone '",
                                            options_.zones[za].name, "' to zone '",
                                            options_.zones[zb].name, "'"));
  std::vector<glm::dvec3> portals;
  for (int z = zb; z != za; z = prev_zone[z]) portals.push_back(options_.portals[via[z]]);
  std::reverse(portals.begin(), portals.end());
  route.waypoints.insert(route.waypoints.end(), portals.begin(), portals.end());
  route.waypoints.push_back(route.target);
  glm::dvec3 prev = from;
  for (const auto& w : route.waypoints) {
    route.length_m += glm::length(w - prev);
    prev = w;
  }
  return route;
}

}  // namespace exo::control
