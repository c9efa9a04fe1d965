#include "server/service/ingest.h"

#include <cmath>

namespace exo {

absl::Status IngestOptions::Validate() const {
  if (max_frame_bytes < 1024) return absl::InvalidArgumentError("max_frame_bytes must be >= 1024");
  if (decode.max_pixels < 1) return absl::InvalidArgumentError("max_pixels must be >= 1");
  return absl::OkStatus();
}

absl::StatusOr<Frame> IngestStream::Admit(const v1::Frame& msg, size_t wire_bytes) {
  if (wire_bytes > options_.max_frame_bytes)
    return absl::ResourceExhaustedError(absl::StrCat("oversized message: frame is ", wire_bytes,
                                                     " bytes, the limit is ",
                                                     options_.max_frame_bytes));
  if (last_sequence_ && msg.sequence() <= *last_sequence_)
    return absl::InvalidArgumentError(
        absl::StrCat("out-of-order sequence number ", msg.sequence(),
                     " (must be greater than the previous ", *last_sequence_, ")"));
  if (std::isfinite(msg.timestamp_s()) && msg.timestamp_s() < last_timestamp_s_)
    return absl::InvalidArgumentError(absl::StrCat("out-of-order timestamp ", msg.timestamp_s(),
                                                   " s (previous ", last_timestamp_s_, " s)"));
  last_sequence_ = msg.sequence();
  if (std::isfinite(msg.timestamp_s())) last_timestamp_s_ = msg.timestamp_s();
  return FrameFromProto(msg, options_.decode);
}

}  // namespace exo
