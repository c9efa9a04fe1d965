// The server's log, read from the stderr of a real exoview_server process on loopback: 1000 bad
// frames on one Upload stream give a rate-limited number of "rejected frame" lines (peer,
// sequence, reason; the suppressed ones counted), and the stream's summary line carries the right
// counts; subscriber connect/disconnect, startup and shutdown are logged; every line has the
// ISO time, the level and the component.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <regex>
#include <sstream>

#include "client/uploader/upload_client.h"
#include "proto/exoview.grpc.pb.h"
#include "server/service/upload_log.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using testing::ReadAll;
using testing::Subprocess;
using testing::WaitForFile;

constexpr int kLinesPerSecond = 4;  // not the default (5): the startup line must show it
constexpr int kBadFrames = 1000;
constexpr int kGoodFrames = 3;

v1::Frame SmallFrame(uint64_t seq) {
  Frame f;
  f.sequence = seq;
  f.timestamp_s = 0.05 * seq;
  f.color_camera = PinholeCamera::FromFov(32, 24, 1.2);
  f.depth_camera = f.color_camera;
  f.color = ImageU8(32, 24, 3, 128);
  f.depth_m = ImageF(32, 24, 1, 2.0f);
  f.world_from_cam.translation = {0.3 * seq, 0.0, 0.0};
  auto m = FrameToProto(f, {});
  EXO_CHECK(m.ok());
  return *m;
}

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) out.push_back(line);
  return out;
}

TEST(ServiceLog, RejectionsRateLimitedAndStreamSummaryCounts) {
  char tmpl[] = "/tmp/exoview_log_XXXXXX";
  ASSERT_NE(mkdtemp(tmpl), nullptr);
  const std::string dir = tmpl;
  Subprocess server(
      EXOVIEW_SERVER_BIN,
      {"--listen=127.0.0.1:0", "--port_file", dir + "/port", "--log_level=info",
       "--log_rejections_per_s=" + std::to_string(kLinesPerSecond), "--max_views", "50"},
      dir + "/server.log");
  ASSERT_TRUE(WaitForFile(dir + "/port", 20)) << server.Log();
  auto channel = MakeChannel("127.0.0.1:" + std::to_string(std::stoi(ReadAll(dir + "/port"))));
  auto stub = v1::Exoview::NewStub(channel);

  // A subscriber connects and leaves.
  {
    grpc::ClientContext ctx;
    auto reader = stub->Subscribe(&ctx, v1::SubscribeRequest{});
    for (int i = 0; i < 500; ++i) {  // until the server has it (it logged the connect)
      grpc::ClientContext stats_ctx;
      v1::Stats stats;
      ASSERT_TRUE(stub->GetStats(&stats_ctx, v1::StatsRequest{}, &stats).ok());
      if (stats.subscribers() == 1) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    ctx.TryCancel();
    v1::Delta d;
    while (reader->Read(&d)) {
    }
    (void)reader->Finish();
  }

  // One Upload stream: good frames around 1000 frames without a pose, one frame in flight.
  std::string reason;
  int accepted = 0;
  const auto t0 = std::chrono::steady_clock::now();
  {
    grpc::ClientContext ctx;
    auto stream = stub->Upload(&ctx);
    uint64_t seq = 0;
    auto send = [&](v1::Frame f) {
      f.set_sequence(++seq);
      f.set_timestamp_s(0.01 * seq);
      ASSERT_TRUE(stream->Write(f));
      v1::Ack ack;
      ASSERT_TRUE(stream->Read(&ack));
      ASSERT_EQ(ack.sequence(), seq);
      if (ack.status() == v1::Ack::ACCEPTED) ++accepted;
      if (ack.status() == v1::Ack::REJECTED) reason = ack.reason();
    };
    send(SmallFrame(1));
    // Spread over more than two seconds, so the limit works over several windows.
    for (int i = 0; i < kBadFrames; ++i) {
      v1::Frame bad = SmallFrame(2 + i);
      bad.clear_world_from_cam();
      send(bad);
      std::this_thread::sleep_for(std::chrono::microseconds(2500));
    }
    for (int i = 1; i < kGoodFrames; ++i) send(SmallFrame(1000 + i));
    stream->WritesDone();
    ASSERT_TRUE(stream->Finish().ok());
  }
  const double stream_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_EQ(accepted, kGoodFrames);
  ASSERT_FALSE(reason.empty());

  server.Signal(SIGTERM);
  ASSERT_EQ(server.Wait(20), 0) << server.Log();
  const std::vector<std::string> lines = Lines(server.Log());
  std::filesystem::remove_all(dir);

  // Every line: ISO time with ms and offset, level, [component].
  const std::regex format(
      R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}[+-]\d\d:\d\d (trace|debug|info|warning|error|critical) \[[a-z_]+\] .+)");
  int rejected_lines = 0;
  uint64_t suppressed_in_lines = 0;
  std::string summary, joined;
  for (const std::string& l : lines) {
    joined += l + "\n";
    EXPECT_TRUE(std::regex_match(l, format)) << l;
    if (l.find("[ingest] rejected frame: peer=ipv4:127.0.0.1:") != std::string::npos) {
      ++rejected_lines;
      EXPECT_NE(l.find(" warning "), std::string::npos) << l;
      EXPECT_NE(l.find("reason=\"" + reason + "\""), std::string::npos) << l;
      std::smatch m;
      if (std::regex_search(l, m, std::regex(R"(\((\d+) similar lines suppressed\))")))
        suppressed_in_lines += std::stoull(m[1]);
    }
    if (l.find("upload stream ended") != std::string::npos) summary = l;
  }
  // The first bad frame (sequence 2) is logged; at most kLinesPerSecond lines per started
  // second of the stream.
  EXPECT_NE(joined.find("rejected frame: peer=ipv4:127.0.0.1:"), std::string::npos);
  EXPECT_NE(joined.find(" sequence=2 reason="), std::string::npos) << joined;
  ASSERT_GT(stream_s, 2.0);
  EXPECT_GE(rejected_lines, 2 * kLinesPerSecond);  // windows of the first two seconds are full
  EXPECT_LE(rejected_lines, kLinesPerSecond * (std::floor(stream_s) + 1))
      << "stream took " << stream_s << " s";
  EXPECT_GT(suppressed_in_lines, 0u);  // a later window's first line counts the earlier ones

  ASSERT_FALSE(summary.empty()) << joined;
  EXPECT_NE(summary.find(" info [ingest] upload stream ended: peer=ipv4:127.0.0.1:"),
            std::string::npos)
      << summary;
  const std::string counts = "received=" + std::to_string(kBadFrames + kGoodFrames) +
                             " accepted=" + std::to_string(kGoodFrames) +
                             " rejected=" + std::to_string(kBadFrames) + " dropped=0 ";
  EXPECT_NE(summary.find(counts), std::string::npos) << summary;
  EXPECT_NE(summary.find("rejected_by_reason={" + UploadStreamLog::ReasonKey(reason) + ": " +
                         std::to_string(kBadFrames) + "}"),
            std::string::npos)
      << summary;
  // Every rejection is either a line or counted as suppressed (in a later line or the summary).
  std::smatch m;
  ASSERT_TRUE(std::regex_search(summary, m, std::regex(R"(log_lines_suppressed=(\d+))")));
  EXPECT_EQ(std::stoull(m[1]), uint64_t(kBadFrames - rejected_lines)) << summary;
  EXPECT_LE(suppressed_in_lines, uint64_t(kBadFrames - rejected_lines));
  std::smatch fps;
  ASSERT_TRUE(std::regex_search(summary, fps, std::regex(R"(duration_s=([0-9.]+) fps=([0-9.]+))")));
  EXPECT_GT(std::stod(fps[1]), 0.0);
  EXPECT_LE(std::stod(fps[1]), stream_s + 0.5);
  EXPECT_GT(std::stod(fps[2]), 0.0);

  // Startup (one line with the config), subscriber, shutdown.
  EXPECT_NE(joined.find("[server] exoview_server "), std::string::npos) << joined;
  EXPECT_NE(joined.find("listening on port"), std::string::npos) << joined;
  EXPECT_NE(joined.find(" max_views=50 "), std::string::npos) << joined;  // changed keys
  EXPECT_NE(joined.find(" log_rejections_per_s=4"), std::string::npos) << joined;
  EXPECT_NE(joined.find("[server] subscriber connected: peer=ipv4:127.0.0.1:"), std::string::npos)
      << joined;
  EXPECT_NE(joined.find("[server] subscriber disconnected: peer=ipv4:127.0.0.1:"),
            std::string::npos)
      << joined;
  EXPECT_NE(joined.find("(cancelled by the client)"), std::string::npos) << joined;
  EXPECT_NE(joined.find("[server] SIGTERM: shutting down"), std::string::npos) << joined;
  EXPECT_NE(joined.find("[server] stopped at model version"), std::string::npos) << joined;
}

}  // namespace
}  // namespace exo
