// Exoview's own on-disk frame layout (written by the synthetic-scene generator and by tools,
// read back by tests, benchmarks and the uploader):
//
//   DIR/intrinsics.txt       key/value text, one dataset-wide camera setup:
//                              exoview_layout 1
//                              color fx fy cx cy width height
//                              depth fx fy cx cy width height
//                              color_from_depth r00 r01 r02 tx r10 r11 r12 ty r20 r21 r22 tz
//                              depth_metres_per_unit 0.001
//   DIR/poses.txt            one line per frame, appended in write order:
//                              seq timestamp_s r00 r01 r02 tx r10 r11 r12 ty r20 r21 r22 tz
//                              exposure   (world_from_cam row-major 3x4; exposure or "nan")
//   DIR/frames/NNNNNN.color.jpg  (or .color.png, lossless, for ground truth), NNNNNN = seq
//   DIR/frames/NNNNNN.depth.png  16-bit PNG, z-depth in depth_metres_per_unit (default mm,
//                                0 = invalid, >65.535 m -> 0), readable by any image tool.
//
// Decision: depth is a 16-bit PNG (not our .exd codec) so the layout is inspectable with
// standard tools; the wire and the view store use common/io/depth_codec.h. Depth in mm caps
// at 65.5 m: for larger scenes pass depth_metres_per_unit (e.g. 0.002).
// The writer is stateless per frame (WriteExoFrame appends), so a generator can stream frames.
// All frames in DIR must share the intrinsics; a mismatch is an error.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/datasets/frame_source.h"

namespace exo {

enum class ExoColorFormat { kJpeg, kPng };

struct ExoLayoutOptions {
  ExoColorFormat color_format = ExoColorFormat::kJpeg;
  int jpeg_quality = 95;
  double depth_metres_per_unit = 0.001;
  absl::Status Validate() const;
};

// Writes one frame: creates DIR and DIR/frames if needed, writes intrinsics.txt on the first
// frame (later frames must match it, including depth_metres_per_unit), the colour and depth
// images and appends a line to poses.txt. The frame must pass Frame::Validate() and have depth.
absl::Status WriteExoFrame(const std::string& dir, const Frame& frame,
                           const ExoLayoutOptions& options = {});

// Convenience wrapper holding the directory and options.
class ExoLayoutWriter {
 public:
  ExoLayoutWriter(std::string dir, ExoLayoutOptions options = {})
      : dir_(std::move(dir)), options_(options) {}
  absl::Status Write(const Frame& frame) { return WriteExoFrame(dir_, frame, options_); }
  const std::string& dir() const { return dir_; }

 private:
  std::string dir_;
  ExoLayoutOptions options_;
};

class ExoLayoutReader : public FrameSource {
 public:
  // Reads intrinsics.txt and poses.txt (frames sorted by seq; duplicate seq -> error).
  static absl::StatusOr<std::unique_ptr<ExoLayoutReader>> Open(const std::string& dir);

  size_t size() const override { return entries_.size(); }
  absl::StatusOr<Frame> Load(size_t i) const override;
  std::string name() const override { return "exo:" + dir_; }

  struct Entry {
    uint64_t sequence = 0;
    double timestamp_s = 0;
    Rigid3d world_from_cam;
    std::optional<double> exposure;
  };
  const Entry& entry(size_t i) const { return entries_[i]; }
  const PinholeCamera& color_camera() const { return color_camera_; }
  const PinholeCamera& depth_camera() const { return depth_camera_; }
  double depth_metres_per_unit() const { return depth_metres_per_unit_; }

 private:
  std::string dir_;
  PinholeCamera color_camera_, depth_camera_;
  Rigid3d color_from_depth_;
  double depth_metres_per_unit_ = 0.001;
  std::vector<Entry> entries_;
};

}  // namespace exo
