// libFuzzer target: the colour path of every uploaded frame (common/io/jpeg.h) on arbitrary
// bytes, with the upload limits (sequential JPEG only, 16 Mpix) and with the general ones (scan
// limit). Any input must give an image or a clear error, never a crash or a sanitizer report.
#include <cstddef>
#include <cstdint>
#include <span>

#include "common/io/jpeg.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::span<const uint8_t> bytes(data, size);
  exo::JpegLimits upload;
  upload.max_pixels = int64_t{1} << 22;  // keeps each run fast; the check is the same
  upload.sequential_only = true;
  if (auto img = exo::DecodeJpeg(bytes, upload); img.ok()) {
    if (img->channels() != 3 || img->width() <= 0) __builtin_trap();
  }
  exo::JpegLimits general;
  general.max_pixels = int64_t{1} << 22;
  (void)exo::DecodeJpeg(bytes, general);
  return 0;
}
