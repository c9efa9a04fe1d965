// Exploration that the model drives (issue 19 item 4): the next view for the drone.
//   - The model side keeps an estimate of τ per occupied occupancy cell from the frames seen so
//     far, with SPEC §4's φ = λφ_d + (1−λ)φ_p per frame: φ_p from the frame's samples on the cell
//     against its expected count at that distance (× g(d)), φ_d from the directions of the first
//     R_max frames that saw the cell.
//   - Autonomous next view: random reachable clear cells × yaw samples; the expected gain of a
//     pose is summed over rays of its frustum marched through the occupancy view: a ray ending
//     on an occupied cell gains (τ_max − τ)/τ_max · g(d), one ending in unknown space (the model's
//     frontier) gains `unknown_gain`; the score is gain per metre of flight (path length from a
//     Dijkstra distance field over the clear cells, + `travel_offset_m`).
//   - Nearest frontier (the classic baseline): the closest reachable clear cell with unknown
//     space within `frontier_reach_m` inside the camera's vertical field of view, facing it;
//     frontier = unknown cells next to known free ones; each goal cell is tried once.
// An occupied cell's expected gain for a ray is (τ_max − τ)/τ_max · (λφ_d + (1−λ)g(d)): views
// from new directions at a good distance of under-covered surface.
// Pure library over OccupancyGrid / SafeFlight.
#pragma once

#include <cstdint>
#include <limits>
#include <optional>
#include <random>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "common/camera.h"
#include "common/drone/drone_types.h"
#include "common/image.h"
#include "common/rigid3.h"
#include "server/control/safe_flight.h"

namespace exo::control {

struct ExploreOptions {
  int candidates = 120;
  int yaws = 8;
  int rays_x = 16, rays_y = 6;
  double hfov_rad = 1.134;  // 65°
  double vfov_rad = 0.9;
  // Camera (gimbal) pitch candidates, rad, + up: {0} = a level camera. A drone with a gimbal
  // can look at floors and ceilings face-on instead of at the grazing angles a level camera
  // sees them at (SPEC §4's φ_p counts the cell's pixels against a face-on view).
  std::vector<double> pitches = {0.0};
  double range_m = 6.0;
  double d_max_m = 2.0, sigma_m = 2.0;  // (3.11)
  double tau_max = 4.0;
  double lambda = 0.4;
  int r_max = 16;
  double unknown_gain = 1.0;
  // A surface cell's weight in the gain is (tau_goal − τ)/tau_goal, clamped to [0, 1]; 0 = τ_max
  // (every cell is worth raising to τ_max).
  double tau_goal = 0.0;
  // Weight a ray's gain by (t/d_max)²: a ray reaching farther sweeps more surface (the cells a
  // ray stands for grow with the square of the distance), so the gain estimates τ_sum, not rays.
  bool area_weight = true;
  double travel_offset_m = 8.0;
  double min_goal_distance_m = 0.5;
  double frontier_reach_m = 0.6;
  uint64_t seed = 1;
  // A systematic sweep as the autonomous mode's fallback (empty: none). When the best view's
  // gain comes mostly from unknown space (gain_unknown > sweep_unknown_share × gain, or no
  // view gains anything), the next view is the next sweep point instead (in order, each once):
  // the highest reachable clear cell of the point's column at or below it, looking along the
  // sweep at `sweep_pitch`; points whose column has no reachable cell wait for a later
  // decision. The sweep starts at its end nearer the drone; a point whose view was not reached
  // (its route dropped) is flown again, once. Large outdoor scenes (the village): the scene's
  // fly-over path, so that the flight sweeps the surface systematically while the planner's
  // view is mostly unknown, and the coverage-driven choice takes over when surface dominates
  // the gain.
  std::vector<glm::dvec3> sweep;
  double sweep_pitch = -0.698;  // 40° down, the fly-over's
  double sweep_unknown_share = 0.9;
  // Looking before climbing (session 15). The drone flies only through air it has seen to be
  // free (unknown space is never entered), so a sweep point above what it has seen needs a
  // look first. While the next sweep point's column is not reachable within
  // `sweep_climb_tolerance_m` of its altitude, the view is a look at it: from the reachable
  // cell with the shortest flight there and on to the point, among those from which the point
  // lies within the camera's view at a pitch in [0, sweep_climb_pitch] and within range_m
  // (its frames observe the air along the line of sight, which the sweep then flies up,
  // camera down); at most two looks per point (a look not reached does not count, up to
  // sweep_look_misses such). Before any cell at the sweep's altitude is reachable and with no
  // place to look from: the reachable cell with the most height per metre of flight
  // (+ travel_offset_m), looking up, and at the top of what it has seen quarter turns in place
  // looking up (four at most). false: the sweep flies to the highest reachable cell under each
  // point (session 14).
  bool sweep_climb = true;
  double sweep_climb_pitch = 0.5;  // rad, + up (within the gimbal's +30°)
  double sweep_climb_tolerance_m = 1.0;
  // Camera pitch while travelling to a sweep point that is at the sweep's altitude (within
  // sweep_climb_tolerance_m) along a route that stays there: NaN = level (the camera looks
  // where the drone flies and observes the air ahead for later routes); e.g. sweep_pitch: the
  // fly-over's look-down all the way.
  double sweep_travel_pitch = std::numeric_limits<double>::quiet_NaN();
  // Sweep points at the sweep's altitude are passed through, not hovered at: the drone is at
  // one once within this distance (m) and the next decision follows at once, so that it flies
  // the sweep as a path without stopping at every point (0: hover as at any view).
  double sweep_pass_m = 1.0;
  // Climbing up a line of sight to a sweep point at the sweep's altitude (the drone more than
  // sweep_climb_tolerance_m below it), the camera faces the centre of the sweep points still to fly, not the leg: the
  // climb enters the sweep at its end, a corner, and facing the leg looks out of the scene
  // (session 16). false: facing the leg (session 15).
  bool sweep_climb_face_centre = true;
  // The hover at a look (sweep_climb's views toward a point above the air seen so far), in s;
  // < 0: the caller's usual dwell. The camera is still during it, so every frame after the
  // first carves the same rays again (session 17). 0.5 s: one frame of the bench's camera
  // (a frame every 0.5 s of flight); measured in session 18 on the village: 50 % 1.5 s sooner
  // than with the usual 1 s (16 of 20 seeds), 66.8 % 3.9 s sooner (14 of 15; docs/control.md).
  double sweep_look_dwell_s = 0.5;
  // Looks at one sweep point that may go unreached (their route dropped by obstacles the next
  // frames reveal) before the point gets no more looks and the climb falls back to the most
  // height per metre (session 15: 4). Session 18's traces: in 4 of 20 village seeds the first
  // look was dropped at 4 frames in a row (4.0-5.5 s) and the fallback then flew 15-20 s to a
  // high place before the sweep began.
  int sweep_look_misses = 4;
};

// A Hilbert-curve sweep (order `order`: 4^order points, in order) over the horizontal box
// [lo, hi] (the two horizontal axes of `frame`; the box is inset by `inset` × its smaller side
// on every side) at `altitude` along frame.up. The scripted fly-over's path; the Control
// service's sweep over the zones' footprint (control_explore_sweep_altitude_m).
std::vector<glm::dvec3> HilbertSweep(const glm::dvec3& lo, const glm::dvec3& hi, double altitude,
                                     const SceneFrame& frame, int order = 3, double inset = 0.15);

struct NextView {
  Setpoint pose;
  double pitch = 0.0;  // camera pitch, rad, + up (one of ExploreOptions::pitches)
  double gain = 0.0, path_m = 0.0, score = 0.0;
  double gain_unknown = 0.0;  // the part of `gain` from rays ending in unknown space
  int sweep_index = -1;       // >= 0: a point of ExploreOptions::sweep (the fallback)
  bool climb = false;         // a climb toward the sweep's altitude (sweep_climb)
  // Camera pitch on the way to the view (before the last waypoint): 0 = level.
  double travel_pitch = 0.0;
  // > 0: a point to pass through (ExploreOptions::sweep_pass_m): reached within this distance,
  // whatever the yaw, and not hovered at.
  double pass_m = 0.0;
  // >= 0: hover this long at the view instead of the caller's dwell (a look:
  // ExploreOptions::sweep_look_dwell_s).
  double dwell_s = -1.0;
};

class ExplorationPlanner {
 public:
  explicit ExplorationPlanner(const ExploreOptions& options)
      : options_(options), rng_(options.seed) {}
  const ExploreOptions& options() const { return options_; }
  // Restarts the candidate sampling (a copy planning off the lock gets its own sequence).
  void Reseed(uint64_t seed) { rng_.seed(seed); }
  // Takes over what a copy decided (the sweep's progress, its looks, the frontier's tried
  // goals), keeping this planner's τ estimates (frames observed meanwhile stay).
  void TakeDecisionState(const ExplorationPlanner& copy);
  // Surface cells with a τ estimate, and those at or above `tau`.
  size_t CellsAtOrAbove(double tau) const {
    size_t n = 0;
    for (const auto& [i, c] : cells_) n += c.tau >= tau;
    return n;
  }
  // The frame's depth (every `stride`-th pixel) raises τ of the occupied cells it hits.
  void Observe(const OccupancyGrid& grid, const ImageF& depth_m, const PinholeCamera& camera,
               const Rigid3d& frame_from_cam, int stride = 4);
  double Tau(size_t cell_index) const;
  size_t cells_seen() const { return cells_.size(); }
  // Dijkstra path lengths (m) over permitted cells from `from` (infinity: unreachable).
  std::vector<float> Distances(const SafeFlight& safe, const glm::dvec3& from) const;
  // Expected gain of a pose (see the header comment).
  // `unknown_part` (optional): the part of the gain from rays ending in unknown space.
  double Gain(const OccupancyGrid& grid, const Setpoint& pose, const SceneFrame& frame,
              double pitch = 0.0, double* unknown_part = nullptr) const;
  // Best-scoring candidate; nullopt when nothing reachable gains anything.
  std::optional<NextView> Autonomous(const SafeFlight& safe, const glm::dvec3& from,
                                     const SceneFrame& frame);
  // A goal cell is tried once (the classic frontier method's blacklist).
  std::optional<NextView> NearestFrontier(const SafeFlight& safe, const glm::dvec3& from,
                                          const SceneFrame& frame);

 private:
  ExploreOptions options_;
  std::mt19937_64 rng_;
  struct Cell {
    double tau = 0.0;
    std::vector<glm::vec3> refs;  // unit directions cell -> camera, first r_max views
  };
  double DirectionalNovelty(const Cell& c, const glm::dvec3& dir) const;
  // The next unvisited sweep point with a reachable cell in its column (see ExploreOptions).
  std::optional<NextView> NextSweepView(const SafeFlight& safe, const glm::dvec3& from,
                                        const SceneFrame& frame, const std::vector<float>& dist);
  // Climbing to the sweep (ExploreOptions::sweep_climb): turns in place at the top of the
  // observed air so far, and whether the climb is over.
  std::optional<NextView> ClimbView(const SafeFlight& safe, const glm::dvec3& from,
                                    const SceneFrame& frame, const std::vector<float>& dist,
                                    size_t k);
  std::optional<NextView> LookView(const SafeFlight& safe, const SceneFrame& frame,
                                   const std::vector<float>& dist, size_t k);
  int climb_turns_ = 0;
  std::vector<std::vector<glm::dvec3>> looks_;  // per sweep point: where it was looked at from
  std::vector<int> look_misses_;                // per sweep point: looks not reached
  int last_look_ = -1;                          // the sweep point looked at last (-1: none)
  glm::dvec3 last_look_place_{0.0};
  bool climb_done_ = false;
  std::vector<glm::dvec3> sweep_;  // ExploreOptions::sweep, from its end nearer the drone
  bool sweep_reversed_ = false;
  std::vector<bool> swept_;
  std::vector<bool> sweep_retried_;
  int last_sweep_ = -1;  // the sweep point proposed last (-1: the last view was none)
  glm::dvec3 last_sweep_goal_{0.0};
  std::unordered_map<size_t, Cell> cells_;
  std::unordered_set<size_t> tried_;
};

}  // namespace exo::control
