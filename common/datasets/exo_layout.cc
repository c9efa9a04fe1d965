#include "common/datasets/exo_layout.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>

#include "absl/strings/str_format.h"
#include "common/datasets/text_util.h"
#include "common/io/depth_codec.h"
#include "common/io/image_file.h"

namespace exo {

using datasets_internal::FileExists;
using datasets_internal::ParseDoubles;
using datasets_internal::ReadTextFile;
using datasets_internal::TokenizeLines;

namespace {

constexpr int kLayoutVersion = 1;

std::string FrameStem(const std::string& dir, uint64_t seq) {
  return absl::StrFormat("%s/frames/%06u", dir, seq);
}

// Row-major 3x4 [R | t] of a rigid transform, full double precision.
std::string Rows3x4(const Rigid3d& t) {
  const glm::dmat3 r = t.RotationMatrix();  // glm: r[col][row]
  std::string s;
  for (int row = 0; row < 3; ++row)
    absl::StrAppendFormat(&s, "%s%.17g %.17g %.17g %.17g", row ? " " : "", r[0][row], r[1][row],
                          r[2][row], t.translation[row]);
  return s;
}

absl::StatusOr<Rigid3d> RigidFrom3x4(const double* v, const std::string& where) {
  std::array<double, 16> m{v[0], v[1], v[2],  v[3],  v[4], v[5], v[6], v[7],
                           v[8], v[9], v[10], v[11], 0.0,  0.0,  0.0,  1.0};
  auto r = RigidFromRowMajor4x4(m);
  if (!r.ok()) return absl::InvalidArgumentError(absl::StrCat(where, ": ", r.status().message()));
  return r;
}

std::string CameraLine(const char* key, const PinholeCamera& c) {
  return absl::StrFormat("%s %.17g %.17g %.17g %.17g %d %d\n", key, c.fx, c.fy, c.cx, c.cy,
                         c.width, c.height);
}

std::string IntrinsicsText(const Frame& f, double metres_per_unit) {
  return absl::StrCat("exoview_layout ", kLayoutVersion, "\n", CameraLine("color", f.color_camera),
                      CameraLine("depth", f.depth_camera), "color_from_depth ",
                      Rows3x4(f.color_from_depth), "\n",
                      absl::StrFormat("depth_metres_per_unit %.17g\n", metres_per_unit));
}

}  // namespace

absl::Status ExoLayoutOptions::Validate() const {
  if (jpeg_quality < 1 || jpeg_quality > 100)
    return absl::InvalidArgumentError(absl::StrCat("jpeg_quality ", jpeg_quality, " not in [1, 100]"));
  if (!(depth_metres_per_unit > 0.0) || !std::isfinite(depth_metres_per_unit))
    return absl::InvalidArgumentError("depth_metres_per_unit must be > 0");
  return absl::OkStatus();
}

absl::Status WriteExoFrame(const std::string& dir, const Frame& frame,
                           const ExoLayoutOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  if (auto s = frame.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("frame ", frame.sequence, ": ", s.message()));
  if (frame.depth_m.empty())
    return absl::InvalidArgumentError(
        absl::StrCat("frame ", frame.sequence, ": the Exoview layout needs a depth image"));
  std::error_code ec;
  std::filesystem::create_directories(dir + "/frames", ec);
  if (ec)
    return absl::PermissionDeniedError(absl::StrCat("cannot create ", dir, "/frames: ", ec.message()));

  const std::string intr_path = dir + "/intrinsics.txt";
  const std::string intr = IntrinsicsText(frame, options.depth_metres_per_unit);
  if (FileExists(intr_path)) {
    EXO_ASSIGN_OR_RETURN(std::string existing, ReadTextFile(intr_path));
    if (existing != intr)
      return absl::InvalidArgumentError(absl::StrCat(
          "frame ", frame.sequence, ": intrinsics/extrinsic/depth scale differ from ", intr_path,
          " (one camera setup per directory)"));
  } else {
    EXO_RETURN_IF_ERROR(WriteFileBytes(
        intr_path, std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(intr.data()),
                                            intr.size())));
  }

  // Images first, then the pose line: a reader never sees a pose without its images.
  const std::string stem = FrameStem(dir, frame.sequence);
  EXO_RETURN_IF_ERROR(WriteColorImage(
      stem + (options.color_format == ExoColorFormat::kJpeg ? ".color.jpg" : ".color.png"),
      frame.color, options.jpeg_quality));
  EXO_RETURN_IF_ERROR(
      WritePng16(stem + ".depth.png", DepthU16FromMeters(frame.depth_m, options.depth_metres_per_unit)));

  const std::string line = absl::StrFormat(
      "%u %.9f %s %s\n", frame.sequence, frame.timestamp_s, Rows3x4(frame.world_from_cam),
      frame.exposure ? absl::StrFormat("%.17g", *frame.exposure) : std::string("nan"));
  FILE* f = std::fopen((dir + "/poses.txt").c_str(), "ab");
  if (f == nullptr) return absl::PermissionDeniedError(absl::StrCat("cannot append to ", dir, "/poses.txt"));
  const bool ok = std::fwrite(line.data(), 1, line.size(), f) == line.size();
  if (std::fclose(f) != 0 || !ok)
    return absl::InternalError(absl::StrCat("short write to ", dir, "/poses.txt"));
  return absl::OkStatus();
}

absl::StatusOr<std::unique_ptr<ExoLayoutReader>> ExoLayoutReader::Open(const std::string& dir) {
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec))
    return absl::NotFoundError(absl::StrCat("Exoview layout directory not found: ", dir));
  auto reader = std::unique_ptr<ExoLayoutReader>(new ExoLayoutReader());
  reader->dir_ = dir;

  const std::string intr_path = dir + "/intrinsics.txt";
  EXO_ASSIGN_OR_RETURN(std::string intr, ReadTextFile(intr_path));
  bool have_color = false, have_depth = false, have_version = false;
  for (const auto& line : TokenizeLines(intr)) {
    const absl::string_view key = line.tokens[0];
    if (key == "exoview_layout") {
      double v;
      EXO_RETURN_IF_ERROR(ParseDoubles(line, 1, 1, &v, intr_path));
      if (v != kLayoutVersion)
        return absl::InvalidArgumentError(absl::StrCat(intr_path, ": layout version ", v,
                                                       ", this build reads ", kLayoutVersion));
      have_version = true;
    } else if (key == "color" || key == "depth") {
      double v[6];
      EXO_RETURN_IF_ERROR(ParseDoubles(line, 1, 6, v, intr_path));
      PinholeCamera c{v[0], v[1], v[2], v[3], static_cast<int>(v[4]), static_cast<int>(v[5])};
      if (auto s = c.Validate(); !s.ok())
        return absl::InvalidArgumentError(absl::StrCat(intr_path, ":", line.number, ": ", s.message()));
      (key == "color" ? reader->color_camera_ : reader->depth_camera_) = c;
      (key == "color" ? have_color : have_depth) = true;
    } else if (key == "color_from_depth") {
      double v[12];
      EXO_RETURN_IF_ERROR(ParseDoubles(line, 1, 12, v, intr_path));
      EXO_ASSIGN_OR_RETURN(reader->color_from_depth_,
                           RigidFrom3x4(v, absl::StrCat(intr_path, ":", line.number)));
    } else if (key == "depth_metres_per_unit") {
      EXO_RETURN_IF_ERROR(ParseDoubles(line, 1, 1, &reader->depth_metres_per_unit_, intr_path));
      if (!(reader->depth_metres_per_unit_ > 0.0))
        return absl::InvalidArgumentError(absl::StrCat(intr_path, ": depth_metres_per_unit <= 0"));
    } else {
      return absl::InvalidArgumentError(
          absl::StrCat(intr_path, ":", line.number, ": unknown key '", key, "'"));
    }
  }
  if (!have_version || !have_color || !have_depth)
    return absl::InvalidArgumentError(
        absl::StrCat(intr_path, ": needs 'exoview_layout', 'color' and 'depth' lines"));

  const std::string poses_path = dir + "/poses.txt";
  EXO_ASSIGN_OR_RETURN(std::string poses, ReadTextFile(poses_path));
  for (const auto& line : TokenizeLines(poses)) {
    double v[15];
    if (line.tokens.size() != 15)
      return absl::InvalidArgumentError(absl::StrCat(poses_path, ":", line.number,
                                                     ": expected 15 fields, got ",
                                                     line.tokens.size()));
    EXO_RETURN_IF_ERROR(ParseDoubles(line, 0, 15, v, poses_path));
    if (!(v[0] >= 0.0) || v[0] != std::floor(v[0]) || v[0] > 9.0e15)
      return absl::InvalidArgumentError(
          absl::StrCat(poses_path, ":", line.number, ": bad sequence number"));
    if (!std::isfinite(v[1]))
      return absl::InvalidArgumentError(absl::StrCat(poses_path, ":", line.number, ": bad timestamp"));
    Entry e;
    e.sequence = static_cast<uint64_t>(v[0]);
    e.timestamp_s = v[1];
    EXO_ASSIGN_OR_RETURN(e.world_from_cam,
                         RigidFrom3x4(v + 2, absl::StrCat(poses_path, ":", line.number)));
    if (std::isfinite(v[14])) e.exposure = v[14];
    reader->entries_.push_back(e);
  }
  std::sort(reader->entries_.begin(), reader->entries_.end(),
            [](const Entry& a, const Entry& b) { return a.sequence < b.sequence; });
  for (size_t i = 1; i < reader->entries_.size(); ++i)
    if (reader->entries_[i].sequence == reader->entries_[i - 1].sequence)
      return absl::InvalidArgumentError(absl::StrCat(poses_path, ": sequence number ",
                                                     reader->entries_[i].sequence,
                                                     " appears twice"));
  return reader;
}

absl::StatusOr<Frame> ExoLayoutReader::Load(size_t i) const {
  if (i >= entries_.size())
    return absl::OutOfRangeError(absl::StrCat("frame ", i, " of ", entries_.size()));
  const Entry& e = entries_[i];
  const std::string stem = FrameStem(dir_, e.sequence);
  Frame f;
  f.sequence = e.sequence;
  f.timestamp_s = e.timestamp_s;
  f.color_camera = color_camera_;
  f.depth_camera = depth_camera_;
  f.color_from_depth = color_from_depth_;
  f.world_from_cam = e.world_from_cam;
  f.exposure = e.exposure;
  const std::string jpg = stem + ".color.jpg", png = stem + ".color.png";
  if (FileExists(jpg)) {
    EXO_ASSIGN_OR_RETURN(f.color, ReadColorImage(jpg));
  } else if (FileExists(png)) {
    EXO_ASSIGN_OR_RETURN(f.color, ReadColorImage(png));
  } else {
    return absl::NotFoundError(absl::StrCat("frame ", e.sequence, ": neither ", jpg, " nor ", png,
                                            " exists"));
  }
  EXO_ASSIGN_OR_RETURN(ImageU16 raw, ReadPng16(stem + ".depth.png"));
  f.depth_m = DepthMetersFromU16(raw, depth_metres_per_unit_);
  if (auto s = f.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat(stem, ": ", s.message()));
  return f;
}

}  // namespace exo
