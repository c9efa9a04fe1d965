#include "server/control/exploration.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <set>

#include "common/synth/trajectory.h"

namespace exo::control {
namespace {

// A 6 x 4 x 3 m zone: x < 3 known free, x >= 3 unknown; optionally a wall (occupied) at
// x in [3, 3.2) instead of unknown there.
SafeFlight MakeWorld(bool wall) {
  SafeFlightOptions o;
  o.zones = {{"room", {0, 0, 0}, {6, 4, 3}}};
  o.cell_m = 0.1;
  o.region_fallback = false;
  auto s = SafeFlight::Create(o);
  EXO_CHECK(s.ok());
  OccupancyGrid& g = s->grid();
  for (size_t i = 0; i < g.num_cells(); ++i) {
    const glm::ivec3 c = g.CellOfIndex(i);
    const glm::dvec3 p = g.CentreOf(c);
    if (p.x < 3)
      g.Set(c, Occupancy::kFree);
    else if (wall && p.x < 3.2)
      g.Set(c, Occupancy::kOccupied);
  }
  return *std::move(s);
}

TEST(Exploration, NearestFrontierFacesTheUnknown) {
  SafeFlight safe = MakeWorld(false);
  ExplorationPlanner p{ExploreOptions{}};
  auto v = p.NearestFrontier(safe, {1, 2, 1.5}, SceneFrame::ZUp());
  ASSERT_TRUE(v.has_value());
  EXPECT_GT(v->pose.position.x, 2.0);  // near the boundary at x = 3
  EXPECT_LT(v->pose.position.x, 3.0);
  EXPECT_LT(std::abs(v->pose.yaw), 0.3);  // facing +x
  EXPECT_TRUE(safe.Permitted(v->pose.position));
  // The same goal is not proposed twice.
  auto w = p.NearestFrontier(safe, {1, 2, 1.5}, SceneFrame::ZUp());
  ASSERT_TRUE(w.has_value());
  EXPECT_NE(w->pose.position, v->pose.position);
}

TEST(Exploration, AutonomousPrefersUnseenSpaceAndIsReachable) {
  SafeFlight safe = MakeWorld(false);
  ExploreOptions o;
  o.seed = 3;
  ExplorationPlanner p(o);
  auto v = p.Autonomous(safe, {1, 2, 1.5}, SceneFrame::ZUp());
  ASSERT_TRUE(v.has_value());
  EXPECT_GT(v->gain, 0);
  EXPECT_LT(std::abs(v->pose.yaw), kPi / 2);  // looks towards the unknown half
  EXPECT_TRUE(std::isfinite(v->path_m));
  EXPECT_TRUE(safe.Plan({1, 2, 1.5}, v->pose.position).ok());
}

TEST(Exploration, ObservingASurfaceRaisesTauAndLowersTheGain) {
  SafeFlight safe = MakeWorld(true);
  ExploreOptions o;
  ExplorationPlanner p(o);
  const Setpoint facing{{1.2, 2, 1.5}, 0.0};
  const double before = p.Gain(safe.grid(), facing, SceneFrame::ZUp());
  EXPECT_GT(before, 0);
  // A camera at (1.2, 2, 1.5) looking along +x at the wall (x = 3.05).
  PinholeCamera cam{80, 80, 39.5, 29.5, 80, 60};
  ImageF depth(80, 60, 1, 1.85f);
  Rigid3d pose;
  pose.rotation =
      glm::quat_cast(glm::dmat3(glm::dvec3(0, -1, 0), glm::dvec3(0, 0, -1), glm::dvec3(1, 0, 0)));
  pose.translation = {1.2, 2, 1.5};
  for (int k = 0; k < 3; ++k) p.Observe(safe.grid(), depth, cam, pose, 2);
  const size_t wall_cell = safe.grid().Index(safe.grid().CellOf({3.05, 2, 1.5}));
  EXPECT_GT(p.Tau(wall_cell), 0.5);
  EXPECT_LE(p.Tau(wall_cell), o.tau_max);
  EXPECT_GT(p.cells_seen(), 10u);
  const double after = p.Gain(safe.grid(), facing, SceneFrame::ZUp());
  EXPECT_LT(after, 0.7 * before);
}

TEST(Exploration, AGimbalLooksDownAtAnUnseenFloor) {
  // A known room, free but for its floor (occupied, never observed: τ = 0).
  SafeFlightOptions o;
  o.zones = {{"room", {0, 0, 0}, {6, 4, 3}}};
  o.cell_m = 0.1;
  o.region_fallback = false;
  auto s = SafeFlight::Create(o);
  ASSERT_TRUE(s.ok());
  OccupancyGrid& g = s->grid();
  for (size_t i = 0; i < g.num_cells(); ++i) {
    const glm::ivec3 c = g.CellOfIndex(i);
    g.Set(c, g.CentreOf(c).z < 0.1 ? Occupancy::kOccupied : Occupancy::kFree);
  }
  ExploreOptions eo;
  eo.pitches = {-0.5, 0.0, 0.5};
  eo.seed = 5;
  ExplorationPlanner p(eo);
  const Setpoint pose{{1, 2, 1.5}, 0.0};
  const double level = p.Gain(g, pose, SceneFrame::ZUp(), 0.0);
  const double down = p.Gain(g, pose, SceneFrame::ZUp(), -0.5);
  const double up = p.Gain(g, pose, SceneFrame::ZUp(), 0.5);
  EXPECT_GT(level, 0);
  EXPECT_GT(down, 1.5 * level);
  EXPECT_EQ(up, 0);  // nothing but free space above
  auto v = p.Autonomous(*s, {1, 2, 1.5}, SceneFrame::ZUp());
  ASSERT_TRUE(v.has_value());
  EXPECT_DOUBLE_EQ(v->pitch, -0.5);
  // A level-only planner never proposes a pitch.
  ExplorationPlanner level_only{ExploreOptions{}};
  auto w = level_only.Autonomous(*s, {1, 2, 1.5}, SceneFrame::ZUp());
  ASSERT_TRUE(w.has_value());
  EXPECT_EQ(w->pitch, 0.0);
}

// The sweep fallback: in MakeWorld(false) every view's gain is unknown space (nothing is
// occupied), so the planner flies the sweep's points in order, each once, at the highest
// reachable cell of the point's column (the points lie above the zone: 5 m, the zone ends at
// 3 m), looking along the sweep at its pitch; a point whose column is unknown (x >= 3) waits,
// and once every reachable point is flown the coverage-driven view comes back.
TEST(Exploration, SweepFallbackWhileTheGainIsMostlyUnknown) {
  SafeFlight safe = MakeWorld(false);
  ExploreOptions o;
  o.seed = 3;
  o.sweep = {{0.52, 0.52, 5}, {2.52, 0.52, 5}, {4.52, 0.52, 5}, {2.52, 3.52, 5}};
  o.sweep_climb = false;  // the session-14 fallback (the look before a climb: below)
  ExplorationPlanner p(o);
  const glm::dvec3 from{1, 2, 1.5};
  auto a = p.Autonomous(safe, from, SceneFrame::ZUp());
  ASSERT_TRUE(a.has_value());
  EXPECT_EQ(a->sweep_index, 0);
  EXPECT_NEAR(a->pose.position.x, 0.55, 1e-9);  // the cell centre under (0.52, 0.52)
  EXPECT_NEAR(a->pose.position.y, 0.55, 1e-9);
  EXPECT_GT(a->pose.position.z, 2.6);  // the top of the zone, inside the drone's clearance
  EXPECT_LT(a->pose.position.z, 3.0);
  EXPECT_NEAR(a->pose.yaw, 0.0, 1e-9);  // towards the next point (+x)
  EXPECT_DOUBLE_EQ(a->pitch, o.sweep_pitch);
  EXPECT_GT(a->gain_unknown, 0.9 * a->gain);  // why: the best view's gain was unknown space
  EXPECT_TRUE(safe.Plan(from, a->pose.position).ok());
  EXPECT_EQ(a->pass_m, 0.0);  // below the sweep's altitude: a view hovered at
  auto b = p.Autonomous(safe, a->pose.position, SceneFrame::ZUp());  // (the drone got there)
  ASSERT_TRUE(b.has_value());
  EXPECT_EQ(b->sweep_index, 1);
  // The drone did not get to b (its route was dropped): b again, once.
  auto b2 = p.Autonomous(safe, from, SceneFrame::ZUp());
  ASSERT_TRUE(b2.has_value());
  EXPECT_EQ(b2->sweep_index, 1);
  auto c = p.Autonomous(safe, from, SceneFrame::ZUp());  // (4.52, 0.52) is unknown: skipped
  ASSERT_TRUE(c.has_value());
  EXPECT_EQ(c->sweep_index, 3);  // (b not again: it was retried once)
  auto d = p.Autonomous(safe, c->pose.position, SceneFrame::ZUp());  // coverage-driven again
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->sweep_index, -1);
  EXPECT_LT(std::abs(d->pose.yaw), kPi / 2);
  // With surface in view (a wall: the gain is not mostly unknown) no sweep point is flown.
  SafeFlight walled = MakeWorld(true);
  ExploreOptions w = o;
  w.unknown_gain = 0.0;
  ExplorationPlanner q(w);
  auto e = q.Autonomous(walled, from, SceneFrame::ZUp());
  ASSERT_TRUE(e.has_value());
  EXPECT_EQ(e->sweep_index, -1);
}

TEST(Exploration, SweepStartsAtItsEndNearerTheDrone) {
  SafeFlight safe = MakeWorld(false);
  ExploreOptions o;
  o.sweep = {{0.52, 0.52, 5}, {2.52, 0.52, 5}, {2.52, 3.52, 5}};
  o.sweep_climb = false;
  ExplorationPlanner p(o);
  auto a = p.Autonomous(safe, {2.4, 3.3, 1.5}, SceneFrame::ZUp());  // beside the last point
  ASSERT_TRUE(a.has_value());
  EXPECT_EQ(a->sweep_index, 2);  // the index in ExploreOptions::sweep's order
  auto b = p.Autonomous(safe, a->pose.position, SceneFrame::ZUp());
  ASSERT_TRUE(b.has_value());
  EXPECT_EQ(b->sweep_index, 1);
}

// A 30 x 30 x 12 m outdoor zone: the air below 3 m is known free (a level camera near the
// ground carves it), everything above unknown; the sweep at 10 m.
SafeFlight MakeOutdoor() {
  SafeFlightOptions o;
  o.zones = {{"village", {0, 0, 0}, {30, 30, 12}}};
  o.cell_m = 0.5;
  o.region_fallback = false;
  auto s = SafeFlight::Create(o);
  EXO_CHECK(s.ok());
  OccupancyGrid& g = s->grid();
  for (size_t i = 0; i < g.num_cells(); ++i)
    if (g.CentreOf(g.CellOfIndex(i)).z < 3) g.Set(g.CellOfIndex(i), Occupancy::kFree);
  return *std::move(s);
}

// Marks free the cells within `r` of the segment a-b (what a look along it carves).
void CarveAlong(SafeFlight* safe, const glm::dvec3& a, const glm::dvec3& b, double r) {
  OccupancyGrid& g = safe->grid();
  for (size_t i = 0; i < g.num_cells(); ++i) {
    const glm::dvec3 p = g.CentreOf(g.CellOfIndex(i));
    const double t = std::clamp(glm::dot(p - a, b - a) / glm::dot(b - a, b - a), 0.0, 1.0);
    if (glm::length(p - (a + t * (b - a))) < r) g.Set(g.CellOfIndex(i), Occupancy::kFree);
  }
}

TEST(Exploration, SweepClimbLooksAtThePointBeforeFlyingUpTheLineOfSight) {
  SafeFlight safe = MakeOutdoor();
  const SceneFrame frame = SceneFrame::ZUp();
  ExploreOptions o;
  o.range_m = 30;
  o.sweep = {{5, 5, 10}, {5, 11, 10}, {11, 11, 10}, {11, 5, 10}};
  ExplorationPlanner p(o);
  const glm::dvec3 from{4, 2, 1.5};
  // 1. The point is 8.5 m above the known air: a look at it from the free layer, never a pose
  //    in unknown space.
  auto look = p.Autonomous(safe, from, frame);
  ASSERT_TRUE(look.has_value());
  EXPECT_TRUE(look->climb);
  EXPECT_EQ(look->sweep_index, -1);
  EXPECT_TRUE(safe.Permitted(look->pose.position));
  EXPECT_TRUE(safe.Plan(from, look->pose.position).ok());
  const glm::dvec3 d = o.sweep[0] - look->pose.position;
  const double elev = std::atan2(d.z, glm::length(glm::dvec2(d)));
  EXPECT_GT(look->pitch, 0.0);
  EXPECT_LE(look->pitch, o.sweep_climb_pitch);
  EXPECT_LE(std::abs(elev - look->pitch), 0.5 * o.vfov_rad);  // the point is in view
  EXPECT_LT(std::abs(WrapAngle(look->pose.yaw - frame.YawOf(d))), 1e-9);  // facing it
  EXPECT_LT(glm::length(d), o.range_m);
  // 2. The look carved its line of sight: the point at its altitude, passed through, the
  //    camera down (straight up the line of sight from where the drone looked).
  CarveAlong(&safe, look->pose.position, o.sweep[0], 1.0);
  auto first = p.Autonomous(safe, look->pose.position, frame);
  ASSERT_TRUE(first.has_value());
  EXPECT_FALSE(first->climb);
  EXPECT_EQ(first->sweep_index, 0);
  EXPECT_GT(first->pose.position.z, 9.0);
  EXPECT_DOUBLE_EQ(first->pitch, o.sweep_pitch);
  EXPECT_EQ(first->pass_m, o.sweep_pass_m);
  EXPECT_TRUE(safe.Plan(look->pose.position, first->pose.position).ok());
  //    Climbing, the camera faces the centre of the points still to fly, not the leg
  //    (session 16: the climb enters the sweep at a corner, and facing the leg looked out of
  //    the scene); with sweep_climb_face_centre off, the leg. Here the two agree roughly (the
  //    drone came from the sweep's side); below, from the north, they do not.
  const glm::dvec3 centre = (o.sweep[1] + o.sweep[2] + o.sweep[3]) / 3.0;
  EXPECT_NEAR(WrapAngle(first->pose.yaw - frame.YawOf(centre - first->pose.position)), 0.0, 1e-9);
  for (const bool face_centre : {true, false}) {
    ExploreOptions n = o;
    n.sweep_climb_face_centre = face_centre;
    ExplorationPlanner r(n);
    SafeFlight s2 = MakeOutdoor();
    const glm::dvec3 north{5, 25, 1.5};
    auto l2 = r.Autonomous(s2, north, frame);
    ASSERT_TRUE(l2.has_value());
    ASSERT_TRUE(l2->climb);
    EXPECT_GT(l2->pose.position.y, 8.0);  // looked at (5, 5) from the north
    CarveAlong(&s2, l2->pose.position, o.sweep[0], 1.0);
    auto f2 = r.Autonomous(s2, l2->pose.position, frame);
    ASSERT_TRUE(f2.has_value());
    EXPECT_EQ(f2->sweep_index, 0);
    const double leg = frame.YawOf(f2->pose.position - l2->pose.position);  // ~ south
    const double mid = frame.YawOf(centre - f2->pose.position);             // ~ north-east
    EXPECT_GT(std::abs(WrapAngle(leg - mid)), 1.5);
    EXPECT_NEAR(WrapAngle(f2->pose.yaw - (face_centre ? mid : leg)), 0.0, 1e-9) << face_centre;
  }
  // 3. The next point (6 m on, not seen): a look from where the drone is, level (pitch 0:
  //    the point is at the drone's height), facing it.
  auto next = p.Autonomous(safe, first->pose.position, frame);
  ASSERT_TRUE(next.has_value());
  EXPECT_TRUE(next->climb);
  EXPECT_LT(glm::length(next->pose.position - first->pose.position), 1.0);
  EXPECT_NEAR(next->pitch, 0.0, 0.1);
  EXPECT_NEAR(next->pose.yaw, kPi / 2, 0.2);  // towards (5, 11)
  // A look not reached (the drone stayed below) does not count; with sweep_climb off the
  // session-14 behaviour: the highest reachable cell under the point, hovered at.
  ExploreOptions off = o;
  off.sweep_climb = false;
  ExplorationPlanner q(off);
  SafeFlight low = MakeOutdoor();
  auto v = q.Autonomous(low, from, frame);
  ASSERT_TRUE(v.has_value());
  EXPECT_EQ(v->sweep_index, 0);
  EXPECT_LT(v->pose.position.z, 3.0);
  EXPECT_EQ(v->pass_m, 0.0);
}

TEST(Exploration, HilbertSweepCoversTheFootprintInUnitSteps) {
  const SceneFrame z = SceneFrame::ZUp();
  const auto s = HilbertSweep({0, 0, 0}, {10, 20, 5}, 8.0, z);
  ASSERT_EQ(s.size(), 64u);
  const double sx = (10 - 2 * 1.5) / 7.0, sy = (20 - 2 * 1.5) / 7.0;  // inset 15 % of 10 m
  EXPECT_NEAR(s.front().x, 1.5, 1e-9);
  EXPECT_NEAR(s.front().y, 1.5, 1e-9);
  std::set<std::pair<long, long>> cells;
  for (size_t i = 0; i < s.size(); ++i) {
    EXPECT_NEAR(s[i].z, 8.0, 1e-9);
    const long cx = std::lround((s[i].x - 1.5) / sx), cy = std::lround((s[i].y - 1.5) / sy);
    EXPECT_NEAR(s[i].x, 1.5 + cx * sx, 1e-9);
    cells.insert({cx, cy});
    if (i > 0) {  // one grid step to the next point
      const long dx = std::labs(cx - std::lround((s[i - 1].x - 1.5) / sx));
      const long dy = std::labs(cy - std::lround((s[i - 1].y - 1.5) / sy));
      EXPECT_EQ(dx + dy, 1) << i;
    }
  }
  EXPECT_EQ(cells.size(), 64u);  // every cell of the 8 x 8 grid once
  // The same points, in the same order, as the scripted fly-over's (synth::HilbertCurve).
  const auto h = synth::HilbertCurve(3);
  for (size_t i = 0; i < s.size(); ++i) {
    EXPECT_NEAR(s[i].x, 1.5 + h[i].x * 7.0, 1e-9) << i;
    EXPECT_NEAR(s[i].y, 1.5 + h[i].y * 17.0, 1e-9) << i;
  }
  // 7-Scenes' frame (y down): the altitude is along -y, the footprint over x and z.
  auto y_down = SceneFrame::FromUp({0, -1, 0});
  ASSERT_TRUE(y_down.ok());
  for (const glm::dvec3& p : HilbertSweep({0, -5, 0}, {10, 0, 10}, 3.0, *y_down)) {
    EXPECT_NEAR(y_down->Height(p), 3.0, 1e-9);
    EXPECT_GE(p.x, 1.5 - 1e-9);
    EXPECT_LE(p.x, 8.5 + 1e-9);
    EXPECT_GE(p.z, 1.5 - 1e-9);
    EXPECT_LE(p.z, 8.5 + 1e-9);
  }
}

TEST(Exploration, NothingReachableGivesNoView) {
  SafeFlightOptions o;
  o.zones = {{"room", {0, 0, 0}, {4, 4, 3}}};
  o.region_fallback = false;
  auto s = SafeFlight::Create(o);
  ASSERT_TRUE(s.ok());
  ExplorationPlanner p{ExploreOptions{}};
  EXPECT_FALSE(p.Autonomous(*s, {1, 1, 1}, SceneFrame::ZUp()).has_value());
  EXPECT_FALSE(p.NearestFrontier(*s, {1, 1, 1}, SceneFrame::ZUp()).has_value());
}

}  // namespace
}  // namespace exo::control
