// Readers for the two RGB-D layouts users bring most besides 7-Scenes and TUM (issue 14):
//
// Redwood / Open3D: color/ (jpg or png) and depth/ (16-bit png, 1 mm units) with one image per
// frame, paired in sorted file-name order, plus a trajectory `*.log` in the folder (Open3D's
// PinholeCameraTrajectory text: per frame a metadata line "i j n" and 4 lines of the 4x4
// camera-to-world matrix; frame k of the log is the k-th image pair). Intrinsics from an Open3D
// `intrinsic.json` / `camera_intrinsic.json` in the folder ({"width", "height",
// "intrinsic_matrix": 9 numbers, column-major}); without one, PrimeSense defaults (525, 525,
// 319.5, 239.5, what Open3D assumes for Redwood) with a warning. Depth is registered to colour
// (Redwood's and Open3D's convention): one camera, color_from_depth = identity.
//
// ScanNet, as exported by its SensReader (`reader.py --export_color_images --export_depth_images
// --export_poses --export_intrinsics`): color/N.jpg, depth/N.png (16-bit, 1 mm), pose/N.txt (4x4
// camera-to-world of the colour camera), intrinsic/intrinsic_color.txt and intrinsic_depth.txt
// (4x4, K in the top-left 3x3), optional intrinsic/extrinsic_color.txt and extrinsic_depth.txt
// (4x4 camera-to-sensor; color_from_depth = inverse(extrinsic_color) * extrinsic_depth, identity
// when absent). Frames are numbered N = 0, 1, ... (sorted numerically); a frame whose pose is
// invalid (ScanNet writes -inf for lost tracking) is skipped at Open() and counted. Colour and
// depth keep their own resolutions and cameras.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "common/datasets/frame_source.h"

namespace exo {

class RedwoodReader : public FrameSource {
 public:
  static constexpr double kDepthMetresPerUnit = 0.001;
  static constexpr double kFrameRateHz = 30.0;
  static absl::StatusOr<std::unique_ptr<RedwoodReader>> Open(const std::string& dir);
  size_t size() const override { return colour_.size(); }
  absl::StatusOr<Frame> Load(size_t i) const override;
  std::string name() const override { return "redwood:" + dir_; }
  const PinholeCamera& camera() const { return camera_; }
  bool default_intrinsics() const { return default_intrinsics_; }

 private:
  std::string dir_;
  PinholeCamera camera_;
  bool default_intrinsics_ = false;
  std::vector<std::string> colour_, depth_;
  std::vector<Rigid3d> poses_;
};

class ScanNetReader : public FrameSource {
 public:
  static constexpr double kDepthMetresPerUnit = 0.001;
  static constexpr double kFrameRateHz = 30.0;
  static absl::StatusOr<std::unique_ptr<ScanNetReader>> Open(const std::string& dir);
  size_t size() const override { return frames_.size(); }
  absl::StatusOr<Frame> Load(size_t i) const override;
  std::string name() const override { return "scannet:" + dir_; }
  size_t skipped_invalid_pose() const { return skipped_; }
  const PinholeCamera& color_camera() const { return color_camera_; }
  const PinholeCamera& depth_camera() const { return depth_camera_; }

 private:
  struct Entry {
    int index = 0;
    Rigid3d world_from_cam;
  };
  std::string dir_;
  PinholeCamera color_camera_, depth_camera_;
  Rigid3d color_from_depth_;
  std::vector<Entry> frames_;
  size_t skipped_ = 0;
};

}  // namespace exo
