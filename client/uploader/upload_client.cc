#include "client/uploader/upload_client.h"

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <fstream>
#include <mutex>
#include <sstream>
#include <thread>
#include <unordered_map>

#include <grpcpp/grpcpp.h>

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
  return encode.Validate();
}

std::string UploadAckStats::ToJson() const {
  std::string reasons;
  for (const auto& [r, n] : reject_reasons)
    reasons += absl::StrCat(reasons.empty() ? "" : ", ", "\"", JsonEscape(r), "\": ", n);
  return absl::StrCat("{\"sent\": ", sent, ", \"accepted\": ", accepted, ", \"rejected\": ", rejected,
                      ", \"dropped\": ", dropped, ", \"elapsed_s\": ", elapsed_s, ", \"fps\": ", fps(),
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
  grpc::ClientContext ctx;
  auto stream = stub->Upload(&ctx);
  UploadAckStats st;
  std::mutex mu;
  std::condition_variable cv;
  uint64_t in_flight = 0;
  std::unordered_map<uint64_t, Clock::time_point> sent_at;
  std::vector<double> latencies;
  const auto t0 = Clock::now();

  std::thread reader([&] {
    v1::Ack ack;
    while (stream->Read(&ack)) {
      std::lock_guard lock(mu);
      if (auto it = sent_at.find(ack.sequence()); it != sent_at.end()) {
        latencies.push_back(std::chrono::duration<double, std::milli>(Clock::now() - it->second).count());
        sent_at.erase(it);
      }
      switch (ack.status()) {
        case v1::Ack::ACCEPTED: ++st.accepted; break;
        case v1::Ack::DROPPED: ++st.dropped; break;
        default:
          ++st.rejected;
          ++st.reject_reasons[ack.reason()];
      }
      st.acks.push_back(ack);
      if (in_flight > 0) --in_flight;
      cv.notify_all();
    }
    std::lock_guard lock(mu);
    in_flight = 0;
    cv.notify_all();
  });

  absl::Status error;
  auto last_print = Clock::now();
  for (size_t i = 0; i < count; ++i) {
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
      cv.wait(lock, [&] { return in_flight < static_cast<uint64_t>(options.max_in_flight); });
      ++in_flight;
      sent_at[msg->sequence()] = Clock::now();
      st.send_times.emplace_back(msg->timestamp_s(),
                                 std::chrono::duration_cast<std::chrono::nanoseconds>(
                                     Clock::now().time_since_epoch()).count());
    }
    st.bytes_sent += msg->ByteSizeLong();
    if (!stream->Write(*msg)) {
      error = absl::UnavailableError("upload stream closed by the server");
      break;
    }
    ++st.sent;
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
  stream->WritesDone();
  reader.join();
  const grpc::Status gs = stream->Finish();
  st.elapsed_s = std::chrono::duration<double>(Clock::now() - t0).count();
  st.ack_latency_p50_ms = Percentile(latencies, 0.5);
  st.ack_latency_p95_ms = Percentile(latencies, 0.95);
  if (!error.ok()) return error;
  if (!gs.ok())
    return absl::UnavailableError(absl::StrCat("upload failed: ", gs.error_message()));
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
