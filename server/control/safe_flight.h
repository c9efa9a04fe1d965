// Safe flight (SPEC §8, thesis 5.2.4): where the drone may be and how it gets there.
//   - Zones: boxes in the control frame (their extent along the up axis is the floor and the
//     ceiling), from the config. The drone's centre stays inside their union.
//   - The modelled space: an OccupancyGrid over the zones; a point is permitted when it is in a
//     zone and its cell is clear (known free, the drone radius away from occupied and unknown
//     space). Unknown space is never entered.
//   - Clamp: every setpoint goes to the nearest permitted point (the point itself, the nearest
//     point of the zones, or the nearest clear cell centre).
//   - Plan: A* over the clear cells (26-neighbourhood, Euclidean costs and heuristic), then
//     line-of-sight shortcuts; the route is a list of waypoints flown in order. No path gives
//     NotFound with the reason. Before anything is modelled (no known cell) the thesis'
//     region-waypoint scheme is the fallback: zones are regions, configured portal points join
//     them, and a route changes region only through a portal.
#pragma once

#include <glm/glm.hpp>
#include <optional>
#include <string>
#include <vector>

#include "common/status.h"
#include "server/control/occupancy.h"

namespace exo::control {

// A box, or a prism: a polygon in the plane of two world axes with a floor and a ceiling along
// the third (`vertical_axis`, 0/1/2 = x/y/z; 7-Scenes' up is -y: vertical axis 1). Polygon
// vertices are (u, v) = the coordinates along the world axes (vertical+1)%3 and (vertical+2)%3,
// in order (either orientation, simple, convex or not). min/max = the prism's bounding box.
struct Zone {
  std::string name;
  glm::dvec3 min{0.0}, max{0.0};
  int vertical_axis = -1;           // -1: a box
  std::vector<glm::dvec2> polygon;  // vertical_axis >= 0 only
  bool Contains(const glm::dvec3& p, double eps = 1e-9) const;
  // The nearest point of the zone (the point itself when inside).
  glm::dvec3 Nearest(const glm::dvec3& p) const;
  // Errors: fewer than 3 vertices, zero area, crossing edges, non-finite, floor >= ceiling.
  // Sets min/max from the polygon and the floor/ceiling.
  static absl::StatusOr<Zone> Prism(std::string name, int vertical_axis,
                                    std::vector<glm::dvec2> polygon, double floor,
                                    double ceiling);
};
// "name:minx,miny,minz,maxx,maxy,maxz" (a box; name optional) or
// "name:poly<x|y|z>:floor,ceiling:u1,v1,u2,v2,u3,v3,..." (a prism, see Zone) -> Zone; errors
// name the bad part.
absl::StatusOr<Zone> ParseZone(const std::string& text);
// The inverse of ParseZone.
std::string ZoneText(const Zone& zone);

struct SafeFlightOptions {
  std::vector<Zone> zones;
  std::vector<glm::dvec3> portals;  // region-waypoint fallback: points joining two zones
  double cell_m = 0.1;
  double drone_radius_m = 0.2;
  bool inflate_unknown = true;
  bool region_fallback = true;  // use the region scheme while nothing is modelled
  // The occupancy view reaches this far beyond the zones' bounding box: the surfaces that bound
  // the flight space (a room's floor, ceiling and walls just outside a zone with a margin) are
  // modelled too, so exploration can see and rate them, and the unknown space just outside a
  // zone keeps the drone's sphere away as any unknown space does. Flight stays in the zones.
  double grid_margin_m = 0.5;
  absl::Status Validate() const;
};

struct Route {
  std::vector<glm::dvec3> waypoints;  // in flight order; the last one is the target
  glm::dvec3 requested{0.0};          // what the interaction asked for
  glm::dvec3 target{0.0};             // after clamping
  bool clamped = false;               // target != requested
  bool start_snapped = false;         // the start was not permitted: the first waypoint leaves it
  bool regions = false;               // planned by the region-waypoint fallback
  double length_m = 0.0;
  size_t expanded = 0;  // A* nodes expanded
};

class SafeFlight {
 public:
  static absl::StatusOr<SafeFlight> Create(const SafeFlightOptions& options);

  OccupancyGrid& grid() { return grid_; }
  const OccupancyGrid& grid() const { return grid_; }
  const SafeFlightOptions& options() const { return options_; }
  // True while nothing is modelled and the region fallback is on.
  bool UsingRegions() const { return options_.region_fallback && !grid_.AnyKnown(); }

  bool InZones(const glm::dvec3& p) const;
  bool Permitted(const glm::dvec3& p) const;
  // Every sample (spacing cell/4) of the segment is permitted.
  bool SegmentPermitted(const glm::dvec3& a, const glm::dvec3& b) const;
  // The nearest permitted point. NotFound when no point is permitted at all.
  absl::StatusOr<glm::dvec3> Clamp(const glm::dvec3& p) const;
  // A route from `from` to the clamped `to`. NotFound (with the reason) when there is none.
  absl::StatusOr<Route> Plan(const glm::dvec3& from, const glm::dvec3& to) const;

 private:
  SafeFlight(const SafeFlightOptions& options, OccupancyGrid grid)
      : options_(options), grid_(std::move(grid)) {}
  bool CellPermitted(const glm::ivec3& c) const;
  absl::StatusOr<Route> PlanRegions(const glm::dvec3& from, const glm::dvec3& to) const;

  SafeFlightOptions options_;
  OccupancyGrid grid_;
};

}  // namespace exo::control
