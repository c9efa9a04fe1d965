#include "common/datasets/exo_layout.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "common/datasets/test_fixture.h"

namespace exo {
namespace {

TEST(ExoLayoutTest, WriteReadRoundTrip) {
  const std::string dir = testing::FreshTempDir("exo_rt");
  ExoLayoutOptions png;
  png.color_format = ExoColorFormat::kPng;
  ExoLayoutWriter writer(dir, png);
  std::vector<Frame> frames;
  for (uint64_t s : {5u, 3u, 4u}) {  // written out of order: reader sorts by seq
    Frame f = testing::MakeFrame(s);
    if (s == 4) f.exposure = 0.25;
    if (s == 3) f.depth_m.at(2, 2) = std::nanf("");  // NaN depth -> invalid (0)
    ASSERT_TRUE(writer.Write(f).ok());
    frames.push_back(f);
  }
  auto reader = ExoLayoutReader::Open(dir);
  ASSERT_TRUE(reader.ok()) << reader.status();
  ASSERT_EQ((*reader)->size(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    auto f = (*reader)->Load(i);
    ASSERT_TRUE(f.ok()) << f.status();
    const Frame& ref = *std::find_if(frames.begin(), frames.end(),
                                     [&](const Frame& x) { return x.sequence == 3 + i; });
    EXPECT_EQ(f->sequence, 3 + i);
    EXPECT_NEAR(f->timestamp_s, ref.timestamp_s, 1e-9);
    // Pose at 1e5 m survives at full double precision (%.17g).
    EXPECT_EQ(f->world_from_cam.translation, ref.world_from_cam.translation);
    EXPECT_NEAR(RotationAngleRad(f->world_from_cam.rotation, ref.world_from_cam.rotation), 0.0,
                1e-12);
    EXPECT_EQ(f->color_camera.fx, ref.color_camera.fx);
    EXPECT_EQ(f->depth_camera.height, ref.depth_camera.height);
    EXPECT_TRUE(f->color == ref.color);  // PNG colour is lossless
    for (int y = 0; y < 12; ++y)
      for (int x = 0; x < 16; ++x) {
        const float want = std::isfinite(ref.depth_m.at(x, y)) ? ref.depth_m.at(x, y) : 0.0f;
        EXPECT_NEAR(f->depth_m.at(x, y), want, 0.0005 + 1e-6) << x << "," << y;
      }
    EXPECT_EQ(f->exposure.has_value(), ref.exposure.has_value());
  }
  EXPECT_EQ(*(*reader)->Load(1)->exposure, 0.25);
}

TEST(ExoLayoutTest, JpegColourAndDepthScale) {
  const std::string dir = testing::FreshTempDir("exo_jpg");
  ExoLayoutOptions o;
  o.depth_metres_per_unit = 0.002;  // 2 mm units: 131 m range
  Frame f = testing::MakeFrame(0);
  f.depth_m.at(5, 5) = 100.0f;
  ASSERT_TRUE(WriteExoFrame(dir, f, o).ok());
  auto reader = ExoLayoutReader::Open(dir);
  ASSERT_TRUE(reader.ok());
  EXPECT_EQ((*reader)->depth_metres_per_unit(), 0.002);
  auto back = (*reader)->Load(0);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_NEAR(back->depth_m.at(5, 5), 100.0f, 0.001);
  EXPECT_TRUE(std::filesystem::exists(dir + "/frames/000000.color.jpg"));
}

TEST(ExoLayoutTest, ClearErrors) {
  const std::string dir = testing::FreshTempDir("exo_err");
  Frame f = testing::MakeFrame(0);
  ASSERT_TRUE(WriteExoFrame(dir, f).ok());
  Frame other = testing::MakeFrame(1);
  other.color_camera.fx = 99;
  other.depth_camera.fx = 99;
  auto s = WriteExoFrame(dir, other);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("intrinsics"), std::string::npos);
  Frame no_depth = testing::MakeFrame(2);
  no_depth.depth_m = ImageF();
  EXPECT_FALSE(WriteExoFrame(dir, no_depth).ok());
  Frame bad_pose = testing::MakeFrame(3);
  bad_pose.world_from_cam.translation.x = NAN;
  EXPECT_FALSE(WriteExoFrame(dir, bad_pose).ok());
  // A second frame with the same seq: the reader refuses the directory.
  ASSERT_TRUE(WriteExoFrame(dir, testing::MakeFrame(0)).ok());
  auto dup = ExoLayoutReader::Open(dir);
  ASSERT_FALSE(dup.ok());
  EXPECT_NE(dup.status().message().find("twice"), std::string::npos);

  const std::string d2 = testing::FreshTempDir("exo_err2");
  ASSERT_TRUE(WriteExoFrame(d2, testing::MakeFrame(7)).ok());
  auto reader = ExoLayoutReader::Open(d2);
  ASSERT_TRUE(reader.ok());
  std::filesystem::remove(d2 + "/frames/000007.color.jpg");
  auto missing = (*reader)->Load(0);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("000007.color"), std::string::npos);
  std::ofstream(d2 + "/poses.txt", std::ios::app) << "8 1.0 1 2 3\n";
  EXPECT_FALSE(ExoLayoutReader::Open(d2).ok());
  EXPECT_EQ(ExoLayoutReader::Open("/nonexistent/exo").status().code(), absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace exo
