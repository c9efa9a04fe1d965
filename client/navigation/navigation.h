// Pure (no SDL, no Vulkan) parts of the interactive viewer (issue 17): fly navigation of a novel
// camera through a lumigraph model, the adaptive-resolution policy of the window, picking (a ray
// through a pixel into the proxy mesh -> point, normal, cell), and camera paths in the TUM
// trajectory format (scripted renders, record/replay of an interactive session).
// Frames: poses are local_from_cam in the model's scene-local frame (camera looks along +z, image
// y down); TUM files hold world_from_cam (= local + model.origin).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/cells.h"
#include "common/lumigraph/model.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo::nav {

// ---- fly navigation ----
struct FlyInput {
  bool forward = false, back = false, left = false, right = false, up = false, down = false;
  double look_dx_px = 0, look_dy_px = 0;  // mouse-look motion this step (pixels)
  double wheel = 0;                       // scroll clicks this step (+ = faster)
};

struct FlyOptions {
  double speed_mps = 1.0;          // translation speed (scroll multiplies it by 1.25 per click)
  double look_rad_per_px = 0.003;  // mouse-look sensitivity
  double max_pitch_rad = 1.45;     // forward never closer than this to +/- up
};

// A free-flying camera: W/S along the view direction, A/D sideways, Q/E along the scene's up,
// mouse look = yaw about the scene's up and pitch about the camera's x axis (the roll of a pose it
// was reset to is kept).
class FlyCamera {
 public:
  FlyCamera(const Rigid3d& local_from_cam, const glm::dvec3& up_local, const FlyOptions& options);
  // Advances by dt seconds; true when the pose changed.
  bool Step(const FlyInput& input, double dt_s);
  void Reset(const Rigid3d& local_from_cam) { pose_ = local_from_cam; }
  const Rigid3d& pose() const { return pose_; }
  double speed_mps() const { return options_.speed_mps; }
  const glm::dvec3& up() const { return up_; }

 private:
  Rigid3d pose_;
  glm::dvec3 up_;
  FlyOptions options_;
};

// The scene's up direction in the local frame: the mean of the stored views' image-up axes
// (-y of each camera), normalised; (0,-1,0) when there are no views.
glm::dvec3 SceneUp(const LumigraphModel& model);
// Axis-aligned bounds of the proxy mesh (or of the view centres when there is no mesh).
struct Bounds {
  glm::dvec3 lo{0.0}, hi{0.0};
  double Diagonal() const { return glm::length(hi - lo); }
};
Bounds ModelBounds(const LumigraphModel& model);
// The stored view whose centre is nearest `p_local` (ties: smaller id); nullopt without views.
std::optional<ViewId> NearestView(const LumigraphModel& model, const glm::dvec3& p_local);

// ---- adaptive resolution ----
struct AdaptiveOptions {
  bool enabled = true;
  int moving_divisor = 4;  // render at 1/d of the window per side while the camera moves
  // Frame-time budget while moving (0 = fixed moving_divisor): a moving frame over budget
  // doubles the divisor (up to max_divisor); one that would fit 4x the pixels halves it (down
  // to min_divisor).
  double target_ms = 33.3;
  int min_divisor = 2, max_divisor = 8;
  absl::Status Validate() const;
};

// What to render next: a divisor of the window size (1 = full resolution) or 0 = nothing (the
// last presented frame is still exact). Moving: the moving divisor every frame (adapted to the
// budget by ReportMovingFrame). Stopped: the divisor halves frame by frame (e.g. ¼ -> ½ ->
// full), then 0 until something changes. Off: full resolution whenever something changed, else 0.
class AdaptiveResolution {
 public:
  explicit AdaptiveResolution(const AdaptiveOptions& options)
      : options_(options), moving_(options.moving_divisor) {}
  int Next(bool changed);
  // Wall time of the last frame rendered while moving (render + present), for the budget.
  void ReportMovingFrame(double frame_ms);
  int last() const { return last_; }
  int moving_divisor() const { return moving_; }

 private:
  AdaptiveOptions options_;
  int moving_;
  int last_ = 0;  // divisor of the last rendered frame (0 = none yet)
};

// ---- picking ----
struct PickResult {
  glm::dvec3 point_local{0.0};
  glm::dvec3 normal_local{0.0};  // unit face normal, facing the camera
  double range_m = 0;            // distance from the camera centre
  double z_depth_m = 0;          // along the optical axis
  CellId cell = 0;
  uint64_t chunk_id = 0;
  uint32_t triangle = 0;  // index within the chunk
};
// Casts the ray through pixel `uv` (pixel centres at integers) of `camera` at `local_from_cam`
// into the proxy mesh (every chunk); the nearest hit, nullopt when the ray hits nothing. Hits
// nearer than `min_z_depth_m` along the optical axis are skipped (the X-ray cut-away's plane).
std::optional<PickResult> Pick(const LumigraphModel& model, const PinholeCamera& camera,
                               const Rigid3d& local_from_cam, const glm::dvec2& uv,
                               double min_z_depth_m = 0.0);

// ---- camera paths (TUM: "timestamp tx ty tz qx qy qz qw", world_from_cam) ----
struct PathPose {
  double timestamp_s = 0;
  Rigid3d world_from_cam;
};
// Reads a TUM trajectory file; '#' comments and blank lines skipped. InvalidArgument naming the
// file and line for a malformed line or a non-unit quaternion; NotFound when unreadable.
absl::StatusOr<std::vector<PathPose>> ReadTumPath(const std::string& path);
absl::Status WriteTumPath(const std::string& path, const std::vector<PathPose>& poses);

}  // namespace exo::nav
