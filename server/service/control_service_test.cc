// The control service on a real loopback server: operators call the interaction RPCs, the
// drone side is the simulated drone (common/drone) streaming its state at 120 Hz and flying the
// setpoints it receives.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <mutex>
#include <set>
#include <thread>

#include "common/drone/sim_drone.h"
#include "common/drone/test_util.h"
#include "common/io/jpeg.h"
#include "proto/frame_proto.h"
#include "proto/control.grpc.pb.h"
#include "server/service/server.h"

namespace exo {
namespace {

namespace cv1 = exoview::control::v1;
using control::testing::AddQuad;

TriangleMesh House() {
  TriangleMesh m;
  AddQuad(&m, {4, 0, 0}, {4, 1.5, 0}, {4, 1.5, 3}, {4, 0, 3});  // wall, door at y 1.5..2.5
  AddQuad(&m, {4, 2.5, 0}, {4, 4, 0}, {4, 4, 3}, {4, 2.5, 3});
  AddQuad(&m, {4, 1.5, 2.2}, {4, 2.5, 2.2}, {4, 2.5, 3}, {4, 1.5, 3});
  AddQuad(&m, {8, 0, 0}, {8, 4, 0}, {8, 4, 3}, {8, 0, 3});  // far wall
  AddQuad(&m, {0, 0, 0}, {8, 0, 0}, {8, 4, 0}, {0, 4, 0});  // floor
  return m;
}

class ControlServiceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ServerConfig c;
    c.listen = "127.0.0.1:0";
    c.enable_geometry = false;
    c.enable_planning = false;
    ASSERT_TRUE(ApplyConfigValue("control_zones", "house:0,0,0,8,4,2.6", &c).ok());
    server_ = std::make_unique<ExoviewServer>(c);
    ASSERT_TRUE(server_->Start().ok());
    control::ControlCore* core = server_->control_core();
    ASSERT_NE(core, nullptr);
    // The modelled world: the house's proxy mesh and its known free space.
    core->UpsertChunk(1, House());
    core->WithSafeFlight([](control::SafeFlight& s) {
      control::OccupancyGrid& g = s.grid();
      for (size_t i = 0; i < g.num_cells(); ++i) g.Set(g.CellOfIndex(i), control::Occupancy::kFree);
    });
    channel_ = grpc::CreateChannel("127.0.0.1:" + std::to_string(server_->port()),
                                   grpc::InsecureChannelCredentials());
    stub_ = cv1::Control::NewStub(channel_);
  }
  void TearDown() override {
    if (server_) server_->Shutdown();
  }

  static cv1::Vec3 V(double x, double y, double z) {
    cv1::Vec3 v;
    v.set_x(x);
    v.set_y(y);
    v.set_z(z);
    return v;
  }
  grpc::Status Gaze(const std::string& op, uint64_t seq, glm::dvec3 eye, glm::dvec3 dir,
                    cv1::InteractionReply* out) {
    cv1::GazeToSeeRequest r;
    r.mutable_header()->set_operator_id(op);
    r.mutable_header()->set_operator_sequence(seq);
    *r.mutable_eye() = V(eye.x, eye.y, eye.z);
    *r.mutable_direction() = V(dir.x, dir.y, dir.z);
    grpc::ClientContext ctx;
    return stub_->GazeToSee(&ctx, r, out);
  }
  grpc::Status Pick(const std::string& op, uint64_t seq, cv1::InteractionReply* out) {
    cv1::PickAndPlaceRequest r;
    r.mutable_header()->set_operator_id(op);
    r.mutable_header()->set_operator_sequence(seq);
    *r.mutable_eye() = V(0.5, 1, 1.6);
    *r.mutable_hand() = V(0.5, 1, 1.6);  // hand at the eye: guarded
    *r.mutable_hand_displacement() = V(0, 0.02, 0);
    grpc::ClientContext ctx;
    return stub_->PickAndPlace(&ctx, r, out);
  }
  cv1::ControlState State() {
    grpc::ClientContext ctx;
    cv1::ControlState s;
    EXPECT_TRUE(stub_->GetControlState(&ctx, cv1::ControlStateRequest(), &s).ok());
    return s;
  }

  std::unique_ptr<ExoviewServer> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<cv1::Control::Stub> stub_;
};

// The drone side: one DroneLink stream, setpoints read on their own thread.
class DroneSide {
 public:
  DroneSide(cv1::Control::Stub* stub, control::SimDrone* drone) : drone_(drone) {
    stream_ = stub->DroneLink(&ctx_);
    reader_ = std::thread([this] {
      cv1::Setpoint sp;
      while (stream_->Read(&sp)) {
        std::lock_guard lock(mu_);
        pending_.push_back(sp);
        all_.push_back(sp);
      }
    });
  }
  ~DroneSide() { Close(); }
  // Applies the setpoints received so far, steps the drone and sends its state.
  bool Step() {
    std::vector<cv1::Setpoint> got;
    {
      std::lock_guard lock(mu_);
      got.swap(pending_);
    }
    const double now = drone_->state().timestamp_s;
    for (const auto& sp : got)
      drone_->Receive(
          {{sp.position().x(), sp.position().y(), sp.position().z()}, sp.yaw(), sp.camera_pitch()},
          now);
    const control::DroneState& s = drone_->Step();
    cv1::DroneState msg;
    msg.set_drone_id("drone");
    msg.set_sequence(++sequence_);
    msg.set_timestamp_s(s.timestamp_s);
    msg.mutable_position()->set_x(s.position.x);
    msg.mutable_position()->set_y(s.position.y);
    msg.mutable_position()->set_z(s.position.z);
    msg.set_yaw(s.yaw);
    msg.set_camera_pitch(s.camera_pitch);
    msg.set_mode(drone_->mode() == control::FlightMode::kHold ? cv1::HOLD_POSITION : cv1::OFFBOARD);
    return stream_->Write(msg);
  }
  void Close() {
    if (closed_) return;
    closed_ = true;
    stream_->WritesDone();
    reader_.join();
    EXPECT_TRUE(stream_->Finish().ok());
  }
  std::vector<cv1::Setpoint> received() {
    std::lock_guard lock(mu_);
    return all_;
  }

 private:
  control::SimDrone* drone_;
  grpc::ClientContext ctx_;
  std::unique_ptr<grpc::ClientReaderWriter<cv1::DroneState, cv1::Setpoint>> stream_;
  std::thread reader_;
  std::mutex mu_;
  std::vector<cv1::Setpoint> pending_, all_;
  uint64_t sequence_ = 0;
  bool closed_ = false;
};

// Runs the drone in real time (120 Hz) for `seconds`.
void Fly(DroneSide* side, double seconds, control::CollisionMonitor* collisions,
         const control::SimDrone& drone) {
  auto next = std::chrono::steady_clock::now();
  for (int i = 0; i < static_cast<int>(seconds * 120); ++i) {
    ASSERT_TRUE(side->Step());
    if (collisions) collisions->Update(drone.state().position);
    next += std::chrono::microseconds(8333);
    std::this_thread::sleep_until(next);
  }
}

TEST_F(ControlServiceTest, OperatorsNeedAConnectedDroneAndGetClearStatuses) {
  cv1::InteractionReply reply;
  EXPECT_FALSE(State().drone_known());
  grpc::Status s = Pick("alice", 1, &reply);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_NE(s.error_message().find("has not reported its state"), std::string::npos);

  control::SimDrone drone{control::SimDroneOptions{}};
  drone.Reset({1, 1, 1}, 0);
  DroneSide side(stub_.get(), &drone);
  ASSERT_TRUE(side.Step());
  for (int i = 0; i < 200 && !State().drone_known(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  ASSERT_TRUE(State().drone_known());

  // Gaze at the sky: NOT_FOUND, nothing commanded.
  s = Gaze("alice", 2, {1, 1, 1.5}, {-1, 0, 1}, &reply);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_NE(s.error_message().find("hits no modelled surface"), std::string::npos);
  // A stale operator sequence: ABORTED.
  s = Gaze("alice", 2, {1, 1, 1.5}, {1, 0, 0}, &reply);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::ABORTED);
  EXPECT_EQ(State().command_sequence(), 0u);

  // Two operators at once: both accepted, the later command wins, both see it.
  cv1::InteractionReply ra, rb;
  grpc::Status sa, sb;
  std::thread ta([&] { sa = Gaze("alice", 3, {0.5, 1, 1.5}, {1, 0, 0}, &ra); });
  std::thread tb([&] { sb = Pick("bob", 1, &rb); });
  ta.join();
  tb.join();
  ASSERT_TRUE(sa.ok()) << sa.error_message();
  ASSERT_TRUE(sb.ok()) << sb.error_message();
  EXPECT_NE(ra.command_sequence(), rb.command_sequence());
  EXPECT_NE(rb.note().find("hand-eye distance guarded"), std::string::npos);
  const bool bob_won = rb.command_sequence() > ra.command_sequence();
  const uint64_t winner = std::max(ra.command_sequence(), rb.command_sequence());
  const cv1::ControlState seen_by_alice = State(), seen_by_bob = State();
  for (const auto& st : {seen_by_alice, seen_by_bob}) {
    EXPECT_EQ(st.command_sequence(), winner);
    EXPECT_EQ(st.operator_id(), bob_won ? "bob" : "alice");
    EXPECT_EQ(st.interaction(), bob_won ? cv1::PICK_AND_PLACE : cv1::GAZE_TO_SEE);
  }
  // The drone side receives the winner's setpoint.
  Fly(&side, 0.2, nullptr, drone);
  const auto got = side.received();
  ASSERT_FALSE(got.empty());
  EXPECT_EQ(got.back().command_sequence(), winner);
  EXPECT_EQ(got.back().operator_id(), bob_won ? "bob" : "alice");
  side.Close();
}

TEST_F(ControlServiceTest, GazeRouteThroughTheDoorSurvivesADroneReconnect) {
  control::SimDrone drone{control::SimDroneOptions{}};
  drone.Reset({1, 0.8, 1.0}, 0);
  control::CollisionMonitor collisions(House(), drone.options().radius_m);
  auto first = std::make_unique<DroneSide>(stub_.get(), &drone);
  ASSERT_TRUE(first->Step());
  for (int i = 0; i < 200 && !State().drone_known(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  cv1::InteractionReply reply;
  const grpc::Status s = Gaze("alice", 1, {1, 2, 1.5}, {1, 0.05, 0}, &reply);
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_TRUE(reply.has_gaze());
  EXPECT_NEAR(reply.gaze_point().x(), 8.0, 1e-6);
  ASSERT_GE(reply.waypoints_size(), 2);
  const glm::dvec3 target(reply.target().x(), reply.target().y(), reply.target().z());

  // Mid-route the drone side drops the link and reconnects.
  Fly(first.get(), 2.0, &collisions, drone);
  const auto before = first->received();
  first->Close();
  ASSERT_FALSE(before.empty());
  for (int i = 0; i < 24; ++i) collisions.Update(drone.Step().position);  // 0.2 s unlinked
  DroneSide second(stub_.get(), &drone);
  Fly(&second, 8.0, &collisions, drone);
  const auto after = second.received();
  ASSERT_FALSE(after.empty());
  // Same command, the route continues (waypoint index and sequence never go back).
  EXPECT_EQ(after.front().command_sequence(), reply.command_sequence());
  EXPECT_GE(after.front().waypoint_index(), before.back().waypoint_index());
  EXPECT_GE(after.front().sequence(), before.back().sequence());
  uint64_t prev_seq = 0;
  for (const auto& sp : after) {
    EXPECT_GE(sp.sequence(), prev_seq);
    prev_seq = sp.sequence();
  }
  EXPECT_EQ(after.back().waypoint_index() + 1, after.back().waypoint_count());
  EXPECT_LT(glm::length(drone.state().position - target), 0.05);
  EXPECT_EQ(collisions.collisions(), 0u);
  const cv1::ControlState st = State();
  EXPECT_EQ(st.waypoint_index() + 1u, static_cast<uint32_t>(st.waypoints_size()));
  EXPECT_GT(st.states_received(), 1000u);
  second.Close();
}

// Gaze at a floor point: the setpoint on the wire carries the gimbal pitch that faces P_gaze,
// the simulated drone pitches its camera down by that much, and its optical axis then passes
// through P_gaze. Waypoints before the last one keep the camera level.
TEST_F(ControlServiceTest, GazeAtTheFloorPitchesTheSimulatedCameraDown) {
  control::SimDrone drone{control::SimDroneOptions{}};
  drone.Reset({1, 1, 1.2}, 0);
  DroneSide side(stub_.get(), &drone);
  ASSERT_TRUE(side.Step());
  for (int i = 0; i < 200 && !State().drone_known(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  EXPECT_EQ(State().drone().camera_pitch(), 0.0);
  cv1::InteractionReply reply;
  const glm::dvec3 eye(0.5, 2, 1.7), floor_point(2.5, 2, 0);
  const grpc::Status st = Gaze("alice", 1, eye, floor_point - eye, &reply);
  ASSERT_TRUE(st.ok()) << st.error_message();
  ASSERT_TRUE(reply.has_gaze());
  EXPECT_TRUE(reply.horizontal_surface());
  const glm::dvec3 p_gaze(reply.gaze_point().x(), reply.gaze_point().y(), reply.gaze_point().z());
  EXPECT_LT(glm::length(p_gaze - floor_point), 1e-6);
  const glm::dvec3 target(reply.target().x(), reply.target().y(), reply.target().z());
  // The amount: the pitch that puts P_gaze on the optical axis from the target, well down.
  const double expected = control::CameraPitchToward(target, p_gaze, control::SceneFrame::ZUp());
  EXPECT_NEAR(reply.camera_pitch(), expected, 1e-9);
  EXPECT_LT(reply.camera_pitch(), -0.5);
  EXPECT_NEAR(State().target_camera_pitch(), reply.camera_pitch(), 1e-9);

  Fly(&side, 5.0, nullptr, drone);
  const auto got = side.received();
  ASSERT_FALSE(got.empty());
  EXPECT_EQ(got.back().waypoint_index() + 1, got.back().waypoint_count());
  for (const auto& sp : got) {
    if (sp.command_sequence() != reply.command_sequence()) continue;
    if (sp.waypoint_index() + 1 == sp.waypoint_count())
      EXPECT_NEAR(sp.camera_pitch(), reply.camera_pitch(), 1e-9);
    else
      EXPECT_EQ(sp.camera_pitch(), 0.0);  // level while travelling
  }
  // The drone's camera pitched down by that amount and the server sees it in the state.
  const control::DroneState& s = drone.state();
  EXPECT_LT(glm::length(s.position - target), 0.05);
  EXPECT_NEAR(s.camera_pitch, reply.camera_pitch(), 1e-3);
  EXPECT_NEAR(State().drone().camera_pitch(), s.camera_pitch, 0.01);
  const control::SceneFrame z = control::SceneFrame::ZUp();
  const glm::dvec3 axis =
      std::cos(s.camera_pitch) * z.Heading(s.yaw) + std::sin(s.camera_pitch) * z.up;
  const double off_axis = std::acos(std::clamp(
      glm::dot(axis, glm::normalize(p_gaze - s.position)), -1.0, 1.0));
  EXPECT_LT(off_axis, 0.05) << "P_gaze is " << off_axis << " rad off the camera axis";
  side.Close();
}

// Autonomous exploration over the service: an operator starts it, the drone side receives the
// planner's views (interaction EXPLORE, a command sequence of their own) through safe flight,
// another operator's interaction takes over, stopping holds the drone.
TEST_F(ControlServiceTest, ExploreStartsStreamsViewsAndYieldsToOtherInteractions) {
  auto explore = [&](const std::string& op, uint64_t seq, bool start, cv1::InteractionReply* out) {
    cv1::ExploreRequest r;
    r.mutable_header()->set_operator_id(op);
    r.mutable_header()->set_operator_sequence(seq);
    r.set_start(start);
    grpc::ClientContext ctx;
    return stub_->Explore(&ctx, r, out);
  };
  cv1::InteractionReply reply;
  EXPECT_EQ(explore("alice", 1, true, &reply).error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  control::SimDrone drone{control::SimDroneOptions{}};
  drone.Reset({1, 1, 1.2}, 0);
  control::CollisionMonitor collisions(House(), drone.options().radius_m);
  DroneSide side(stub_.get(), &drone);
  ASSERT_TRUE(side.Step());
  for (int i = 0; i < 200 && !State().drone_known(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  ASSERT_TRUE(explore("alice", 2, true, &reply).ok());
  EXPECT_EQ(reply.interaction(), cv1::EXPLORE);
  const uint64_t started = reply.command_sequence();
  EXPECT_TRUE(State().exploring());
  // The hold, 1 s of dwell, then the planner's views (the house's walls and floor are unseen
  // surface: every view gains). The service plans on the wall clock (a decision takes a few
  // hundred ms, seconds on a loaded machine) while the drone flies in real time, so the drone
  // flies 6 s and then on, half a second at a time, until the second view has reached it or
  // exploration ended, for at most 60 s of wall time (at load 8-9 two decisions did not always
  // fit into 6 s; session 17).
  auto explore_views = [&] {
    std::set<uint64_t> views;
    for (const auto& sp : side.received())
      if (sp.interaction() == cv1::EXPLORE && sp.command_sequence() > started)
        views.insert(sp.command_sequence());
    return views.size();
  };
  Fly(&side, 6.0, &collisions, drone);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (State().exploring() && explore_views() < 2 &&
         std::chrono::steady_clock::now() < deadline)
    Fly(&side, 0.5, &collisions, drone);
  cv1::ControlState st = State();
  EXPECT_TRUE(st.exploring()) << st.explore_note();
  EXPECT_GE(st.explore_decisions(), 2u) << st.explore_note();
  EXPECT_EQ(st.interaction(), cv1::EXPLORE);
  EXPECT_GT(st.command_sequence(), started);
  EXPECT_EQ(st.operator_id(), "alice");
  EXPECT_GE(explore_views(), 2u);
  EXPECT_GT(glm::length(drone.state().position - glm::dvec3(1, 1, 1.2)), 0.3);
  EXPECT_EQ(collisions.collisions(), 0u);
  // Bob's gaze takes over: exploration stops, no more EXPLORE setpoints after his command.
  cv1::InteractionReply gaze;
  ASSERT_TRUE(Gaze("bob", 1, {1, 2, 1.5}, {1, 0.05, 0}, &gaze).ok());
  st = State();
  EXPECT_FALSE(st.exploring());
  EXPECT_EQ(st.interaction(), cv1::GAZE_TO_SEE);
  Fly(&side, 0.5, &collisions, drone);
  EXPECT_EQ(State().command_sequence(), gaze.command_sequence());
  EXPECT_EQ(side.received().back().interaction(), cv1::GAZE_TO_SEE);
  // Restart, then stop: the drone holds where it is.
  ASSERT_TRUE(explore("alice", 3, true, &reply).ok());
  EXPECT_TRUE(State().exploring());
  ASSERT_TRUE(explore("alice", 4, false, &reply).ok());
  EXPECT_EQ(reply.interaction(), cv1::HOLD);
  EXPECT_NE(reply.note().find("exploration stopped"), std::string::npos);
  st = State();
  EXPECT_FALSE(st.exploring());
  EXPECT_EQ(st.interaction(), cv1::HOLD);
  side.Close();
}

// A real sensor's missing depth through the running service (session 17): with
// control_carve_sky_rule a stored view (published to the model store as the pipeline does) carves
// free space along its pixels without depth only where its JPEG colour is sky: the blue upper left,
// not the black upper right, which the rule without colour would carve too.
TEST(ControlServiceSkyRule, StoredViewsCarveOnlyTheSkyOfTheirMissingDepth) {
  ServerConfig c;
  c.listen = "127.0.0.1:0";
  c.enable_geometry = false;
  c.enable_planning = false;
  ASSERT_TRUE(ApplyConfigValue("control_zones", "yard:0,0,0,8,4,3", &c).ok());
  ASSERT_TRUE(ApplyConfigValue("control_carve_sky_rule", "true", &c).ok());
  ExoviewServer server(c);
  ASSERT_TRUE(server.Start().ok());
  // A level camera at (0.5, 2, 1.5) looking along +x (image left = +y, top = +z). The lower half
  // of its depth (half the camera's size, as stored depth often is) measures a wall 3 m away,
  // the upper half returns nothing: blue sky on the left, a black surface on the right.
  const PinholeCamera cam{100, 100, 63.5, 47.5, 128, 96};
  Rigid3d pose;
  pose.rotation = glm::quat_cast(
      glm::dmat3(glm::dvec3(0, -1, 0), glm::dvec3(0, 0, -1), glm::dvec3(1, 0, 0)));
  pose.translation = {0.5, 2, 1.5};
  ImageF depth(64, 48, 1, 0.0f);
  for (int y = 24; y < 48; ++y)
    for (int x = 0; x < 64; ++x) depth.at(x, y) = 3.0f;
  ImageU8 colour(128, 96, 3);
  for (int y = 0; y < 96; ++y)
    for (int x = 0; x < 128; ++x) {
      const bool black = x >= 64 && y < 48;
      colour.at(x, y, 0) = black ? 10 : 110;
      colour.at(x, y, 1) = black ? 10 : 160;
      colour.at(x, y, 2) = black ? 12 : 230;
    }
  v1::ViewAdded v;
  v.set_view_id(7);
  IntrinsicsToProto(cam, v.mutable_intrinsics());
  PoseToProto(pose, v.mutable_local_from_cam());
  DepthToProto(depth, 0.001, v.mutable_depth());
  auto jpeg = EncodeJpeg(colour);
  ASSERT_TRUE(jpeg.ok());
  v.set_color_jpeg(std::string(jpeg->begin(), jpeg->end()));
  server.store().AddView(std::move(v));
  // Known-free cells in a box 2-3.5 m ahead: above the camera (0.6-1.2 m) to its left and
  // right, and below it, in front of the wall.
  auto free_cells = [&](double y0, double y1, double z0, double z1) {
    size_t n = 0;
    server.control_core()->WithSafeFlight([&](control::SafeFlight& s) {
      const control::OccupancyGrid& g = s.grid();
      for (double x = 2.05; x < 3.5; x += 0.1)
        for (double y = y0 + 0.05; y < y1; y += 0.1)
          for (double z = z0 + 0.05; z < z1; z += 0.1)
            n += g.At(glm::dvec3(x, y, z)) == control::Occupancy::kFree;
    });
    return n;
  };
  for (int i = 0; i < 400 && free_cells(2.6, 3.4, 2.1, 2.7) == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  EXPECT_GT(free_cells(2.6, 3.4, 2.1, 2.7), 20u);  // the sky on the left: carved
  EXPECT_EQ(free_cells(0.6, 1.4, 2.1, 2.7), 0u);   // the black surface on the right: not
  // The measured lower half: free in front of the wall, either side (the ordinary carving).
  EXPECT_GT(free_cells(2.6, 3.4, 0.7, 1.3), 20u);
  EXPECT_GT(free_cells(0.6, 1.4, 0.7, 1.3), 20u);
  server.Shutdown();
  // The two carving rules exclude each other; the elevation is an angle.
  ServerConfig both = c;
  ASSERT_TRUE(ApplyConfigValue("control_carve_no_return", "true", &both).ok());
  auto refused = control::ControlCore::Create(both.control.core);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("exclude each other"), std::string::npos);
  auto steep = ApplyConfigValue("control_carve_sky_min_elevation_rad", "2", &c);
  EXPECT_NE(steep.message().find("control_carve_sky_min_elevation_rad"), std::string::npos) << steep;
  ASSERT_TRUE(ApplyConfigValue("control_carve_sky_min_elevation_rad", "-0.3", &c).ok());
  EXPECT_EQ(c.control.core.carve_sky_min_elevation_rad, -0.3);
}

TEST(ControlServiceConfig, KeysParseAndRejectWithClearErrors) {
  ServerConfig c;
  EXPECT_FALSE(c.control.enabled());
  ASSERT_TRUE(ApplyConfigValue("control_zones", "a:0,0,0,4,4,3; b:4,1,0,6,2,3", &c).ok());
  EXPECT_EQ(c.control.core.safe.zones.size(), 2u);
  EXPECT_TRUE(c.control.enabled());
  ASSERT_TRUE(ApplyConfigValue("control_up", "0,-1,0", &c).ok());
  EXPECT_EQ(c.control.core.up, glm::dvec3(0, -1, 0));
  ASSERT_TRUE(ApplyConfigValue("control_portals", "4,1.5,1; 6,1.5,1", &c).ok());
  EXPECT_EQ(c.control.core.safe.portals.size(), 2u);
  auto bad = ApplyConfigValue("control_zones", "a:0,0,0,4,4", &c);
  EXPECT_NE(bad.message().find("control_zones"), std::string::npos);
  EXPECT_FALSE(ApplyConfigValue("control_up", "0,0,0", &c).ok());
  EXPECT_FALSE(ApplyConfigValue("control_cell_m", "-1", &c).ok());
  ASSERT_TRUE(ApplyConfigValue("control_cell_m", "0.2", &c).ok());
  EXPECT_EQ(c.control.core.safe.cell_m, 0.2);
  // A polygon zone (floor and ceiling along z) beside a box; printed back as it was read.
  ASSERT_TRUE(
      ApplyConfigValue("control_zones", "hall:polyz:0.3,2.4:0,0,6,0,6,3,3,3,3,6,0,6; b:6,0,0,8,2,3",
                       &c)
          .ok());
  ASSERT_EQ(c.control.core.safe.zones.size(), 2u);
  EXPECT_EQ(c.control.core.safe.zones[0].vertical_axis, 2);
  EXPECT_EQ(c.control.core.safe.zones[0].polygon.size(), 6u);
  std::string text;
  for (const ConfigKey& k : ConfigKeys())
    if (k.name == "control_zones") text = k.get(c);
  EXPECT_EQ(text, "hall:polyz:0.3,2.4:0,0,6,0,6,3,3,3,3,6,0,6;b:6,0,0,8,2,3");
  auto crossing = ApplyConfigValue("control_zones", "x:polyz:0,2:0,0,2,1,2,0,0,2", &c);
  EXPECT_NE(crossing.message().find("cross"), std::string::npos) << crossing;
  // Exploration's scale (a village's values from docs/control.md, session 12).
  EXPECT_EQ(c.control.core.carve_max_range_m, 5.0);
  EXPECT_EQ(c.control.core.explore.range_m, 6.0);
  ASSERT_TRUE(ApplyConfigValue("control_carve_range_m", "30", &c).ok());
  ASSERT_TRUE(ApplyConfigValue("control_explore_range_m", "30", &c).ok());
  ASSERT_TRUE(ApplyConfigValue("control_explore_d_max_m", "13.7", &c).ok());
  ASSERT_TRUE(ApplyConfigValue("control_explore_sigma_m", "18.3", &c).ok());
  EXPECT_EQ(c.control.core.carve_max_range_m, 30.0);
  EXPECT_EQ(c.control.core.explore.range_m, 30.0);
  EXPECT_EQ(c.control.core.explore.d_max_m, 13.7);
  EXPECT_EQ(c.control.core.explore.sigma_m, 18.3);
  auto zero = ApplyConfigValue("control_explore_range_m", "0", &c);
  EXPECT_NE(zero.message().find("control_explore_range_m"), std::string::npos) << zero;
  EXPECT_EQ(c.control.core.explore.range_m, 30.0);  // unchanged by the refused value
  // The outdoor sweep (session 15): off by default; 0 allowed (off), negatives and words not.
  EXPECT_EQ(c.control.core.explore_sweep_altitude_m, 0.0);
  EXPECT_TRUE(c.control.core.explore.sweep_climb);
  EXPECT_EQ(c.control.core.explore.sweep_pass_m, 1.0);
  EXPECT_EQ(c.control.core.explore.sweep_look_dwell_s, 0.5);
  EXPECT_FALSE(c.control.core.carve_no_return);
  EXPECT_FALSE(c.control.core.carve_sky_rule);
  EXPECT_EQ(c.control.core.carve_sky_min_elevation_rad, -0.1);
  ASSERT_TRUE(ApplyConfigValue("control_explore_sweep_altitude_m", "22", &c).ok());
  ASSERT_TRUE(ApplyConfigValue("control_explore_sweep_climb", "false", &c).ok());
  ASSERT_TRUE(ApplyConfigValue("control_explore_sweep_pass_m", "0", &c).ok());
  ASSERT_TRUE(ApplyConfigValue("control_explore_sweep_look_dwell_s", "1", &c).ok());
  ASSERT_TRUE(ApplyConfigValue("control_carve_no_return", "true", &c).ok());
  EXPECT_EQ(c.control.core.explore_sweep_altitude_m, 22.0);
  EXPECT_FALSE(c.control.core.explore.sweep_climb);
  EXPECT_EQ(c.control.core.explore.sweep_pass_m, 0.0);
  EXPECT_EQ(c.control.core.explore.sweep_look_dwell_s, 1.0);
  EXPECT_TRUE(c.control.core.carve_no_return);
  auto dwell = ApplyConfigValue("control_explore_sweep_look_dwell_s", "-1", &c);
  EXPECT_NE(dwell.message().find("control_explore_sweep_look_dwell_s"), std::string::npos)
      << dwell;
  EXPECT_EQ(c.control.core.explore.sweep_look_dwell_s, 1.0);
  auto neg = ApplyConfigValue("control_explore_sweep_altitude_m", "-3", &c);
  EXPECT_NE(neg.message().find("control_explore_sweep_altitude_m"), std::string::npos) << neg;
  EXPECT_EQ(c.control.core.explore_sweep_altitude_m, 22.0);
  auto word = ApplyConfigValue("control_explore_sweep_climb", "maybe", &c);
  EXPECT_NE(word.message().find("true or false"), std::string::npos) << word;
  EXPECT_FALSE(c.control.core.explore.sweep_climb);
  std::string climb;
  for (const ConfigKey& k : ConfigKeys())
    if (k.name == "control_explore_sweep_climb") climb = k.get(c);
  EXPECT_EQ(climb, "false");
}

}  // namespace
}  // namespace exo
