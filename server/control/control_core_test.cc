#include "server/control/control_core.h"

#include <gtest/gtest.h>

#include "common/drone/sim_drone.h"
#include "common/drone/test_util.h"

namespace exo::control {
namespace {

using testing::AddQuad;

// Two rooms split by a wall at x = 4 with a door (y in [1.5, 2.5], z < 2.2); the wall is a mesh
// (what the proxy gives) and the free space is carved from "views" looking around each room.
TriangleMesh WallWithDoor() {
  TriangleMesh m;
  AddQuad(&m, {4, 0, 0}, {4, 1.5, 0}, {4, 1.5, 3}, {4, 0, 3});
  AddQuad(&m, {4, 2.5, 0}, {4, 4, 0}, {4, 4, 3}, {4, 2.5, 3});
  AddQuad(&m, {4, 1.5, 2.2}, {4, 2.5, 2.2}, {4, 2.5, 3}, {4, 1.5, 3});
  AddQuad(&m, {0, 0, 0}, {8, 0, 0}, {8, 4, 0}, {0, 4, 0});  // floor
  return m;
}

std::unique_ptr<ControlCore> MakeCore() {
  ControlCoreOptions o;
  o.safe.zones = {{"house", {0, 0, 0}, {8, 4, 2.6}}};
  o.safe.cell_m = 0.1;
  o.safe.drone_radius_m = 0.2;
  auto core = ControlCore::Create(o);
  EXO_CHECK(core.ok());
  (*core)->UpsertChunk(1, WallWithDoor());
  // Known free space: everything in the zones that is not within the wall/floor (as carving
  // many views would give).
  (*core)->WithSafeFlight([](SafeFlight& s) {
    OccupancyGrid& g = s.grid();
    for (size_t i = 0; i < g.num_cells(); ++i) g.Set(g.CellOfIndex(i), Occupancy::kFree);
  });
  return *std::move(core);
}

DroneState At(const glm::dvec3& p) {
  DroneState s;
  s.position = p;
  return s;
}

TEST(ControlCore, CommandsNeedADroneAndIncreasingOperatorSequences) {
  auto core = MakeCore();
  Command c{"alice", 1, "drone"};
  EXPECT_EQ(core->PickAndPlace(c, {0, 0, 1.6}, {0.3, 0, 1.4}, {0, 0.1, 0}, 0).status().code(),
            absl::StatusCode::kFailedPrecondition);
  core->OnDroneState("drone", At({1, 1, 1}), 0);
  c.operator_sequence = 2;
  auto ok = core->PickAndPlace(c, {0, 1, 1.6}, {0.3, 1, 1.4}, {0, 0.1, 0}, 0);
  ASSERT_TRUE(ok.ok()) << ok.status();
  EXPECT_EQ(ok->command_sequence, 1u);
  auto stale = core->PickAndPlace(c, {0, 1, 1.6}, {0.3, 1, 1.4}, {0, 0.1, 0}, 0);
  EXPECT_EQ(stale.status().code(), absl::StatusCode::kAborted);
  EXPECT_NE(stale.status().message().find("stale"), std::string::npos);
  EXPECT_EQ(core->PickAndPlace({"", 1, "drone"}, {}, {1, 0, 0}, {}, 0).status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(ControlCore, TwoOperatorsLastWriterWinsAndBothSeeTheOutcome) {
  auto core = MakeCore();
  core->OnDroneState("drone", At({1, 1, 1}), 0);
  auto a = core->GazeToSee({"alice", 7, "drone"}, {0.5, 1, 1.5}, {1, 0, 0}, 0.0);
  auto b = core->PickAndPlace({"bob", 1, "drone"}, {0.5, 1, 1.6}, {0.8, 1, 1.4}, {0, 0.1, 0}, 0.0);
  ASSERT_TRUE(a.ok()) << a.status();
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_LT(a->command_sequence, b->command_sequence);
  const DroneView v = core->View("drone");
  EXPECT_EQ(v.command_sequence, b->command_sequence);
  EXPECT_EQ(v.operator_id, "bob");
  EXPECT_EQ(v.kind, InteractionKind::kPickAndPlace);
  auto sp = core->NextSetpoint("drone", 0.0);
  ASSERT_TRUE(sp.has_value());
  EXPECT_EQ(sp->command_sequence, b->command_sequence);
  EXPECT_EQ(sp->operator_id, "bob");
}

TEST(ControlCore, GazeThroughTheDoorStreamsWaypointsInOrder) {
  auto core = MakeCore();
  core->OnDroneState("drone", At({1, 0.8, 1.0}), 0);
  // Look through the door at the far room's wall (x = 8 has no mesh: add one).
  TriangleMesh far;
  AddQuad(&far, {8, 0, 0}, {8, 4, 0}, {8, 4, 3}, {8, 0, 3});
  core->UpsertChunk(2, far);
  auto r = core->GazeToSee({"alice", 1, "drone"}, {1, 2, 1.5}, {1, 0.05, 0}, 0.0);
  ASSERT_TRUE(r.ok()) << r.status();
  ASSERT_TRUE(r->gaze.has_value());
  EXPECT_NEAR(r->gaze->hit.point.x, 8.0, 1e-6);
  EXPECT_NEAR(r->target.position.x, 7.5, 0.11);
  EXPECT_NEAR(r->target.yaw, 0.0, 0.2);
  ASSERT_GE(r->route.waypoints.size(), 2u);
  auto first = core->NextSetpoint("drone", 0.0);
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->waypoint_index, 0u);
  EXPECT_EQ(first->kind, InteractionKind::kGazeToSee);
  // Not due again before 1/30 s, due after.
  EXPECT_FALSE(core->NextSetpoint("drone", 0.01).has_value());
  auto repeat = core->NextSetpoint("drone", 0.04);
  ASSERT_TRUE(repeat.has_value());
  EXPECT_EQ(repeat->sequence, first->sequence);
  // At the first waypoint: the next one, immediately, with a new sequence.
  core->OnDroneState("drone", At(first->setpoint.position), 0.05);
  auto second = core->NextSetpoint("drone", 0.05);
  ASSERT_TRUE(second.has_value());
  EXPECT_EQ(second->waypoint_index, 1u);
  EXPECT_GT(second->sequence, first->sequence);
}

TEST(ControlCore, GazeAtTheSkyAndAtAWallInsideTheZoneEdge) {
  auto core = MakeCore();
  core->OnDroneState("drone", At({1, 1, 1}), 0);
  auto sky = core->GazeToSee({"alice", 1, "drone"}, {1, 1, 1.5}, {-1, 0, 1}, 0);
  EXPECT_EQ(sky.status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(core->View("drone").command_sequence, 0u);  // nothing changed
}

TEST(ControlCore, GoToAStoredView) {
  auto core = MakeCore();
  core->SetOrigin({0, 0, 0});
  Rigid3d pose;
  // Camera looking along +y (cam z -> world +y).
  const glm::dmat3 r(glm::dvec3(1, 0, 0), glm::dvec3(0, 0, -1), glm::dvec3(0, 1, 0));
  pose.rotation = glm::quat_cast(r);
  pose.translation = {2, 1, 1.2};
  core->AddView(5, pose, PinholeCamera{100, 100, 50, 50, 100, 100}, nullptr);
  core->OnDroneState("drone", At({1, 1, 1}), 0);
  auto res = core->GoToView({"op", 1, "drone"}, 5, 0);
  ASSERT_TRUE(res.ok()) << res.status();
  EXPECT_NEAR(res->target.position.x, 2, 1e-9);
  EXPECT_NEAR(res->target.yaw, kPi / 2, 1e-9);
  EXPECT_EQ(core->GoToView({"op", 2, "drone"}, 99, 0).status().code(), absl::StatusCode::kNotFound);
}

// Closed loop in one process: the core streams a gaze route through the door to the simulated
// drone at 120 Hz; the drone must arrive with no collision against the wall mesh.
TEST(ControlCore, ClosedLoopWithTheSimulatedDroneHasNoCollision) {
  auto core = MakeCore();
  TriangleMesh far;
  AddQuad(&far, {8, 0, 0}, {8, 4, 0}, {8, 4, 3}, {8, 0, 3});
  core->UpsertChunk(2, far);
  SimDrone drone{SimDroneOptions{}};
  drone.Reset({1, 0.8, 1.0}, 0);
  TriangleMesh truth = WallWithDoor();
  truth.Append(far);
  CollisionMonitor collisions(truth, drone.options().radius_m);
  core->OnDroneState("drone", drone.state(), 0);
  auto r = core->GazeToSee({"alice", 1, "drone"}, {1, 2, 1.5}, {1, 0.05, 0}, 0.0);
  ASSERT_TRUE(r.ok()) << r.status();
  for (int i = 0; i < 120 * 30; ++i) {
    const double now = drone.state().timestamp_s;
    core->OnDroneState("drone", drone.state(), now);
    if (auto sp = core->NextSetpoint("drone", now)) drone.Receive(sp->setpoint, now);
    collisions.Update(drone.Step().position);
  }
  EXPECT_LT(glm::length(drone.state().position - r->target.position), 0.05);
  EXPECT_EQ(collisions.collisions(), 0u);
  EXPECT_GT(collisions.min_clearance_m(), 0.0);
  EXPECT_EQ(core->View("drone").waypoint_index + 1, r->route.waypoints.size());
}

// The outdoor sweep over the service's core (explore_sweep_altitude_m, session 15): a look
// before the climb, then the sweep's points passed through without a hover, its progress kept
// across decisions (each planned on a copy off the lock).
TEST(ControlCore, ExploreSweepLooksThenClimbsAndPassesThroughItsPoints) {
  ControlCoreOptions o;
  o.safe.zones = {{"village", {0, 0, 0}, {20, 20, 10}}};
  o.safe.cell_m = 0.5;
  o.safe.drone_radius_m = 0.2;
  o.explore_sweep_altitude_m = 8.0;
  o.explore.range_m = 30.0;  // an outdoor scale (the village's)
  auto made = ControlCore::Create(o);
  ASSERT_TRUE(made.ok()) << made.status();
  ControlCore& core = **made;
  ASSERT_EQ(core.options().explore.sweep.size(), 64u);
  const glm::dvec3 p0 = core.options().explore.sweep.front();  // the inset corner (3, 3, 8)
  EXPECT_NEAR(p0.x, 3.0, 1e-9);
  EXPECT_NEAR(p0.y, 3.0, 1e-9);
  EXPECT_NEAR(p0.z, 8.0, 1e-9);
  // Known free: the air below 3 m (what a level camera carves near the ground); above: unknown.
  auto free_below = [](double top) {
    return [top](SafeFlight& s) {
      OccupancyGrid& g = s.grid();
      for (size_t i = 0; i < g.num_cells(); ++i)
        if (g.CentreOf(g.CellOfIndex(i)).z < top) g.Set(g.CellOfIndex(i), Occupancy::kFree);
    };
  };
  core.WithSafeFlight(free_below(3.0));
  core.OnDroneState("drone", At({4, 4, 1.5}), 0);
  ASSERT_TRUE(core.Explore({"op", 1, "drone"}, true, 0).ok());
  EXPECT_FALSE(core.ExploreStep("drone", 0.0));  // at the hold: the dwell starts
  ASSERT_TRUE(core.ExploreStep("drone", 1.1));
  // 1. A look at the first point from the free layer: the camera pitched up toward it.
  DroneView v = core.View("drone");
  EXPECT_NE(v.explore_note.find("climb"), std::string::npos) << v.explore_note;
  EXPECT_GT(v.target.camera_pitch, 0.0);
  EXPECT_LT(v.target.position.z, 3.0);
  const glm::dvec3 look = v.target.position;
  const double to_p0 = std::atan2(p0.z - look.z, glm::length(glm::dvec2(p0 - look)));
  EXPECT_LT(std::abs(to_p0 - v.target.camera_pitch), 0.45);  // within the vertical half-FOV
  // 2. The look has carved the air (all of it, here): the sweep's first point at its altitude.
  core.WithSafeFlight(free_below(100.0));
  DroneState s = At(look);
  s.yaw = v.target.yaw;
  s.camera_pitch = v.target.camera_pitch;
  core.OnDroneState("drone", s, 2.0);
  EXPECT_FALSE(core.ExploreStep("drone", 2.0));
  EXPECT_FALSE(core.ExploreStep("drone", 2.4));  // the look's hover: sweep_look_dwell_s (0.5 s)
  ASSERT_TRUE(core.ExploreStep("drone", 2.6));
  v = core.View("drone");
  EXPECT_NE(v.explore_note.find("sweep point 0"), std::string::npos) << v.explore_note;
  EXPECT_NEAR(v.target.position.x, p0.x, 0.5);
  EXPECT_NEAR(v.target.position.y, p0.y, 0.5);
  EXPECT_GT(v.target.position.z, 7.0);  // at the altitude (the cell under the point)
  EXPECT_EQ(v.target.camera_pitch, o.explore.sweep_pitch);
  const auto sp = core.NextSetpoint("drone", 3.2);
  ASSERT_TRUE(sp.has_value());
  EXPECT_EQ(sp->setpoint.camera_pitch, o.explore.sweep_pitch);  // one leg: the last waypoint
  // 3. Passed through: 0.8 m short of the point, facing elsewhere, and no hover: the next
  //    decision at once, the next point (the sweep's progress survived the copy).
  s = At(v.target.position + glm::dvec3(0, 0, -0.8));
  s.yaw = 2.0;
  core.OnDroneState("drone", s, 10.0);
  const uint64_t decisions = core.View("drone").explore_decisions;
  ASSERT_TRUE(core.ExploreStep("drone", 10.0));
  v = core.View("drone");
  EXPECT_EQ(v.explore_decisions, decisions + 1);
  EXPECT_NE(v.explore_note.find("sweep point 1"), std::string::npos) << v.explore_note;
  // A second core from `opts`: known air below `free_top`, the drone at `at`, exploring, its
  // first decision after the hold's dwell (explore_dwell_s, whatever sweep_look_dwell_s is).
  auto first_view = [&](const ControlCoreOptions& opts, double free_top, glm::dvec3 at) {
    auto made = ControlCore::Create(opts);
    EXO_CHECK(made.ok());
    std::unique_ptr<ControlCore> c = *std::move(made);
    c->WithSafeFlight(free_below(free_top));
    c->OnDroneState("drone", At(at), 0);
    EXPECT_TRUE(c->Explore({"op", 1, "drone"}, true, 0).ok());
    EXPECT_FALSE(c->ExploreStep("drone", 0.0));
    EXPECT_FALSE(c->ExploreStep("drone", 0.5));
    EXPECT_TRUE(c->ExploreStep("drone", 1.1));
    return c;
  };
  // With the hover (sweep_pass_m 0) the same place is not the goal yet.
  ControlCoreOptions h = o;
  h.explore.sweep_pass_m = 0.0;
  const std::unique_ptr<ControlCore> hovering = first_view(h, 100.0, {4, 4, 8});
  const DroneView w = hovering->View("drone");
  DroneState t = At(w.target.position + glm::dvec3(0, 0, -0.8));
  t.yaw = 2.0;
  hovering->OnDroneState("drone", t, 5.0);
  EXPECT_FALSE(hovering->ExploreStep("drone", 5.0));
  EXPECT_FALSE(hovering->ExploreStep("drone", 7.0));
  // The look's hover at the usual dwell (sweep_look_dwell_s < 0: explore_dwell_s, 1 s; the
  // default before session 18): the same look is not done after 0.6 s, done after 1 s.
  ControlCoreOptions q = o;
  q.explore.sweep_look_dwell_s = -1.0;
  const std::unique_ptr<ControlCore> usual = first_view(q, 3.0, {4, 4, 1.5});
  const DroneView ul = usual->View("drone");
  EXPECT_NE(ul.explore_note.find("climb"), std::string::npos) << ul.explore_note;
  EXPECT_LT(glm::length(ul.target.position - look), 1e-9);  // the same look
  usual->WithSafeFlight(free_below(100.0));
  DroneState us = At(look);
  us.yaw = ul.target.yaw;
  us.camera_pitch = ul.target.camera_pitch;
  usual->OnDroneState("drone", us, 2.0);
  EXPECT_FALSE(usual->ExploreStep("drone", 2.0));
  EXPECT_FALSE(usual->ExploreStep("drone", 2.6));
  ASSERT_TRUE(usual->ExploreStep("drone", 3.1));
  EXPECT_NE(usual->View("drone").explore_note.find("sweep point 0"), std::string::npos)
      << usual->View("drone").explore_note;
}

}  // namespace
}  // namespace exo::control
