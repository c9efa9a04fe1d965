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


// Issue 20 item 5: HMAC-SHA256 datagrams. A valid one verifies; any changed byte, a wrong key or
// a missing MAC is unauthenticated; the sequence comes back for the replay check.
TEST(UdpPose, HmacSignedDatagramsVerifyAndAnyChangeIsCaught) {
  const std::string key = "0123456789abcdef-shared";
  const std::string d = SignPoseDatagram(key, 42, "1.5 0.1 0.2 0.3 0 0 0 1");
  uint64_t seq = 0;
  auto p = VerifyPoseDatagram(key, d, &seq);
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_EQ(seq, 42u);
  EXPECT_DOUBLE_EQ(p->timestamp_s, 1.5);
  EXPECT_DOUBLE_EQ(p->world_from_cam.translation.z, 0.3);
  // RFC 4231 test case 2: HMAC-SHA256("Jefe", "what do ya want for nothing?").
  EXPECT_EQ(PoseHmacHex("Jefe", "what do ya want for nothing?"),
            "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843");
  for (size_t i = 0; i < d.size(); ++i) {
    std::string t = d;
    t[i] = t[i] == '1' ? '2' : '1';
    EXPECT_FALSE(VerifyPoseDatagram(key, t, &seq).ok()) << i;
  }
  EXPECT_EQ(VerifyPoseDatagram("another-key-0123456", d, &seq).status().code(),
            absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(VerifyPoseDatagram(key, "1.5 5000 0 0 0 0 0 1", &seq).status().code(),
            absl::StatusCode::kUnauthenticated);
}

TEST(UdpPose, AuthenticatedInputDropsSpoofedAndReplayedDatagramsAndCountsThem) {
  const std::string key = "0123456789abcdef-shared";
  auto in = UdpPoseInput::Start("127.0.0.1", 0, 64, key);
  ASSERT_TRUE(in.ok()) << in.status();
  boost::asio::io_context io;
  boost::asio::ip::udp::socket s(io, boost::asio::ip::udp::v4());
  const boost::asio::ip::udp::endpoint to(boost::asio::ip::make_address("127.0.0.1"),
                                          static_cast<unsigned short>((*in)->port()));
  const std::string good1 = SignPoseDatagram(key, 100, "10.0 0 0 0 0 0 0 1");
  const std::string good2 = SignPoseDatagram(key, 101, "10.1 1 0 0 0 0 0 1");
  const std::string msgs[] = {
      good1,
      "10.05 5000 0 0 0 0 0 1",                                        // spoofed: no MAC
      SignPoseDatagram("attacker-key-012345", 102, "10.05 5000 0 0 0 0 0 1"),  // wrong key
      good2,
      good1,                                                          // replay
      SignPoseDatagram(key, 101, "10.07 4000 0 0 0 0 0 1"),           // reused sequence
  };
  for (const auto& m : msgs) s.send_to(boost::asio::buffer(m), to);
  for (int i = 0; i < 400 && (*in)->received() + (*in)->unauthenticated() + (*in)->replayed() < 6; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  EXPECT_EQ((*in)->received(), 2u);
  EXPECT_EQ((*in)->unauthenticated(), 2u);
  EXPECT_EQ((*in)->replayed(), 2u);
  auto p = (*in)->PoseAt(10.05, 0.06);
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_NEAR(p->translation.x, 0.5, 1e-9);  // between the two authentic samples only
}

}  // namespace
}  // namespace exo

namespace exo {
namespace {

// The time gate (issue 20 item 5): bounds against the server clock, each reason counted by its
// verdict, later good datagrams accepted, and a re-anchoring after a consistent bad stretch.
TEST(UdpPoseTimeGate, RejectsFuturePastAndBackwardsAndKeepsAcceptingGoodPoses) {
  PoseTimeGateOptions o;  // lead 5 s, lag 5 s, backwards 1 s, rebase after 2 s
  PoseTimeGate g(o);
  using V = PoseTimeGate::Verdict;
  // Sender time base: t = server time + 1000 (anchored by the first datagram).
  EXPECT_EQ(g.Check(1000.0, 0.0), V::kAccept);
  EXPECT_EQ(g.Check(1000.1, 0.1), V::kAccept);
  // A bursty good sender (3 s of poses at once) is within the lead bound.
  for (int i = 0; i < 360; ++i) EXPECT_EQ(g.Check(1000.2 + i / 120.0, 0.2), V::kAccept) << i;
  EXPECT_EQ(g.Check(1e300, 0.3), V::kFuture);
  EXPECT_EQ(g.Check(1000.3 + 6.0, 0.3), V::kFuture);  // 6 s ahead of the server clock
  EXPECT_EQ(g.Check(1000.3 + 4.5, 0.3), V::kAccept);  // 4.5 s ahead: within max_lead_s
  EXPECT_EQ(g.Check(1000.3 - 6.0, 0.3), V::kPast);    // 6 s behind
  EXPECT_EQ(g.Check(1004.8 - 1.5, 0.31), V::kBackwards);  // 1.5 s before the newest accepted
  EXPECT_EQ(g.Check(1004.8 - 0.5, 0.32), V::kAccept);     // reordering within the window
  // Interleaved future datagrams (a spoofer) for 10 s never rebase the good stream.
  for (int i = 0; i < 100; ++i) {
    const double now = 1.0 + i * 0.1;
    EXPECT_EQ(g.Check(now + 1000.0 + 4.0, now), V::kAccept) << i;
    EXPECT_EQ(g.Check(now + 5000.0, now), V::kFuture) << i;
  }
}

TEST(UdpPoseTimeGate, ConsistentBadStretchReanchorsWithoutRestart) {
  PoseTimeGate g;
  using V = PoseTimeGate::Verdict;
  // A bad first datagram anchors the time base 1e6 s in the future...
  EXPECT_EQ(g.Check(1e6, 0.0), V::kAccept);
  // ...then the real sender (t = server time + 10) is "past" for 2 s, then re-anchored.
  int rejected = 0;
  double now = 0.01;
  for (; now < 3.0; now += 0.01) {
    const V v = g.Check(now + 10.0, now);
    if (v == V::kRebased) break;
    EXPECT_EQ(v, V::kPast);
    ++rejected;
  }
  EXPECT_NEAR(now, 2.01, 0.02);
  EXPECT_GT(rejected, 150);
  EXPECT_EQ(g.Check(now + 0.01 + 10.0, now + 0.01), V::kAccept);
  // Inconsistent rejected datagrams (each far from the last) never add up to a stretch.
  PoseTimeGate h;
  EXPECT_EQ(h.Check(100.0, 0.0), V::kAccept);
  for (int i = 1; i < 400; ++i)
    EXPECT_NE(h.Check(100.0 + 100.0 * (i % 2 ? i : -i), i * 0.01), V::kRebased) << i;
  EXPECT_FALSE(PoseTimeGateOptions{.max_lead_s = 0}.Validate().ok());
}

// Over a real socket: a flood of future-stamped datagrams is rejected and counted, and the good
// poses that follow are matched to frames.
TEST(UdpPoseTimeGate, FutureFloodOverTheSocketDoesNotPushOutGoodPoses) {
  auto in = UdpPoseInput::Start("127.0.0.1", 0, /*capacity=*/64);
  ASSERT_TRUE(in.ok()) << in.status();
  boost::asio::io_context io;
  boost::asio::ip::udp::socket s(io, boost::asio::ip::udp::v4());
  const boost::asio::ip::udp::endpoint to(boost::asio::ip::make_address("127.0.0.1"),
                                          static_cast<unsigned short>((*in)->port()));
  auto send = [&](double t, double x) {
    s.send_to(boost::asio::buffer(std::to_string(t) + " " + std::to_string(x) + " 0 0 0 0 0 1"), to);
  };
  send(1.0, 0.0);  // anchors
  for (int i = 0; i < 200; ++i) send(1e6 + i, 1000.0);  // future flood, 3x the capacity
  for (int i = 1; i <= 20; ++i) send(1.0 + i / 100.0, 0.01 * i);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while ((*in)->received() + (*in)->rejected_future() < 221 &&
         std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  EXPECT_EQ((*in)->rejected_future(), 200u);
  EXPECT_EQ((*in)->received(), 21u);
  auto pose = (*in)->PoseAt(1.105, 0.02);
  ASSERT_TRUE(pose.ok()) << pose.status();
  EXPECT_NEAR(pose->translation.x, 0.105, 1e-6);
}

}  // namespace
}  // namespace exo
