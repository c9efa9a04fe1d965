// Dataset readers and writers produce/consume the one in-memory exo::Frame (common/frame.h).
// Every reader is a FrameSource: size(), Load(i) -> Frame (or a clear error naming the file).
#pragma once

#include <cstddef>
#include <string>

#include "common/frame.h"
#include "common/status.h"

namespace exo {

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  virtual size_t size() const = 0;
  // Loads and decodes frame i (0-based, in sequence order). The returned frame passes
  // Frame::Validate(). Errors: OutOfRange for i >= size(), NotFound for a missing file,
  // InvalidArgument for a corrupt one; the message names the file.
  virtual absl::StatusOr<Frame> Load(size_t i) const = 0;
  virtual std::string name() const = 0;  // e.g. "7scenes:/path"
};

}  // namespace exo
