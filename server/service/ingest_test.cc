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
  ASSERT_TRUE(s.Admit(ok1, ok1.ByteSizeLong()).ok());
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

}  // namespace
}  // namespace exo
