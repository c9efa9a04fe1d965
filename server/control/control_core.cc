#include "server/control/control_core.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace exo::control {

absl::Status ControlCoreOptions::Validate() const {
  EXO_RETURN_IF_ERROR(safe.Validate());
  EXO_RETURN_IF_ERROR(SceneFrame::FromUp(up).status());
  if (!(waypoint_tolerance_m > 0) || !(setpoint_rate_hz > 0))
    return absl::InvalidArgumentError("control: waypoint_tolerance_m and setpoint_rate_hz > 0");
  if (!(gaze.offset_m > 0)) return absl::InvalidArgumentError("control: gaze offset must be > 0");
  if (carve_no_return && carve_sky_rule)
    return absl::InvalidArgumentError(
        "control: carve_no_return and carve_sky_rule exclude each other (every missing depth "
        "carved, or only the sky's)");
  if (!(std::abs(carve_sky_min_elevation_rad) <= kPi / 2))
    return absl::InvalidArgumentError("control: carve_sky_min_elevation_rad must be in [-pi/2, pi/2]");
  return absl::OkStatus();
}

absl::StatusOr<std::unique_ptr<ControlCore>> ControlCore::Create(
    const ControlCoreOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_ASSIGN_OR_RETURN(SceneFrame frame, SceneFrame::FromUp(options.up));
  EXO_ASSIGN_OR_RETURN(SafeFlight safe, SafeFlight::Create(options.safe));
  ControlCoreOptions o = options;
  if (o.explore_sweep_altitude_m > 0 && !o.safe.zones.empty()) {
    glm::dvec3 lo = o.safe.zones.front().min, hi = o.safe.zones.front().max;
    for (const Zone& z : o.safe.zones) {
      lo = glm::min(lo, z.min);
      hi = glm::max(hi, z.max);
    }
    o.explore.sweep = HilbertSweep(lo, hi, o.explore_sweep_altitude_m, frame);
  }
  return std::unique_ptr<ControlCore>(new ControlCore(o, frame, std::move(safe)));
}

void ControlCore::SetOrigin(const glm::dvec3& origin_in_world) {
  std::lock_guard lock(mu_);
  origin_ = origin_in_world;
  raycaster_.reset();
}

void ControlCore::UpsertChunk(uint64_t id, TriangleMesh mesh_local) {
  std::lock_guard lock(mu_);
  safe_.grid().MarkMeshOccupied(mesh_local, origin_);
  chunks_[id] = std::move(mesh_local);
  raycaster_.reset();
}

void ControlCore::RemoveChunk(uint64_t id) {
  std::lock_guard lock(mu_);
  if (chunks_.erase(id)) raycaster_.reset();
}

void ControlCore::AddView(uint32_t id, const Rigid3d& local_from_cam, const PinholeCamera& camera,
                          const ImageF* depth_m, const ImageU8* colour_srgb) {
  // The sky rule's colour, converted off the lock.
  ImageF colour;
  if (options_.carve_sky_rule && colour_srgb && depth_m)
    colour = OccupancyGrid::SkyColour(*colour_srgb, depth_m->width(), depth_m->height());
  std::lock_guard lock(mu_);
  view_poses_[id] = local_from_cam;
  if (depth_m && !depth_m->empty()) {
    Rigid3d world_from_cam = local_from_cam;
    world_from_cam.translation += origin_;
    if (options_.carve_sky_rule) {
      OccupancyGrid::SkyRule sky;
      sky.up = options_.up;
      sky.min_elevation_rad = options_.carve_sky_min_elevation_rad;
      sky.color = colour.empty() ? nullptr : &colour;
      safe_.grid().CarveDepth(*depth_m, camera, world_from_cam, options_.carve_stride,
                              options_.carve_max_range_m, sky);
    } else {
      safe_.grid().CarveDepth(*depth_m, camera, world_from_cam, options_.carve_stride,
                              options_.carve_max_range_m, options_.carve_no_return);
    }
    // The view raises τ of the surface cells it sees (exploration's estimate of the lumigraph).
    planner_.Observe(safe_.grid(), *depth_m, camera, world_from_cam, options_.carve_stride);
  }
}

void ControlCore::UpdateViewPose(uint32_t id, const Rigid3d& local_from_cam) {
  std::lock_guard lock(mu_);
  if (auto it = view_poses_.find(id); it != view_poses_.end()) it->second = local_from_cam;
}

void ControlCore::RemoveView(uint32_t id) {
  std::lock_guard lock(mu_);
  view_poses_.erase(id);
}

const MeshRaycaster& ControlCore::Raycaster() {
  if (!raycaster_) {
    TriangleMesh all;
    for (const auto& [id, m] : chunks_) {
      const uint32_t base = static_cast<uint32_t>(all.positions.size());
      all.positions.insert(all.positions.end(), m.positions.begin(), m.positions.end());
      for (uint32_t i : m.indices) all.indices.push_back(base + i);
    }
    raycaster_.emplace(std::move(all), origin_);
  }
  return *raycaster_;
}

void ControlCore::OnDroneState(const std::string& drone_id, const DroneState& state, double now_s) {
  std::lock_guard lock(mu_);
  Drone& d = drones_[drone_id];
  d.view.known = true;
  d.view.state = state;
  // An exploring drone's own volume is free space (it is there); early on it lets the planner
  // start from where the drone is before its camera has carved around it.
  if (d.view.exploring) safe_.grid().MarkSphereFree(state.position, options_.drone_sphere_m);
  ++d.view.states;
  // Route progress: the next waypoint once the drone is close to the current one.
  DroneView& v = d.view;
  while (!v.waypoints.empty() && v.waypoint_index + 1 < v.waypoints.size() &&
         glm::length(state.position - v.waypoints[v.waypoint_index]) <
             options_.waypoint_tolerance_m) {
    ++v.waypoint_index;
    ++v.setpoint_sequence;
  }
}

std::optional<OutgoingSetpoint> ControlCore::NextSetpoint(const std::string& drone_id,
                                                          double now_s) {
  std::lock_guard lock(mu_);
  auto it = drones_.find(drone_id);
  if (it == drones_.end()) return std::nullopt;
  Drone& d = it->second;
  const DroneView& v = d.view;
  if (v.waypoints.empty()) return std::nullopt;
  const bool changed = d.sent_sequence != v.setpoint_sequence;
  if (!changed && now_s - d.last_sent_s < 1.0 / options_.setpoint_rate_hz) return std::nullopt;
  OutgoingSetpoint out;
  out.sequence = v.setpoint_sequence;
  // The gimbal pitch of the view asked for on the last waypoint; level while travelling (the
  // camera looks where the drone flies).
  const bool last = v.waypoint_index + 1 == v.waypoints.size();
  out.setpoint = Setpoint{v.waypoints[v.waypoint_index], v.target.yaw,
                          last ? v.target.camera_pitch
                               : v.kind == InteractionKind::kExplore ? d.travel_pitch : 0.0};
  out.kind = v.kind;
  out.command_sequence = v.command_sequence;
  out.operator_id = v.operator_id;
  out.waypoint_index = v.waypoint_index;
  out.waypoint_count = static_cast<uint32_t>(v.waypoints.size());
  out.issued_s = d.issued_s;
  d.sent_sequence = v.setpoint_sequence;
  d.last_sent_s = now_s;
  ++d.view.setpoints;
  return out;
}

absl::StatusOr<ControlCore::Drone*> ControlCore::Admit(const Command& c) {
  if (c.operator_id.empty())
    return absl::InvalidArgumentError("control: the command has no operator id");
  uint64_t& last = operator_sequences_[c.operator_id];
  if (c.operator_sequence <= last)
    return absl::AbortedError(absl::StrCat("control: stale command from operator '", c.operator_id,
                                           "': sequence ", c.operator_sequence, " <= last ", last));
  last = c.operator_sequence;
  auto it = drones_.find(c.drone_id);
  if (it == drones_.end() || !it->second.view.known)
    return absl::FailedPreconditionError(
        absl::StrCat("control: drone '", c.drone_id, "' has not reported its state yet"));
  return &it->second;
}

glm::dvec3 ControlCore::DronePosition(const Drone& d) const { return d.view.state.position; }

absl::StatusOr<CommandResult> ControlCore::Commit(const Command& c, Drone* d, InteractionKind kind,
                                                  const Setpoint& target, double now_s) {
  CommandResult r;
  r.kind = kind;
  EXO_ASSIGN_OR_RETURN(r.route, safe_.Plan(DronePosition(*d), target.position));
  r.target = Setpoint{r.route.target, target.yaw, target.camera_pitch};
  r.command_sequence = ++command_sequence_;
  DroneView& v = d->view;
  v.command_sequence = r.command_sequence;
  v.kind = kind;
  v.operator_id = c.operator_id;
  v.target = r.target;
  v.waypoints = r.route.waypoints;
  v.waypoint_index = 0;
  ++v.setpoint_sequence;
  d->issued_s = now_s;
  // Any other interaction takes over from autonomous exploration.
  if (kind != InteractionKind::kExplore) v.exploring = false;
  if (r.route.clamped)
    r.note = absl::StrFormat("target clamped by %.2f m to the nearest permitted point",
                             glm::length(r.route.target - r.route.requested));
  if (r.route.regions) r.note += (r.note.empty() ? "" : "; ") + std::string("region waypoints");
  return r;
}

absl::StatusOr<CommandResult> ControlCore::PickAndPlace(const Command& c, const glm::dvec3& eye,
                                                        const glm::dvec3& hand,
                                                        const glm::dvec3& disp, double now_s) {
  std::lock_guard lock(mu_);
  EXO_ASSIGN_OR_RETURN(Drone * d, Admit(c));
  EXO_ASSIGN_OR_RETURN(auto p,
                       control::PickAndPlace(DronePosition(*d), eye, hand, disp, options_.pick));
  EXO_ASSIGN_OR_RETURN(CommandResult r, Commit(c, d, InteractionKind::kPickAndPlace,
                                               Setpoint{p.target, d->view.state.yaw,
                                                        d->view.state.camera_pitch},
                                               now_s));
  if (p.guarded) r.note += (r.note.empty() ? "" : "; ") + std::string("hand-eye distance guarded");
  return r;
}

absl::StatusOr<CommandResult> ControlCore::GazeToSee(const Command& c, const glm::dvec3& eye,
                                                     const glm::dvec3& dir, double now_s) {
  std::lock_guard lock(mu_);
  EXO_ASSIGN_OR_RETURN(Drone * d, Admit(c));
  EXO_ASSIGN_OR_RETURN(GazeResult g,
                       control::GazeToSee(Raycaster(), eye, dir, frame_, options_.gaze));
  EXO_ASSIGN_OR_RETURN(CommandResult r, Commit(c, d, InteractionKind::kGazeToSee, g.target, now_s));
  // Facing P_gaze from where the drone ends up (after clamping).
  r.target.yaw = d->view.target.yaw = frame_.YawOf(g.hit.point - r.target.position);
  // The gimbal faces P_gaze from there as well (a floor point: looking down the gaze ray).
  r.target.camera_pitch = d->view.target.camera_pitch =
      CameraPitchToward(r.target.position, g.hit.point, frame_, options_.gimbal);
  if (g.horizontal_surface)
    r.note +=
        (r.note.empty() ? "" : "; ") + std::string("horizontal surface: between user and point");
  r.gaze = g;
  return r;
}

absl::StatusOr<CommandResult> ControlCore::Joypad(const Command& c, const JoypadInput& in,
                                                  double dt_s, double now_s) {
  std::lock_guard lock(mu_);
  EXO_ASSIGN_OR_RETURN(Drone * d, Admit(c));
  const DroneView& v = d->view;
  const Setpoint current = v.kind == InteractionKind::kJoypad && !v.waypoints.empty()
                               ? Setpoint{v.waypoints.back(), v.target.yaw}
                               : Setpoint{v.state.position, v.state.yaw, v.state.camera_pitch};
  const glm::dvec3 drone = v.state.position;
  const JoypadResult j =
      IntegrateJoypad(current, in, dt_s, frame_, options_.joypad, &safe_, &drone);
  CommandResult r;
  r.kind = InteractionKind::kJoypad;
  r.target = j.setpoint;
  r.route.requested = r.route.target = j.setpoint.position;
  r.route.waypoints = {j.setpoint.position};
  r.command_sequence = ++command_sequence_;
  DroneView& w = d->view;
  w.command_sequence = r.command_sequence;
  w.kind = InteractionKind::kJoypad;
  w.operator_id = c.operator_id;
  w.target = r.target;
  w.waypoints = r.route.waypoints;
  w.waypoint_index = 0;
  ++w.setpoint_sequence;
  d->issued_s = now_s;
  w.exploring = false;
  r.note = j.blocked ? "blocked at the boundary" : j.slid ? "slid along the boundary" : "";
  return r;
}

absl::StatusOr<CommandResult> ControlCore::GoToView(const Command& c, uint32_t view_id,
                                                    double now_s) {
  std::lock_guard lock(mu_);
  auto it = view_poses_.find(view_id);
  if (it == view_poses_.end())
    return absl::NotFoundError(absl::StrCat("control: no stored view ", view_id));
  const Rigid3d pose = it->second;
  EXO_ASSIGN_OR_RETURN(Drone * d, Admit(c));
  Setpoint target;
  target.position = pose.translation + origin_;
  const glm::dvec3 forward = pose.rotation * glm::dvec3(0, 0, 1);
  target.yaw = frame_.YawOf(forward);
  // The stored view's camera elevation, within the gimbal's limits.
  target.camera_pitch = std::clamp(
      std::atan2(glm::dot(forward, frame_.up), glm::length(frame_.Horizontal(forward))),
      options_.gimbal.min_pitch_rad, options_.gimbal.max_pitch_rad);
  return Commit(c, d, InteractionKind::kGoToView, target, now_s);
}

CommandResult ControlCore::Hold(const Command& c, Drone* d, InteractionKind kind,
                                const Setpoint& at, double now_s) {
  CommandResult r;
  r.kind = kind;
  r.target = at;
  r.route.requested = r.route.target = at.position;
  r.route.waypoints = {at.position};
  r.command_sequence = ++command_sequence_;
  DroneView& v = d->view;
  v.command_sequence = r.command_sequence;
  v.kind = kind;
  v.operator_id = c.operator_id;
  v.target = at;
  v.waypoints = r.route.waypoints;
  v.waypoint_index = 0;
  ++v.setpoint_sequence;
  d->issued_s = now_s;
  d->arrived_s = -1.0;
  return r;
}

absl::StatusOr<CommandResult> ControlCore::Explore(const Command& c, bool start, double now_s) {
  std::lock_guard lock(mu_);
  EXO_ASSIGN_OR_RETURN(Drone * d, Admit(c));
  DroneView& v = d->view;
  const Setpoint here{v.state.position, v.state.yaw, v.state.camera_pitch};
  const bool was = v.exploring;
  if (!start) {
    CommandResult r = Hold(c, d, InteractionKind::kHold, here, now_s);
    v.exploring = false;
    v.explore_note = "stopped by " + c.operator_id;
    r.note = was ? "exploration stopped: holding" : "exploration was not running: holding";
    return r;
  }
  // Hold where it is; the first view follows after the dwell (ExploreStep).
  CommandResult r = Hold(c, d, InteractionKind::kExplore, here, now_s);
  v.exploring = true;
  d->idle_turns = 0;
  v.explore_operator = c.operator_id;
  v.explore_note = "started by " + c.operator_id;
  r.note = was ? "exploring (restarted)" : "exploring: the next view follows when the drone is idle";
  return r;
}

bool ControlCore::ExploreStep(const std::string& drone_id, double now_s) {
  std::unique_lock lock(mu_);
  auto it = drones_.find(drone_id);
  if (it == drones_.end() || !it->second.view.exploring) return false;
  {
    Drone& d = it->second;
    const DroneView& v = d.view;
    const DroneState& s = v.state;
    // A goal to pass through (a sweep point at the sweep's altitude): there once within its
    // distance, whatever the yaw, and no hover.
    const double dist_to_goal =
        v.waypoints.empty() ? 0.0 : glm::length(s.position - v.waypoints.back());
    const bool at_goal =
        !v.waypoints.empty() && v.waypoint_index + 1 == v.waypoints.size() &&
        (d.pass_m > 0 ? dist_to_goal < d.pass_m
                      : dist_to_goal < options_.waypoint_tolerance_m &&
                            std::abs(WrapAngle(s.yaw - v.target.yaw)) < 0.1);
    if (!at_goal) d.arrived_s = -1.0;
    else if (d.arrived_s < 0) d.arrived_s = now_s;
    const double dwell = d.pass_m > 0 ? 0.0 : d.dwell_s >= 0 ? d.dwell_s : options_.explore_dwell_s;
    bool due = (at_goal && now_s - d.arrived_s >= dwell) ||
               now_s - d.issued_s > options_.explore_goal_timeout_s;
    // A route that crosses newly seen obstacles (or unknown space) is dropped.
    glm::dvec3 a = s.position;
    for (size_t k = v.waypoint_index; !due && k < v.waypoints.size(); ++k) {
      if (!safe_.SegmentPermitted(a, v.waypoints[k])) due = true;
      a = v.waypoints[k];
    }
    if (!due) return false;
  }
  // Plan on copies, off the lock (a decision takes a few hundred ms; the drone link and the
  // other interactions go on meanwhile).
  const SafeFlight safe = safe_;
  ExplorationPlanner planner = planner_;
  DroneView& v0 = it->second.view;
  planner.Reseed(options_.explore.seed + 7919 * ++v0.explore_decisions);
  const uint64_t command = v0.command_sequence;
  const glm::dvec3 from = v0.state.position;
  const double yaw = v0.state.yaw;
  lock.unlock();
  const std::optional<NextView> next = planner.Autonomous(safe, from, frame_);
  lock.lock();
  it = drones_.find(drone_id);
  if (it == drones_.end()) return false;
  Drone* d = &it->second;
  DroneView& v = d->view;
  if (!v.exploring || v.command_sequence != command) return false;  // superseded meanwhile
  planner_.TakeDecisionState(planner);  // the sweep's progress (the τ estimates stay)
  d->travel_pitch = 0.0;
  d->pass_m = 0.0;
  d->dwell_s = -1.0;
  const Command c{v.explore_operator, 0, drone_id};
  if (!next) {
    // Nothing reachable gains anything (early on: too little modelled to fly anywhere). Turn
    // in place and look again; after a full turn with nothing, exploration ends.
    if (++d->idle_turns > 4) {
      v.exploring = false;
      v.explore_note = "nothing reachable gains anything after a full turn: exploration ended";
      return false;
    }
    Hold(c, d, InteractionKind::kExplore, Setpoint{from, WrapAngle(yaw + kPi / 2), 0.0}, now_s);
    v.explore_note = "nothing reachable gains anything yet: turning to look";
    v.exploring = true;
    return true;
  }
  d->idle_turns = 0;
  auto r = Commit(c, d, InteractionKind::kExplore,
                  Setpoint{next->pose.position, next->pose.yaw, next->pitch}, now_s);
  if (r.ok()) {
    d->travel_pitch = next->travel_pitch;
    d->pass_m = next->pass_m;
    d->dwell_s = next->dwell_s;
    v.explore_note = absl::StrFormat(
        "view %d%s: gain %.1f (%.0f%% from unknown space), path %.1f m, pitch %.2f rad",
        v.explore_decisions,
        next->climb             ? " (climb: looking at the sweep)"
        : next->sweep_index >= 0 ? absl::StrFormat(" (sweep point %d)", next->sweep_index)
                                 : std::string(),
        next->gain, next->gain > 0 ? 100 * next->gain_unknown / next->gain : 0,
        r->route.length_m, next->pitch);
  } else {
    // No route this time: turn in place and look again.
    Hold(c, d, InteractionKind::kExplore, Setpoint{from, WrapAngle(yaw + kPi / 2), 0.0}, now_s);
    v.explore_note = absl::StrCat("no route to the proposed view (", r.status().message(),
                                  "): turning to look again");
  }
  v.exploring = true;
  d->arrived_s = -1.0;
  return true;
}

std::vector<std::string> ControlCore::ExploringDrones() const {
  std::lock_guard lock(mu_);
  std::vector<std::string> out;
  for (const auto& [id, d] : drones_)
    if (d.view.exploring) out.push_back(id);
  return out;
}

ExploreCoverage ControlCore::Coverage() const {
  std::lock_guard lock(mu_);
  const double goal =
      options_.explore.tau_goal > 0 ? options_.explore.tau_goal : options_.explore.tau_max;
  return {planner_.cells_seen(), planner_.CellsAtOrAbove(goal)};
}

DroneView ControlCore::View(const std::string& drone_id) const {
  std::lock_guard lock(mu_);
  auto it = drones_.find(drone_id);
  return it == drones_.end() ? DroneView{} : it->second.view;
}

size_t ControlCore::CountCells(Occupancy s) const {
  std::lock_guard lock(mu_);
  return safe_.grid().CountState(s);
}

bool ControlCore::UsingRegions() const {
  std::lock_guard lock(mu_);
  return safe_.UsingRegions();
}

}  // namespace exo::control
