// Drone-side upload client: streams frames to the server's Upload RPC at a chosen rate with a
// bounded number of frames in flight, reads the per-frame acks on a second thread and keeps
// ack statistics (accepted / rejected with reasons / dropped, ack latency). Frames come from
// any exo::FrameSource (datasets, the built-in synthetic scene) or as pre-encoded messages.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "common/datasets/frame_source.h"
#include "common/status.h"
#include "proto/exoview.pb.h"
#include "proto/frame_proto.h"

namespace grpc {
class Channel;
}

namespace exo {

struct UploadOptions {
  double rate_hz = 30.0;        // 0 = as fast as the server acks
  int max_in_flight = 16;       // frames sent but not yet acked
  FrameEncodeOptions encode;
  bool progress = false;        // one line per second on stderr
  // Durable acknowledgements (docs/security.md): the `exoview-uploader-id` call header; with it a
  // server that runs a frame journal answers a resent frame it already holds as a duplicate.
  std::string uploader_id;
  // When the stream breaks (the server restarted), reconnect for up to this long and resend
  // every frame not yet acked, in order. 0 = the upload fails at the first broken stream.
  double reconnect_s = 0;
  std::function<void(const v1::Ack&)> on_ack;  // called on the reader thread for every ack
  absl::Status Validate() const;
};

struct UploadAckStats {
  uint64_t sent = 0, accepted = 0, rejected = 0, dropped = 0;
  uint64_t durable = 0;     // ACCEPTED acks that said durable
  uint64_t duplicates = 0;  // of those, frames the server already held (resent after a restart)
  uint64_t resent = 0, reconnects = 0;
  std::map<std::string, uint64_t> reject_reasons;
  std::vector<v1::Ack> acks;    // in arrival order
  // (frame timestamp_s, steady-clock ns when written): cross-process latency joins on one host.
  std::vector<std::pair<double, int64_t>> send_times;
  double elapsed_s = 0;
  uint64_t bytes_sent = 0;
  double ack_latency_p50_ms = 0, ack_latency_p95_ms = 0;
  double fps() const { return elapsed_s > 0 ? sent / elapsed_s : 0; }
  std::string ToJson() const;
};

std::shared_ptr<grpc::Channel> MakeChannel(const std::string& target, size_t max_message_bytes = 64 << 20);

// How a client reaches a server with TLS and a role (docs/security.md). Empty = plain text.
struct ChannelSecurity {
  std::string tls_ca;           // CA that signed the server's certificate (PEM): turns TLS on
  std::string tls_cert, tls_key;  // client certificate and key (PEM), for mutual TLS
  std::string server_name;      // name to verify in the server certificate (default: the host)
  std::string token_file;       // bearer token (first line of the file), sent on every call
  bool empty() const { return tls_ca.empty() && tls_cert.empty() && token_file.empty(); }
};
// A channel with TLS (and a client certificate, and a per-call bearer token) when `security`
// says so; plain text otherwise. A token needs TLS.
absl::StatusOr<std::shared_ptr<grpc::Channel>> MakeChannel(const std::string& target,
                                                           const ChannelSecurity& security,
                                                           size_t max_message_bytes = 64 << 20);

// Sends `count` messages produced by `next(i)` (which may fail: the error ends the upload).
absl::StatusOr<UploadAckStats> UploadStream(
    const std::shared_ptr<grpc::Channel>& channel, size_t count,
    const std::function<absl::StatusOr<v1::Frame>(size_t)>& next, const UploadOptions& options);

// Loads, encodes and sends frames [first, first + count) of a FrameSource.
absl::StatusOr<UploadAckStats> UploadFrames(const std::shared_ptr<grpc::Channel>& channel,
                                         const FrameSource& source, size_t first, size_t count,
                                         const UploadOptions& options);

}  // namespace exo
