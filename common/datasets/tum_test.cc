#include "common/datasets/tum.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>

#include "absl/strings/str_format.h"
#include "common/datasets/test_fixture.h"
#include "common/io/image_file.h"

namespace exo {
namespace {

// TUM-layout fixture: ground truth at 100 Hz for t in [100.00, 100.50], rotation about z by
// (t - 100) rad and translation (t - 100, 2 (t - 100), 0), quaternions printed with 4 decimals
// as in the real files. rgb every 33 ms from 100.005; the third rgb has no depth within 20 ms,
// one rgb at 101.0 lies beyond the ground truth.
std::string MakeTum(const std::string& name) {
  const std::string dir = testing::FreshTempDir(name);
  std::filesystem::create_directories(dir + "/rgb");
  std::filesystem::create_directories(dir + "/depth");
  std::ofstream gt(dir + "/groundtruth.txt");
  gt << "# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n";
  for (int k = 0; k <= 50; ++k) {
    const double t = 100.0 + 0.01 * k, a = t - 100.0;
    char line[256];
    std::snprintf(line, sizeof(line), "%.4f %.4f %.4f %.4f %.4f %.4f %.4f %.4f\n", t, a, 2 * a,
                  0.0, 0.0, 0.0, std::sin(a / 2), std::cos(a / 2));
    gt << line;
  }
  std::ofstream rgb(dir + "/rgb.txt"), depth(dir + "/depth.txt");
  rgb << "# color images\n";
  depth << "# depth maps\n";
  const Frame proto = testing::MakeFrame(0, 8, 6);
  ImageU16 raw(8, 6, 1, 5000);  // 1 m at TUM's 5000 units/m
  raw.at(0, 0) = 0;
  std::vector<double> rgb_t;
  for (int k = 0; k < 6; ++k) rgb_t.push_back(100.005 + 0.033 * k);
  rgb_t.push_back(101.0);
  for (size_t k = 0; k < rgb_t.size(); ++k) {
    char f[64];
    std::snprintf(f, sizeof(f), "rgb/%.6f.png", rgb_t[k]);
    rgb << absl::StrFormat("%.6f %s\n", rgb_t[k], f);
    EXPECT_TRUE(WriteColorImage(dir + "/" + f, proto.color).ok());
    const double dt = (k == 2) ? 0.05 : 0.004;
    std::snprintf(f, sizeof(f), "depth/%.6f.png", rgb_t[k] + dt);
    depth << absl::StrFormat("%.6f %s\n", rgb_t[k] + dt, f);
    EXPECT_TRUE(WritePng16(dir + "/" + f, raw).ok());
  }
  return dir;
}

TumOptions SmallCamera() {
  TumOptions o;
  o.camera = PinholeCamera{10.0, 10.0, 3.5, 2.5, 8, 6};
  return o;
}

TEST(TumTest, AssociatesAndInterpolates) {
  const std::string dir = MakeTum("ok");
  auto reader = TumReader::Open(dir, SmallCamera());
  ASSERT_TRUE(reader.ok()) << reader.status();
  EXPECT_EQ((*reader)->size(), 5u);
  EXPECT_EQ((*reader)->skipped_no_depth(), 1u);  // rgb #2: nearest depth 50 ms away
  EXPECT_EQ((*reader)->skipped_no_pose(), 1u);   // rgb at 101.0: 0.5 s after the ground truth
  // Frame 1 is rgb #1 at 100.038: between ground-truth samples 100.03 and 100.04.
  auto f = (*reader)->Load(1);
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_NEAR(f->timestamp_s, 100.038, 1e-9);
  EXPECT_NEAR((*reader)->entry(1).depth_t, 100.042, 1e-9);
  EXPECT_NEAR(f->world_from_cam.translation.x, 0.038, 1e-9);
  EXPECT_NEAR(f->world_from_cam.translation.y, 0.076, 1e-9);
  // 4-decimal quaternions: rotation within ~1e-4 rad of the analytic 0.038 rad about z.
  EXPECT_NEAR(RotationAngleRad(f->world_from_cam.rotation,
                               glm::angleAxis(0.038, glm::dvec3(0, 0, 1))),
              0.0, 2e-4);
  EXPECT_FLOAT_EQ(f->depth_m.at(3, 3), 1.0f);
  EXPECT_EQ(f->depth_m.at(0, 0), 0.0f);
  EXPECT_EQ(f->color.width(), 8);
  // Frame 2 is rgb #3 (rgb #2 was skipped).
  EXPECT_NEAR((*reader)->entry(2).rgb_t, 100.104, 1e-9);
}

TEST(TumTest, ClearErrors) {
  EXPECT_EQ(TumReader::Open("/nonexistent/tum").status().code(), absl::StatusCode::kNotFound);
  {
    const std::string dir = MakeTum("nogt");
    std::filesystem::remove(dir + "/groundtruth.txt");
    auto r = TumReader::Open(dir, SmallCamera());
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("groundtruth.txt"), std::string::npos);
  }
  {
    const std::string dir = MakeTum("badq");
    std::ofstream(dir + "/groundtruth.txt", std::ios::app) << "100.6 0 0 0 0 0 0.5 0.5\n";
    auto r = TumReader::Open(dir, SmallCamera());
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("quaternion"), std::string::npos);
  }
  {
    const std::string dir = MakeTum("missingimg");
    auto reader = TumReader::Open(dir, SmallCamera());
    ASSERT_TRUE(reader.ok());
    std::filesystem::remove(dir + "/" + (*reader)->entry(0).depth_file);
    auto f = (*reader)->Load(0);
    ASSERT_FALSE(f.ok());
    EXPECT_EQ(f.status().code(), absl::StatusCode::kNotFound);
  }
  {  // default 640x480 intrinsics vs 8x6 images: the frame is refused with a size message
    const std::string dir = MakeTum("wrongsize");
    auto reader = TumReader::Open(dir);
    ASSERT_TRUE(reader.ok());
    auto f = (*reader)->Load(0);
    ASSERT_FALSE(f.ok());
    EXPECT_NE(f.status().message().find("intrinsics say"), std::string::npos) << f.status();
  }
  {  // tolerances so tight that nothing associates
    const std::string dir = MakeTum("tight");
    TumOptions o = SmallCamera();
    o.max_depth_dt_s = 0.001;
    EXPECT_EQ(TumReader::Open(dir, o).status().code(), absl::StatusCode::kNotFound);
  }
}

}  // namespace
}  // namespace exo
