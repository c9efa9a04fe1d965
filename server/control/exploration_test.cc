#include "server/control/exploration.h"

#include <gtest/gtest.h>

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
  auto b = p.Autonomous(safe, from, SceneFrame::ZUp());
  ASSERT_TRUE(b.has_value());
  EXPECT_EQ(b->sweep_index, 1);
  auto c = p.Autonomous(safe, from, SceneFrame::ZUp());  // (4.52, 0.52) is unknown: skipped
  ASSERT_TRUE(c.has_value());
  EXPECT_EQ(c->sweep_index, 3);
  auto d = p.Autonomous(safe, from, SceneFrame::ZUp());  // the coverage-driven view again
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
