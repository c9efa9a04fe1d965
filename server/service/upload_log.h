// The server log of one Upload stream (component "ingest"): each rejected or dropped frame with
// the client's peer address, the frame's sequence number and the reason, at most
// `max_lines_per_s` such lines per second per stream (the others are counted, and the next line
// says how many were suppressed); at the end of the stream one summary line: frames received,
// accepted, rejected and dropped (by reason), duration and frame rate.
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <string_view>

#include "common/log/log.h"
#include "proto/exoview.pb.h"

namespace exo {

class UploadStreamLog {
 public:
  UploadStreamLog(std::string peer, int max_lines_per_s);
  ~UploadStreamLog();  // logs the summary
  UploadStreamLog(const UploadStreamLog&) = delete;
  UploadStreamLog& operator=(const UploadStreamLog&) = delete;

  // One frame's outcome, as acknowledged to the client.
  void Record(const ::exoview::v1::Ack& ack);

  // The reason's class for the per-reason counts: its text up to the first ':' or digit
  // ("oversized message: frame is 9 MB" -> "oversized message").
  static std::string ReasonKey(std::string_view reason);

 private:
  static constexpr size_t kMaxReasonKeys = 16;  // more distinct reasons count as "other"

  void Count(std::map<std::string, uint64_t>* by_reason, std::string_view reason);

  std::shared_ptr<spdlog::logger> log_;
  std::string peer_;
  log::RateLimit limit_;
  std::chrono::steady_clock::time_point start_;
  uint64_t received_ = 0, accepted_ = 0, rejected_ = 0, dropped_ = 0;
  std::map<std::string, uint64_t> rejected_by_reason_, dropped_by_reason_;
};

}  // namespace exo
