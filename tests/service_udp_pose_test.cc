// UDP pose input on the real server process (SPEC §2): frames uploaded without a pose get it from
// the UDP pose stream at their timestamp; a frame with no pose sample within the tolerance is
// rejected with a clear reason and the stream goes on.
#include <filesystem>
#include <fstream>
#include <regex>
#include <utility>  // before Boost.Asio 1.74 (awaitable.hpp needs std::exchange)

#include <boost/asio.hpp>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include "client/uploader/upload_client.h"
#include "proto/exoview.grpc.pb.h"
#include "server/service/udp_pose_input.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

v1::Frame PoselessFrame(uint64_t seq, double t) {
  Frame f;
  f.sequence = seq;
  f.timestamp_s = t;
  f.color_camera = PinholeCamera::FromFov(64, 48, 1.2);
  f.depth_camera = f.color_camera;
  f.color = ImageU8(64, 48, 3, 128);
  f.depth_m = ImageF(64, 48, 1, 2.0f);
  auto m = FrameToProto(f, {});
  EXO_CHECK(m.ok());
  m->clear_world_from_cam();
  return *m;
}

TEST(ServiceUdpPose, PoselessFramesTakeTheirPoseFromUdp) {
  char tmpl[] = "/tmp/exoview_udp_XXXXXX";
  ASSERT_NE(mkdtemp(tmpl), nullptr);
  const std::string dir = tmpl;
  testing::Subprocess server(EXOVIEW_SERVER_BIN,
                             {"--listen=127.0.0.1:0", "--port_file=" + dir + "/port",
                              "--udp_pose_port=0", "--udp_pose_tolerance_s=0.02"},
                             dir + "/server.log");
  ASSERT_TRUE(testing::WaitForFile(dir + "/port", 20)) << server.Log();
  std::smatch m;
  const std::string log = server.Log();
  ASSERT_TRUE(std::regex_search(log, m, std::regex("UDP poses on port ([0-9]+)"))) << log;
  const int udp_port = std::stoi(m[1]);
  const std::string target = "127.0.0.1:" + std::to_string(std::stoi(testing::ReadAll(dir + "/port")));

  // Poses at 120 Hz for t in [1, 2] s and [3, 4] s (a one-second gap in between).
  boost::asio::io_context io;
  boost::asio::ip::udp::socket s(io, boost::asio::ip::udp::v4());
  const boost::asio::ip::udp::endpoint to(boost::asio::ip::make_address("127.0.0.1"),
                                          static_cast<unsigned short>(udp_port));
  for (double start : {1.0, 3.0})
    for (int i = 0; i <= 120; ++i) {
      const std::string d =
          std::to_string(start + i / 120.0) + " " + std::to_string(0.01 * i) + " 0 0 0 0 0 1";
      s.send_to(boost::asio::buffer(d), to);
    }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));

  std::vector<v1::Frame> frames{PoselessFrame(1, 1.5), PoselessFrame(2, 2.5), PoselessFrame(3, 3.5)};
  UploadOptions opt;
  opt.rate_hz = 0;
  opt.max_in_flight = 1;
  auto st = UploadStream(MakeChannel(target), frames.size(),
                         [&](size_t i) -> absl::StatusOr<v1::Frame> { return frames[i]; }, opt);
  ASSERT_TRUE(st.ok()) << st.status();
  ASSERT_EQ(st->acks.size(), 3u);
  EXPECT_EQ(st->acks[0].status(), v1::Ack::ACCEPTED) << st->acks[0].reason();
  EXPECT_EQ(st->acks[1].status(), v1::Ack::REJECTED);
  EXPECT_NE(st->acks[1].reason().find("no pose for the frame from the UDP pose stream"),
            std::string::npos) << st->acks[1].reason();
  EXPECT_EQ(st->acks[2].status(), v1::Ack::ACCEPTED) << st->acks[2].reason();
  server.Signal(SIGTERM);
  EXPECT_EQ(server.Wait(15), 0) << server.Log();
  std::filesystem::remove_all(dir);
}


// Issue 20 item 5 on the real server: with udp_pose_key_file only HMAC-signed datagrams move
// poses. A spoofed datagram (5 km off, no MAC) and a replayed one are dropped and counted, and
// the frame at their timestamp is accepted with the authentic pose (a 5 km pose would be
// rejected by the scene radius).
TEST(ServiceUdpPose, AuthenticatedPosesIgnoreSpoofedAndReplayedDatagrams) {
  char tmpl[] = "/tmp/exoview_udp_XXXXXX";
  ASSERT_NE(mkdtemp(tmpl), nullptr);
  const std::string dir = tmpl;
  const std::string key = "udp-shared-key-0123456789";
  {
    std::ofstream(dir + "/udp.key") << key << "\n";
    std::filesystem::permissions(dir + "/udp.key", std::filesystem::perms::owner_read |
                                                       std::filesystem::perms::owner_write);
  }
  testing::Subprocess server(EXOVIEW_SERVER_BIN,
                             {"--listen=127.0.0.1:0", "--port_file=" + dir + "/port",
                              "--udp_pose_port=0", "--udp_pose_tolerance_s=0.02",
                              "--udp_pose_key_file=" + dir + "/udp.key"},
                             dir + "/server.log");
  ASSERT_TRUE(testing::WaitForFile(dir + "/port", 20)) << server.Log();
  std::smatch m;
  const std::string log = server.Log();
  ASSERT_TRUE(std::regex_search(log, m, std::regex("UDP poses on port ([0-9]+)"))) << log;
  EXPECT_NE(log.find("HMAC-SHA256 authenticated"), std::string::npos) << log;
  const int udp_port = std::stoi(m[1]);
  const std::string target = "127.0.0.1:" + std::to_string(std::stoi(testing::ReadAll(dir + "/port")));
  boost::asio::io_context io;
  boost::asio::ip::udp::socket s(io, boost::asio::ip::udp::v4());
  const boost::asio::ip::udp::endpoint to(boost::asio::ip::make_address("127.0.0.1"),
                                          static_cast<unsigned short>(udp_port));
  std::string first;
  for (int i = 0; i <= 120; ++i) {
    const std::string d = SignPoseDatagram(
        key, 1000 + i, std::to_string(1.0 + i / 120.0) + " " + std::to_string(0.01 * i) + " 0 0 0 0 0 1");
    if (i == 0) first = d;
    s.send_to(boost::asio::buffer(d), to);
  }
  s.send_to(boost::asio::buffer(std::string("1.5 5000 0 0 0 0 0 1")), to);  // spoofed
  s.send_to(boost::asio::buffer(first), to);                                 // replayed
  std::this_thread::sleep_for(std::chrono::milliseconds(300));

  std::vector<v1::Frame> frames{PoselessFrame(1, 1.5)};
  UploadOptions opt;
  opt.rate_hz = 0;
  auto st = UploadStream(MakeChannel(target), frames.size(),
                         [&](size_t i) -> absl::StatusOr<v1::Frame> { return frames[i]; }, opt);
  ASSERT_TRUE(st.ok()) << st.status();
  ASSERT_EQ(st->acks.size(), 1u);
  EXPECT_EQ(st->acks[0].status(), v1::Ack::ACCEPTED) << st->acks[0].reason();
  auto stub = v1::Exoview::NewStub(MakeChannel(target));
  grpc::ClientContext ctx;
  v1::Stats stats;
  ASSERT_TRUE(stub->GetStats(&ctx, v1::StatsRequest{}, &stats).ok());
  EXPECT_EQ(stats.counters().at("udp.received"), 121.0);
  EXPECT_EQ(stats.counters().at("udp.unauthenticated"), 1.0);
  EXPECT_EQ(stats.counters().at("udp.replayed"), 1.0);
  server.Signal(SIGTERM);
  EXPECT_EQ(server.Wait(15), 0) << server.Log();
  std::filesystem::remove_all(dir);
}

TEST(ServiceUdpPose, PlainPosesOnANonLoopbackAddressAreRefusedAtStart) {
  char tmpl[] = "/tmp/exoview_udp_XXXXXX";
  ASSERT_NE(mkdtemp(tmpl), nullptr);
  const std::string dir = tmpl;
  testing::Subprocess server(EXOVIEW_SERVER_BIN,
                             {"--listen=127.0.0.1:0", "--udp_pose_port=0",
                              "--udp_pose_address=0.0.0.0"},
                             dir + "/server.log");
  const auto rc = server.Wait(20);
  ASSERT_TRUE(rc.has_value());
  EXPECT_NE(*rc, 0);
  EXPECT_NE(server.Log().find("refusing unauthenticated UDP poses on 0.0.0.0"), std::string::npos)
      << server.Log();
  std::filesystem::remove_all(dir);
}


// Timestamp bounds against the server clock (issue 20 item 5) on the real server: a flood of
// datagrams stamped far in the future (3x the stream's capacity) is rejected and counted, and
// later frames still get their pose; then the sender restarts with another time base (its poses
// now look 10 s old): rejected as "past" for udp_pose_rebase_after_s, then re-anchored without
// a server restart, and frames in the new time base are accepted.
TEST(ServiceUdpPose, FutureFloodAndATimeBaseChangeAreSurvivedWithoutRestart) {
  char tmpl[] = "/tmp/exoview_udp_XXXXXX";
  ASSERT_NE(mkdtemp(tmpl), nullptr);
  const std::string dir = tmpl;
  testing::Subprocess server(EXOVIEW_SERVER_BIN,
                             {"--listen=127.0.0.1:0", "--port_file=" + dir + "/port",
                              "--udp_pose_port=0", "--udp_pose_tolerance_s=0.02",
                              "--udp_pose_rebase_after_s=0.5"},
                             dir + "/server.log");
  ASSERT_TRUE(testing::WaitForFile(dir + "/port", 20)) << server.Log();
  std::smatch m;
  const std::string log = server.Log();
  ASSERT_TRUE(std::regex_search(log, m, std::regex("UDP poses on port ([0-9]+)"))) << log;
  const int udp_port = std::stoi(m[1]);
  const std::string target = "127.0.0.1:" + std::to_string(std::stoi(testing::ReadAll(dir + "/port")));
  boost::asio::io_context io;
  boost::asio::ip::udp::socket s(io, boost::asio::ip::udp::v4());
  const boost::asio::ip::udp::endpoint to(boost::asio::ip::make_address("127.0.0.1"),
                                          static_cast<unsigned short>(udp_port));
  auto send = [&](double t, double x) {
    const std::string d = std::to_string(t) + " " + std::to_string(x) + " 0 0 0 0 0 1";
    s.send_to(boost::asio::buffer(d), to);
  };
  auto stats = [&] {
    auto stub = v1::Exoview::NewStub(MakeChannel(target));
    grpc::ClientContext ctx;
    v1::Stats out;
    EXPECT_TRUE(stub->GetStats(&ctx, v1::StatsRequest{}, &out).ok());
    return out;
  };
  auto upload = [&](uint64_t seq, double t) {
    std::vector<v1::Frame> frames{PoselessFrame(seq, t)};
    UploadOptions opt;
    opt.rate_hz = 0;
    auto st = UploadStream(MakeChannel(target), 1,
                           [&](size_t) -> absl::StatusOr<v1::Frame> { return frames[0]; }, opt);
    EXPECT_TRUE(st.ok()) << st.status();
    return st.ok() && !st->acks.empty() ? st->acks[0] : v1::Ack{};
  };
  send(10.0, 0.0);                                       // anchors the sender's time base
  for (int i = 0; i < 3 * 4096; ++i) send(1e9 + i, 1000.0);  // the flood: all in the future
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // (less to drop at the socket)
  for (int i = 1; i <= 60; ++i) send(10.0 + i / 120.0, 0.01 * i);
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  const v1::Ack a1 = upload(1, 10.25);
  EXPECT_EQ(a1.status(), v1::Ack::ACCEPTED) << a1.reason();
  v1::Stats st = stats();
  // (UDP may drop datagrams of a 12k burst at the socket, more so under a sanitizer build: 59 of
  // the 61 good ones arrived there once. At least the stream's capacity was refused.)
  EXPECT_GT(st.counters().at("udp.rejected_future"), 4096.0);
  EXPECT_LE(st.counters().at("udp.received"), 61.0);
  EXPECT_GE(st.counters().at("udp.received"), 40.0);

  // The sender restarts with a time base 10 s behind: "past" until the gate re-anchors.
  const auto t0 = std::chrono::steady_clock::now();
  double rebased = 0;
  for (int i = 0; rebased == 0 && i < 300; ++i) {
    const double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    send(el, 0.0);
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    if (i % 20 == 19) rebased = stats().counters().at("udp.rebased");
  }
  ASSERT_EQ(rebased, 1.0) << server.Log();
  st = stats();
  EXPECT_GT(st.counters().at("udp.rejected_past"), 10.0);
  const double now = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  for (int i = 0; i <= 24; ++i) send(now + i / 120.0, 1.0 + 0.01 * i);
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  const v1::Ack a2 = upload(2, now + 0.1);
  EXPECT_EQ(a2.status(), v1::Ack::ACCEPTED) << a2.reason();
  server.Signal(SIGTERM);
  EXPECT_EQ(server.Wait(15), 0) << server.Log();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace exo
