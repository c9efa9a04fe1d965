#include "client/uploader/upload_client.h"

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <fstream>
#include <mutex>
#include <sstream>
#include <thread>
#include <unordered_map>

#include <grpcpp/grpcpp.h>

#include "absl/strings/match.h"
#include "proto/exoview.grpc.pb.h"

namespace exo {
namespace {
using Clock = std::chrono::steady_clock;

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5))];
}

std::string JsonEscape(const std::string& s) {
  std::string o;
  for (char c : s) {
    if (c == '"' || c == '\\') o += '\\';
    if (static_cast<unsigned char>(c) < 0x20) continue;
    o += c;
  }
  return o;
}
}  // namespace

absl::Status UploadOptions::Validate() const {
  if (rate_hz < 0) return absl::InvalidArgumentError("rate_hz must be >= 0");
  if (max_in_flight < 1) return absl::InvalidArgumentError("max_in_flight must be >= 1");
  if (!(reconnect_s >= 0)) return absl::InvalidArgumentError("reconnect_s must be >= 0");
  return encode.Validate();
}

std::string UploadAckStats::ToJson() const {
  std::string reasons;
  for (const auto& [r, n] : reject_reasons)
    reasons += absl::StrCat(reasons.empty() ? "" : ", ", "\"", JsonEscape(r), "\": ", n);
  return absl::StrCat("{\"sent\": ", sent, ", \"accepted\": ", accepted, ", \"rejected\": ", rejected,
                      ", \"dropped\": ", dropped, ", \"durable\": ", durable,
                      ", \"duplicates\": ", duplicates, ", \"resent\": ", resent,
                      ", \"reconnects\": ", reconnects, ", \"elapsed_s\": ", elapsed_s, ", \"fps\": ", fps(),
                      ", \"bytes_sent\": ", bytes_sent, ", \"ack_latency_p50_ms\": ", ack_latency_p50_ms,
                      ", \"ack_latency_p95_ms\": ", ack_latency_p95_ms, ", \"reject_reasons\": {",
                      reasons, "}}");
}

std::shared_ptr<grpc::Channel> MakeChannel(const std::string& target, size_t max_message_bytes) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(static_cast<int>(max_message_bytes));
  args.SetMaxSendMessageSize(static_cast<int>(max_message_bytes));
  return grpc::CreateCustomChannel(target, grpc::InsecureChannelCredentials(), args);
}

namespace {
absl::StatusOr<std::string> ReadFileText(const std::string& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot read ", what, " ", path));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Adds "authorization: Bearer TOKEN" to every call of the channel.
class BearerToken final : public grpc::MetadataCredentialsPlugin {
 public:
  explicit BearerToken(std::string token) : header_("Bearer " + std::move(token)) {}
  bool IsBlocking() const override { return false; }
  grpc::Status GetMetadata(grpc::string_ref, grpc::string_ref, const grpc::AuthContext&,
                           std::multimap<grpc::string, grpc::string>* metadata) override {
    metadata->insert({"authorization", header_});
    return grpc::Status::OK;
  }

 private:
  std::string header_;
};
}  // namespace

absl::StatusOr<std::shared_ptr<grpc::Channel>> MakeChannel(const std::string& target,
                                                           const ChannelSecurity& sec,
                                                           size_t max_message_bytes) {
  if (sec.empty()) return MakeChannel(target, max_message_bytes);
  if (sec.tls_ca.empty())
    return absl::InvalidArgumentError(
        "--tls_cert/--tls_key/--token_file need TLS: give --tls_ca (the CA of the server's "
        "certificate)");
  if (sec.tls_cert.empty() != sec.tls_key.empty())
    return absl::InvalidArgumentError("--tls_cert and --tls_key go together");
  grpc::SslCredentialsOptions o;
  EXO_ASSIGN_OR_RETURN(o.pem_root_certs, ReadFileText(sec.tls_ca, "--tls_ca"));
  if (!sec.tls_cert.empty()) {
    EXO_ASSIGN_OR_RETURN(o.pem_cert_chain, ReadFileText(sec.tls_cert, "--tls_cert"));
    EXO_ASSIGN_OR_RETURN(o.pem_private_key, ReadFileText(sec.tls_key, "--tls_key"));
  }
  std::shared_ptr<grpc::ChannelCredentials> creds = grpc::SslCredentials(o);
  if (!sec.token_file.empty()) {
    EXO_ASSIGN_OR_RETURN(std::string text, ReadFileText(sec.token_file, "--token_file"));
    std::string token = text.substr(0, text.find('\n'));
    while (!token.empty() && (token.back() == '\r' || token.back() == ' ')) token.pop_back();
    if (token.empty()) return absl::InvalidArgumentError("--token_file holds no token");
    creds = grpc::CompositeChannelCredentials(
        creds, grpc::MetadataCredentialsFromPlugin(std::make_unique<BearerToken>(token)));
  }
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(static_cast<int>(max_message_bytes));
  args.SetMaxSendMessageSize(static_cast<int>(max_message_bytes));
  if (!sec.server_name.empty()) args.SetSslTargetNameOverride(sec.server_name);
  return grpc::CreateCustomChannel(target, creds, args);
}

absl::StatusOr<UploadAckStats> UploadStream(
    const std::shared_ptr<grpc::Channel>& channel, size_t count,
    const std::function<absl::StatusOr<v1::Frame>(size_t)>& next, const UploadOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  auto stub = v1::Exoview::NewStub(channel);
  UploadAckStats st;
  std::mutex mu;
  std::condition_variable cv;
  // Frames sent and not yet acked, oldest first (resent in order after a reconnect).
  std::deque<v1::Frame> unacked;
  std::unordered_map<uint64_t, Clock::time_point> sent_at;
  std::vector<double> latencies;
  const auto t0 = Clock::now();
  const auto give_up_at = t0 + std::chrono::duration_cast<Clock::duration>(
                                   std::chrono::duration<double>(options.reconnect_s));
  absl::Status error;
  auto last_print = Clock::now();
  size_t i = 0;  // next frame to produce
  for (int attempt = 0;; ++attempt) {
    grpc::ClientContext ctx;
    if (!options.uploader_id.empty()) ctx.AddMetadata("exoview-uploader-id", options.uploader_id);
    if (options.reconnect_s > 0) ctx.set_wait_for_ready(true);
    auto stream = stub->Upload(&ctx);
    bool reader_done = false;
    std::thread reader([&] {
      v1::Ack ack;
      while (stream->Read(&ack)) {
        std::lock_guard lock(mu);
        if (auto it = sent_at.find(ack.sequence()); it != sent_at.end()) {
          latencies.push_back(
              std::chrono::duration<double, std::milli>(Clock::now() - it->second).count());
          sent_at.erase(it);
        }
        // Acks come in order: this one answers the oldest unacked frame with its sequence.
        while (!unacked.empty() && unacked.front().sequence() < ack.sequence()) unacked.pop_front();
        if (!unacked.empty() && unacked.front().sequence() == ack.sequence()) unacked.pop_front();
        switch (ack.status()) {
          case v1::Ack::ACCEPTED:
            ++st.accepted;
            if (ack.durable()) ++st.durable;
            if (absl::StartsWith(ack.reason(), "duplicate")) ++st.duplicates;
            break;
          case v1::Ack::DROPPED: ++st.dropped; break;
          default:
            ++st.rejected;
            ++st.reject_reasons[ack.reason()];
        }
        st.acks.push_back(ack);
        if (options.on_ack) options.on_ack(ack);
        cv.notify_all();
      }
      std::lock_guard lock(mu);
      reader_done = true;
      cv.notify_all();
    });
    bool broken = false;
    // After a reconnect: what the server did not ack, again, in order.
    std::vector<v1::Frame> resend;
    {
      std::lock_guard lock(mu);
      resend.assign(unacked.begin(), unacked.end());
    }
    for (const v1::Frame& f : resend) {
      st.bytes_sent += f.ByteSizeLong();
      ++st.resent;
      if (!stream->Write(f)) {
        broken = true;
        break;
      }
    }
    for (; !broken && i < count; ++i) {
      if (options.rate_hz > 0)
        std::this_thread::sleep_until(t0 + std::chrono::duration_cast<Clock::duration>(
                                               std::chrono::duration<double>(i / options.rate_hz)));
      auto msg = next(i);
      if (!msg.ok()) {
        error = msg.status();
        break;
      }
      {
        std::unique_lock lock(mu);
        cv.wait(lock, [&] {
          return unacked.size() < static_cast<size_t>(options.max_in_flight) || reader_done;
        });
        if (reader_done) {  // the server ended the stream: this frame goes with the next attempt
          broken = true;
          break;
        }
        unacked.push_back(*msg);
        sent_at[msg->sequence()] = Clock::now();
        st.send_times.emplace_back(msg->timestamp_s(),
                                   std::chrono::duration_cast<std::chrono::nanoseconds>(
                                       Clock::now().time_since_epoch())
                                       .count());
      }
      st.bytes_sent += msg->ByteSizeLong();
      ++st.sent;
      if (!stream->Write(*msg)) {
        ++i;  // it is in `unacked`: resent with the next attempt
        broken = true;
        break;
      }
      if (options.progress && Clock::now() - last_print > std::chrono::seconds(1)) {
        last_print = Clock::now();
        std::lock_guard lock(mu);
        std::fprintf(stderr, "[upload] sent %llu/%zu  accepted %llu  rejected %llu  dropped %llu\n",
                     static_cast<unsigned long long>(st.sent), count,
                     static_cast<unsigned long long>(st.accepted),
                     static_cast<unsigned long long>(st.rejected),
                     static_cast<unsigned long long>(st.dropped));
      }
    }
    if (!broken) stream->WritesDone();
    reader.join();
    const grpc::Status gs = stream->Finish();
    size_t left;
    {
      std::lock_guard lock(mu);
      left = unacked.size();
    }
    if (!error.ok()) break;
    if (gs.ok() && !broken && left == 0) break;  // everything sent and acked
    const bool retry = options.reconnect_s > 0 && Clock::now() < give_up_at &&
                       (gs.error_code() == grpc::StatusCode::UNAVAILABLE ||
                        gs.error_code() == grpc::StatusCode::CANCELLED ||
                        gs.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED ||
                        gs.error_code() == grpc::StatusCode::INTERNAL || gs.ok());
    if (!retry) {
      error = gs.ok() ? absl::UnavailableError(absl::StrCat("upload stream closed by the server with ",
                                                            left, " frames not acked"))
                      : absl::UnavailableError(absl::StrCat("upload failed: ", gs.error_message()));
      break;
    }
    ++st.reconnects;
    if (options.progress)
      std::fprintf(stderr, "[upload] stream lost (%s); reconnecting, %zu frames to resend\n",
                   gs.error_message().c_str(), left);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  st.elapsed_s = std::chrono::duration<double>(Clock::now() - t0).count();
  st.ack_latency_p50_ms = Percentile(latencies, 0.5);
  st.ack_latency_p95_ms = Percentile(latencies, 0.95);
  if (!error.ok()) return error;
  return st;
}

absl::StatusOr<UploadAckStats> UploadFrames(const std::shared_ptr<grpc::Channel>& channel,
                                         const FrameSource& source, size_t first, size_t count,
                                         const UploadOptions& options) {
  count = std::min(count, source.size() > first ? source.size() - first : 0);
  return UploadStream(channel, count,
                      [&](size_t i) -> absl::StatusOr<v1::Frame> {
                        EXO_ASSIGN_OR_RETURN(Frame f, source.Load(first + i));
                        return FrameToProto(f, options.encode);
                      },
                      options);
}

}  // namespace exo
