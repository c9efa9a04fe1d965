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
  // decision. Large outdoor scenes (the village): the scene's fly-over path, so that the
  // flight sweeps the surface systematically while the planner's view is mostly unknown, and
  // the coverage-driven choice takes over when surface dominates the gain.
  std::vector<glm::dvec3> sweep;
  double sweep_pitch = -0.698;  // 40° down, the fly-over's
  double sweep_unknown_share = 0.9;
};

struct NextView {
  Setpoint pose;
  double pitch = 0.0;  // camera pitch, rad, + up (one of ExploreOptions::pitches)
  double gain = 0.0, path_m = 0.0, score = 0.0;
  double gain_unknown = 0.0;  // the part of `gain` from rays ending in unknown space
  int sweep_index = -1;       // >= 0: a point of ExploreOptions::sweep (the fallback)
};

class ExplorationPlanner {
 public:
  explicit ExplorationPlanner(const ExploreOptions& options)
      : options_(options), rng_(options.seed) {}
  const ExploreOptions& options() const { return options_; }
  // Restarts the candidate sampling (a copy planning off the lock gets its own sequence).
  void Reseed(uint64_t seed) { rng_.seed(seed); }
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
  std::vector<bool> swept_;
  std::unordered_map<size_t, Cell> cells_;
  std::unordered_set<size_t> tried_;
};

}  // namespace exo::control
