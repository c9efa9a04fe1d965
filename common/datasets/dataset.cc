#include "common/datasets/dataset.h"

#include "absl/strings/str_cat.h"
#include "common/datasets/exo_layout.h"
#include "common/datasets/redwood.h"
#include "common/datasets/seven_scenes.h"
#include "common/datasets/text_util.h"
#include "common/datasets/tum.h"

namespace exo {
namespace {

// The frames of `inner` that are not held out, in order.
class HeldOutFilter final : public FrameSource {
 public:
  HeldOutFilter(std::unique_ptr<FrameSource> inner, int every, int offset)
      : inner_(std::move(inner)) {
    for (size_t i = 0; i < inner_->size(); ++i)
      if (!IsHeldOut(i, every, offset)) kept_.push_back(i);
    name_ = absl::StrCat(inner_->name(), " (every ", every, "th frame held out)");
  }
  size_t size() const override { return kept_.size(); }
  absl::StatusOr<Frame> Load(size_t i) const override {
    if (i >= kept_.size())
      return absl::OutOfRangeError(absl::StrCat("frame ", i, " of ", kept_.size()));
    return inner_->Load(kept_[i]);
  }
  std::string name() const override { return name_; }

 private:
  std::unique_ptr<FrameSource> inner_;
  std::vector<size_t> kept_;
  std::string name_;
};

}  // namespace

absl::Status DatasetOptions::Validate() const {
  if (format != "7scenes" && format != "tum" && format != "exo" && format != "redwood" &&
      format != "scannet")
    return absl::InvalidArgumentError(absl::StrCat("unknown dataset format '", format,
                                                   "' (7scenes, tum, redwood, scannet, exo)"));
  if (!intrinsics.empty() && intrinsics.size() != 4)
    return absl::InvalidArgumentError("intrinsics: give fx,fy,cx,cy (4 numbers)");
  if (!intrinsics.empty() && !camera_file.empty())
    return absl::InvalidArgumentError("give intrinsics or a camera file, not both");
  if ((!intrinsics.empty() || !camera_file.empty()) && format != "tum")
    return absl::InvalidArgumentError("intrinsics / camera file only apply to --format=tum");
  if (hold_out_every == 1 || hold_out_every < 0)
    return absl::InvalidArgumentError("hold_out_every must be 0 (off) or >= 2");
  if (hold_out_offset < -1 || (hold_out_every >= 2 && hold_out_offset >= hold_out_every))
    return absl::InvalidArgumentError(absl::StrCat("hold_out_offset ", hold_out_offset,
                                                   " must be -1 (last) or 0..hold_out_every-1"));
  return absl::OkStatus();
}

absl::StatusOr<PinholeCamera> ReadCameraFile(const std::string& path) {
  EXO_ASSIGN_OR_RETURN(std::string text, datasets_internal::ReadTextFile(path));
  const auto lines = datasets_internal::TokenizeLines(text);
  if (lines.size() != 1 || (lines[0].tokens.size() != 4 && lines[0].tokens.size() != 6))
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": expected one line \"fx fy cx cy [width height]\""));
  double v[6] = {0, 0, 0, 0, 640, 480};
  EXO_RETURN_IF_ERROR(
      datasets_internal::ParseDoubles(lines[0], 0, lines[0].tokens.size(), v, path));
  PinholeCamera c{v[0], v[1], v[2], v[3], static_cast<int>(v[4]), static_cast<int>(v[5])};
  if (auto s = c.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat(path, ": ", s.message()));
  return c;
}

absl::StatusOr<std::unique_ptr<FrameSource>> OpenDataset(const std::string& dir,
                                                         const DatasetOptions& o,
                                                         std::vector<std::string>* warnings) {
  EXO_RETURN_IF_ERROR(o.Validate());
  std::unique_ptr<FrameSource> source;
  if (o.format == "7scenes") {
    SevenScenesOptions so;
    so.register_depth = o.register_depth;
    EXO_ASSIGN_OR_RETURN(source, SevenScenesReader::Open(dir, so));
  } else if (o.format == "tum") {
    TumOptions to;
    if (!o.intrinsics.empty()) {
      to.camera.fx = o.intrinsics[0];
      to.camera.fy = o.intrinsics[1];
      to.camera.cx = o.intrinsics[2];
      to.camera.cy = o.intrinsics[3];
    } else if (!o.camera_file.empty()) {
      EXO_ASSIGN_OR_RETURN(to.camera, ReadCameraFile(o.camera_file));
    } else if (warnings != nullptr) {
      warnings->push_back(
          "TUM: no --intrinsics or --camera_file given: using TUM's defaults fx = fy = 525, "
          "cx = 319.5, cy = 239.5 (wrong for most sensors: fr1 517.3 516.5 318.6 255.3, fr2 "
          "520.9 521.0 325.1 249.7, fr3 535.4 539.2 320.1 247.6; 7-Scenes in TUM layout 585 "
          "585 320 240)");
    }
    EXO_ASSIGN_OR_RETURN(source, TumReader::Open(dir, to));
  } else if (o.format == "redwood") {
    EXO_ASSIGN_OR_RETURN(auto r, RedwoodReader::Open(dir));
    if (r->default_intrinsics() && warnings != nullptr)
      warnings->push_back(
          "Redwood: no intrinsic.json in the folder: using PrimeSense defaults "
          "fx = fy = 525, cx = 319.5, cy = 239.5");
    source = std::move(r);
  } else if (o.format == "scannet") {
    EXO_ASSIGN_OR_RETURN(auto r, ScanNetReader::Open(dir));
    if (r->skipped_invalid_pose() > 0 && warnings != nullptr)
      warnings->push_back(absl::StrCat("ScanNet: ", r->skipped_invalid_pose(),
                                       " frames without a valid pose (-inf) left out"));
    source = std::move(r);
  } else {
    EXO_ASSIGN_OR_RETURN(source, ExoLayoutReader::Open(dir));
  }
  if (o.hold_out_every >= 2)
    source = std::make_unique<HeldOutFilter>(std::move(source), o.hold_out_every,
                                             o.hold_out_offset);
  return source;
}

}  // namespace exo
