// Bounded under abuse (issue 20 item 4) on the real server process: count limits end new calls
// with RESOURCE_EXHAUSTED and a reason naming the limit; a client's in-flight bytes are bounded;
// never-reading subscribers share the model's single copy, are timed out, and do not disturb
// normal viewers (digest-equal) or the server's memory (RSS bound below). The 500-subscriber
// version is the benchmark tests/service_abuse_bench.cc.
#include <gtest/gtest.h>

#include <filesystem>

#include "tests/abuse_scenario.h"

namespace exo {
namespace {

using testing::ReadAll;
using testing::Subprocess;
using testing::WaitForFile;

class Abuse : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/exoview_abuse_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override {
    if (server_) {
      server_->Signal(SIGTERM);
      server_->Wait(10);
    }
    if (!HasFailure()) std::filesystem::remove_all(dir_);
  }
  void Start(std::vector<std::string> extra) {
    std::filesystem::remove(dir_ + "/port");
    std::vector<std::string> args{"--listen=127.0.0.1:0", "--port_file=" + dir_ + "/port",
                                  "--refinement=false"};
    args.insert(args.end(), extra.begin(), extra.end());
    server_ = std::make_unique<Subprocess>(EXOVIEW_SERVER_BIN, args, dir_ + "/server.log");
    ASSERT_TRUE(WaitForFile(dir_ + "/port", 20)) << server_->Log();
    target_ = "127.0.0.1:" + std::to_string(std::stoi(ReadAll(dir_ + "/port")));
  }
  std::string dir_, target_;
  std::unique_ptr<Subprocess> server_;
};

Frame SynthFrame(int w, int h, uint64_t seq) {
  SynthSourceOptions so;
  so.scene = "apartment";
  so.trajectory = "walk";
  so.width = w;
  so.height = h;
  so.num_frames = 4;
  auto src = SynthFrameSource::Create(so);
  EXO_CHECK(src.ok());
  auto f = (*src)->Load(seq % 4);
  EXO_CHECK(f.ok());
  f->sequence = seq;
  f->timestamp_s = 0.1 * seq;
  return *std::move(f);
}

TEST_F(Abuse, CountAndByteLimitsAnswerResourceExhaustedWithTheLimit) {
  Start({"--max_subscribers=2", "--max_upload_streams=1", "--max_client_inflight_bytes=1048576"});
  // Subscribers: two held open, the third refused.
  std::vector<abuse::NeverReader> held;
  for (int i = 0; i < 2; ++i) held.push_back(abuse::OpenNeverReader(target_, i));
  for (int i = 0;
       i < 100 && abuse::ServerStats(target_).counters().at("server.subscriber_calls") < 2; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  {
    auto stub = v1::Exoview::NewStub(MakeChannel(target_));
    grpc::ClientContext ctx;
    auto reader = stub->Subscribe(&ctx, v1::SubscribeRequest{});
    v1::Delta d;
    EXPECT_FALSE(reader->Read(&d));
    const grpc::Status s = reader->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_EQ(s.error_message(), "too many subscribers: the limit is max_subscribers = 2");
  }
  // Upload streams: one open, a second refused.
  auto stub = v1::Exoview::NewStub(MakeChannel(target_));
  grpc::ClientContext ctx1;
  auto first = stub->Upload(&ctx1);
  // In-flight bytes: a 640x480 frame decodes to 2.1 MB > 1 MiB for this client: REJECTED.
  auto big = FrameToProto(SynthFrame(640, 480, 1), {});
  ASSERT_TRUE(big.ok());
  ASSERT_TRUE(first->Write(*big));
  v1::Ack ack;
  ASSERT_TRUE(first->Read(&ack));
  EXPECT_EQ(ack.status(), v1::Ack::REJECTED);
  EXPECT_EQ(ack.code(), v1::Ack::RESOURCE_EXHAUSTED);
  EXPECT_NE(ack.reason().find("would exceed max_client_inflight_bytes = 1048576"),
            std::string::npos)
      << ack.reason();
  // A 256x192 frame (0.35 MB) fits, on the same stream.
  auto small = FrameToProto(SynthFrame(256, 192, 2), {});
  ASSERT_TRUE(small.ok());
  ASSERT_TRUE(first->Write(*small));
  ASSERT_TRUE(first->Read(&ack));
  EXPECT_NE(ack.status(), v1::Ack::REJECTED) << ack.reason();
  {
    grpc::ClientContext ctx2;
    auto second = stub->Upload(&ctx2);
    v1::Ack a;
    EXPECT_FALSE(second->Read(&a));
    const grpc::Status s = second->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_EQ(s.error_message(), "too many upload streams: the limit is max_upload_streams = 1");
  }
  first->WritesDone();
  while (first->Read(&ack)) {
  }
  EXPECT_TRUE(first->Finish().ok());
  const v1::Stats st = abuse::ServerStats(target_);
  EXPECT_EQ(st.counters().at("server.refused_subscribers"), 1.0);
  EXPECT_EQ(st.counters().at("server.refused_uploads"), 1.0);
  EXPECT_EQ(st.counters().at("server.inflight_rejections"), 1.0);
  for (auto& n : held) n.ctx->TryCancel();
}

// 48 never-reading subscribers + 4 viewers + an uploader at 30 Hz (2-core scale). Bound: the
// server's peak RSS stays under the peak of the same run without the never-readers + 2 x the
// model + 100 MB (a copy of the model per never-reader, as before issue 20, is 48 x the model);
// the viewers end digest-equal; every never-reader is timed out (subscriber_write_timeout_s = 2).
TEST_F(Abuse, NeverReadingSubscribersAreBoundedSharedAndTimedOut) {
  abuse::Options o;
  // Full-resolution proxy on the wire (no clients' LOD, 16-bit format-2 chunks, a snapshot's chunks
  // one by one instead of zstd batches): the model must stay far beyond a stream's flow-control
  // window for the never-readers' Writes to block.
  const std::vector<std::string> flags = {"--subscriber_write_timeout_s=2",
                                          "--chunk_lod_error_voxels=0", "--chunk_step_voxels=0",
                                          "--snapshot_chunk_batch_bytes=0"};
  Start(flags);
  abuse::Options base_o = o;
  base_o.never_readers = 0;
  const abuse::Result base = abuse::Run(target_, server_->pid(), base_o);
  ASSERT_TRUE(base.error.empty()) << base.error;
  server_->Signal(SIGTERM);
  server_->Wait(10);
  Start(flags);
  const abuse::Result r = abuse::Run(target_, server_->pid(), o);
  ASSERT_TRUE(r.error.empty()) << r.error;
  std::printf(
      "abuse: model %.1f MB; peak RSS without never-readers %.1f MB, with %d: %.1f MB "
      "(before %.1f, after %.1f); threads peak %d; timed out %.0f\n",
      r.model_mb, base.rss_peak_mb, o.never_readers, r.rss_peak_mb, r.rss_before_mb, r.rss_after_mb,
      r.threads_peak, r.timed_out_calls);
  EXPECT_GT(r.model_mb, 2.0);  // far beyond a stream's flow-control window: Writes block
  EXPECT_EQ(r.viewers_equal, o.viewers);
  EXPECT_EQ(base.viewers_equal, o.viewers);
  EXPECT_LT(r.rss_peak_mb, base.rss_peak_mb + 2 * r.model_mb + 100);
  EXPECT_GE(r.timed_out_calls, o.never_readers);
  EXPECT_EQ(r.subscribers_left, 0);
  EXPECT_TRUE(server_->running());
}

}  // namespace
}  // namespace exo
