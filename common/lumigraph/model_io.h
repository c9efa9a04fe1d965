// On-disk form of a LumigraphModel (the data a render client holds): a versioned little-endian
// binary file so that a model built by the server, a benchmark or a dataset run can be rendered
// later (client/vulkan exoview_render). Layout (all integers little-endian):
//   "EXOMODL1" magic, u32 format version (1), u32 section count
//   sections, each: u32 tag, u64 payload bytes, payload, u64 FNV-1a checksum of the payload
//     'ORIG' origin (3 f64) + cell size (f64) + model version (u64)
//     'VIEW' one per view: id, intrinsics, pose (f64), exposure, colour (raw RGB8 or JPEG),
//            depth (lossless 16-bit codec of common/io with a per-view metres-per-unit)
//     'CELL' all cell references: count, then (cell id u64, n u32, n view ids u32)
//     'CHNK' one per mesh chunk: id, version, positions (f32), indices (u32)
// Colour is lossless by default (JPEG optional, quality in the options); depth is quantised to
// max(min step, max_depth / 65535) per view (0 stays invalid; NaN/Inf/negative become 0).
// Truncated, corrupt (checksum) or inconsistent files give a DataLoss / InvalidArgument status, never a crash.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "common/lumigraph/model.h"
#include "common/status.h"

namespace exo {

struct ModelIoOptions {
  // 0 = raw RGB8 (lossless, default); 1..100 = JPEG quality (4:2:0).
  int color_jpeg_quality = 0;
  // Depth quantisation step never finer than this (metres per 16-bit unit).
  double min_depth_step_m = 0.0005;

  absl::Status Validate() const;
};

absl::StatusOr<std::vector<uint8_t>> SerializeModel(const LumigraphModel& model,
                                                    const ModelIoOptions& options = {});
absl::StatusOr<LumigraphModel> DeserializeModel(std::span<const uint8_t> bytes);

absl::Status SaveModel(const std::string& path, const LumigraphModel& model,
                       const ModelIoOptions& options = {});
absl::StatusOr<LumigraphModel> LoadModel(const std::string& path);

}  // namespace exo
