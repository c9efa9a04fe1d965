// Lossless codec for 16-bit depth images (the depth path of every frame and of the view store),
// and the one place where raw 16-bit sensor depth converts to metres and back.
//
// Stream layout (little endian): 24-byte header then the payload.
//   0  magic "EXD1" | 4 version (u8, = 1) | 5 codec (u8, DepthCodec) | 6 reserved (u16, 0)
//   8  width (u32)  | 12 height (u32) | 16 payload size (u32) | 20 reserved (u32, 0)
// Default codec (kDeltaPlanesZstd, chosen by measurement, see docs/io.md): each pixel minus its
// left neighbour (first column: minus the pixel above), residual zig-zag mapped, the 16-bit
// residuals split into a high-byte plane and a low-byte plane, then zstd level 1 with zstd's
// content checksum, so a flipped bit in the payload is detected, not silently decoded.
#pragma once

#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

#include "common/image.h"
#include "common/status.h"

namespace exo {

enum class DepthCodec : uint8_t {
  kRawZstd = 1,          // zstd on the raw little-endian u16 samples
  kDeltaZstd = 2,        // left/up predictor + zig-zag, interleaved bytes, zstd
  kDeltaPlanesZstd = 3,  // left/up predictor + zig-zag, high/low byte planes, zstd (default)
  kPng = 4,              // 16-bit greyscale PNG (encoded by OpenCV, decoded by libpng only)
};
std::string_view DepthCodecName(DepthCodec codec);

struct DepthCodecOptions {
  DepthCodec codec = DepthCodec::kDeltaPlanesZstd;
  int zstd_level = 1;         // 1..19 for the zstd codecs
  int png_compression = 1;    // 0..9 for kPng
  absl::Status Validate() const;
};

inline constexpr size_t kDepthHeaderBytes = 24;
inline constexpr int64_t kMaxDepthPixels = int64_t{1} << 26;  // 67 Mpix

// Encodes with the default options. Never fails for a valid 1-channel image (EXO_CHECK).
std::vector<uint8_t> EncodeDepth(const ImageU16& depth);
absl::StatusOr<std::vector<uint8_t>> EncodeDepth(const ImageU16& depth,
                                                 const DepthCodecOptions& options);
// The 24-byte header alone (no allocation): codec, size. Checked: magic, version, a size within
// kMaxDepthPixels, the payload length. A caller with tighter limits checks the size before
// DecodeDepth allocates anything.
struct DepthInfo {
  DepthCodec codec = DepthCodec::kDeltaPlanesZstd;
  int width = 0;
  int height = 0;
};
absl::StatusOr<DepthInfo> ReadDepthInfo(std::span<const uint8_t> bytes);

// Decodes any codec above. Truncated, garbage, bit-flipped or inconsistent data -> error. The
// header is read and checked (size <= max_pixels) before any allocation. A PNG payload is read
// by libpng only (its IHDR must be 16-bit greyscale, not interlaced, of the header's size); no
// other image format is ever decoded here.
absl::StatusOr<ImageU16> DecodeDepth(std::span<const uint8_t> bytes,
                                     int64_t max_pixels = kMaxDepthPixels);

// Raw sensor units -> metres (0 stays 0 = invalid). 7-Scenes: 0.001 (mm); TUM: 1/5000.
ImageF DepthMetersFromU16(const ImageU16& depth_raw, double metres_per_unit);
// Metres -> raw units, rounded to nearest. NaN, inf, <= 0 and values that do not fit in
// [1, 65535] units become 0 (invalid): an out-of-range depth is dropped, never wrapped.
ImageU16 DepthU16FromMeters(const ImageF& depth_m, double metres_per_unit);

}  // namespace exo
