// One entry point to the dataset readers, used by every tool that reads a dataset folder
// (exoview_uploader, exoview_eval): the format name -> the FrameSource of that format, with the
// product's defaults (7-Scenes depth registered to colour; TUM intrinsics from a flag or a camera
// file, with a warning when TUM's 525 / 319.5 defaults are used) and exoview_eval's hold-out split.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/datasets/frame_source.h"

namespace exo {

struct DatasetOptions {
  std::string format = "7scenes";  // 7scenes | tum | redwood | scannet | exo (redwood.h)
  bool register_depth = true;      // 7-Scenes: depth registered to colour (docs/registration.md)
  // TUM: fx, fy, cx, cy (image size from the data's 640x480) or a camera file ("fx fy cx cy
  // [width height]", '#' comments); neither: TUM's defaults, with a warning.
  std::vector<double> intrinsics;
  std::string camera_file;
  // 0: every frame; k >= 2: frames with i % k == k - 1 are left out (exoview_eval's held-out
  // test frames, IsHeldOut).
  int hold_out_every = 0;
  // Which residue is held out (the fold): i % k == hold_out_offset; -1 = k - 1 (frames 9, 19, ...).
  int hold_out_offset = -1;
  absl::Status Validate() const;
};

// exoview_eval's split: frame i is a test frame (never ingested) when i % every == offset
// (offset -1: every - 1). The ten folds of 7-Scenes are offsets 0..9 with every = 10.
inline bool IsHeldOut(size_t i, int every, int offset = -1) {
  if (every < 2) return false;
  const int r = offset < 0 ? every - 1 : offset;
  return i % static_cast<size_t>(every) == static_cast<size_t>(r);
}

// Reads "fx fy cx cy [width height]" (width/height default 640x480).
absl::StatusOr<PinholeCamera> ReadCameraFile(const std::string& path);

// Opens `dir` in the given format. Warnings (e.g. default intrinsics) are appended to
// `warnings` when given.
absl::StatusOr<std::unique_ptr<FrameSource>> OpenDataset(
    const std::string& dir, const DatasetOptions& options,
    std::vector<std::string>* warnings = nullptr);

}  // namespace exo
