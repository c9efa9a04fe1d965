// JPEG encode/decode of RGB8 images with libjpeg-turbo's TurboJPEG API. This is the colour path of
// every frame (one MJPEG frame per upload) and of the view store. Bad input (corrupt, truncated,
// garbage, absurd header dimensions) returns a clear absl::Status, never crashes: libjpeg
// *warnings* (e.g. "Premature end of JPEG file", which libjpeg turns into grey padding) are
// treated as errors, because a silently padded image would poison the model.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "common/image.h"
#include "common/status.h"

namespace exo {

// Images larger than this many pixels are refused on decode (a garbage header can claim
// 65535x65535, i.e. a 12 GB allocation).
inline constexpr int64_t kMaxJpegPixels = int64_t{1} << 27;  // 134 Mpix

// Encodes a 3-channel RGB8 image (4:2:0 chroma subsampling, `quality` in [1, 100]).
absl::StatusOr<std::vector<uint8_t>> EncodeJpeg(const ImageU8& rgb, int quality = 90);

// Decodes any baseline/progressive JPEG to RGB8 (3 channels; greyscale JPEGs are expanded).
absl::StatusOr<ImageU8> DecodeJpeg(std::span<const uint8_t> bytes);

// Reads only the header: width, height. Same error behaviour as DecodeJpeg.
struct JpegInfo {
  int width = 0;
  int height = 0;
};
absl::StatusOr<JpegInfo> ReadJpegInfo(std::span<const uint8_t> bytes);

}  // namespace exo
