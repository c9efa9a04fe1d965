// zstd with one reusable context per thread (libzstd): the depth codec's payloads and the
// compact mesh chunks on the wire (proto/frame_proto.cc).
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "common/status.h"

namespace exo {

// Appends the zstd frame of src[0..n) (with content size and checksum) to `out`, returned.
absl::StatusOr<std::vector<uint8_t>> ZstdCompress(const uint8_t* src, size_t n, int level,
                                                  std::vector<uint8_t> out);
// Decodes one zstd frame into exactly `expected` bytes at dst; anything else (not a frame, a
// different content size, corrupt or truncated data) is an InvalidArgument naming `what`.
absl::Status ZstdDecompress(std::span<const uint8_t> src, uint8_t* dst, size_t expected,
                            const char* what);

}  // namespace exo
