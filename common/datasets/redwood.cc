#include "common/datasets/redwood.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "common/datasets/seven_scenes.h"
#include "common/datasets/text_util.h"
#include "common/io/depth_codec.h"
#include "common/io/image_file.h"

namespace exo {
namespace {

using datasets_internal::ParseDoubles;
using datasets_internal::ReadMatrix4x4;
using datasets_internal::ReadTextFile;
using datasets_internal::TokenizeLines;
namespace fs = std::filesystem;

// Regular files of `dir` whose extension is one of `exts`, sorted by name.
std::vector<std::string> ListFiles(const std::string& dir,
                                   std::initializer_list<const char*> exts) {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    if (!e.is_regular_file()) continue;
    std::string ext = e.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
    for (const char* x : exts)
      if (ext == x) out.push_back(e.path().string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

absl::StatusOr<Rigid3d> PoseFromRows(std::array<double, 16> m, const std::string& what) {
  EXO_RETURN_IF_ERROR(OrthonormalizeNearRotation(&m, what));
  auto pose = RigidFromRowMajor4x4(m);
  if (!pose.ok())
    return absl::InvalidArgumentError(absl::StrCat(what, ": ", pose.status().message()));
  return pose;
}


absl::StatusOr<PinholeCamera> CameraFromMatrix(const std::array<double, 16>& m, int w, int h,
                                               const std::string& what) {
  PinholeCamera c{m[0], m[5], m[2], m[6], w, h};
  if (auto s = c.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat(what, ": ", s.message()));
  return c;
}

}  // namespace

// ---- Redwood / Open3D ----

absl::StatusOr<std::unique_ptr<RedwoodReader>> RedwoodReader::Open(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    return absl::NotFoundError(absl::StrCat("Redwood directory not found: ", dir));
  auto r = std::unique_ptr<RedwoodReader>(new RedwoodReader());
  r->dir_ = dir;
  r->colour_ = ListFiles(dir + "/color", {".jpg", ".jpeg", ".png"});
  if (r->colour_.empty()) r->colour_ = ListFiles(dir + "/image", {".jpg", ".jpeg", ".png"});
  r->depth_ = ListFiles(dir + "/depth", {".png"});
  if (r->colour_.empty() || r->depth_.empty())
    return absl::NotFoundError(
        absl::StrCat(dir, ": expected color/ and depth/ folders with images"));
  if (r->colour_.size() != r->depth_.size())
    return absl::InvalidArgumentError(absl::StrCat(
        dir, ": ", r->colour_.size(), " colour images but ", r->depth_.size(), " depth images"));
  const std::vector<std::string> logs = ListFiles(dir, {".log"});
  if (logs.size() != 1)
    return absl::InvalidArgumentError(
        absl::StrCat(dir, ": expected one trajectory *.log, found ", logs.size()));
  EXO_ASSIGN_OR_RETURN(std::string text, ReadTextFile(logs[0]));
  const auto lines = TokenizeLines(text);
  if (lines.size() % 5 != 0)
    return absl::InvalidArgumentError(absl::StrCat(
        logs[0], ": expected 5 lines per frame (\"i j n\" + 4x4), got ", lines.size(), " lines"));
  for (size_t k = 0; k < lines.size(); k += 5) {
    std::array<double, 16> m{};
    for (int row = 0; row < 4; ++row) {
      const auto& line = lines[k + 1 + row];
      if (line.tokens.size() != 4)
        return absl::InvalidArgumentError(
            absl::StrCat(logs[0], ":", line.number, ": expected 4 numbers"));
      EXO_RETURN_IF_ERROR(ParseDoubles(line, 0, 4, m.data() + 4 * row, logs[0]));
    }
    EXO_ASSIGN_OR_RETURN(Rigid3d pose,
                         PoseFromRows(m, absl::StrCat(logs[0], ":", lines[k + 1].number)));
    r->poses_.push_back(pose);
  }
  if (r->poses_.size() < r->colour_.size())
    return absl::InvalidArgumentError(
        absl::StrCat(logs[0], ": ", r->poses_.size(), " poses for ", r->colour_.size(), " frames"));
  EXO_ASSIGN_OR_RETURN(ImageU8 c0, ReadColorImage(r->colour_[0]));
  r->camera_ = PinholeCamera{525.0, 525.0, 319.5, 239.5, c0.width(), c0.height()};
  r->default_intrinsics_ = true;
  for (const char* name : {"/intrinsic.json", "/camera_intrinsic.json"}) {
    if (!fs::exists(dir + name)) continue;
    EXO_ASSIGN_OR_RETURN(std::string js, ReadTextFile(dir + name));
    const nlohmann::json j = nlohmann::json::parse(js, nullptr, /*allow_exceptions=*/false);
    if (j.is_discarded() || !j.contains("intrinsic_matrix") || !j["intrinsic_matrix"].is_array() ||
        j["intrinsic_matrix"].size() != 9 || !j.contains("width") || !j.contains("height"))
      return absl::InvalidArgumentError(absl::StrCat(
          dir, name, ": expected {\"width\", \"height\", \"intrinsic_matrix\": [9 numbers]}"));
    const auto& k = j["intrinsic_matrix"];  // column-major 3x3
    r->camera_ = PinholeCamera{k[0].get<double>(), k[4].get<double>(),    k[6].get<double>(),
                               k[7].get<double>(), j["width"].get<int>(), j["height"].get<int>()};
    if (auto s = r->camera_.Validate(); !s.ok())
      return absl::InvalidArgumentError(absl::StrCat(dir, name, ": ", s.message()));
    r->default_intrinsics_ = false;
    break;
  }
  if (r->camera_.width != c0.width() || r->camera_.height != c0.height())
    return absl::InvalidArgumentError(absl::StrCat(dir, ": intrinsics are for ", r->camera_.width,
                                                   "x", r->camera_.height, ", the images are ",
                                                   c0.width(), "x", c0.height()));
  return r;
}

absl::StatusOr<Frame> RedwoodReader::Load(size_t i) const {
  if (i >= colour_.size())
    return absl::OutOfRangeError(absl::StrCat("frame ", i, " of ", colour_.size()));
  Frame f;
  f.sequence = i;
  f.timestamp_s = i / kFrameRateHz;
  f.color_camera = camera_;
  f.depth_camera = camera_;
  f.color_from_depth = Rigid3d::Identity();
  f.world_from_cam = poses_[i];
  EXO_ASSIGN_OR_RETURN(f.color, ReadColorImage(colour_[i]));
  EXO_ASSIGN_OR_RETURN(ImageU16 d, ReadPng16(depth_[i]));
  f.depth_m = DepthMetersFromU16(d, kDepthMetresPerUnit);
  if (auto s = f.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat(colour_[i], ": ", s.message()));
  return f;
}

// ---- ScanNet ----

absl::StatusOr<std::unique_ptr<ScanNetReader>> ScanNetReader::Open(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    return absl::NotFoundError(absl::StrCat("ScanNet directory not found: ", dir));
  auto r = std::unique_ptr<ScanNetReader>(new ScanNetReader());
  r->dir_ = dir;
  std::vector<int> indices;
  for (const std::string& p : ListFiles(dir + "/pose", {".txt"})) {
    const std::string stem = fs::path(p).stem().string();
    if (stem.empty() || !std::all_of(stem.begin(), stem.end(), ::isdigit))
      return absl::InvalidArgumentError(absl::StrCat(p, ": pose files are named N.txt"));
    indices.push_back(std::stoi(stem));
  }
  if (indices.empty()) return absl::NotFoundError(absl::StrCat(dir, ": no pose/N.txt files"));
  std::sort(indices.begin(), indices.end());
  const std::string in = dir + "/intrinsic/";
  EXO_ASSIGN_OR_RETURN(auto kc, ReadMatrix4x4(in + "intrinsic_color.txt"));
  EXO_ASSIGN_OR_RETURN(auto kd, ReadMatrix4x4(in + "intrinsic_depth.txt"));
  const std::string first = std::to_string(indices[0]);
  EXO_ASSIGN_OR_RETURN(ImageU8 c0, ReadColorImage(dir + "/color/" + first + ".jpg"));
  EXO_ASSIGN_OR_RETURN(ImageU16 d0, ReadPng16(dir + "/depth/" + first + ".png"));
  EXO_ASSIGN_OR_RETURN(r->color_camera_,
                       CameraFromMatrix(kc, c0.width(), c0.height(), in + "intrinsic_color.txt"));
  EXO_ASSIGN_OR_RETURN(r->depth_camera_,
                       CameraFromMatrix(kd, d0.width(), d0.height(), in + "intrinsic_depth.txt"));
  Rigid3d sensor_from_color, sensor_from_depth;
  if (fs::exists(in + "extrinsic_color.txt")) {
    EXO_ASSIGN_OR_RETURN(auto m, ReadMatrix4x4(in + "extrinsic_color.txt"));
    EXO_ASSIGN_OR_RETURN(sensor_from_color, PoseFromRows(m, in + "extrinsic_color.txt"));
  }
  if (fs::exists(in + "extrinsic_depth.txt")) {
    EXO_ASSIGN_OR_RETURN(auto m, ReadMatrix4x4(in + "extrinsic_depth.txt"));
    EXO_ASSIGN_OR_RETURN(sensor_from_depth, PoseFromRows(m, in + "extrinsic_depth.txt"));
  }
  r->color_from_depth_ = sensor_from_color.Inverse() * sensor_from_depth;
  for (int idx : indices) {
    const std::string path = dir + "/pose/" + std::to_string(idx) + ".txt";
    EXO_ASSIGN_OR_RETURN(auto m, ReadMatrix4x4(path));
    if (!std::all_of(m.begin(), m.end(), [](double v) { return std::isfinite(v); })) {
      ++r->skipped_;  // lost tracking: ScanNet writes -inf
      continue;
    }
    EXO_ASSIGN_OR_RETURN(Rigid3d pose, PoseFromRows(m, path));
    r->frames_.push_back({idx, pose});
  }
  if (r->frames_.empty())
    return absl::InvalidArgumentError(absl::StrCat(dir, ": no frame with a valid pose"));
  return r;
}

absl::StatusOr<Frame> ScanNetReader::Load(size_t i) const {
  if (i >= frames_.size())
    return absl::OutOfRangeError(absl::StrCat("frame ", i, " of ", frames_.size()));
  const Entry& e = frames_[i];
  const std::string n = std::to_string(e.index);
  Frame f;
  f.sequence = static_cast<uint64_t>(e.index);
  f.timestamp_s = e.index / kFrameRateHz;
  f.color_camera = color_camera_;
  f.depth_camera = depth_camera_;
  f.color_from_depth = color_from_depth_;
  f.world_from_cam = e.world_from_cam;
  EXO_ASSIGN_OR_RETURN(f.color, ReadColorImage(dir_ + "/color/" + n + ".jpg"));
  EXO_ASSIGN_OR_RETURN(ImageU16 d, ReadPng16(dir_ + "/depth/" + n + ".png"));
  f.depth_m = DepthMetersFromU16(d, kDepthMetresPerUnit);
  if (auto s = f.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat(dir_, "/color/", n, ".jpg: ", s.message()));
  return f;
}

}  // namespace exo
