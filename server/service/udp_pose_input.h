// Optional UDP pose input (SPEC §2): timestamped camera-to-world poses, e.g. from a motion-capture
// system at up to 120 Hz, one per datagram as text in the TUM ground-truth convention
//   "timestamp_s tx ty tz qx qy qz qw"
// received on a Boost.Asio UDP socket (own thread) into a bounded common/pose_stream.h buffer.
// Frames uploaded without a pose get theirs by SLERP/lerp at the frame timestamp; a frame with no
// pose within the tolerance is rejected with the reason. Malformed datagrams are counted and
// ignored (UDP has no one to answer).
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "common/pose_stream.h"
#include "common/status.h"

namespace exo {

// Parses one datagram. Errors: wrong field count, non-numbers, invalid quaternion/translation.
absl::StatusOr<PoseSample> ParsePoseDatagram(const std::string& text);

class UdpPoseInput {
 public:
  // Binds 127.0.0.1/0.0.0.0 `address`:`port` (port 0 = any free port, see port()).
  static absl::StatusOr<std::unique_ptr<UdpPoseInput>> Start(const std::string& address, int port,
                                                             size_t capacity = 4096);
  ~UdpPoseInput();
  int port() const { return port_; }
  // Pose at `timestamp_s` (see PoseStream::Interpolate); NotFound/FailedPrecondition with reason.
  absl::StatusOr<Rigid3d> PoseAt(double timestamp_s, double tolerance_s) const;
  uint64_t received() const { return received_.load(); }
  uint64_t malformed() const { return malformed_.load(); }

 private:
  UdpPoseInput() = default;
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int port_ = 0;
  mutable std::mutex mu_;
  PoseStream stream_;
  std::thread thread_;
  std::atomic<uint64_t> received_{0}, malformed_{0};
  std::atomic<bool> stopping_{false};
};

}  // namespace exo
