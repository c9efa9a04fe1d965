// Camera trajectories through the synthetic scenes (SPEC §9): a 2D Hilbert-curve fly-over at a
// fixed altitude (looking forward and down), a walking path at eye height along the scene's
// waypoints, and seeded random test poses inside the navigable region that look at content.
// Issue 22 adds two realistic streams, deterministic from a seed (trajectory_streams.cc): a drone
// exploration ("drone": legs at varying speed between places, hovers of several seconds, fast
// yaw pans, revisits of earlier places) and a handheld walk ("handheld": variable walking speed,
// stops with look-arounds, walking back to earlier places, hand shake and head bob). Their
// frames carry a Motion label and a place index so tests and benchmarks can find the hovers,
// pans and revisits. Poses are local_from_cam (camera frame x right, y down, z forward;
// scene-local frame z up).
#pragma once

#include <cstdint>
#include <vector>

#include "common/camera.h"
#include "common/rigid3.h"
#include "common/status.h"
#include "common/synth/scene.h"

namespace exo::synth {

enum class TrajectoryKind { kFlyover, kWalk, kDrone, kHandheld };
const char* TrajectoryKindName(TrajectoryKind k);
absl::StatusOr<TrajectoryKind> ParseTrajectoryKind(const std::string& name);

struct TrajectoryOptions {
  int num_frames = 120;           // thesis: 5000
  int hilbert_order = 3;          // 4^order curve vertices over the scene footprint
  double flyover_pitch_deg = 40;  // below the horizon
  double walk_look_around_deg = 20;  // amplitude of a slow yaw sweep while walking, [0, 180]
  double frame_rate_hz = 30;      // timestamps
  // drone / handheld: the mission (places, speeds, hover and stop lengths, pans, shake). The
  // stream of N frames is the first N frames of the stream of any M > N frames (same seed).
  uint64_t seed = 1;
  absl::Status Validate() const;
};

// What the camera does at a frame (drone / handheld; flyover and walk frames are all kMove).
enum class Motion {
  kMove,        // travelling between places
  kHover,       // drone hovering: the pose does not change
  kPan,         // drone yaw pan on the spot (90-180 deg/s)
  kStop,        // handheld standing still (hand shake only)
  kLookAround,  // handheld turning on the spot (40-80 deg/s)
};
const char* MotionName(Motion m);

struct TimedPose {
  double timestamp_s = 0;
  Rigid3d local_from_cam;
  Motion motion = Motion::kMove;
  int place = -1;  // the place the camera is at (hover, pan, stop, look-around); -1 when moving.
                   // A revisit reuses the index of the earlier place.
};

// A camera pose at `eye` looking at `target` with z up (no roll).
Rigid3d LookAt(const glm::dvec3& eye, const glm::dvec3& target);
// The 2D Hilbert curve of the given order as points in [0,1]^2 (4^order points).
std::vector<glm::dvec2> HilbertCurve(int order);

// Errors: a trajectory the scene does not support (fly-over indoors), bad options.
// kDrone outdoors flies between places at 14-24 m (looking 25-55 deg down); indoors it flies
// along the walk path at 1.2-2.0 m. kHandheld walks the walk path at eye height.
absl::StatusOr<std::vector<TimedPose>> MakeTrajectory(const SynthScene& scene, TrajectoryKind kind,
                                                      const TrajectoryOptions& options);

struct TestPoseOptions {
  int count = 200;
  uint64_t seed = 7;
  // Accept a pose when at least this fraction of a low-res depth render hits geometry and no
  // surface is closer than min_depth_m (no pose inside or against geometry).
  double min_coverage = 0.9;
  double min_depth_m = 0.4;
  absl::Status Validate() const;
};
absl::StatusOr<std::vector<Rigid3d>> MakeTestPoses(const SynthScene& scene,
                                                   const PinholeCamera& camera,
                                                   const TestPoseOptions& options);

// Test poses off the input path but near it (the evaluation's "near" set): the eye within
// ±10 % of the scene extent horizontally (±0.3 m vertically on a walk, ±2 m on a fly-over) of a
// random input pose, the view direction within ±45° yaw and ±10° pitch of that pose's, accepted
// by the rule of MakeTestPoses (>= 90 % geometry hits, nothing closer than 0.4 m, eye 0.5 m from
// solids). Deterministic for a seed.
absl::StatusOr<std::vector<Rigid3d>> MakeNearTestPoses(const SynthScene& scene,
                                                       const std::vector<Rigid3d>& input,
                                                       const PinholeCamera& camera, int count,
                                                       uint64_t seed, bool flyover);

}  // namespace exo::synth
