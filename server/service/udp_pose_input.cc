#include "server/service/udp_pose_input.h"

#include <array>
#include <chrono>
#include <cmath>
#include <sstream>

#include <sys/stat.h>

#include <fstream>

#include <boost/asio.hpp>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>

#include "absl/strings/numbers.h"

namespace exo {

absl::StatusOr<PoseSample> ParsePoseDatagram(const std::string& text) {
  std::istringstream in(text);
  double v[8];
  for (double& x : v)
    if (!(in >> x))
      return absl::InvalidArgumentError(
          "pose datagram must be 'timestamp_s tx ty tz qx qy qz qw'");
  std::string extra;
  if (in >> extra) return absl::InvalidArgumentError("pose datagram has extra fields");
  PoseSample s;
  s.timestamp_s = v[0];
  s.world_from_cam.translation = {v[1], v[2], v[3]};
  s.world_from_cam.rotation = glm::dquat(v[7], v[4], v[5], v[6]);
  if (!std::isfinite(v[0])) return absl::InvalidArgumentError("pose timestamp is NaN or Inf");
  EXO_RETURN_IF_ERROR(ValidateQuaternion(s.world_from_cam.rotation));
  for (int i = 1; i <= 3; ++i)
    if (!std::isfinite(v[i])) return absl::InvalidArgumentError("pose translation has NaN or Inf");
  return s;
}

std::string PoseHmacHex(const std::string& key, const std::string& text) {
  unsigned char mac[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  HMAC(EVP_sha256(), key.data(), static_cast<int>(key.size()),
       reinterpret_cast<const unsigned char*>(text.data()), text.size(), mac, &len);
  static const char* kHex = "0123456789abcdef";
  std::string out;
  for (unsigned int i = 0; i < len; ++i) {
    out.push_back(kHex[mac[i] >> 4]);
    out.push_back(kHex[mac[i] & 15]);
  }
  return out;
}

std::string SignPoseDatagram(const std::string& key, uint64_t sequence, const std::string& pose_text) {
  const std::string body = absl::StrCat(sequence, " ", pose_text);
  return absl::StrCat(body, " ", PoseHmacHex(key, body));
}

absl::StatusOr<PoseSample> VerifyPoseDatagram(const std::string& key, const std::string& text,
                                              uint64_t* sequence) {
  const size_t sp = text.find_last_of(' ');
  if (sp == std::string::npos || text.size() - sp - 1 != 64)
    return absl::UnauthenticatedError("pose datagram carries no HMAC");
  const std::string body = text.substr(0, sp);
  const std::string want = PoseHmacHex(key, body);
  if (CRYPTO_memcmp(want.data(), text.data() + sp + 1, 64) != 0)
    return absl::UnauthenticatedError("pose datagram HMAC does not match");
  const size_t first = body.find(' ');
  if (first == std::string::npos || !absl::SimpleAtoi(body.substr(0, first), sequence))
    return absl::InvalidArgumentError("authenticated pose datagram must start with its sequence");
  return ParsePoseDatagram(body.substr(first + 1));
}

absl::StatusOr<std::string> ReadPoseKeyFile(const std::string& path) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0)
    return absl::NotFoundError(absl::StrCat("cannot open UDP pose key file ", path));
  if ((st.st_mode & (S_IROTH | S_IWOTH)) != 0)
    return absl::PermissionDeniedError(absl::StrCat(
        "UDP pose key file ", path, " is readable or writable by others (chmod 600 it)"));
  std::ifstream in(path);
  std::string key;
  std::getline(in, key);
  while (!key.empty() && (key.back() == '\r' || key.back() == ' ')) key.pop_back();
  if (key.size() < 16)
    return absl::InvalidArgumentError(
        absl::StrCat("UDP pose key file ", path, ": the key needs at least 16 bytes"));
  return key;
}

struct UdpPoseInput::Impl {
  boost::asio::io_context io;
  boost::asio::ip::udp::socket socket{io};
};

absl::Status PoseTimeGateOptions::Validate() const {
  if (!(max_lead_s > 0) || !(max_lag_s > 0) || !(max_backwards_s >= 0) || !(rebase_after_s > 0) ||
      !std::isfinite(max_lead_s + max_lag_s + max_backwards_s + rebase_after_s))
    return absl::InvalidArgumentError(
        "udp_pose_max_lead_s, udp_pose_max_lag_s and udp_pose_rebase_after_s must be finite and "
        "> 0, udp_pose_max_backwards_s finite and >= 0");
  return absl::OkStatus();
}

const char* PoseTimeGate::Name(Verdict v) {
  switch (v) {
    case Verdict::kAccept: return "accept";
    case Verdict::kRebased: return "rebased";
    case Verdict::kFuture: return "future";
    case Verdict::kPast: return "past";
    case Verdict::kBackwards: return "backwards";
  }
  return "?";
}

PoseTimeGate::Verdict PoseTimeGate::Check(double t, double now_s) {
  const double off = t - now_s;
  if (!anchored_) {
    anchored_ = true;
    offset_ = off;
    newest_ = t;
    return Verdict::kAccept;
  }
  const double lead = off - offset_;
  Verdict v = Verdict::kAccept;
  if (lead > o_.max_lead_s)
    v = Verdict::kFuture;
  else if (lead < -o_.max_lag_s)
    v = Verdict::kPast;
  else if (t < newest_ - o_.max_backwards_s)
    v = Verdict::kBackwards;
  if (v == Verdict::kAccept) {
    in_stretch_ = false;
    newest_ = std::max(newest_, t);
    return v;
  }
  if (!in_stretch_ || std::abs(off - stretch_offset_) > o_.max_lead_s) {
    in_stretch_ = true;  // a new stretch of rejected datagrams starts here
    stretch_start_s_ = now_s;
    stretch_offset_ = off;
  } else if (now_s - stretch_start_s_ >= o_.rebase_after_s) {
    in_stretch_ = false;
    offset_ = off;
    newest_ = t;
    return Verdict::kRebased;
  }
  return v;
}

absl::StatusOr<std::unique_ptr<UdpPoseInput>> UdpPoseInput::Start(const std::string& address,
                                                                  int port, size_t capacity,
                                                                  const std::string& hmac_key,
                                                                  const PoseTimeGateOptions& time) {
  EXO_RETURN_IF_ERROR(time.Validate());
  auto in = std::unique_ptr<UdpPoseInput>(new UdpPoseInput);
  in->key_ = hmac_key;
  in->gate_ = PoseTimeGate(time);
  in->stream_ = PoseStream(capacity);
  in->impl_ = std::make_unique<Impl>();
  boost::system::error_code ec;
  const auto addr = boost::asio::ip::make_address(address, ec);
  if (ec) return absl::InvalidArgumentError("bad UDP pose address " + address);
  in->impl_->socket.open(addr.is_v6() ? boost::asio::ip::udp::v6() : boost::asio::ip::udp::v4(), ec);
  if (!ec) in->impl_->socket.bind({addr, static_cast<unsigned short>(port)}, ec);
  if (ec) return absl::UnavailableError("cannot bind UDP pose port: " + ec.message());
  in->port_ = in->impl_->socket.local_endpoint().port();
  UdpPoseInput* self = in.get();
  in->thread_ = std::thread([self] {
    std::array<char, 512> buf;
    boost::asio::ip::udp::endpoint from;
    for (;;) {
      boost::system::error_code ec;
      const size_t n = self->impl_->socket.receive_from(boost::asio::buffer(buf), from, 0, ec);
      if (self->stopping_.load()) return;
      if (ec) continue;
      const std::string text(buf.data(), n);
      uint64_t seq = 0;
      auto sample = self->key_.empty() ? ParsePoseDatagram(text)
                                       : VerifyPoseDatagram(self->key_, text, &seq);
      if (!sample.ok()) {
        (sample.status().code() == absl::StatusCode::kUnauthenticated ? self->unauthenticated_
                                                                       : self->malformed_)
            .fetch_add(1);
        continue;
      }
      if (!self->key_.empty()) {
        if (seq <= self->last_sequence_) {  // a replay of an earlier datagram
          self->replayed_.fetch_add(1);
          continue;
        }
        self->last_sequence_ = seq;
      }
      const double now_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
      const PoseTimeGate::Verdict v = self->gate_.Check(sample->timestamp_s, now_s);
      if (v == PoseTimeGate::Verdict::kFuture) {
        self->rejected_future_.fetch_add(1);
        continue;
      }
      if (v == PoseTimeGate::Verdict::kPast) {
        self->rejected_past_.fetch_add(1);
        continue;
      }
      if (v == PoseTimeGate::Verdict::kBackwards) {
        self->rejected_backwards_.fetch_add(1);
        continue;
      }
      std::lock_guard lock(self->mu_);
      if (v == PoseTimeGate::Verdict::kRebased) {  // the old samples are in another time base
        self->rebased_.fetch_add(1);
        self->stream_ = PoseStream(self->stream_.capacity());
      }
      if (self->stream_.Add(sample->timestamp_s, sample->world_from_cam).ok())
        self->received_.fetch_add(1);
      else
        self->malformed_.fetch_add(1);
    }
  });
  return in;
}

UdpPoseInput::~UdpPoseInput() {
  if (!impl_) return;
  stopping_.store(true);
  boost::system::error_code ec;
  // Wake the blocking receive with a datagram to ourselves, then join and close.
  auto local = impl_->socket.local_endpoint(ec);
  if (local.address().is_unspecified())
    local.address(local.address().is_v6()
                      ? boost::asio::ip::address(boost::asio::ip::address_v6::loopback())
                      : boost::asio::ip::address(boost::asio::ip::address_v4::loopback()));
  while (thread_.joinable()) {
    boost::asio::io_context io;
    boost::asio::ip::udp::socket s(io, local.protocol());
    s.send_to(boost::asio::buffer("x", 1), local, 0, ec);
    thread_.join();
  }
  impl_->socket.close(ec);
}

absl::StatusOr<Rigid3d> UdpPoseInput::PoseAt(double timestamp_s, double tolerance_s) const {
  std::lock_guard lock(mu_);
  if (stream_.empty())
    return absl::FailedPreconditionError("no pose: the UDP pose stream has received nothing yet");
  return stream_.Interpolate(timestamp_s, tolerance_s);
}

}  // namespace exo
