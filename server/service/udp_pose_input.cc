#include "server/service/udp_pose_input.h"

#include <array>
#include <sstream>

#include <boost/asio.hpp>

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

struct UdpPoseInput::Impl {
  boost::asio::io_context io;
  boost::asio::ip::udp::socket socket{io};
};

absl::StatusOr<std::unique_ptr<UdpPoseInput>> UdpPoseInput::Start(const std::string& address,
                                                                  int port, size_t capacity) {
  auto in = std::unique_ptr<UdpPoseInput>(new UdpPoseInput);
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
      auto sample = ParsePoseDatagram(std::string(buf.data(), n));
      if (!sample.ok()) {
        self->malformed_.fetch_add(1);
        continue;
      }
      std::lock_guard lock(self->mu_);
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
