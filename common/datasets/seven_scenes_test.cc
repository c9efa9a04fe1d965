#include "common/datasets/seven_scenes.h"

#include <gtest/gtest.h>

#include <fstream>

#include "common/datasets/test_fixture.h"
#include "common/io/image_file.h"

namespace exo {
namespace {

void WriteText(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

// A tiny layout the test writes itself (runs without the shared data).
std::string MakeTiny7Scenes(const std::string& name, int frames) {
  const std::string dir = testing::FreshTempDir(name);
  WriteText(dir + "/camera-intrinsics.txt", "20 0 7.5\n0 20 5.5\n0 0 1\n");
  for (int i = 0; i < frames; ++i) {
    const Frame f = testing::MakeFrame(i);
    char stem[64];
    std::snprintf(stem, sizeof(stem), "/frame-%06d", i);
    EXPECT_TRUE(WriteColorImage(dir + stem + ".color.jpg", f.color).ok());
    ImageU16 mm(16, 12);
    for (size_t k = 0; k < mm.size(); ++k) mm.data()[k] = static_cast<uint16_t>(1000 + k);
    EXPECT_TRUE(WritePng16(dir + stem + ".depth.png", mm).ok());
    WriteText(dir + stem + ".pose.txt",
              "1 0 0 0.5\n0 0 -1 " + std::to_string(i) + "\n0 1 0 2\n0 0 0 1\n");
  }
  return dir;
}

TEST(SevenScenesTest, TinyLayoutLoads) {
  const std::string dir = MakeTiny7Scenes("tiny", 3);
  auto reader = SevenScenesReader::Open(dir);
  ASSERT_TRUE(reader.ok()) << reader.status();
  ASSERT_EQ((*reader)->size(), 3u);
  auto f = (*reader)->Load(2);
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_EQ(f->sequence, 2u);
  EXPECT_NEAR(f->timestamp_s, 2.0 / 30.0, 1e-12);
  EXPECT_EQ(f->color_camera.fx, 20.0);
  EXPECT_EQ(f->depth_camera.cx, 7.5);
  EXPECT_EQ(f->color_camera.width, 16);
  EXPECT_FLOAT_EQ(f->depth_m.at(3, 0), 1.003f);  // mm -> m
  EXPECT_EQ(f->world_from_cam.translation, glm::dvec3(0.5, 2.0, 2.0));
  // Row-major [1 0 0; 0 0 -1; 0 1 0] maps camera +y to world +z.
  const glm::dvec3 y_in_world = f->world_from_cam.rotation * glm::dvec3(0, 1, 0);
  EXPECT_NEAR(y_in_world.z, 1.0, 1e-12);
  EXPECT_EQ((*reader)->Load(3).status().code(), absl::StatusCode::kOutOfRange);
}

TEST(SevenScenesTest, ClearErrors) {
  EXPECT_EQ(SevenScenesReader::Open("/nonexistent/7s").status().code(),
            absl::StatusCode::kNotFound);
  {  // missing intrinsics
    const std::string dir = MakeTiny7Scenes("noK", 1);
    std::filesystem::remove(dir + "/camera-intrinsics.txt");
    auto r = SevenScenesReader::Open(dir);
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("camera-intrinsics.txt"), std::string::npos);
  }
  {  // malformed K
    const std::string dir = MakeTiny7Scenes("badK", 1);
    WriteText(dir + "/camera-intrinsics.txt", "20 0 7.5\n0 20 5.5\n");
    EXPECT_EQ(SevenScenesReader::Open(dir).status().code(), absl::StatusCode::kInvalidArgument);
  }
  {  // missing depth, non-orthonormal pose, NaN pose, truncated JPEG: errors naming the file
    const std::string dir = MakeTiny7Scenes("bad", 4);
    auto reader = SevenScenesReader::Open(dir);
    ASSERT_TRUE(reader.ok());
    std::filesystem::remove(dir + "/frame-000000.depth.png");
    auto r0 = (*reader)->Load(0);
    ASSERT_FALSE(r0.ok());
    EXPECT_EQ(r0.status().code(), absl::StatusCode::kNotFound);
    EXPECT_NE(r0.status().message().find("frame-000000.depth.png"), std::string::npos);
    WriteText(dir + "/frame-000001.pose.txt", "1 0.1 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
    auto r1 = (*reader)->Load(1);
    ASSERT_FALSE(r1.ok());
    EXPECT_NE(r1.status().message().find("orthonormal"), std::string::npos) << r1.status();
    WriteText(dir + "/frame-000002.pose.txt", "nan 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
    EXPECT_FALSE((*reader)->Load(2).ok());
    std::filesystem::resize_file(dir + "/frame-000003.color.jpg", 200);
    auto r3 = (*reader)->Load(3);
    ASSERT_FALSE(r3.ok());
    EXPECT_NE(r3.status().message().find("frame-000003.color.jpg"), std::string::npos);
  }
}

// Guard: OrthonormalizeNearRotation. A pose 1e-3 off orthonormal (like real 7-Scenes files,
// which are ~1e-4 off) is repaired to an exact rotation; without the repair RigidFromRowMajor4x4
// rejects it (kRotationTolerance 1e-4) and the real data cannot be read.
TEST(SevenScenesTest, RepairsNearlyOrthonormalPose) {
  const std::string dir = testing::FreshTempDir("repair");
  const std::string path = dir + "/p.txt";
  WriteText(path, "1.001 0 0 1\n0 1 0.0005 2\n0 0 0.9995 3\n0 0 0 1\n");
  auto pose = ReadPoseFile4x4(path);
  ASSERT_TRUE(pose.ok()) << pose.status();
  EXPECT_TRUE(ValidateRotation(pose->RotationMatrix()).ok());
  EXPECT_LT(RotationAngleRad(pose->rotation, glm::dquat(1, 0, 0, 0)), 1e-3);
  EXPECT_EQ(pose->translation, glm::dvec3(1, 2, 3));
  WriteText(path, "1 0 0 0\n0 1 0 0\n0 0 -1 0\n0 0 0 1\n");  // reflection: never repaired
  EXPECT_FALSE(ReadPoseFile4x4(path).ok());
}

TEST(SevenScenesTest, RealRedkitchen) {
  const std::string dir = testing::SharedDir() + "/data/7scenes-redkitchen";
  if (!std::filesystem::exists(dir + "/camera-intrinsics.txt"))
    GTEST_SKIP() << "7-Scenes data not found at " << dir << " (set EXOVIEW_SHARED_DIR)";
  auto reader = SevenScenesReader::Open(dir);
  ASSERT_TRUE(reader.ok()) << reader.status();
  EXPECT_EQ((*reader)->size(), 300u);
  EXPECT_EQ((*reader)->camera().fx, 585.0);
  EXPECT_EQ((*reader)->camera().cx, 320.0);
  for (size_t i : {size_t{0}, size_t{150}, size_t{299}}) {
    auto f = (*reader)->Load(i);
    ASSERT_TRUE(f.ok()) << f.status();
    EXPECT_EQ(f->color.width(), 640);
    EXPECT_EQ(f->depth_m.height(), 480);
    size_t valid = 0;
    float lo = 1e9f, hi = 0.0f;
    for (float d : f->depth_m.span())
      if (d > 0) {
        ++valid;
        lo = std::min(lo, d);
        hi = std::max(hi, d);
      }
    const double frac = double(valid) / f->depth_m.size();
    EXPECT_GT(frac, 0.6) << "frame " << i;  // README: ~89 % valid
    EXPECT_GT(lo, 0.3f);                     // metres, not millimetres
    EXPECT_LT(hi, 8.0f);
    auto pose = (*reader)->LoadPose(i);
    ASSERT_TRUE(pose.ok());
    EXPECT_EQ(pose->translation, f->world_from_cam.translation);
  }
}

}  // namespace
}  // namespace exo
