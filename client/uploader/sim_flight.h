// The uploader's --drone=sim mode (SPEC §8): a simulated drone (common/drone) flies in the
// synthetic scene under the server's control service and its camera uploads what it sees.
//   - Drone side of exoview.control.v1.Control/DroneLink: the state goes out at 120 Hz (real
//     time), setpoints come in through a link with the configured delay and loss; with no
//     setpoint for a while the drone brakes and holds.
//   - Camera: at `frame_rate_hz` the scene is rendered from the drone's pose (facing its yaw,
//     pitched by its gimbal as the setpoints' camera_pitch asks; z up as the synthetic scenes are) and uploaded over the Upload stream, so where the
//     operators (or an autonomous planner) send the drone is what gets modelled.
//   - Collisions of the drone's sphere with the scene's ground-truth mesh are counted.
#pragma once

#include <memory>
#include <string>

#include "client/uploader/upload_client.h"
#include "common/drone/sim_drone.h"
#include "common/status.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"

namespace grpc {
class Channel;
}

namespace exo {

struct SimFlightOptions {
  std::string drone_id = "drone";
  double flight_s = 20.0;
  double frame_rate_hz = 10.0;
  control::SimDroneOptions drone;
  control::LinkOptions link;  // setpoints: delay, loss, stalls
  // Start: the scene's first walk waypoint (eye height) unless given.
  bool start_given = false;
  glm::dvec3 start_local{0.0};
  double start_yaw = 0.0;
  absl::Status Validate() const;
};

struct SimFlightStats {
  uint64_t states_sent = 0, setpoints_received = 0, setpoints_lost = 0;
  uint64_t last_command_sequence = 0;
  uint64_t collisions = 0, hold_events = 0;
  double min_clearance_m = 0.0, path_length_m = 0.0;
  glm::dvec3 final_local{0.0};
  double final_yaw = 0.0;
  double final_camera_pitch = 0.0;
  // The camera pitch of the frames rendered (from their poses), rad, + up.
  double min_frame_pitch = 1e9, max_frame_pitch = -1e9, last_frame_pitch = 0.0;
  UploadAckStats upload;
  std::string ToJson() const;
};

// The sim camera's pose: at the drone, facing its yaw, pitched by its gimbal (z up as the
// synthetic scenes are).
Rigid3d SimCameraPose(const control::DroneState& s);

// "name:minx,...,maxz" of the scene's navigable box in world coordinates: the control_zones
// value that matches the scene.
std::string SceneZoneText(const synth::SynthScene& scene);

// Flies for options.flight_s seconds (blocking). Errors: bad options, the control or upload
// stream failing.
absl::StatusOr<SimFlightStats> FlySimDrone(const std::shared_ptr<grpc::Channel>& channel,
                                           const synth::SynthScene& scene,
                                           const synth::RenderOptions& render,
                                           const SimFlightOptions& options,
                                           const UploadOptions& upload);

}  // namespace exo
