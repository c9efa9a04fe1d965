#include "common/datasets/tum.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "common/datasets/text_util.h"
#include "common/io/depth_codec.h"
#include "common/io/image_file.h"
#include "common/pose_stream.h"

namespace exo {

using datasets_internal::ParseDoubles;
using datasets_internal::ReadTextFile;
using datasets_internal::TokenizeLines;

namespace {

struct Stamped {
  double t;
  std::string file;
};

absl::StatusOr<std::vector<Stamped>> ReadList(const std::string& path) {
  EXO_ASSIGN_OR_RETURN(std::string text, ReadTextFile(path));
  std::vector<Stamped> out;
  for (const auto& line : TokenizeLines(text)) {
    double t;
    EXO_RETURN_IF_ERROR(ParseDoubles(line, 0, 1, &t, path));
    if (line.tokens.size() < 2)
      return absl::InvalidArgumentError(absl::StrCat(path, ":", line.number, ": no file name"));
    if (!std::isfinite(t))
      return absl::InvalidArgumentError(absl::StrCat(path, ":", line.number, ": bad timestamp"));
    out.push_back({t, std::string(line.tokens[1])});
  }
  std::stable_sort(out.begin(), out.end(),
                   [](const Stamped& a, const Stamped& b) { return a.t < b.t; });
  return out;
}

}  // namespace

absl::Status TumOptions::Validate() const {
  if (!(max_depth_dt_s >= 0.0) || !(pose_tolerance_s >= 0.0))
    return absl::InvalidArgumentError("TUM tolerances must be >= 0");
  if (!(depth_metres_per_unit > 0.0) || !std::isfinite(depth_metres_per_unit))
    return absl::InvalidArgumentError("TUM depth_metres_per_unit must be > 0");
  return camera.Validate();
}

absl::StatusOr<std::unique_ptr<TumReader>> TumReader::Open(const std::string& dir,
                                                           const TumOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec))
    return absl::NotFoundError(absl::StrCat("TUM directory not found: ", dir));
  auto reader = std::unique_ptr<TumReader>(new TumReader());
  reader->dir_ = dir;
  reader->options_ = options;
  EXO_ASSIGN_OR_RETURN(const std::vector<Stamped> rgb, ReadList(dir + "/rgb.txt"));
  EXO_ASSIGN_OR_RETURN(const std::vector<Stamped> depth, ReadList(dir + "/depth.txt"));

  const std::string gt_path = dir + "/groundtruth.txt";
  EXO_ASSIGN_OR_RETURN(std::string gt_text, ReadTextFile(gt_path));
  const auto gt_lines = TokenizeLines(gt_text);
  PoseStream poses(std::max<size_t>(1, gt_lines.size()));
  for (const auto& line : gt_lines) {
    double v[8];  // t tx ty tz qx qy qz qw
    EXO_RETURN_IF_ERROR(ParseDoubles(line, 0, 8, v, gt_path));
    glm::dquat q(v[7], v[4], v[5], v[6]);  // glm: (w, x, y, z)
    const double norm = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
    if (!std::isfinite(norm) || std::abs(norm - 1.0) > 1e-2)
      return absl::InvalidArgumentError(absl::StrCat(gt_path, ":", line.number,
                                                     ": quaternion norm ", norm, " is not ~1"));
    q = q / norm;  // TUM prints 4 decimals
    auto s = poses.Add(v[0], Rigid3d{q, glm::dvec3(v[1], v[2], v[3])});
    if (!s.ok())
      return absl::InvalidArgumentError(absl::StrCat(gt_path, ":", line.number, ": ", s.message()));
  }

  for (const Stamped& c : rgb) {
    // Nearest depth timestamp.
    auto it = std::lower_bound(depth.begin(), depth.end(), c.t,
                               [](const Stamped& d, double t) { return d.t < t; });
    const Stamped* best = nullptr;
    if (it != depth.end()) best = &*it;
    if (it != depth.begin() && (best == nullptr || c.t - (it - 1)->t < best->t - c.t))
      best = &*(it - 1);
    if (best == nullptr || std::abs(best->t - c.t) > options.max_depth_dt_s) {
      ++reader->skipped_no_depth_;
      continue;
    }
    auto pose = poses.Interpolate(c.t, options.pose_tolerance_s);
    if (!pose.ok()) {
      ++reader->skipped_no_pose_;
      continue;
    }
    reader->frames_.push_back({c.t, best->t, c.file, best->file, *pose});
  }
  if (reader->frames_.empty())
    return absl::NotFoundError(absl::StrCat(
        "no usable frames in ", dir, ": ", rgb.size(), " rgb images, ",
        reader->skipped_no_depth_, " without depth within ", options.max_depth_dt_s, " s, ",
        reader->skipped_no_pose_, " without a pose within ", options.pose_tolerance_s, " s"));
  return reader;
}

absl::StatusOr<Frame> TumReader::Load(size_t i) const {
  if (i >= frames_.size())
    return absl::OutOfRangeError(absl::StrCat("frame ", i, " of ", frames_.size()));
  const Entry& e = frames_[i];
  Frame f;
  f.sequence = i;
  f.timestamp_s = e.rgb_t;
  f.color_camera = options_.camera;
  f.depth_camera = options_.camera;  // TUM depth is registered to colour
  f.world_from_cam = e.world_from_cam;
  EXO_ASSIGN_OR_RETURN(f.color, ReadColorImage(dir_ + "/" + e.rgb_file));
  EXO_ASSIGN_OR_RETURN(ImageU16 raw, ReadPng16(dir_ + "/" + e.depth_file));
  f.depth_m = DepthMetersFromU16(raw, options_.depth_metres_per_unit);
  if (auto s = f.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat(dir_, "/", e.rgb_file, ": ", s.message()));
  return f;
}

}  // namespace exo
