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
// The same baseline JPEG with Huffman tables optimised for this image (libjpeg's
// optimize_coding: a second pass over the coefficients): the same DCT and quantisation, so it
// decodes to exactly the pixels of EncodeJpeg's, in ~7 % fewer bytes at quality 50, for ~1.3x
// the encode time. What the server publishes views with (each is encoded once, sent to every
// viewer).
absl::StatusOr<std::vector<uint8_t>> EncodeJpegOptimized(const ImageU8& rgb, int quality = 90);

// What a decode may cost. The scan limit is always on (TJFLAG_LIMITSCANS: more than 500 scans is
// an error: a small progressive JPEG with hundreds of scans costs seconds of CPU).
struct JpegLimits {
  int64_t max_pixels = kMaxJpegPixels;
  // Only sequential (baseline / extended Huffman, SOF0/SOF1) JPEGs: one scan per component at
  // most. The upload path (one MJPEG frame) sets it.
  bool sequential_only = false;
};

// Decodes any baseline/progressive JPEG to RGB8 (3 channels; greyscale JPEGs are expanded).
absl::StatusOr<ImageU8> DecodeJpeg(std::span<const uint8_t> bytes, const JpegLimits& limits = {});

// Reads only the header: width, height, the frame type. Same error behaviour as DecodeJpeg.
struct JpegInfo {
  int width = 0;
  int height = 0;
  int sof_marker = 0;  // 0xC0 baseline, 0xC1 extended sequential, 0xC2 progressive, ...
};
absl::StatusOr<JpegInfo> ReadJpegInfo(std::span<const uint8_t> bytes,
                                      const JpegLimits& limits = {});

}  // namespace exo
