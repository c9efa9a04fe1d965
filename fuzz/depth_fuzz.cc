// libFuzzer target: the depth codec (common/io/depth_codec.h) on arbitrary bytes: header first,
// then zstd or libpng. A decoded image must match the header's size.
#include <cstddef>
#include <cstdint>
#include <span>

#include "common/io/depth_codec.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::span<const uint8_t> bytes(data, size);
  auto info = exo::ReadDepthInfo(bytes);
  auto depth = exo::DecodeDepth(bytes, int64_t{1} << 22);
  if (depth.ok() &&
      (!info.ok() || depth->width() != info->width || depth->height() != info->height))
    __builtin_trap();
  return 0;
}
