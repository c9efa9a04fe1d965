// Ingest validation (SPEC §12): each bad field gives a clear error; good frames round-trip.
#include "server/service/frame_proto.h"

#include <cmath>

#include <gtest/gtest.h>

#include "server/service/ingest.h"
#include "server/service/model_proto.h"

namespace exo {
namespace {

Frame SmallFrame(int w = 32, int h = 24, uint64_t seq = 1) {
  Frame f;
  f.sequence = seq;
  f.timestamp_s = 0.1 * seq;
  f.color_camera = PinholeCamera::FromFov(w, h, 1.0);
  f.depth_camera = f.color_camera;
  f.color = ImageU8(w, h, 3);
  f.depth_m = ImageF(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c) f.color.at(x, y, c) = static_cast<uint8_t>((x * 7 + y * 3 + c * 50) % 256);
      f.depth_m.at(x, y) = 1.0f + 0.01f * x;
    }
  f.world_from_cam.translation = {1.0, 2.0, 3.0};
  f.world_from_cam.rotation = glm::normalize(glm::dquat(0.9, 0.1, 0.2, 0.3));
  return f;
}

v1::Frame Wire(const Frame& f) {
  auto m = FrameToProto(f, {});
  EXPECT_TRUE(m.ok()) << m.status();
  return *m;
}

TEST(FrameProto, RoundTripKeepsPoseIntrinsicsAndDepth) {
  const Frame f = SmallFrame();
  auto back = FrameFromProto(Wire(f), {});
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->sequence, 1u);
  EXPECT_EQ(back->color_camera.fx, f.color_camera.fx);
  EXPECT_EQ(back->world_from_cam.rotation, f.world_from_cam.rotation);  // bit-exact quaternion
  EXPECT_EQ(back->world_from_cam.translation, f.world_from_cam.translation);
  // Lossless depth at 1 mm: error <= 0.5 mm.
  for (int y = 0; y < 24; ++y)
    for (int x = 0; x < 32; ++x) EXPECT_NEAR(back->depth_m.at(x, y), f.depth_m.at(x, y), 5.1e-4);
}

TEST(FrameProto, CorruptJpegIsRejected) {
  v1::Frame m = Wire(SmallFrame());
  std::string jpeg = m.color_jpeg();
  for (size_t i = jpeg.size() / 3; i < jpeg.size(); ++i) jpeg[i] = static_cast<char>(i * 31);
  m.set_color_jpeg(jpeg.substr(0, jpeg.size() - 40));
  auto r = FrameFromProto(m, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("JPEG"), std::string::npos) << r.status();
}

TEST(FrameProto, DepthOfWrongSizeIsRejected) {
  v1::Frame m = Wire(SmallFrame());
  DepthToProto(ImageF(16, 12, 1, 1.0f), 0.001, m.mutable_depth());
  auto r = FrameFromProto(m, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("depth image is 16x12"), std::string::npos) << r.status();
}

TEST(FrameProto, NanAndNonOrthonormalPosesAreRejected) {
  v1::Frame m = Wire(SmallFrame());
  m.mutable_world_from_cam()->mutable_quaternion()->set_x(std::nan(""));
  auto r = FrameFromProto(m, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("NaN"), std::string::npos) << r.status();

  v1::Frame m2 = Wire(SmallFrame());
  auto* mat = m2.mutable_world_from_cam()->mutable_matrix();
  for (double v : {1.0, 0.2, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0}) mat->add_row_major(v);
  auto r2 = FrameFromProto(m2, {});
  ASSERT_FALSE(r2.ok());
  EXPECT_NE(r2.status().message().find("not orthonormal"), std::string::npos) << r2.status();
}

TEST(FrameProto, MissingIntrinsicsAreRejected) {
  v1::Frame m = Wire(SmallFrame());
  m.clear_color_intrinsics();
  auto r = FrameFromProto(m, {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("missing intrinsics"), std::string::npos) << r.status();
}

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
            Fnv1a64({reinterpret_cast<const uint8_t*>(msg->color_jpeg().data()), msg->color_jpeg().size()}));
}

}  // namespace
}  // namespace exo
