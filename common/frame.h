// The one in-memory frame type every stage uses (ingest, geometry, planning, refinement,
// inpainting, evaluation): decoded colour, depth in metres (z-depth, 0 = invalid), intrinsics,
// camera-to-world pose, timestamp and sequence number.
#pragma once

#include <cstdint>
#include <optional>

#include "common/camera.h"
#include "common/image.h"
#include "common/rigid3.h"

namespace exo {

struct Frame {
  uint64_t sequence = 0;
  double timestamp_s = 0.0;
  PinholeCamera color_camera;  // intrinsics of `color`
  // Depth camera, when depth is not registered to colour (7-Scenes); otherwise == color_camera.
  PinholeCamera depth_camera;
  // depth-camera -> colour-camera extrinsic (identity when registered).
  Rigid3d color_from_depth;
  Rigid3d world_from_cam;  // pose of the colour camera
  ImageU8 color;           // RGB8, sRGB
  ImageF depth_m;          // z-depth in metres, 0 = invalid; size of depth_camera
  std::optional<double> exposure;  // optional metadata (relative exposure)

  // Checks sizes, intrinsics, finiteness of the pose. Clear message on failure.
  absl::Status Validate() const;
};

}  // namespace exo
