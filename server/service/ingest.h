// Ingest validation of one Upload stream (SPEC §12): size limit, sequence/timestamp order (both
// strictly increasing), then the full decode + plausibility limits of frame_proto.h /
// frame_limits.h. Each failure is a clear reason for the frame's REJECTED ack. A rejected frame
// changes no state of its stream: the order marks move only when the caller Commit()s a frame it
// took (accepted, or dropped under overload).
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
  // Validates and decodes one frame. `wire_bytes` is the serialized size of `msg`. Moves no mark.
  absl::StatusOr<Frame> Admit(const v1::Frame& msg, size_t wire_bytes);
  // The frame was taken: later frames must come after its sequence number and timestamp.
  void Commit(const Frame& frame);

 private:
  const IngestOptions options_;
  std::optional<uint64_t> last_sequence_;
  std::optional<double> last_timestamp_s_;
};

}  // namespace exo
