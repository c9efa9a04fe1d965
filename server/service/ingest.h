// Ingest validation of one Upload stream (SPEC §12): size limit, sequence/timestamp order,
// then the full decode + validation of frame_proto.h. Each failure is a clear reason for the
// frame's REJECTED ack; the stream state only advances on frames whose order was valid.
#pragma once

#include <cstdint>
#include <optional>

#include "common/frame.h"
#include "common/status.h"
#include "proto/exoview.pb.h"
#include "proto/frame_proto.h"

namespace exo {

struct IngestOptions {
  size_t max_frame_bytes = size_t{8} << 20;  // per-frame limit (REJECTED above it)
  FrameDecodeOptions decode;
  absl::Status Validate() const;
};

class IngestStream {
 public:
  explicit IngestStream(const IngestOptions& options) : options_(options) {}
  // Validates and decodes one frame. `wire_bytes` is the serialized size of `msg`.
  absl::StatusOr<Frame> Admit(const v1::Frame& msg, size_t wire_bytes);

 private:
  const IngestOptions options_;
  std::optional<uint64_t> last_sequence_;
  double last_timestamp_s_ = -1e300;
};

}  // namespace exo
