// libFuzzer target: ingest validation of a whole uploaded message: the bytes parsed as an
// exoview.v1.Frame, then FrameFromProto with the server's limits (proto/frame_limits.h). An
// accepted frame must satisfy every limit (CheckFrame) and its images must match its cameras.
#include <cstddef>
#include <cstdint>

#include "proto/frame_limits.h"
#include "proto/frame_proto.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  exo::v1::Frame msg;
  if (!msg.ParseFromArray(data, static_cast<int>(size))) return 0;
  exo::FrameDecodeOptions o;
  o.limits.max_pixels = int64_t{1} << 22;
  auto f = exo::FrameFromProto(msg, o);
  if (f.ok() && !exo::CheckFrame(*f, o.limits).ok()) __builtin_trap();
  o.pose_required = false;
  (void)exo::FrameFromProto(msg, o);
  return 0;
}
