// Optional UDP pose input (SPEC §2): timestamped camera-to-world poses, e.g. from a motion-capture
// system at up to 120 Hz, one per datagram as text in the TUM ground-truth convention
//   "timestamp_s tx ty tz qx qy qz qw"
// received on a Boost.Asio UDP socket (own thread) into a bounded common/pose_stream.h buffer.
// Frames uploaded without a pose get theirs by SLERP/lerp at the frame timestamp; a frame with no
// pose within the tolerance is rejected with the reason. Malformed datagrams are counted and
// ignored (UDP has no one to answer).
//
// Authenticated datagrams (issue 20 item 5; docs/security.md): with a shared key (config
// udp_pose_key_file) every datagram must be
//   "SEQ timestamp_s tx ty tz qx qy qz qw MAC"
// where MAC is the lowercase hex HMAC-SHA256 (OpenSSL) of everything before the last space
// ("SEQ timestamp_s ... qw"), and SEQ a decimal u64 that increases with every datagram (senders
// use e.g. microseconds since the epoch, which also survives their restart). A datagram without
// a valid MAC is dropped and counted (unauthenticated); one whose SEQ is not above the last
// accepted one is a replay: dropped and counted. Without a key, plain datagrams as above.
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

// HMAC-SHA256 of `text` under `key`, lowercase hex (64 characters).
std::string PoseHmacHex(const std::string& key, const std::string& text);
// "SEQ POSE_TEXT MAC": what an authenticated sender puts in a datagram.
std::string SignPoseDatagram(const std::string& key, uint64_t sequence, const std::string& pose_text);
// Checks an authenticated datagram: the MAC (constant-time compare) first, then the fields.
// Errors: kUnauthenticated (no / bad MAC), kInvalidArgument (fields). Sets *sequence.
absl::StatusOr<PoseSample> VerifyPoseDatagram(const std::string& key, const std::string& text,
                                              uint64_t* sequence);
// Reads a key file: the first line, at least 16 bytes; the file must not be readable by others.
absl::StatusOr<std::string> ReadPoseKeyFile(const std::string& path);

// Timestamp bounds of the pose stream against the server's clock (issue 20 item 5). The
// sender's time base is whatever it uses (mocap clock, dataset time): the first accepted datagram
// anchors it, offset = timestamp - server receive time. A later datagram's lead = its own offset
// minus the anchor's (how far its timestamp runs ahead of the server clock since the anchor):
//  - lead > max_lead_s: "future" (a timestamp the server clock has not reached), rejected;
//  - lead < -max_lag_s: "past" (too old to be a current pose), rejected;
//  - timestamp < newest accepted - max_backwards_s: "backwards", rejected.
// A rejected datagram never enters the stream, so it cannot push good samples out of it.
// Recovery without a restart: when datagrams have been rejected for rebase_after_s of server
// time in a row and agree among themselves (offsets within max_lead_s of the stretch's first),
// the sender's time base changed (or the anchor was bad): the gate re-anchors on them and the
// stream is cleared (its samples are in the old time base). An interleaved bad sender never
// rebases a good stream: every accepted datagram ends the stretch.
struct PoseTimeGateOptions {
  double max_lead_s = 5.0;
  double max_lag_s = 5.0;
  double max_backwards_s = 1.0;
  double rebase_after_s = 2.0;
  absl::Status Validate() const;
};

class PoseTimeGate {
 public:
  enum class Verdict { kAccept, kRebased, kFuture, kPast, kBackwards };
  explicit PoseTimeGate(const PoseTimeGateOptions& o = {}) : o_(o) {}
  // `now_s`: the server's receive time (steady clock, seconds). kAccept / kRebased: take it.
  Verdict Check(double timestamp_s, double now_s);
  static const char* Name(Verdict v);

 private:
  PoseTimeGateOptions o_;
  bool anchored_ = false;
  double offset_ = 0, newest_ = 0;
  bool in_stretch_ = false;
  double stretch_start_s_ = 0, stretch_offset_ = 0;
};

class UdpPoseInput {
 public:
  // Binds 127.0.0.1/0.0.0.0 `address`:`port` (port 0 = any free port, see port()).
  // `hmac_key` non-empty: only authenticated datagrams are taken (see above).
  static absl::StatusOr<std::unique_ptr<UdpPoseInput>> Start(const std::string& address, int port,
                                                             size_t capacity = 4096,
                                                             const std::string& hmac_key = "",
                                                             const PoseTimeGateOptions& time = {});
  ~UdpPoseInput();
  int port() const { return port_; }
  // Pose at `timestamp_s` (see PoseStream::Interpolate); NotFound/FailedPrecondition with reason.
  absl::StatusOr<Rigid3d> PoseAt(double timestamp_s, double tolerance_s) const;
  uint64_t received() const { return received_.load(); }
  uint64_t malformed() const { return malformed_.load(); }
  uint64_t unauthenticated() const { return unauthenticated_.load(); }
  uint64_t replayed() const { return replayed_.load(); }
  // Datagrams the time gate rejected, by reason, and its re-anchorings.
  uint64_t rejected_future() const { return rejected_future_.load(); }
  uint64_t rejected_past() const { return rejected_past_.load(); }
  uint64_t rejected_backwards() const { return rejected_backwards_.load(); }
  uint64_t rebased() const { return rebased_.load(); }
  bool authenticated() const { return !key_.empty(); }

 private:
  UdpPoseInput() = default;
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int port_ = 0;
  mutable std::mutex mu_;
  PoseStream stream_;
  std::thread thread_;
  std::atomic<uint64_t> received_{0}, malformed_{0}, unauthenticated_{0}, replayed_{0},
      rejected_future_{0}, rejected_past_{0}, rejected_backwards_{0}, rebased_{0};
  PoseTimeGate gate_;  // receiver thread only
  std::string key_;
  uint64_t last_sequence_ = 0;  // receiver thread only
  std::atomic<bool> stopping_{false};
};

}  // namespace exo
