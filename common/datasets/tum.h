// Reader for the TUM RGB-D benchmark layout: rgb.txt and depth.txt ("timestamp filename" lines,
// '#' comments), groundtruth.txt ("timestamp tx ty tz qx qy qz qw", camera-to-world), depth PNG
// with 5000 units per metre. Each rgb image is associated with the depth image of nearest
// timestamp (within max_depth_dt_s); its pose is interpolated at the rgb timestamp from the
// ground truth through a PoseStream (SLERP + lerp, within pose_tolerance_s). Colour images
// without a depth match or a pose are left out at Open() and counted (skipped_no_depth(),
// skipped_no_pose()). TUM's depth is registered to colour: depth_camera = color_camera.
// Ground-truth quaternions are printed with 4 decimals, so they are renormalised when their
// norm is within 1e-2 of 1 (farther -> error); NaN -> error.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "common/datasets/frame_source.h"

namespace exo {

struct TumOptions {
  double max_depth_dt_s = 0.02;     // rgb <-> depth association window
  double pose_tolerance_s = 0.02;   // PoseStream::Interpolate tolerance
  double depth_metres_per_unit = 1.0 / 5000.0;
  // Intrinsics; TUM's "ROS default" for 640x480 unless the caller knows the sensor
  // (fr1: 517.3 516.5 318.6 255.3; fr2: 520.9 521.0 325.1 249.7; fr3: 535.4 539.2 320.1 247.6).
  PinholeCamera camera{525.0, 525.0, 319.5, 239.5, 640, 480};
  absl::Status Validate() const;
};

class TumReader : public FrameSource {
 public:
  static absl::StatusOr<std::unique_ptr<TumReader>> Open(const std::string& dir,
                                                         const TumOptions& options = {});

  size_t size() const override { return frames_.size(); }
  absl::StatusOr<Frame> Load(size_t i) const override;
  std::string name() const override { return "tum:" + dir_; }

  size_t skipped_no_depth() const { return skipped_no_depth_; }
  size_t skipped_no_pose() const { return skipped_no_pose_; }

  struct Entry {
    double rgb_t = 0, depth_t = 0;
    std::string rgb_file, depth_file;  // relative to dir
    Rigid3d world_from_cam;
  };
  const Entry& entry(size_t i) const { return frames_[i]; }

 private:
  std::string dir_;
  TumOptions options_;
  std::vector<Entry> frames_;
  size_t skipped_no_depth_ = 0, skipped_no_pose_ = 0;
};

}  // namespace exo
