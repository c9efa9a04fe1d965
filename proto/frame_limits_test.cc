// Plausibility limits (issue 20 item 2): every absurd-but-finite value the issue found accepted is
// rejected by FrameFromProto with the limit in the reason, and values a real sensor produces
// (7-Scenes intrinsics, depth scales of 7-Scenes and TUM) pass.
#include "proto/frame_limits.h"

#include <gtest/gtest.h>

#include <limits>

#include "common/io/depth_codec.h"
#include "proto/frame_proto.h"
#include "proto/test_frames.h"

namespace exo {
namespace {

using wire_test::SmallFrame;
using wire_test::Wire;

void ExpectRejected(const v1::Frame& m, const std::string& part) {
  auto r = FrameFromProto(m, {});
  ASSERT_FALSE(r.ok()) << "accepted, expected: " << part;
  EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find(part), std::string::npos) << r.status();
}

TEST(FrameLimits, DefaultsAreValidAndRealCamerasPass) {
  FrameLimits l;
  ASSERT_TRUE(l.Validate().ok());
  PinholeCamera kinect{585.0, 585.0, 320.0, 240.0, 640, 480};  // 7-Scenes
  EXPECT_TRUE(CheckIntrinsics(kinect, l, "c").ok());
  EXPECT_TRUE(CheckDepthScale(0.001, l).ok());
  EXPECT_TRUE(CheckDepthScale(0.0002, l).ok());  // TUM
  EXPECT_TRUE(CheckExposure(1.0, l).ok());
  EXPECT_TRUE(CheckTimestamp(1.7e9, l).ok());  // Unix time
  EXPECT_TRUE(CheckCameraPosition({10, -3, 2}, l).ok());
  FrameLimits bad = l;
  bad.max_exposure = 1e300;  // not a float
  EXPECT_FALSE(bad.Validate().ok());
}

TEST(FrameLimits, ExposureIsCheckedAsTheStoredFloat) {
  Frame f = SmallFrame();
  f.exposure = 1.0;
  v1::Frame m = Wire(f);
  m.set_exposure(1e300);  // finite as a double, inf as the stored float
  ExpectRejected(m, "exposure 1e+300 (inf as stored float) is outside [0.001, 1000]");
  m.set_exposure(1e-300);  // 0 as float
  ExpectRejected(m, "is outside [0.001, 1000]");
  m.set_exposure(std::numeric_limits<double>::quiet_NaN());
  ExpectRejected(m, "exposure nan");
  m.set_exposure(2.5);
  EXPECT_TRUE(FrameFromProto(m, {}).ok());
}

TEST(FrameLimits, AbsurdIntrinsics) {
  v1::Frame m = Wire(SmallFrame(32, 24));
  m.mutable_color_intrinsics()->set_cx(1e300);
  ExpectRejected(m, "colour intrinsics: principal point (1e+300, ");
  m = Wire(SmallFrame(32, 24));
  m.mutable_color_intrinsics()->set_fx(1e-300);
  ExpectRejected(m, "colour intrinsics: fx = 1e-300 outside the plausible range [1.6, 1600]");
  m = Wire(SmallFrame(32, 24));
  m.mutable_color_intrinsics()->set_fy(1e9);
  ExpectRejected(m, "fy = 1e+09 outside the plausible range");
}

TEST(FrameLimits, FarTranslationIsOutsideTheSceneRadius) {
  v1::Frame m = Wire(SmallFrame());
  m.mutable_world_from_cam()->mutable_translation()->set_x(1e15);
  ExpectRejected(m, "outside the scene radius 1000 m");
  FrameDecodeOptions o;
  o.limits.scene_center = {1e15, 0, 0};  // a scene far from the world origin is configurable
  EXPECT_TRUE(FrameFromProto(m, o).ok());
}

TEST(FrameLimits, DepthScaleRange) {
  for (double s : {1e300, 1e-320, 0.0, -1.0, 2.0, 1e-7}) {
    v1::Frame m = Wire(SmallFrame());
    m.mutable_depth()->set_depth_scale_m(s);
    ExpectRejected(m, "m/unit is outside [1e-06, 1]");
  }
}

TEST(FrameLimits, ColourFromDepthOffsetUnderAMetre) {
  Frame f = SmallFrame(32, 24);
  f.depth_camera = PinholeCamera::FromFov(16, 12, 1.0);
  f.depth_m = ImageF(16, 12, 1, 1.5f);
  f.color_from_depth.translation = {1e6, 0, 0};
  ExpectRejected(Wire(f), "depth-to-colour extrinsic: offset 1e+06 m is not under the limit 1 m");
  f.color_from_depth.translation = {0.025, 0, 0};  // a real RGB-D baseline
  EXPECT_TRUE(FrameFromProto(Wire(f), {}).ok());
}

TEST(FrameLimits, DepthIntrinsicsDoNotBypassThePixelLimit) {
  v1::Frame m = Wire(SmallFrame(32, 24));
  auto* di = m.mutable_depth_intrinsics();
  di->set_width(8192);
  di->set_height(8192);
  di->set_fx(4000);
  di->set_fy(4000);
  di->set_cx(4096);
  di->set_cy(4096);
  ExpectRejected(m, "depth intrinsics: image 8192x8192 exceeds the limit of 16777216 pixels");
}

TEST(FrameLimits, DepthHeaderClaimingMoreThanTheMessageIsRefusedBeforeDecoding) {
  v1::Frame m = Wire(SmallFrame(32, 24));
  const std::vector<uint8_t> big = EncodeDepth(ImageU16(4096, 4096));
  m.mutable_depth()->set_data(big.data(), big.size());
  ExpectRejected(m, "depth decodes to 4096x4096 but the message says 32x24");
}

TEST(FrameLimits, TimestampRange) {
  v1::Frame m = Wire(SmallFrame());
  m.set_timestamp_s(1e300);
  ExpectRejected(m, "timestamp 1e+300 s is outside +-1e+10 s");
}

}  // namespace
}  // namespace exo
