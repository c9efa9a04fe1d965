// The control loop's state on the server (SPEC §8), without any wire: the world the drone flies
// in (the proxy mesh for ray casting, the occupancy view, the stored views' poses), the
// operators' commands and what each drone must fly next.
//   - Commands (pick-and-place, gaze-to-see, joypad, go-to-view) get a server-wide increasing
//     command sequence; the newest command of any operator replaces the drone's route
//     (last-writer-wins). An operator's own sequence must increase: a stale or repeated one is
//     refused (Aborted), so a retried request cannot overwrite a newer command.
//   - Every target is clamped and routed by SafeFlight; the route's waypoints are streamed in
//     order: the drone gets waypoint k until it is within `waypoint_tolerance_m` of it.
//   - Setpoints carry a per-drone sequence that increases whenever the setpoint changes, and
//     are repeated at `setpoint_rate_hz` while the drone sends states (a drone that stops
//     hearing them holds position by itself). Route progress belongs to the drone id, so a drone
//     that reconnects mid-route continues where it was.
// World coordinates throughout; meshes and views arrive in the scene-local frame with the
// scene origin (SetOrigin). Thread-safe (one mutex).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/drone/drone_types.h"
#include "common/image.h"
#include "common/mesh.h"
#include "common/rigid3.h"
#include "common/status.h"
#include "server/control/exploration.h"
#include "server/control/interactions.h"
#include "server/control/safe_flight.h"

namespace exo::control {

struct ControlCoreOptions {
  SafeFlightOptions safe;
  glm::dvec3 up{0, 0, 1};
  GazeOptions gaze;
  PickAndPlaceOptions pick;
  JoypadOptions joypad;
  GimbalLimits gimbal;  // the camera pitch range setpoints ask for
  double waypoint_tolerance_m = 0.15;
  double setpoint_rate_hz = 30.0;
  int carve_stride = 4;  // depth pixels carved per view: every k-th in both directions
  double carve_max_range_m = 5.0;
  // Autonomous exploration (the Explore interaction): the planner's options (its τ comes from
  // the stored views' depth), the hover at each goal before the next decision, and the time
  // after which a goal not reached is given up.
  ExploreOptions explore = DefaultExploreOptions();
  double explore_dwell_s = 1.0;
  // > 0: exploration sweeps the zones' footprint at this height along `up` (a Hilbert curve,
  // HilbertSweep; ExploreOptions::sweep: flown while the best view's gain is mostly unknown
  // space, with the climb and pass-through of ExploreOptions). 0: no sweep.
  double explore_sweep_altitude_m = 0.0;
  // Pixels without depth (a simulated sky) carve free space up to carve_max_range_m
  // (OccupancyGrid::CarveDepth's no_return_is_free); off for real sensors, whose black or
  // specular surfaces return nothing too.
  bool carve_no_return = false;
  // Pixels without depth carve free space where OccupancyGrid::SkyRule takes them for sky (a
  // rule for real sensors, session 17): the ray above carve_sky_min_elevation_rad (along `up`),
  // nothing measured above it in its image column, and, when the view's colour is given to
  // AddView, bright and blue. Off by default; excludes carve_no_return.
  bool carve_sky_rule = false;
  double carve_sky_min_elevation_rad = -0.1;
  double explore_goal_timeout_s = 30.0;
  double drone_sphere_m = 0.15;  // an exploring drone's own volume, marked free
  static ExploreOptions DefaultExploreOptions() {
    ExploreOptions e;
    e.tau_goal = 2.0;              // τ_max/2: the coverage threshold of SPEC §8's metric
    e.pitches = {-0.5, 0.0, 0.5};  // the gimbal's pitch candidates (setpoint camera_pitch)
    return e;
  }
  absl::Status Validate() const;
};

struct Command {
  std::string operator_id;
  uint64_t operator_sequence = 0;
  std::string drone_id = "drone";
};

struct CommandResult {
  uint64_t command_sequence = 0;
  InteractionKind kind = InteractionKind::kNone;
  Setpoint target;
  Route route;
  std::optional<GazeResult> gaze;
  std::string note;  // what was done (clamped, horizontal surface, slid...)
};

struct OutgoingSetpoint {
  uint64_t sequence = 0;  // per drone
  Setpoint setpoint;
  InteractionKind kind = InteractionKind::kNone;
  uint64_t command_sequence = 0;
  std::string operator_id;
  uint32_t waypoint_index = 0, waypoint_count = 0;
  double issued_s = 0.0;  // when the command was accepted (core clock)
};

struct DroneView {
  bool known = false;
  DroneState state;
  uint64_t states = 0, setpoints = 0;
  uint64_t command_sequence = 0;
  InteractionKind kind = InteractionKind::kNone;
  std::string operator_id;
  Setpoint target;
  std::vector<glm::dvec3> waypoints;
  uint32_t waypoint_index = 0;
  uint64_t setpoint_sequence = 0;
  // Autonomous exploration: on (started by an operator, until stopped, another interaction or
  // nothing left to gain), decisions taken, the last decision's note.
  bool exploring = false;
  std::string explore_operator;
  uint64_t explore_decisions = 0;
  std::string explore_note;
};

// What the exploration planner knows: surface cells with a τ estimate and those at τ_goal.
struct ExploreCoverage {
  size_t surface_cells = 0, covered_cells = 0;
};

class ControlCore {
 public:
  static absl::StatusOr<std::unique_ptr<ControlCore>> Create(const ControlCoreOptions& options);

  // ---- the world ----
  void SetOrigin(const glm::dvec3& origin_in_world);
  void UpsertChunk(uint64_t id, TriangleMesh mesh_local);  // also marks its cells occupied
  void RemoveChunk(uint64_t id);
  // A stored view: its pose (go-to-view) and its depth carved into the occupancy view.
  // `colour_srgb` (the view's camera image, any size; may be null) serves carve_sky_rule only.
  void AddView(uint32_t id, const Rigid3d& local_from_cam, const PinholeCamera& camera,
               const ImageF* depth_m, const ImageU8* colour_srgb = nullptr);
  void UpdateViewPose(uint32_t id, const Rigid3d& local_from_cam);
  void RemoveView(uint32_t id);
  // Direct access for tests and tools (under the core's lock).
  template <typename F>
  void WithSafeFlight(F&& f) {
    std::lock_guard lock(mu_);
    f(safe_);
  }

  // ---- the drone side ----
  void OnDroneState(const std::string& drone_id, const DroneState& state, double now_s);
  // The setpoint to send now, if any (changed, or due for repetition).
  std::optional<OutgoingSetpoint> NextSetpoint(const std::string& drone_id, double now_s);

  // ---- the operators ----
  absl::StatusOr<CommandResult> PickAndPlace(const Command& c, const glm::dvec3& eye,
                                             const glm::dvec3& hand,
                                             const glm::dvec3& hand_displacement, double now_s);
  absl::StatusOr<CommandResult> GazeToSee(const Command& c, const glm::dvec3& eye,
                                          const glm::dvec3& dir, double now_s);
  absl::StatusOr<CommandResult> Joypad(const Command& c, const JoypadInput& in, double dt_s,
                                       double now_s);
  absl::StatusOr<CommandResult> GoToView(const Command& c, uint32_t view_id, double now_s);
  // Starts (or stops) autonomous exploration for the drone. While it runs, ExploreStep proposes
  // the next view (ExplorationPlanner::Autonomous: expected τ gain per metre over reachable
  // safe poses) whenever the drone has reached its goal and hovered explore_dwell_s; the views
  // are commands of kind kExplore routed by safe flight like any other. Any other interaction
  // takes over (exploration stops); stopping holds the drone where it is.
  absl::StatusOr<CommandResult> Explore(const Command& c, bool start, double now_s);
  // One step of exploration for a drone (the host calls it a few times a second, off the wire
  // threads): decides when due, planning on copies of the world outside the lock. Returns
  // whether a new view was commanded. A command that arrived meanwhile wins.
  bool ExploreStep(const std::string& drone_id, double now_s);
  std::vector<std::string> ExploringDrones() const;
  ExploreCoverage Coverage() const;

  DroneView View(const std::string& drone_id) const;
  const ControlCoreOptions& options() const { return options_; }
  const SceneFrame& frame() const { return frame_; }
  size_t CountCells(Occupancy s) const;
  bool UsingRegions() const;

 private:
  struct Drone {
    DroneView view;
    double issued_s = 0.0;
    double last_sent_s = -1e9;
    uint64_t sent_sequence = 0;  // the setpoint sequence last sent
    double arrived_s = -1.0;     // exploring: when the drone reached its goal (-1: not there)
    int idle_turns = 0;          // exploring: turns in place with nothing to gain, in a row
    double travel_pitch = 0.0;   // exploring: camera pitch before the route's last waypoint
    double pass_m = 0.0;         // exploring: > 0: the goal is passed through (NextView)
    double dwell_s = -1.0;       // exploring: >= 0: the hover at the goal (NextView)
  };
  ControlCore(const ControlCoreOptions& options, const SceneFrame& frame, SafeFlight safe)
      : options_(options), frame_(frame), safe_(std::move(safe)), planner_(options.explore) {}
  // Checks the operator's sequence and the drone; returns the drone (created if new).
  absl::StatusOr<Drone*> Admit(const Command& c);
  // Routes from the drone's position to `target` and makes it the drone's command.
  absl::StatusOr<CommandResult> Commit(const Command& c, Drone* d, InteractionKind kind,
                                       const Setpoint& target, double now_s);
  // Makes `at` the drone's command as it is (no route: hold there, or turn in place).
  CommandResult Hold(const Command& c, Drone* d, InteractionKind kind, const Setpoint& at,
                     double now_s);
  const MeshRaycaster& Raycaster();
  glm::dvec3 DronePosition(const Drone& d) const;

  ControlCoreOptions options_;
  SceneFrame frame_;
  mutable std::mutex mu_;
  SafeFlight safe_;
  ExplorationPlanner planner_;
  glm::dvec3 origin_{0.0};
  std::map<uint64_t, TriangleMesh> chunks_;
  std::optional<MeshRaycaster> raycaster_;  // rebuilt lazily
  std::map<uint32_t, Rigid3d> view_poses_;  // local
  std::map<std::string, Drone> drones_;
  std::map<std::string, uint64_t> operator_sequences_;
  uint64_t command_sequence_ = 0;
};

}  // namespace exo::control
