#include "server/service/ingest.h"

#include <cmath>

namespace exo {

absl::Status IngestOptions::Validate() const {
  if (max_frame_bytes < 1024) return absl::InvalidArgumentError("max_frame_bytes must be >= 1024");
  return decode.limits.Validate();
}

absl::StatusOr<Frame> IngestStream::Admit(const v1::Frame& msg, size_t wire_bytes) {
  if (wire_bytes > options_.max_frame_bytes)
    return absl::ResourceExhaustedError(absl::StrCat("oversized message: frame is ", wire_bytes,
                                                     " bytes, the limit is ",
                                                     options_.max_frame_bytes));
  if (last_sequence_ && msg.sequence() <= *last_sequence_)
    return absl::InvalidArgumentError(absl::StrCat("out-of-order sequence number ", msg.sequence(),
                                                   " (must be greater than the previous ",
                                                   *last_sequence_, ")"));
  EXO_RETURN_IF_ERROR(CheckTimestamp(msg.timestamp_s(), options_.decode.limits));
  if (last_timestamp_s_ && !(msg.timestamp_s() > *last_timestamp_s_))
    return absl::InvalidArgumentError(absl::StrCat(
        msg.timestamp_s() == *last_timestamp_s_ ? "duplicate" : "out-of-order", " timestamp ",
        msg.timestamp_s(), " s (must be greater than the previous ", *last_timestamp_s_, " s)"));
  return FrameFromProto(msg, options_.decode);
}

void IngestStream::Commit(const Frame& frame) {
  last_sequence_ = frame.sequence;
  last_timestamp_s_ = frame.timestamp_s;
}

}  // namespace exo
