#include "server/service/upload_log.h"

#include <cctype>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/strip.h"

namespace exo {
namespace {

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

std::string Join(const std::map<std::string, uint64_t>& counts) {
  return absl::StrJoin(counts, ", ", [](std::string* out, const auto& kv) {
    absl::StrAppend(out, kv.first, ": ", kv.second);
  });
}

}  // namespace

UploadStreamLog::UploadStreamLog(std::string peer, int max_lines_per_s)
    : log_(log::Get("ingest")),
      peer_(std::move(peer)),
      limit_(max_lines_per_s, 1.0),
      start_(std::chrono::steady_clock::now()) {
  log_->info("upload stream opened: peer={}", peer_);
}

UploadStreamLog::~UploadStreamLog() {
  const double s = SecondsSince(start_);
  log_->info(
      "upload stream ended: peer={} received={} accepted={} rejected={} dropped={} "
      "duration_s={:.2f} fps={:.1f} rejected_by_reason={{{}}} dropped_by_reason={{{}}} "
      "log_lines_suppressed={}",
      peer_, received_, accepted_, rejected_, dropped_, s, s > 0 ? received_ / s : 0.0,
      Join(rejected_by_reason_), Join(dropped_by_reason_), limit_.suppressed_total());
}

std::string UploadStreamLog::ReasonKey(std::string_view reason) {
  size_t end = 0;
  while (end < reason.size() && reason[end] != ':' &&
         !std::isdigit(static_cast<unsigned char>(reason[end])))
    ++end;
  std::string key(
      absl::StripAsciiWhitespace(absl::string_view(reason.data(), std::min<size_t>(end, 60))));
  return key.empty() ? "other" : key;
}

void UploadStreamLog::Count(std::map<std::string, uint64_t>* by_reason, std::string_view reason) {
  std::string key = ReasonKey(reason);
  if (by_reason->size() >= kMaxReasonKeys && !by_reason->count(key)) key = "other";
  ++(*by_reason)[key];
}

void UploadStreamLog::Record(const ::exoview::v1::Ack& ack) {
  namespace v1 = ::exoview::v1;
  ++received_;
  const char* what = nullptr;
  switch (ack.status()) {
    case v1::Ack::ACCEPTED:
      ++accepted_;
      return;
    case v1::Ack::DROPPED:
      ++dropped_;
      Count(&dropped_by_reason_, ack.reason());
      what = "dropped";
      break;
    default:
      ++rejected_;
      Count(&rejected_by_reason_, ack.reason());
      what = "rejected";
      break;
  }
  uint64_t suppressed = 0;
  if (!limit_.Allow(SecondsSince(start_), &suppressed)) return;
  // Rejected = the client sent something wrong (warning); dropped = server overload (info).
  const auto level = ack.status() == v1::Ack::DROPPED ? spdlog::level::info : spdlog::level::warn;
  if (suppressed > 0)
    log_->log(level, "{} frame: peer={} sequence={} reason=\"{}\" ({} similar lines suppressed)",
              what, peer_, ack.sequence(), ack.reason(), suppressed);
  else
    log_->log(level, "{} frame: peer={} sequence={} reason=\"{}\"", what, peer_, ack.sequence(),
              ack.reason());
}

}  // namespace exo
