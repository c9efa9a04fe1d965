// Stream-level ingest checks (SPEC §12): size limit and sequence order; the stream goes on.
#include "server/service/ingest.h"

#include <gtest/gtest.h>

#include "proto/test_frames.h"

namespace exo {
namespace {

using wire_test::SmallFrame;
using wire_test::Wire;

TEST(Ingest, OversizedAndOutOfOrderFramesAreRejectedAndStreamGoesOn) {
  IngestOptions opt;
  opt.max_frame_bytes = 4096;
  IngestStream s(opt);
  v1::Frame ok1 = Wire(SmallFrame(32, 24, 5));
  auto a1 = s.Admit(ok1, ok1.ByteSizeLong());
  ASSERT_TRUE(a1.ok());
  s.Commit(*a1);
  v1::Frame big = Wire(SmallFrame(32, 24, 6));
  big.set_color_jpeg(std::string(5000, 'x'));
  auto r = s.Admit(big, big.ByteSizeLong());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("oversized"), std::string::npos);
  v1::Frame old = Wire(SmallFrame(32, 24, 4));
  auto r2 = s.Admit(old, old.ByteSizeLong());
  ASSERT_FALSE(r2.ok());
  EXPECT_NE(r2.status().message().find("out-of-order sequence"), std::string::npos);
  v1::Frame ok2 = Wire(SmallFrame(32, 24, 7));
  EXPECT_TRUE(s.Admit(ok2, ok2.ByteSizeLong()).ok());
}

// Issue 20: a rejected frame carrying sequence 2^64-1 or timestamp 1e300 moved the stream's marks
// and every later good frame was rejected. Now only Commit() moves them.
TEST(Ingest, RejectedFramesNeverMoveTheMarks) {
  IngestStream s(IngestOptions{});
  v1::Frame f1 = Wire(SmallFrame(32, 24, 1));
  auto a1 = s.Admit(f1, f1.ByteSizeLong());
  ASSERT_TRUE(a1.ok()) << a1.status();
  s.Commit(*a1);
  v1::Frame corrupt = Wire(SmallFrame(32, 24, 2));
  corrupt.set_sequence(~uint64_t{0});
  corrupt.set_color_jpeg("not a jpeg");
  EXPECT_FALSE(s.Admit(corrupt, corrupt.ByteSizeLong()).ok());
  v1::Frame late = Wire(SmallFrame(32, 24, 3));
  late.set_timestamp_s(1e300);
  auto r = s.Admit(late, late.ByteSizeLong());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("timestamp 1e+300 s is outside"), std::string::npos);
  v1::Frame corrupt_ts = Wire(SmallFrame(32, 24, 4));
  corrupt_ts.set_timestamp_s(1e9);
  corrupt_ts.clear_color_intrinsics();
  EXPECT_FALSE(s.Admit(corrupt_ts, corrupt_ts.ByteSizeLong()).ok());
  v1::Frame good = Wire(SmallFrame(32, 24, 5));
  auto g = s.Admit(good, good.ByteSizeLong());
  EXPECT_TRUE(g.ok()) << g.status();
}

TEST(Ingest, DuplicateTimestampIsRejected) {
  IngestStream s(IngestOptions{});
  v1::Frame f1 = Wire(SmallFrame(32, 24, 1));
  auto a1 = s.Admit(f1, f1.ByteSizeLong());
  ASSERT_TRUE(a1.ok());
  s.Commit(*a1);
  v1::Frame dup = Wire(SmallFrame(32, 24, 2));
  dup.set_timestamp_s(f1.timestamp_s());
  auto r = s.Admit(dup, dup.ByteSizeLong());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("duplicate timestamp 0.1 s"), std::string::npos) << r.status();
  v1::Frame next = Wire(SmallFrame(32, 24, 3));
  EXPECT_TRUE(s.Admit(next, next.ByteSizeLong()).ok());
}

}  // namespace
}  // namespace exo
