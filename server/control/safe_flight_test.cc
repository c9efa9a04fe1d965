#include "server/control/safe_flight.h"

#include <gtest/gtest.h>

#include "server/geometry/tsdf_volume.h"

namespace exo::control {
namespace {

// Two rooms (x in [0,4] and [4.2,8], y in [0,4], z in [0,3]) split by a wall at x in [4, 4.2]
// with a door at y in [1.5, 2.5], z < 2.2. Cells with z >= 2.6 stay unknown (not yet modelled);
// everything else not in the wall is known free.
SafeFlight MakeWorld(bool door_open = true, double top_known = 2.6) {
  SafeFlightOptions o;
  o.zones = {{"house", {0, 0, 0}, {8.2, 4, 3}}};
  o.cell_m = 0.1;
  o.drone_radius_m = 0.2;
  auto safe = SafeFlight::Create(o);
  EXO_CHECK(safe.ok());
  OccupancyGrid& g = safe->grid();
  const glm::ivec3 d = g.dims();
  for (int z = 0; z < d.z; ++z)
    for (int y = 0; y < d.y; ++y)
      for (int x = 0; x < d.x; ++x) {
        const glm::dvec3 p = g.CentreOf({x, y, z});
        if (p.z >= top_known) continue;
        const bool wall = p.x >= 4.0 && p.x < 4.2;
        const bool door = door_open && p.y > 1.5 && p.y < 2.5 && p.z < 2.2;
        const bool floor = p.z < 0.1;
        g.Set({x, y, z}, (wall && !door) || floor ? Occupancy::kOccupied : Occupancy::kFree);
      }
  return *std::move(safe);
}

void ExpectRouteSafe(const SafeFlight& safe, const glm::dvec3& from, const Route& r) {
  glm::dvec3 prev = from;
  for (size_t i = 0; i < r.waypoints.size(); ++i) {
    const glm::dvec3& w = r.waypoints[i];
    EXPECT_TRUE(safe.Permitted(w)) << "waypoint " << i;
    if (i > 0 || !r.start_snapped) EXPECT_TRUE(safe.SegmentPermitted(prev, w)) << "segment " << i;
    // Never into unknown space, not even the drone's sphere: the cell and its neighbours
    // within the radius are known.
    EXPECT_EQ(safe.grid().At(w), Occupancy::kFree);
    prev = w;
  }
  EXPECT_EQ(r.waypoints.back(), r.target);
}

TEST(ParseZone, ReadsAndRejects) {
  auto z = ParseZone("kitchen: 0,0,0, 4,4,2.5");
  ASSERT_TRUE(z.ok()) << z.status();
  EXPECT_EQ(z->name, "kitchen");
  EXPECT_EQ(z->max, glm::dvec3(4, 4, 2.5));
  EXPECT_NE(ParseZone("1,2,3").status().message().find("6 numbers"), std::string::npos);
  EXPECT_NE(ParseZone("a:0,0,0,1,x,1").status().message().find("'x' is not a number"),
            std::string::npos);
  EXPECT_FALSE(ParseZone("0,0,0,0,1,1").ok());
  SafeFlightOptions none;
  EXPECT_FALSE(SafeFlight::Create(none).ok());
}

TEST(ParseZone, PolygonZonesWithFloorAndCeiling) {
  // An L: the square [0,6]² without its corner [3,6]x[3,6]; floor 0.3, ceiling 2.4 along z.
  auto z = ParseZone("ell: polyz: 0.3, 2.4: 0,0, 6,0, 6,3, 3,3, 3,6, 0,6");
  ASSERT_TRUE(z.ok()) << z.status();
  EXPECT_EQ(z->name, "ell");
  EXPECT_EQ(z->vertical_axis, 2);
  EXPECT_EQ(z->min, glm::dvec3(0, 0, 0.3));
  EXPECT_EQ(z->max, glm::dvec3(6, 6, 2.4));
  EXPECT_TRUE(z->Contains({1, 5, 1}));
  EXPECT_TRUE(z->Contains({5, 1, 2.4}));    // on the ceiling
  EXPECT_FALSE(z->Contains({5, 5, 1}));     // in the notch
  EXPECT_FALSE(z->Contains({1, 1, 0.2}));   // below the floor
  EXPECT_FALSE(z->Contains({1, 1, 2.5}));   // above the ceiling
  // Nearest: the notch goes to its nearest edge, height clamped to floor/ceiling.
  const glm::dvec3 n = z->Nearest({4, 3.5, 3.0});
  EXPECT_NEAR(n.x, 4.0, 1e-12);
  EXPECT_NEAR(n.y, 3.0, 1e-12);
  EXPECT_NEAR(n.z, 2.4, 1e-12);
  EXPECT_EQ(z->Nearest({1, 1, 1}), glm::dvec3(1, 1, 1));
  // Round trip through the config text.
  auto again = ParseZone(ZoneText(*z));
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(again->polygon, z->polygon);
  EXPECT_EQ(again->min, z->min);
  EXPECT_EQ(again->max, z->max);
  // 7-Scenes is y down: a prism along y (floor/ceiling in y, the polygon over z, x).
  auto y = ParseZone("seven:polyy:-2.2,-0.2:0,0,4,0,0,3");
  ASSERT_TRUE(y.ok()) << y.status();
  EXPECT_TRUE(y->Contains({0.5, -1, 0.5}));  // (u, v) = (z, x) = (0.5, 0.5)
  EXPECT_FALSE(y->Contains({2.5, -1, 2.5}));
  // Errors name the problem.
  EXPECT_NE(ParseZone("a:polyz:0,2:0,0,1,0").status().message().find("at least 3"),
            std::string::npos);
  EXPECT_NE(ParseZone("a:polyz:2,1:0,0,1,0,0,1").status().message().find("ceiling"),
            std::string::npos);
  EXPECT_NE(ParseZone("a:polyz:0,2:0,0,2,1,2,0,0,2").status().message().find("cross"),
            std::string::npos);  // a bow tie
  EXPECT_NE(ParseZone("a:polyz:0,2:0,0,1,0,2,0").status().message().find("no area"),
            std::string::npos);
  EXPECT_NE(ParseZone("a:polyz:0,2:0,0,1,0,1").status().message().find("pairs"),
            std::string::npos);
  EXPECT_NE(ParseZone("a:polyw:0,2:0,0,1,0,0,1").status().message().find("poly<x|y|z>"),
            std::string::npos);
  EXPECT_NE(ParseZone("a:polyz:0,2:0,0,1,q,0,1").status().message().find("'q'"),
            std::string::npos);
  // A hand-built zone with a broken polygon is refused by the options.
  SafeFlightOptions bad;
  bad.zones = {*z};
  bad.zones[0].polygon.resize(2);
  EXPECT_FALSE(SafeFlight::Create(bad).ok());
}

TEST(SafeFlight, PolygonZoneRoutesAroundItsNotchAndClampsToItsBorder) {
  SafeFlightOptions o;
  auto ell = ParseZone("ell:polyz:0.3,2.4:0,0,6,0,6,3,3,3,3,6,0,6");
  ASSERT_TRUE(ell.ok()) << ell.status();
  o.zones = {*ell};
  o.cell_m = 0.1;
  o.drone_radius_m = 0.2;
  o.region_fallback = false;
  auto safe = SafeFlight::Create(o);
  ASSERT_TRUE(safe.ok()) << safe.status();
  OccupancyGrid& g = safe->grid();
  for (size_t i = 0; i < g.num_cells(); ++i) g.Set(g.CellOfIndex(i), Occupancy::kFree);
  // The notch is known free space but outside the zone: never flown through.
  EXPECT_FALSE(safe->Permitted({4.5, 4.5, 1.2}));
  EXPECT_TRUE(safe->Permitted({4.5, 1.5, 1.2}));
  const glm::dvec3 from(5.0, 1.0, 1.2), to(1.0, 5.0, 1.2);
  auto r = safe->Plan(from, to);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_FALSE(r->clamped);
  ExpectRouteSafe(*safe, from, *r);
  glm::dvec3 prev = from;
  for (const glm::dvec3& w : r->waypoints) {
    for (int k = 0; k <= 20; ++k) EXPECT_TRUE(ell->Contains(prev + (w - prev) * (k / 20.0)));
    prev = w;
  }
  // A target in the notch is clamped to the nearest border and reached.
  auto c = safe->Plan(from, {4.5, 3.4, 1.2});
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_TRUE(c->clamped);
  EXPECT_NEAR(c->target.y, 3.0, 1e-9);
  EXPECT_NEAR(c->target.x, 4.5, 1e-9);
  ExpectRouteSafe(*safe, from, *c);
  // Above the ceiling: clamped down below it (the drone's radius from the grid's unknown
  // outside, as for a box zone), straight below the request.
  auto up = safe->Clamp({1.0, 1.0, 2.9});
  ASSERT_TRUE(up.ok());
  EXPECT_TRUE(safe->Permitted(*up));
  EXPECT_LE(up->z, 2.4);
  EXPECT_GT(up->z, 2.0);
  EXPECT_NEAR(up->x, 1.0, 0.06);
  EXPECT_NEAR(up->y, 1.0, 0.06);
}

TEST(Occupancy, InflationKeepsTheDroneRadiusFromOccupiedAndUnknown) {
  SafeFlight safe = MakeWorld();
  const OccupancyGrid& g = safe.grid();
  EXPECT_GT(g.CountState(Occupancy::kFree), 0u);
  EXPECT_GT(g.CountState(Occupancy::kOccupied), 0u);
  // Wall cells centred at x = 4.05: radius 0.2 + one cell keeps clear centres > 0.3 m away.
  EXPECT_FALSE(safe.Permitted({3.85, 0.8, 1.0}));
  EXPECT_TRUE(safe.Permitted({3.65, 0.8, 1.0}));
  // Unknown above z = 2.6: not permitted near it either.
  EXPECT_FALSE(safe.Permitted({2, 2, 2.45}));
  EXPECT_TRUE(safe.Permitted({2, 2, 2.25}));
  // Occupied is sticky.
  OccupancyGrid copy = g;
  const glm::ivec3 wall = copy.CellOf({4.05, 0.5, 1.0});
  copy.Set(wall, Occupancy::kFree);
  EXPECT_EQ(copy.At(wall), Occupancy::kOccupied);
}

TEST(SafeFlight, AStarGoesThroughTheDoor) {
  SafeFlight safe = MakeWorld();
  const glm::dvec3 from(1, 0.8, 1.0), to(7, 0.8, 1.0);
  auto r = safe.Plan(from, to);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_FALSE(r->clamped);
  EXPECT_GE(r->waypoints.size(), 2u);                     // a corner at the door, then the target
  EXPECT_GT(r->length_m, glm::length(to - from) + 0.25);  // the detour through the door
  ExpectRouteSafe(safe, from, *r);
  bool through_door = false;
  std::vector<glm::dvec3> pts = {from};
  pts.insert(pts.end(), r->waypoints.begin(), r->waypoints.end());
  for (size_t i = 1; i < pts.size(); ++i) {
    const glm::dvec3 a = pts[i - 1], b = pts[i];
    if ((a.x - 4.1) * (b.x - 4.1) <= 0) {
      const double t = (4.1 - a.x) / (b.x - a.x);
      const glm::dvec3 c = a + t * (b - a);
      through_door = c.y > 1.5 && c.y < 2.5 && c.z < 2.2;
    }
  }
  EXPECT_TRUE(through_door);
}

TEST(SafeFlight, TargetInsideAWallIsClampedToAReachablePoint) {
  SafeFlight safe = MakeWorld();
  const glm::dvec3 from(1, 0.8, 1.0), inside_wall(4.1, 0.8, 1.0);
  auto r = safe.Plan(from, inside_wall);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(r->clamped);
  EXPECT_TRUE(safe.Permitted(r->target));
  EXPECT_LT(glm::length(r->target - inside_wall), 0.5);  // the nearest border, one side or other
  ExpectRouteSafe(safe, from, *r);
}

TEST(SafeFlight, TargetOutsideEveryZoneGoesToTheNearestBorder) {
  SafeFlightOptions o;
  o.zones = {{"room", {0, 0, 0}, {4, 4, 3}}};
  o.inflate_unknown = false;  // the zone face itself is reachable
  auto safe = SafeFlight::Create(o);
  ASSERT_TRUE(safe.ok());
  OccupancyGrid& g = safe->grid();
  for (size_t i = 0; i < g.num_cells(); ++i) g.Set(g.CellOfIndex(i), Occupancy::kFree);
  auto c = safe->Clamp({6, 2, 1});
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(*c, glm::dvec3(4, 2, 1));
  auto r = safe->Plan({1, 2, 1}, {2, 2, 10});  // above the ceiling
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(r->clamped);
  EXPECT_EQ(r->target, glm::dvec3(2, 2, 3));
  EXPECT_EQ(r->waypoints.size(), 1u);  // straight line in free space
}

TEST(SafeFlight, TargetInUnknownSpaceIsClampedIntoKnownFreeSpace) {
  SafeFlight safe = MakeWorld();
  const glm::dvec3 from(1, 1, 1), unknown(2, 2, 2.9);
  ASSERT_EQ(safe.grid().At(unknown), Occupancy::kUnknown);
  auto r = safe.Plan(from, unknown);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(r->clamped);
  EXPECT_LT(r->target.z, 2.45);
  EXPECT_NEAR(r->target.x, 2.0, 0.11);
  ExpectRouteSafe(safe, from, *r);
}

TEST(SafeFlight, NoPathIsAClearStatus) {
  SafeFlight safe = MakeWorld(/*door_open=*/false);
  auto r = safe.Plan({1, 0.8, 1.0}, {7, 0.8, 1.0});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(r.status().message().find("no path through known free space"), std::string::npos)
      << r.status();
}

TEST(SafeFlight, NothingPermittedYetIsAClearStatus) {
  SafeFlightOptions o;
  o.zones = {{"room", {0, 0, 0}, {4, 4, 3}}};
  o.region_fallback = false;
  auto safe = SafeFlight::Create(o);
  ASSERT_TRUE(safe.ok());
  auto r = safe->Plan({1, 1, 1}, {2, 2, 2});
  EXPECT_EQ(r.status().code(), absl::StatusCode::kNotFound);
}

TEST(SafeFlight, RegionWaypointsBeforeAnythingIsModelled) {
  SafeFlightOptions o;
  o.zones = {{"a", {0, 0, 0}, {4, 4, 3}},
             {"corridor", {4, 1.5, 0}, {6, 2.5, 3}},
             {"b", {6, 0, 0}, {10, 4, 3}}};
  o.portals = {{4, 2, 1.2}, {6, 2, 1.2}};
  auto safe = SafeFlight::Create(o);
  ASSERT_TRUE(safe.ok());
  ASSERT_TRUE(safe->UsingRegions());
  auto r = safe->Plan({1, 1, 1}, {9, 3, 1});
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(r->regions);
  ASSERT_EQ(r->waypoints.size(), 3u);
  EXPECT_EQ(r->waypoints[0], glm::dvec3(4, 2, 1.2));
  EXPECT_EQ(r->waypoints[1], glm::dvec3(6, 2, 1.2));
  EXPECT_EQ(r->waypoints[2], glm::dvec3(9, 3, 1));
  // Same zone: straight.
  auto same = safe->Plan({1, 1, 1}, {3, 3, 2});
  ASSERT_TRUE(same.ok());
  EXPECT_EQ(same->waypoints.size(), 1u);
  // Without a portal into b: no route.
  o.portals.pop_back();
  auto cut = SafeFlight::Create(o);
  ASSERT_TRUE(cut.ok());
  EXPECT_EQ(cut->Plan({1, 1, 1}, {9, 3, 1}).status().code(), absl::StatusCode::kNotFound);
}

// A fronto-parallel plane 1.95 m in front of a camera at the origin looking along +x (z up).
void PlaneDepth(ImageF* depth, PinholeCamera* cam, Rigid3d* pose) {
  *cam = PinholeCamera{100, 100, 63.5, 47.5, 128, 96};
  *depth = ImageF(128, 96, 1, 1.95f);
  // camera x right = -y, y down = -z, z forward = +x
  const glm::dmat3 r(glm::dvec3(0, -1, 0), glm::dvec3(0, 0, -1), glm::dvec3(1, 0, 0));
  pose->rotation = glm::quat_cast(r);
  pose->translation = glm::dvec3(0.5, 2, 1.5);
}

TEST(Occupancy, CarvingADepthImageFreesTheRaysAndOccupiesTheHits) {
  OccupancyOptions o;
  o.min = {0, 0, 0};
  o.max = {4, 4, 3};
  auto g = OccupancyGrid::Create(o);
  ASSERT_TRUE(g.ok());
  ImageF depth;
  PinholeCamera cam;
  Rigid3d pose;
  PlaneDepth(&depth, &cam, &pose);
  g->CarveDepth(depth, cam, pose, 2);
  EXPECT_EQ(g->At(glm::dvec3(1.5, 2.0, 1.5)), Occupancy::kFree);
  EXPECT_EQ(g->At(glm::dvec3(2.45, 2.0, 1.5)), Occupancy::kOccupied);
  EXPECT_EQ(g->At(glm::dvec3(3.2, 2.0, 1.5)), Occupancy::kUnknown);  // behind the surface
  EXPECT_EQ(g->At(glm::dvec3(1.5, 0.1, 1.5)), Occupancy::kUnknown);  // outside the frustum
  EXPECT_FALSE(OccupancyGrid::Create(OccupancyOptions{}).ok());
}

// A real sensor's missing depth (session 16): only sky is carved — above the horizon, nothing
// measured above it in its column, bright and blue; the renderer's rule (no_return_is_free)
// carves every missing pixel.
TEST(Occupancy, SkyRuleCarvesOnlyTheSkyOfARealSensorsMissingDepth) {
  OccupancyOptions o;
  o.min = {0, 0, 0};
  o.max = {4, 4, 3};
  ImageF depth;
  PinholeCamera cam;
  Rigid3d pose;
  PlaneDepth(&depth, &cam, &pose);  // level, looking along +x; image left = +y, top = +z
  ImageF colour(128, 96, 3, 0.0f);
  for (int y = 0; y < 96; ++y)
    for (int x = 0; x < 128; ++x) {
      depth.at(x, y) = 0.0f;  // no return ...
      const bool dark = x >= 96;  // ... a dark grey surface on the right, blue sky elsewhere
      colour.at(x, y, 0) = dark ? 0.05f : 0.2f;
      colour.at(x, y, 1) = dark ? 0.05f : 0.3f;
      colour.at(x, y, 2) = dark ? 0.05f : 0.6f;
    }
  for (int y = 20; y < 30; ++y)  // a measured surface in the left half, above the horizon
    for (int x = 0; x < 64; ++x) depth.at(x, y) = 1.95f;
  const glm::dvec3 sky_left(3.0, 2.79, 2.44), under_measured(3.0, 2.79, 1.69),
      sky_right(3.0, 1.59, 2.44), dark_right(3.0, 0.79, 2.44), below_horizon(3.0, 1.59, 0.94);
  auto carve = [&](auto&& how) {
    auto g = OccupancyGrid::Create(o);
    EXO_CHECK(g.ok());
    how(*g);
    return *std::move(g);
  };
  OccupancyGrid::SkyRule rule;
  rule.color = &colour;
  const OccupancyGrid sky = carve([&](OccupancyGrid& g) { g.CarveDepth(depth, cam, pose, 1, 5.0, rule); });
  EXPECT_EQ(sky.At(sky_left), Occupancy::kFree);
  EXPECT_EQ(sky.At(sky_right), Occupancy::kFree);
  EXPECT_EQ(sky.At(under_measured), Occupancy::kUnknown);  // something measured above it
  EXPECT_EQ(sky.At(dark_right), Occupancy::kUnknown);      // not sky-coloured
  EXPECT_EQ(sky.At(below_horizon), Occupancy::kUnknown);   // below the horizon
  EXPECT_EQ(sky.At(glm::dvec3(2.45, 2.79, 1.94)), Occupancy::kOccupied);  // the measured surface
  // Without colour the dark surface counts as sky; the renderer's rule carves everything.
  rule.color = nullptr;
  const OccupancyGrid grey = carve([&](OccupancyGrid& g) { g.CarveDepth(depth, cam, pose, 1, 5.0, rule); });
  EXPECT_EQ(grey.At(dark_right), Occupancy::kFree);
  EXPECT_EQ(grey.At(under_measured), Occupancy::kUnknown);
  const OccupancyGrid all = carve([&](OccupancyGrid& g) { g.CarveDepth(depth, cam, pose, 1, 5.0, true); });
  for (const glm::dvec3& p : {sky_left, under_measured, sky_right, dark_right, below_horizon})
    EXPECT_EQ(all.At(p), Occupancy::kFree);
  const OccupancyGrid none = carve([&](OccupancyGrid& g) { g.CarveDepth(depth, cam, pose, 1, 5.0, false); });
  for (const glm::dvec3& p : {sky_left, under_measured, sky_right, dark_right, below_horizon})
    EXPECT_EQ(none.At(p), Occupancy::kUnknown);
}

TEST(Occupancy, TsdfViewMarksFrontFreeAndSurfaceOccupied) {
  TsdfOptions to;
  to.voxel_size_m = 0.04f;
  to.integrate_color = false;
  to.num_threads = 1;
  TsdfVolume vol(to);
  ImageF depth;
  PinholeCamera cam;
  Rigid3d pose;
  PlaneDepth(&depth, &cam, &pose);
  ASSERT_TRUE(vol.IntegrateDepth(depth, cam, pose).ok());
  OccupancyOptions o;
  o.min = {0, 0, 0};
  o.max = {4, 4, 3};
  o.cell_m = 0.08;
  auto g = OccupancyGrid::Create(o);
  ASSERT_TRUE(g.ok());
  g->MarkFromTsdf(vol, glm::dvec3(0.0));
  EXPECT_GT(g->CountState(Occupancy::kOccupied), 100u);
  EXPECT_GT(g->CountState(Occupancy::kFree), 100u);
  // The surface at x = 2.45 is occupied, the band in front of it free, far in front unknown
  // (the TSDF keeps nothing there).
  EXPECT_EQ(g->At(glm::dvec3(2.45, 2.0, 1.5)), Occupancy::kOccupied);
  EXPECT_EQ(g->At(glm::dvec3(2.30, 2.0, 1.5)), Occupancy::kFree);
  EXPECT_EQ(g->At(glm::dvec3(1.2, 2.0, 1.5)), Occupancy::kUnknown);
}

}  // namespace
}  // namespace exo::control
