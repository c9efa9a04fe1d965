// Control-loop health (issue 19 metrics), one JSON line:
//   - over a real loopback server: operator interaction -> setpoint at the drone side latency
//     (p50/p95; the drone side streams its state at 120 Hz and gets setpoints in reply), the
//     interaction RPC's own round trip, the state and setpoint rates;
//   - the simulated drone behind a lossy link (no network): a 4 m flight with 10 % setpoint
//     loss, and with a 1 s stall mid-flight: arrival error, hold events, drift while holding,
//     flight time against the loss-free link; the drone's step response (overshoot).
#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "common/cli/cli.h"
#include "common/drone/sim_drone.h"
#include "proto/control.grpc.pb.h"
#include "server/service/server.h"

namespace {

using namespace exo;
namespace cv1 = exoview::control::v1;
using Clock = std::chrono::steady_clock;

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(p * (v.size() - 1) + 0.5))];
}

struct LinkResult {
  double arrival_error_m = 0, time_to_target_s = -1;
  double drift_while_holding_m = -1;  // -1: the stall is too short to have a holding phase
  uint64_t hold_events = 0, sent = 0, lost = 0;
};

// A 4 m flight, target streamed at 30 Hz through the link. Drift: the most the drone moves in
// [stall_start + 2 s, stall end) (after braking).
LinkResult FlyLink(const control::LinkOptions& lo, double stall_start, double stall_len) {
  control::SimDrone d{control::SimDroneOptions{}};
  d.Reset({0, 0, 1}, 0);
  control::Link<control::Setpoint> link(lo);
  const control::Setpoint target{{4, 0, 1}, 0};
  LinkResult r;
  glm::dvec3 held(0.0);
  bool have_held = false;
  for (int i = 0; i < 120 * 15; ++i) {
    const double now = d.state().timestamp_s;
    if (i % 4 == 0) link.Send(target, now);
    for (const auto& sp : link.Receive(now)) d.Receive(sp, now);
    const control::DroneState& s = d.Step();
    if (stall_len > 0 && s.timestamp_s > stall_start + 2.0 &&
        s.timestamp_s < stall_start + stall_len) {
      if (!have_held) held = s.position, have_held = true, r.drift_while_holding_m = 0;
      r.drift_while_holding_m = std::max(r.drift_while_holding_m, glm::length(s.position - held));
    }
    if (r.time_to_target_s < 0 && glm::length(s.position - target.position) < 0.05)
      r.time_to_target_s = s.timestamp_s;
  }
  r.arrival_error_m = glm::length(d.state().position - target.position);
  r.hold_events = d.hold_events();
  r.sent = link.sent();
  r.lost = link.lost();
  return r;
}

// The simulated drone's 1 m step response: overshoot, 2 cm settling time, peak speed.
nlohmann::json StepResponse(double step_m) {
  control::SimDrone d{control::SimDroneOptions{}};
  d.Reset({0, 0, 1}, 0);
  double overshoot = 0, settle = 0, peak_speed = 0;
  for (int i = 0; i < 120 * 10; ++i) {
    d.Receive({{step_m, 0, 1}, 0}, d.state().timestamp_s);
    const control::DroneState& s = d.Step();
    overshoot = std::max(overshoot, (s.position.x - step_m) / step_m);
    if (std::abs(s.position.x - step_m) > 0.02) settle = s.timestamp_s;
    peak_speed = std::max(peak_speed, glm::length(s.velocity));
  }
  return {{"step_m", step_m},
          {"overshoot_pct", 100 * overshoot},
          {"settle_2cm_s", settle},
          {"peak_speed_mps", peak_speed}};
}

nlohmann::json ToJson(const LinkResult& r) {
  return {{"arrival_error_m", r.arrival_error_m},
          {"time_to_target_s", r.time_to_target_s},
          {"drift_while_holding_m", r.drift_while_holding_m < 0
                                        ? nlohmann::json(nullptr)
                                        : nlohmann::json(r.drift_while_holding_m)},
          {"hold_events", r.hold_events},
          {"setpoints_sent", r.sent},
          {"setpoints_lost", r.lost}};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Control-loop health: setpoint latency, rates, hold on loss.",
               "exoview_control_loop_bench"};
  exo::cli::Setup(app);
  int commands = 100;
  double command_hz = 10;
  app.add_option("--commands", commands, "operator interactions")->check(CLI::PositiveNumber);
  app.add_option("--command_hz", command_hz, "interaction rate")->check(CLI::PositiveNumber);
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;

  ServerConfig c;
  c.listen = "127.0.0.1:0";
  c.enable_geometry = false;
  c.enable_planning = false;
  if (auto s = ApplyConfigValue("control_zones", "room:0,0,0,10,10,3", &c); !s.ok()) return 1;
  ExoviewServer server(c);
  if (auto s = server.Start(); !s.ok()) {
    std::fprintf(stderr, "exoview_control_loop_bench: %s\n", std::string(s.message()).c_str());
    return 1;
  }
  // A known free room (no obstacle): the loop, not the planner, is measured.
  server.control_core()->WithSafeFlight([](control::SafeFlight& s) {
    for (size_t i = 0; i < s.grid().num_cells(); ++i)
      s.grid().Set(s.grid().CellOfIndex(i), control::Occupancy::kFree);
  });
  auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(server.port()),
                                     grpc::InsecureChannelCredentials());
  auto stub = cv1::Control::NewStub(channel);

  // Drone side.
  control::SimDrone drone{control::SimDroneOptions{}};
  drone.Reset({5, 5, 1.5}, 0);
  std::mutex mu;
  std::map<uint64_t, Clock::time_point> first_arrival;  // command sequence -> time
  uint64_t setpoints = 0, states = 0;
  std::atomic<bool> stop{false};
  grpc::ClientContext ctx;
  auto stream = stub->DroneLink(&ctx);
  std::vector<control::Setpoint> pending;
  std::thread reader([&] {
    cv1::Setpoint sp;
    while (stream->Read(&sp)) {
      const auto now = Clock::now();
      std::lock_guard lock(mu);
      ++setpoints;
      first_arrival.emplace(sp.command_sequence(), now);
      pending.push_back({{sp.position().x(), sp.position().y(), sp.position().z()}, sp.yaw()});
    }
  });
  const auto t_start = Clock::now();
  std::thread flyer([&] {
    auto next = Clock::now();
    while (!stop.load()) {
      cv1::DroneState msg;
      {
        std::lock_guard lock(mu);
        const double now = drone.state().timestamp_s;
        for (const auto& sp : pending) drone.Receive(sp, now);
        pending.clear();
        const control::DroneState& s = drone.Step();
        msg.set_drone_id("drone");
        msg.set_timestamp_s(s.timestamp_s);
        msg.mutable_position()->set_x(s.position.x);
        msg.mutable_position()->set_y(s.position.y);
        msg.mutable_position()->set_z(s.position.z);
        msg.set_yaw(s.yaw);
        ++states;
      }
      if (!stream->Write(msg)) break;
      next += std::chrono::microseconds(8333);
      std::this_thread::sleep_until(next);
    }
  });
  while (server.control_core()->View("drone").states == 0)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));

  // Operator: pick-and-place nudges of +-0.2 m at command_hz.
  std::vector<std::pair<uint64_t, Clock::time_point>> sent;
  std::vector<double> rpc_ms;
  int failed = 0;
  auto next = Clock::now();
  for (int i = 0; i < commands; ++i) {
    cv1::PickAndPlaceRequest r;
    r.mutable_header()->set_operator_id("op");
    r.mutable_header()->set_operator_sequence(i + 1);
    r.mutable_eye()->set_x(5);
    r.mutable_eye()->set_y(2);
    r.mutable_eye()->set_z(1.6);
    r.mutable_hand()->set_x(5);
    r.mutable_hand()->set_y(2.5);
    r.mutable_hand()->set_z(1.5);
    r.mutable_hand_displacement()->set_x(i % 2 ? -0.03 : 0.03);
    cv1::InteractionReply reply;
    grpc::ClientContext cctx;
    const auto t0 = Clock::now();
    const grpc::Status s = stub->PickAndPlace(&cctx, r, &reply);
    rpc_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    if (s.ok())
      sent.emplace_back(reply.command_sequence(), t0);
    else
      ++failed;
    next +=
        std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1 / command_hz));
    std::this_thread::sleep_until(next);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  stop.store(true);
  flyer.join();
  stream->WritesDone();
  reader.join();
  (void)stream->Finish();
  const double elapsed = std::chrono::duration<double>(Clock::now() - t_start).count();
  std::vector<double> latency_ms;
  int missing = 0;
  {
    std::lock_guard lock(mu);
    for (const auto& [seq, t0] : sent) {
      auto it = first_arrival.find(seq);
      if (it == first_arrival.end()) {
        ++missing;
        continue;
      }
      latency_ms.push_back(std::chrono::duration<double, std::milli>(it->second - t0).count());
    }
  }
  server.Shutdown();

  control::LinkOptions clean, lossy, stall;
  clean.delay_s = lossy.delay_s = stall.delay_s = 0.025;
  lossy.loss = 0.1;
  stall.stalls = {{1.0, 1.0}};
  control::LinkOptions long_stall = clean;
  long_stall.stalls = {{1.0, 4.0}};

  nlohmann::json j;
  j["bench"] = "control_loop";
  j["commands"] = commands;
  j["commands_failed"] = failed;
  j["commands_without_setpoint"] = missing;
  j["interaction_to_setpoint_ms_p50"] = Percentile(latency_ms, 0.5);
  j["interaction_to_setpoint_ms_p95"] = Percentile(latency_ms, 0.95);
  j["interaction_rpc_ms_p50"] = Percentile(rpc_ms, 0.5);
  j["interaction_rpc_ms_p95"] = Percentile(rpc_ms, 0.95);
  j["state_rate_hz"] = states / elapsed;
  j["setpoint_rate_hz"] = setpoints / elapsed;
  j["step_response"] = {StepResponse(0.5), StepResponse(1.0), StepResponse(4.0)};
  j["link"] = {{"clean_25ms", ToJson(FlyLink(clean, -1, 0))},
               {"loss_10pct_25ms", ToJson(FlyLink(lossy, -1, 0))},
               {"stall_1s_at_1s", ToJson(FlyLink(stall, 1.0, 1.0))},
               {"stall_4s_at_1s", ToJson(FlyLink(long_stall, 1.0, 4.0))}};
  std::printf("%s\n", j.dump().c_str());
  return 0;
}
