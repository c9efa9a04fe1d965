#include "common/datasets/redwood.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "common/datasets/test_fixture.h"
#include "common/io/image_file.h"

namespace exo {
namespace {

ImageU8 Colour(int w, int h, int seed) {
  ImageU8 c(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int k = 0; k < 3; ++k)
        c.at(x, y, k) = static_cast<uint8_t>(40 + (x * 3 + y * 2 + k * 30 + seed * 20) % 150);
  return c;
}
ImageU16 DepthMm(int w, int h, int seed) {
  ImageU16 d(w, h, 1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) d.at(x, y) = static_cast<uint16_t>(1000 + 10 * x + y + 100 * seed);
  d.at(0, 0) = 0;  // invalid
  return d;
}
// Row-major camera-to-world: a rotation about z by `deg` and a translation.
std::string Matrix(double deg, double tx, double ty, double tz) {
  const double a = deg * M_PI / 180, c = std::cos(a), s = std::sin(a);
  char buf[256];
  std::snprintf(buf, sizeof(buf), "%.6f %.6f 0 %.4f\n%.6f %.6f 0 %.4f\n0 0 1 %.4f\n0 0 0 1\n", c,
                -s, tx, s, c, ty, tz);
  return buf;
}

std::string WriteRedwood(const std::string& name, bool with_intrinsics) {
  const std::string dir = testing::FreshTempDir(name);
  std::filesystem::create_directories(dir + "/color");
  std::filesystem::create_directories(dir + "/depth");
  std::ofstream log(dir + "/trajectory.log");
  for (int i = 0; i < 3; ++i) {
    char n[32];
    std::snprintf(n, sizeof(n), "%06d", i);
    EXPECT_TRUE(WriteColorImage(dir + "/color/" + n + ".jpg", Colour(64, 48, i), 95).ok());
    EXPECT_TRUE(WritePng16(dir + "/depth/" + n + ".png", DepthMm(64, 48, i)).ok());
    log << i << " " << i << " " << i + 1 << "\n" << Matrix(10.0 * i, 0.1 * i, 2, 0.5);
  }
  if (with_intrinsics)
    std::ofstream(dir + "/intrinsic.json")
        << R"({"width": 64, "height": 48, "intrinsic_matrix": [50, 0, 0, 0, 51, 0, 31.5, 23.5, 1]})";
  return dir;
}

TEST(RedwoodReader, ReadsFramesPosesAndOpen3dIntrinsics) {
  const std::string dir = WriteRedwood("redwood", true);
  auto r = RedwoodReader::Open(dir);
  ASSERT_TRUE(r.ok()) << r.status();
  ASSERT_EQ((*r)->size(), 3u);
  EXPECT_FALSE((*r)->default_intrinsics());
  EXPECT_EQ((*r)->camera().fx, 50.0);
  EXPECT_EQ((*r)->camera().fy, 51.0);
  EXPECT_EQ((*r)->camera().cx, 31.5);
  auto f = (*r)->Load(2);
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_FLOAT_EQ(f->depth_m.at(5, 7), 0.001f * (1000 + 50 + 7 + 200));
  EXPECT_EQ(f->depth_m.at(0, 0), 0.0f);
  EXPECT_NEAR(f->color.at(10, 10, 1), Colour(64, 48, 2).at(10, 10, 1), 6);  // JPEG q95
  EXPECT_NEAR(f->world_from_cam.translation.x, 0.2, 1e-9);
  const glm::dvec3 x = f->world_from_cam.RotationMatrix() * glm::dvec3(1, 0, 0);
  EXPECT_NEAR(std::atan2(x.y, x.x) * 180 / M_PI, 20.0, 1e-4);
  EXPECT_EQ(f->color_camera.fx, f->depth_camera.fx);
  EXPECT_FALSE((*r)->Load(3).ok());
}

TEST(RedwoodReader, DefaultIntrinsicsAndBadLayouts) {
  const std::string dir = WriteRedwood("redwood_default", false);
  auto r = RedwoodReader::Open(dir);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE((*r)->default_intrinsics());
  EXPECT_EQ((*r)->camera().fx, 525.0);
  std::filesystem::remove(dir + "/depth/000002.png");
  auto bad = RedwoodReader::Open(dir);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("3 colour images but 2 depth"), std::string::npos)
      << bad.status();
  const std::string no_log = WriteRedwood("redwood_nolog", false);
  std::filesystem::remove(no_log + "/trajectory.log");
  EXPECT_NE(RedwoodReader::Open(no_log).status().message().find("*.log"), std::string::npos);
  EXPECT_EQ(RedwoodReader::Open("/nonexistent/redwood").status().code(),
            absl::StatusCode::kNotFound);
}

std::string WriteScanNet(const std::string& name) {
  const std::string dir = testing::FreshTempDir(name);
  for (const char* d : {"/color", "/depth", "/pose", "/intrinsic"})
    std::filesystem::create_directories(dir + d);
  // ScanNet's files: colour larger than depth, numbered without padding (0 .. 10: numeric order).
  for (int i : {0, 1, 2, 10}) {
    const std::string n = std::to_string(i);
    EXPECT_TRUE(WriteColorImage(dir + "/color/" + n + ".jpg", Colour(80, 60, i), 95).ok());
    EXPECT_TRUE(WritePng16(dir + "/depth/" + n + ".png", DepthMm(40, 30, i)).ok());
    std::ofstream(dir + "/pose/" + n + ".txt")
        << (i == 2 ? std::string("-inf -inf -inf -inf\n-inf -inf -inf -inf\n-inf -inf -inf "
                                 "-inf\n-inf -inf -inf -inf\n")
                   : Matrix(5.0 * i, i, 0, 1));
  }
  std::ofstream(dir + "/intrinsic/intrinsic_color.txt")
      << "70 0 39.5 0\n0 71 29.5 0\n0 0 1 0\n0 0 0 1\n";
  std::ofstream(dir + "/intrinsic/intrinsic_depth.txt")
      << "35 0 19.5 0\n0 35.5 14.5 0\n0 0 1 0\n0 0 0 1\n";
  std::ofstream(dir + "/intrinsic/extrinsic_color.txt") << Matrix(0, 0, 0, 0);
  std::ofstream(dir + "/intrinsic/extrinsic_depth.txt") << Matrix(0, 0.025, 0, 0);
  return dir;
}

TEST(ScanNetReader, ReadsExportedLayoutSkipsLostPosesAndKeepsBothCameras) {
  const std::string dir = WriteScanNet("scannet");
  auto r = ScanNetReader::Open(dir);
  ASSERT_TRUE(r.ok()) << r.status();
  ASSERT_EQ((*r)->size(), 3u);  // 0, 1, 10 (2 has -inf: lost tracking)
  EXPECT_EQ((*r)->skipped_invalid_pose(), 1u);
  EXPECT_EQ((*r)->color_camera().width, 80);
  EXPECT_EQ((*r)->depth_camera().width, 40);
  EXPECT_EQ((*r)->depth_camera().fy, 35.5);
  auto f = (*r)->Load(2);  // frame 10
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_EQ(f->sequence, 10u);
  EXPECT_NEAR(f->world_from_cam.translation.x, 10.0, 1e-9);
  EXPECT_FLOAT_EQ(f->depth_m.at(3, 4), 0.001f * (1000 + 30 + 4 + 1000));
  EXPECT_EQ(f->color.width(), 80);
  EXPECT_NEAR(f->color_from_depth.translation.x, 0.025, 1e-9);
}

TEST(ScanNetReader, ErrorsNameTheFile) {
  const std::string dir = WriteScanNet("scannet_bad");
  std::filesystem::remove(dir + "/intrinsic/intrinsic_depth.txt");
  auto r = ScanNetReader::Open(dir);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("intrinsic_depth.txt"), std::string::npos) << r.status();
  std::ofstream(dir + "/pose/x.txt") << "1";
  EXPECT_NE(ScanNetReader::Open(dir).status().message().find("N.txt"), std::string::npos);
}

}  // namespace
}  // namespace exo
