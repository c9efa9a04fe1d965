// UDP pose input: datagram parsing (bad datagrams rejected) and SLERP/lerp matching of a frame
// timestamp to poses received over a real loopback UDP socket.
#include "server/service/udp_pose_input.h"

#include <chrono>
#include <cmath>
#include <thread>

#include <boost/asio.hpp>
#include <gtest/gtest.h>

namespace exo {
namespace {

TEST(UdpPose, ParseRejectsMalformedDatagrams) {
  EXPECT_TRUE(ParsePoseDatagram("1.0 0 0 0 0 0 0 1").ok());
  EXPECT_FALSE(ParsePoseDatagram("1.0 0 0 0 0 0 0").ok());            // 7 fields
  EXPECT_FALSE(ParsePoseDatagram("1.0 0 0 0 0 0 0 1 9").ok());        // 9 fields
  EXPECT_FALSE(ParsePoseDatagram("1.0 0 0 0 0 0 0 2").ok());          // |q| = 2
  EXPECT_FALSE(ParsePoseDatagram("nan 0 0 0 0 0 0 1").ok());
  EXPECT_FALSE(ParsePoseDatagram("1.0 a 0 0 0 0 0 1").ok());
}

TEST(UdpPose, FramesMatchedByTimestampWithSlerp) {
  auto in = UdpPoseInput::Start("127.0.0.1", 0);
  ASSERT_TRUE(in.ok()) << in.status();
  boost::asio::io_context io;
  boost::asio::ip::udp::socket s(io, boost::asio::ip::udp::v4());
  const boost::asio::ip::udp::endpoint to(boost::asio::ip::make_address("127.0.0.1"),
                                          static_cast<unsigned short>((*in)->port()));
  const double c = std::cos(M_PI / 4), sn = std::sin(M_PI / 4);  // 90 deg about z
  const std::string msgs[] = {"10.0 0 0 0 0 0 0 1", "garbage",
                              "10.1 1 2 0 0 0 " + std::to_string(sn) + " " + std::to_string(c)};
  for (const auto& m : msgs) s.send_to(boost::asio::buffer(m), to);
  for (int i = 0; i < 200 && (*in)->received() + (*in)->malformed() < 3; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  EXPECT_EQ((*in)->received(), 2u);
  EXPECT_EQ((*in)->malformed(), 1u);
  auto p = (*in)->PoseAt(10.05, 0.06);
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_NEAR(p->translation.x, 0.5, 1e-9);
  EXPECT_NEAR(p->translation.y, 1.0, 1e-9);
  // Halfway between 0 and 90 degrees about z.
  EXPECT_NEAR(RotationAngleRad(p->rotation, glm::dquat(1, 0, 0, 0)), M_PI / 4, 1e-5);
  // No sample within tolerance: a clear error (the frame would be rejected with it).
  EXPECT_FALSE((*in)->PoseAt(12.0, 0.02).ok());
}

}  // namespace
}  // namespace exo
