// The closed loop of SPEC §8 end to end: a real server (modeling + control service) on
// loopback, the uploader's simulated drone (--drone=sim: DroneLink at 120 Hz + camera frames of
// the synthetic apartment uploaded from where it is) and an operator turning it with the joypad.
// What the drone sees becomes the model, and the model becomes the control service's world.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <chrono>
#include <thread>

#include "client/uploader/sim_flight.h"
#include "common/synth/scene.h"
#include "proto/control.grpc.pb.h"
#include "server/service/server.h"

namespace exo {
namespace {

namespace cv1 = exoview::control::v1;

TEST(DroneSimE2E, JoypadTurnsTheSimulatedDroneAndItsFramesBuildTheModel) {
  synth::SceneOptions so;
  auto scene = synth::MakeScene(synth::SceneKind::kApartment, so);
  ASSERT_TRUE(scene.ok());
  ServerConfig c;
  c.listen = "127.0.0.1:0";
  ASSERT_TRUE(ApplyConfigValue("control_zones", SceneZoneText(*scene), &c).ok());
  ASSERT_TRUE(ApplyConfigValue("voxel_size_m", "0.08", &c).ok());
  ASSERT_TRUE(ApplyConfigValue("control_cell_m", "0.15", &c).ok());
  ExoviewServer server(c);
  ASSERT_TRUE(server.Start().ok());
  const std::string addr = "127.0.0.1:" + std::to_string(server.port());

  synth::RenderOptions render;
  render.width = 160;
  render.height = 120;
  SimFlightOptions fo;
  fo.flight_s = 6.0;
  fo.frame_rate_hz = 5.0;
  fo.link.delay_s = 0.025;
  absl::StatusOr<SimFlightStats> flight;
  std::thread drone([&] { flight = FlySimDrone(MakeChannel(addr), *scene, render, fo, {}); });

  auto stub = cv1::Control::NewStub(MakeChannel(addr));
  auto state = [&] {
    grpc::ClientContext ctx;
    cv1::ControlState s;
    EXPECT_TRUE(stub->GetControlState(&ctx, cv1::ControlStateRequest(), &s).ok());
    return s;
  };
  for (int i = 0; i < 400 && !state().drone_known(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  ASSERT_TRUE(state().drone_known());
  const double yaw0 = state().drone().yaw();
  // 2.5 s of full left yaw stick at 10 Hz.
  uint64_t accepted = 0;
  for (int i = 1; i <= 25; ++i) {
    cv1::JoypadRequest r;
    r.mutable_header()->set_operator_id("pilot");
    r.mutable_header()->set_operator_sequence(i);
    r.set_left_x(1.0);
    r.set_dt_s(0.1);
    cv1::InteractionReply reply;
    grpc::ClientContext ctx;
    if (stub->Joypad(&ctx, r, &reply).ok()) ++accepted;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  drone.join();
  ASSERT_TRUE(flight.ok()) << flight.status();
  EXPECT_EQ(accepted, 25u);
  EXPECT_GT(flight->setpoints_received, 25u);
  EXPECT_EQ(flight->last_command_sequence, 25u);
  EXPECT_EQ(flight->collisions, 0u);
  EXPECT_EQ(flight->upload.rejected, 0u);
  EXPECT_GE(flight->upload.accepted + flight->upload.dropped, 25u);
  // The joypad turned the drone: ~2.4 rad (stick 1.0 = 1 rad/s after the 5 % deadzone).
  const double turned = std::remainder(flight->final_yaw - yaw0, 2 * M_PI);
  EXPECT_GT(std::abs(turned), 1.5) << turned;
  // It held its position while turning (yaw only).
  const cv1::ControlState s = state();
  EXPECT_GT(s.states_received(), 500u);
  // The model built from its frames reached the control service: mesh cells occupied, views
  // carved into known free space, so the region fallback is off.
  const ModelStore::Summary m = server.store().GetSummary();
  EXPECT_GT(m.num_chunks, 0u);
  for (int i = 0; i < 100 && (state().occupied_cells() == 0 || state().free_cells() == 0); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_GT(state().occupied_cells(), 0u);
  EXPECT_GT(state().free_cells(), 0u);
  EXPECT_FALSE(state().using_regions());
  server.Shutdown();
}

}  // namespace
}  // namespace exo
