// Stored views on the wire: downscaled depth, exposure and the digest inputs survive a round trip.
#include "proto/model_proto.h"

#include <gtest/gtest.h>

#include "proto/test_frames.h"

namespace exo {
namespace {

using wire_test::SmallFrame;
using wire_test::Wire;

TEST(ModelProto, ViewRoundTripDownscalesDepthAndKeepsDigestInputs) {
  const Frame f = SmallFrame(64, 48);
  StoredView v;
  v.id = 7;
  v.camera = f.color_camera;
  v.local_from_cam = f.world_from_cam;
  v.color = f.color;
  v.depth_m = f.depth_m;
  v.exposure = 1.25f;
  ViewEncodeOptions opt;
  opt.depth_downscale = 4;
  auto msg = ViewToProto(v, opt);
  ASSERT_TRUE(msg.ok()) << msg.status();
  EXPECT_EQ(msg->depth().width(), 16);
  auto back = ViewFromProto(*msg);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->depth_m.width(), 64);  // brought back to the colour size
  EXPECT_EQ(back->exposure, 1.25f);
  // Depth is a ramp in x: nearest sample of the 4-px block is within 4 px * 0.01 m.
  for (int x = 0; x < 64; ++x) EXPECT_NEAR(back->depth_m.at(x, 10), f.depth_m.at(x, 10), 0.041);
  EXPECT_EQ(DigestRecordFromProto(*msg).color_hash,
            Fnv1a64({reinterpret_cast<const uint8_t*>(msg->color_jpeg().data()),
                     msg->color_jpeg().size()}));
}

}  // namespace
}  // namespace exo
