#include "server/control/safe_flight.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <queue>

#include "absl/strings/match.h"
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

namespace {

glm::dvec2 Uv(const glm::dvec3& p, int vertical) {
  return {p[(vertical + 1) % 3], p[(vertical + 2) % 3]};
}

glm::dvec2 NearestOnSegment(const glm::dvec2& p, const glm::dvec2& a, const glm::dvec2& b) {
  const glm::dvec2 d = b - a;
  const double l2 = glm::dot(d, d);
  const double t = l2 > 0 ? std::clamp(glm::dot(p - a, d) / l2, 0.0, 1.0) : 0.0;
  return a + t * d;
}

glm::dvec2 NearestOnBoundary(const std::vector<glm::dvec2>& poly, const glm::dvec2& p) {
  glm::dvec2 best = poly[0];
  double best_d = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < poly.size(); ++i) {
    const glm::dvec2 q = NearestOnSegment(p, poly[i], poly[(i + 1) % poly.size()]);
    const double d = glm::length(q - p);
    if (d < best_d) {
      best_d = d;
      best = q;
    }
  }
  return best;
}

// Even-odd rule; points within eps of an edge count as inside.
bool InPolygon(const std::vector<glm::dvec2>& poly, const glm::dvec2& p, double eps) {
  bool inside = false;
  for (size_t i = 0, j = poly.size() - 1; i < poly.size(); j = i++) {
    const glm::dvec2 &a = poly[i], &b = poly[j];
    if ((a.y > p.y) != (b.y > p.y) && p.x < (b.x - a.x) * (p.y - a.y) / (b.y - a.y) + a.x)
      inside = !inside;
  }
  return inside || glm::length(NearestOnBoundary(poly, p) - p) <= eps;
}

double Cross(const glm::dvec2& a, const glm::dvec2& b) { return a.x * b.y - a.y * b.x; }

bool SegmentsCross(const glm::dvec2& a, const glm::dvec2& b, const glm::dvec2& c,
                   const glm::dvec2& d) {
  const double d1 = Cross(b - a, c - a), d2 = Cross(b - a, d - a), d3 = Cross(d - c, a - c),
               d4 = Cross(d - c, b - c);
  if (((d1 > 0 && d2 < 0) || (d1 < 0 && d2 > 0)) && ((d3 > 0 && d4 < 0) || (d3 < 0 && d4 > 0)))
    return true;
  // Touching (collinear overlap or an endpoint on the other segment).
  auto on = [](const glm::dvec2& p, const glm::dvec2& q, const glm::dvec2& r, double cr) {
    return cr == 0 && std::min(p.x, q.x) <= r.x && r.x <= std::max(p.x, q.x) &&
           std::min(p.y, q.y) <= r.y && r.y <= std::max(p.y, q.y);
  };
  return on(a, b, c, d1) || on(a, b, d, d2) || on(c, d, a, d3) || on(c, d, b, d4);
}

std::string Num(double v) { return absl::StrFormat("%.9g", v); }

}  // namespace

bool Zone::Contains(const glm::dvec3& p, double eps) const {
  if (!(p.x >= min.x - eps && p.y >= min.y - eps && p.z >= min.z - eps && p.x <= max.x + eps &&
        p.y <= max.y + eps && p.z <= max.z + eps))
    return false;
  return vertical_axis < 0 || InPolygon(polygon, Uv(p, vertical_axis), eps);
}

glm::dvec3 Zone::Nearest(const glm::dvec3& p) const {
  if (vertical_axis < 0) return glm::clamp(p, min, max);
  glm::dvec3 q = p;
  const int v = vertical_axis;
  q[v] = std::clamp(p[v], min[v], max[v]);
  const glm::dvec2 uv = Uv(p, v);
  if (!InPolygon(polygon, uv, 0.0)) {
    const glm::dvec2 n = NearestOnBoundary(polygon, uv);
    q[(v + 1) % 3] = n.x;
    q[(v + 2) % 3] = n.y;
  }
  return q;
}

absl::StatusOr<Zone> Zone::Prism(std::string name, int vertical_axis,
                                 std::vector<glm::dvec2> polygon, double floor, double ceiling) {
  const std::string what = absl::StrCat("zone '", name, "': ");
  if (vertical_axis < 0 || vertical_axis > 2)
    return absl::InvalidArgumentError(absl::StrCat(what, "the vertical axis must be x, y or z"));
  if (polygon.size() < 3)
    return absl::InvalidArgumentError(
        absl::StrCat(what, "a polygon needs at least 3 vertices, got ", polygon.size()));
  if (!std::isfinite(floor) || !std::isfinite(ceiling) || !(ceiling > floor))
    return absl::InvalidArgumentError(absl::StrCat(what, "the ceiling must exceed the floor"));
  double area2 = 0;
  for (size_t i = 0; i < polygon.size(); ++i) {
    if (!std::isfinite(polygon[i].x) || !std::isfinite(polygon[i].y))
      return absl::InvalidArgumentError(absl::StrCat(what, "a vertex is not finite"));
    area2 += Cross(polygon[i], polygon[(i + 1) % polygon.size()]);
  }
  if (!(std::abs(area2) > 1e-12))
    return absl::InvalidArgumentError(absl::StrCat(what, "the polygon has no area"));
  const size_t n = polygon.size();
  for (size_t i = 0; i < n; ++i)
    for (size_t j = i + 1; j < n; ++j) {
      if (j == i + 1 || (i == 0 && j == n - 1)) continue;  // neighbours share a vertex
      if (SegmentsCross(polygon[i], polygon[(i + 1) % n], polygon[j], polygon[(j + 1) % n]))
        return absl::InvalidArgumentError(absl::StrCat(
            what, "the polygon's edges ", i, " and ", j, " cross (it must be simple)"));
    }
  Zone z;
  z.name = std::move(name);
  z.vertical_axis = vertical_axis;
  const int a = (vertical_axis + 1) % 3, b = (vertical_axis + 2) % 3;
  z.min[vertical_axis] = floor;
  z.max[vertical_axis] = ceiling;
  z.min[a] = z.max[a] = polygon[0].x;
  z.min[b] = z.max[b] = polygon[0].y;
  for (const glm::dvec2& q : polygon) {
    z.min[a] = std::min(z.min[a], q.x);
    z.max[a] = std::max(z.max[a], q.x);
    z.min[b] = std::min(z.min[b], q.y);
    z.max[b] = std::max(z.max[b], q.y);
  }
  z.polygon = std::move(polygon);
  return z;
}

std::string ZoneText(const Zone& z) {
  if (z.vertical_axis < 0)
    return absl::StrCat(z.name, ":", Num(z.min.x), ",", Num(z.min.y), ",", Num(z.min.z), ",",
                        Num(z.max.x), ",", Num(z.max.y), ",", Num(z.max.z));
  std::string s = absl::StrCat(z.name, ":poly", std::string(1, "xyz"[z.vertical_axis]), ":",
                               Num(z.min[z.vertical_axis]), ",", Num(z.max[z.vertical_axis]), ":");
  for (size_t i = 0; i < z.polygon.size(); ++i)
    absl::StrAppend(&s, i ? "," : "", Num(z.polygon[i].x), ",", Num(z.polygon[i].y));
  return s;
}

absl::StatusOr<Zone> ParseZone(const std::string& text) {
  Zone z;
  absl::string_view body = absl::StripAsciiWhitespace(text);
  if (const size_t colon = body.find(':'); colon != absl::string_view::npos) {
    z.name = std::string(absl::StripAsciiWhitespace(body.substr(0, colon)));
    body = body.substr(colon + 1);
  }
  if (absl::StartsWith(absl::StripLeadingAsciiWhitespace(body), "poly")) {
    const std::vector<std::string> f = absl::StrSplit(body, ':');
    const std::string axis(absl::StripAsciiWhitespace(f[0]));
    if (f.size() != 3 || axis.size() != 5 || axis.find_first_of("xyz", 4) != 4)
      return absl::InvalidArgumentError(absl::StrCat(
          "zone '", text, "': expected name:poly<x|y|z>:floor,ceiling:u1,v1,u2,v2,u3,v3,..."));
    auto numbers = [&](const std::string& list) -> absl::StatusOr<std::vector<double>> {
      std::vector<double> out;
      for (absl::string_view p : absl::StrSplit(list, ',')) {
        double v;
        if (!absl::SimpleAtod(absl::StripAsciiWhitespace(p), &v) || !std::isfinite(v))
          return absl::InvalidArgumentError(
              absl::StrCat("zone '", text, "': '", p, "' is not a number"));
        out.push_back(v);
      }
      return out;
    };
    EXO_ASSIGN_OR_RETURN(const std::vector<double> fc, numbers(f[1]));
    EXO_ASSIGN_OR_RETURN(const std::vector<double> uv, numbers(f[2]));
    if (fc.size() != 2)
      return absl::InvalidArgumentError(
          absl::StrCat("zone '", text, "': expected floor,ceiling (2 numbers)"));
    if (uv.size() % 2 != 0)
      return absl::InvalidArgumentError(
          absl::StrCat("zone '", text, "': polygon coordinates come in pairs, got ", uv.size()));
    std::vector<glm::dvec2> poly;
    for (size_t i = 0; i + 1 < uv.size(); i += 2) poly.push_back({uv[i], uv[i + 1]});
    return Zone::Prism(z.name, axis[4] - 'x', std::move(poly), fc[0], fc[1]);
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
  for (const Zone& z : zones) {
    if (!(z.max.x > z.min.x && z.max.y > z.min.y && z.max.z > z.min.z))
      return absl::InvalidArgumentError(absl::StrCat("safe flight: zone '", z.name, "' is empty"));
    if (z.vertical_axis >= 0) {
      auto prism = Zone::Prism(z.name, z.vertical_axis, z.polygon, z.min[z.vertical_axis],
                               z.max[z.vertical_axis]);
      if (!prism.ok())
        return absl::InvalidArgumentError(absl::StrCat("safe flight: ", prism.status().message()));
    }
  }
  if (!(cell_m > 0)) return absl::InvalidArgumentError("safe flight: cell_m must be > 0");
  if (!(drone_radius_m >= 0)) return absl::InvalidArgumentError("safe flight: drone_radius_m < 0");
  if (!(grid_margin_m >= 0)) return absl::InvalidArgumentError("safe flight: grid_margin_m < 0");
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
  o.min -= glm::dvec3(options.grid_margin_m);
  o.max += glm::dvec3(options.grid_margin_m);
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
            // The target's own cell may have its centre outside the zones (a target on a
            // polygon edge); the target point itself is permitted (Clamp).
            if (closed[qi] || (!CellPermitted(q) && qi != gi)) continue;
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
