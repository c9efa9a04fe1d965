#include "client/uploader/sim_flight.h"

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <glm/gtc/quaternion.hpp>
#include <chrono>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "absl/strings/str_cat.h"
#include "common/synth/trajectory.h"
#include "proto/control.grpc.pb.h"
#include "proto/frame_proto.h"

namespace exo {
namespace {

namespace cv1 = exoview::control::v1;
using Clock = std::chrono::steady_clock;

void ToProto(const glm::dvec3& v, cv1::Vec3* out) {
  out->set_x(v.x);
  out->set_y(v.y);
  out->set_z(v.z);
}

}  // namespace

absl::Status SimFlightOptions::Validate() const {
  if (!(flight_s > 0) || !(frame_rate_hz > 0))
    return absl::InvalidArgumentError("sim flight: flight_s and frame_rate_hz must be > 0");
  if (drone_id.empty()) return absl::InvalidArgumentError("sim flight: empty drone id");
  EXO_RETURN_IF_ERROR(drone.Validate());
  return link.Validate();
}

std::string SimFlightStats::ToJson() const {
  nlohmann::json j;
  j["states_sent"] = states_sent;
  j["setpoints_received"] = setpoints_received;
  j["setpoints_lost"] = setpoints_lost;
  j["last_command_sequence"] = last_command_sequence;
  j["collisions"] = collisions;
  j["hold_events"] = hold_events;
  j["min_clearance_m"] = min_clearance_m;
  j["path_length_m"] = path_length_m;
  j["final_position_local"] = {final_local.x, final_local.y, final_local.z};
  j["final_yaw"] = final_yaw;
  j["final_camera_pitch"] = final_camera_pitch;
  j["frame_pitch"] = {{"min", min_frame_pitch}, {"max", max_frame_pitch}, {"last", last_frame_pitch}};
  j["upload"] = nlohmann::json::parse(upload.ToJson());
  return j.dump();
}

Rigid3d SimCameraPose(const control::DroneState& s) {
  const control::SceneFrame z_up = control::SceneFrame::ZUp();
  const glm::dvec3 dir = std::cos(s.camera_pitch) * z_up.Heading(s.yaw) +
                         std::sin(s.camera_pitch) * z_up.up;
  // No roll: the image's right axis is horizontal whatever the pitch (also straight down), as
  // synth::LookAt builds it for a level camera.
  const glm::dvec3 right = glm::normalize(glm::cross(z_up.Heading(s.yaw), z_up.up));
  const glm::dvec3 down = glm::cross(dir, right);
  Rigid3d out;
  out.rotation = glm::normalize(glm::quat_cast(glm::dmat3(right, down, dir)));
  out.translation = s.position;
  return out;
}

std::string SceneZoneText(const synth::SynthScene& scene) {
  const glm::dvec3 lo = scene.navigable.min + scene.origin.origin_in_world;
  const glm::dvec3 hi = scene.navigable.max + scene.origin.origin_in_world;
  return absl::StrCat(scene.name.empty() ? "scene" : scene.name, ":", lo.x, ",", lo.y, ",", lo.z,
                      ",", hi.x, ",", hi.y, ",", hi.z);
}

absl::StatusOr<SimFlightStats> FlySimDrone(const std::shared_ptr<grpc::Channel>& channel,
                                           const synth::SynthScene& scene,
                                           const synth::RenderOptions& render,
                                           const SimFlightOptions& options,
                                           const UploadOptions& upload) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(render.Validate());
  const glm::dvec3 origin = scene.origin.origin_in_world;
  glm::dvec3 start = options.start_local;
  if (!options.start_given) {
    if (scene.walk_waypoints.empty())
      return absl::FailedPreconditionError(
          "sim flight: the scene has no walk waypoint to start at");
    start = scene.walk_waypoints.front();
  }
  control::SimDrone drone(options.drone);
  drone.Reset(start, options.start_yaw);
  control::CollisionMonitor collisions(scene.mesh, options.drone.radius_m);
  control::Link<control::Setpoint> link(options.link);

  std::mutex mu;  // guards drone, link, stats below
  SimFlightStats stats;
  std::atomic<bool> stop{false};

  auto stub = cv1::Control::NewStub(channel);
  grpc::ClientContext ctx;
  auto stream = stub->DroneLink(&ctx);
  std::thread reader([&] {
    cv1::Setpoint sp;
    while (stream->Read(&sp)) {
      std::lock_guard lock(mu);
      ++stats.setpoints_received;
      stats.last_command_sequence = sp.command_sequence();
      link.Send({glm::dvec3(sp.position().x(), sp.position().y(), sp.position().z()) - origin,
                 sp.yaw(), sp.camera_pitch()},
                drone.state().timestamp_s);
    }
  });
  absl::Status drone_error;
  std::thread flyer([&] {
    auto next = Clock::now();
    const auto period = std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(drone.period_s()));
    uint64_t seq = 0;
    glm::dvec3 prev = start;
    while (!stop.load()) {
      cv1::DroneState msg;
      {
        std::lock_guard lock(mu);
        const double now = drone.state().timestamp_s;
        for (const control::Setpoint& sp : link.Receive(now)) drone.Receive(sp, now);
        const control::DroneState& s = drone.Step();
        collisions.Update(s.position);
        stats.path_length_m += glm::length(s.position - prev);
        prev = s.position;
        msg.set_drone_id(options.drone_id);
        msg.set_sequence(++seq);
        msg.set_timestamp_s(s.timestamp_s);
        ToProto(s.position + origin, msg.mutable_position());
        ToProto(s.velocity, msg.mutable_velocity());
        msg.set_yaw(s.yaw);
        msg.set_camera_pitch(s.camera_pitch);
        msg.set_battery(-1);
        msg.set_mode(drone.mode() == control::FlightMode::kHold ? cv1::HOLD_POSITION
                                                                : cv1::OFFBOARD);
        ++stats.states_sent;
      }
      if (!stream->Write(msg)) {
        drone_error = absl::UnavailableError("sim flight: the control stream closed");
        break;
      }
      next += period;
      std::this_thread::sleep_until(next);
    }
  });

  // The camera: frames rendered from the drone's pose, uploaded at frame_rate_hz.
  UploadOptions up = upload;
  double last_frame_s = -1.0;
  up.rate_hz = options.frame_rate_hz;
  const size_t count = static_cast<size_t>(std::ceil(options.flight_s * options.frame_rate_hz));
  auto uploaded = UploadStream(
      channel, count,
      [&](size_t i) -> absl::StatusOr<v1::Frame> {
        // Each frame at a newer drone time than the last: under load the upload may catch up
        // faster than the drone's clock advances, and the server refuses a repeated timestamp.
        control::DroneState s;
        for (int wait = 0;; ++wait) {
          {
            std::lock_guard lock(mu);
            s = drone.state();
          }
          if (s.timestamp_s > last_frame_s) break;
          if (stop.load() || wait > 1000)
            return absl::UnavailableError("sim flight: the drone's clock stopped advancing");
          std::this_thread::sleep_for(std::chrono::milliseconds(2));
        }
        last_frame_s = s.timestamp_s;
        const Rigid3d local_from_cam = SimCameraPose(s);
        {
          std::lock_guard lock(mu);
          const glm::dvec3 fwd = local_from_cam.rotation * glm::dvec3(0, 0, 1);
          const double pitch = std::asin(std::clamp(fwd.z, -1.0, 1.0));
          stats.min_frame_pitch = std::min(stats.min_frame_pitch, pitch);
          stats.max_frame_pitch = std::max(stats.max_frame_pitch, pitch);
          stats.last_frame_pitch = pitch;
        }
        EXO_ASSIGN_OR_RETURN(
            synth::RenderedFrame r,
            synth::RenderFrame(scene, local_from_cam, render, {}, i + 1, s.timestamp_s));
        return FrameToProto(r.frame, up.encode);
      },
      up);
  stop.store(true);
  flyer.join();
  stream->WritesDone();
  reader.join();
  const grpc::Status fin = stream->Finish();
  if (!uploaded.ok()) return uploaded.status();
  if (!drone_error.ok()) return drone_error;
  if (!fin.ok())
    return absl::UnavailableError(
        absl::StrCat("sim flight: control stream: ", fin.error_message()));
  stats.upload = *std::move(uploaded);
  stats.collisions = collisions.collisions();
  stats.min_clearance_m = collisions.min_clearance_m();
  stats.hold_events = drone.hold_events();
  stats.setpoints_lost = link.lost();
  stats.final_local = drone.state().position;
  stats.final_yaw = drone.state().yaw;
  stats.final_camera_pitch = drone.state().camera_pitch;
  return stats;
}

}  // namespace exo
