// Plausibility limits on every field of an uploaded frame (SPEC §12, issue 20 item 2): the one
// place where "absurd but finite" is defined. Every check returns InvalidArgument with the field,
// the value and the limit in the reason. Values are checked as they are stored (exposure after
// its conversion to float), so nothing accepted can make a client fail. FrameFromProto
// (frame_proto.h) applies them while decoding, sizes before any allocation; the server applies
// CheckFrame again after it fills a pose from the UDP pose stream.
#pragma once

#include <cstdint>
#include <string>

#include "common/camera.h"
#include "common/frame.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo {

struct FrameLimits {
  int64_t max_pixels = int64_t{1} << 24;  // per image (colour and depth each): 16 Mpix
  int max_side = 16384;                   // width and height of each image
  // Focal lengths relative to the larger image side: 0.05 (a ~170 degree field of view) to 50
  // (~1 degree).
  double min_focal_rel = 0.05;
  double max_focal_rel = 50.0;
  // Principal point inside the image or at most this fraction of its size outside it.
  double principal_margin = 0.5;
  // Relative exposure (0 on the wire = not given), checked after conversion to float.
  double min_exposure = 1e-3;
  double max_exposure = 1e3;
  double min_depth_scale_m = 1e-6;  // metres per depth unit
  double max_depth_scale_m = 1.0;
  // Camera positions (world_from_cam translation) within this radius of the scene centre.
  double scene_radius_m = 1000.0;
  glm::dvec3 scene_center{0.0, 0.0, 0.0};
  double max_color_from_depth_m = 1.0;  // depth-to-colour offset (exclusive)
  double max_abs_timestamp_s = 1e10;    // sensor time, |t| (~317 years)
  absl::Status Validate() const;
};

// Each names the field (`what`) and the limit that failed.
absl::Status CheckImageSize(int width, int height, const FrameLimits& limits,
                            const std::string& what);
absl::Status CheckIntrinsics(const PinholeCamera& camera, const FrameLimits& limits,
                             const std::string& what);
absl::Status CheckExposure(double exposure, const FrameLimits& limits);
absl::Status CheckDepthScale(double metres_per_unit, const FrameLimits& limits);
absl::Status CheckTimestamp(double timestamp_s, const FrameLimits& limits);
absl::Status CheckCameraPosition(const glm::dvec3& world_position, const FrameLimits& limits);
absl::Status CheckColorFromDepth(const Rigid3d& color_from_depth, const FrameLimits& limits);
// Every check above on a decoded frame (plus Frame::Validate).
absl::Status CheckFrame(const Frame& frame, const FrameLimits& limits);

}  // namespace exo
