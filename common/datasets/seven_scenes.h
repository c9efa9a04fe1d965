// Reader for the Microsoft 7-Scenes layout: frame-NNNNNN.{color.jpg,depth.png,pose.txt} plus
// camera-intrinsics.txt (3x3 K). Depth: 16-bit PNG in millimetres, 0 = invalid. Pose: 4x4
// camera-to-world, validated (orthonormal rotation, last row 0 0 0 1).
//
// Caveat of the data (see ../shared/data/README.md): K and the pose belong to the DEPTH camera
// and colour is NOT registered to depth (edges are offset by 10-20 px). The data gives no colour
// intrinsics or extrinsic, so the reader sets color_camera = depth_camera = K and
// color_from_depth = identity, as the data's README prescribes; world_from_cam is the depth
// camera's pose. 7-Scenes has no timestamps: timestamp_s = index / 30 (Kinect v1 rate).
//
// With SevenScenesOptions{.register_depth = true} the reader returns REGISTERED frames instead
// (rgbd_registration.h, RegisterFrame with the calibration estimated from the data,
// SevenScenesKinectV1Calibration()): colour camera K for both colour and depth, depth warped
// into the colour camera, world_from_cam = pose of the COLOUR camera
// (= world_from_depth * inverse(color_from_depth)); camera() and LoadPose() follow.
#pragma once

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/datasets/frame_source.h"
#include "common/datasets/rgbd_registration.h"

namespace exo {

struct SevenScenesOptions {
  bool register_depth = false;  // default: raw frames, as before
  // Calibration used when register_depth; nullopt = SevenScenesKinectV1Calibration().
  std::optional<DepthColorCalibration> calibration;
};

class SevenScenesReader : public FrameSource {
 public:
  static constexpr double kDepthMetresPerUnit = 0.001;
  static constexpr double kFrameRateHz = 30.0;

  // Scans `dir` for frame-*.color.jpg and reads camera-intrinsics.txt. Errors: NotFound if the
  // directory, the intrinsics or every frame is missing; InvalidArgument for a malformed K.
  static absl::StatusOr<std::unique_ptr<SevenScenesReader>> Open(const std::string& dir);
  // Errors as above, plus InvalidArgument for a calibration whose colour size differs from the
  // images'.
  static absl::StatusOr<std::unique_ptr<SevenScenesReader>> Open(const std::string& dir,
                                                                 const SevenScenesOptions& options);

  size_t size() const override { return indices_.size(); }
  absl::StatusOr<Frame> Load(size_t i) const override;
  std::string name() const override { return "7scenes:" + dir_; }

  int frame_index(size_t i) const { return indices_[i]; }  // the NNNNNN of frame i
  // The camera of the frames' images: the depth K for raw frames, the colour camera when
  // registering.
  const PinholeCamera& camera() const { return registered_ ? calibration_.color_camera : camera_; }
  const PinholeCamera& depth_camera() const { return camera_; }  // the data's K
  bool registered() const { return registered_; }
  // Only the pose of frame i (cheap: no image decoding); the same world_from_cam as Load(i).
  absl::StatusOr<Rigid3d> LoadPose(size_t i) const;

 private:
  std::string dir_;
  PinholeCamera camera_;  // depth camera (the data's K)
  bool registered_ = false;
  DepthColorCalibration calibration_;
  std::vector<int> indices_;
};

// Real 7-Scenes poses (KinectFusion, printed with limited precision) are not orthonormal to
// kRotationTolerance (frame 0 of redkitchen: max|R^T R - I| = 1.1e-4). A rotation within
// kPoseRepairTolerance of orthonormal (and det > 0) is replaced by its nearest rotation (polar
// decomposition, SVD); anything farther, or NaN/Inf, is an error.
inline constexpr double kPoseRepairTolerance = 1e-2;
absl::Status OrthonormalizeNearRotation(std::array<double, 16>* row_major_4x4,
                                        const std::string& what);

// Parses a whitespace-separated 4x4 row-major matrix file into a validated rigid transform
// (near-orthonormal rotations repaired as above).
absl::StatusOr<Rigid3d> ReadPoseFile4x4(const std::string& path);

}  // namespace exo
