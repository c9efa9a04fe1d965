// The live DR view from the uploader's side (issue 18: "the uploader side can request it too"):
// while the uploader streams, a second call (WatchDrView) receives the server's diminished-reality
// stream of the same camera (the frames with the marked regions removed) and writes each frame
// as dr_<sequence>.jpg (the server's JPEG, unchanged) into a folder, with counts for the JSON.
// A slow disk only loses DR frames (the server skips frames for a slow reader); the upload
// never waits for it. WatchDrView is a viewer-role call: with a token of another role the
// recorder reports the server's PERMISSION_DENIED in `error` and the upload goes on.
#pragma once

#include <memory>
#include <string>

#include "common/status.h"

namespace grpc {
class Channel;
}

namespace exo {

struct DrViewRecordOptions {
  std::string out_dir;    // created if missing
  int jpeg_quality = 90;  // 1..100
  absl::Status Validate() const;
};

struct DrViewRecordStats {
  uint64_t frames = 0;      // DR frames received
  uint64_t composited = 0;  // of those, with a region removed (false: no keyframe / ROI not in view)
  uint64_t written = 0;     // JPEG files written
  double fps = 0;           // received frames per second (first to last)
  double latency_ms_mean = 0;  // the server's admission-to-output latency
  std::string error;        // the stream's error ("" = none; a cancel at Stop is not one)
  std::string ToJson() const;
};

class DrViewRecorder {
 public:
  // Starts the WatchDrView call on its own thread. Errors: bad options, a folder that cannot be
  // created.
  static absl::StatusOr<std::unique_ptr<DrViewRecorder>> Start(std::shared_ptr<grpc::Channel> channel,
                                                               const DrViewRecordOptions& options);
  ~DrViewRecorder();
  // Ends the call (after `linger_s` for the last frames of the upload) and returns the counts.
  DrViewRecordStats Stop(double linger_s = 0.5);

 private:
  DrViewRecorder() = default;
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace exo
