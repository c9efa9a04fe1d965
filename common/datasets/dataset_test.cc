#include "common/datasets/dataset.h"

#include <fstream>

#include <gtest/gtest.h>

#include "common/datasets/exo_layout.h"
#include "common/datasets/test_fixture.h"

namespace exo {
namespace {

TEST(Dataset, HeldOutSplitIsTheEvals) {
  EXPECT_FALSE(IsHeldOut(0, 10));
  EXPECT_TRUE(IsHeldOut(9, 10));
  EXPECT_TRUE(IsHeldOut(19, 10));
  EXPECT_FALSE(IsHeldOut(9, 0));
  EXPECT_TRUE(IsHeldOut(0, 10, 0));
  EXPECT_TRUE(IsHeldOut(13, 10, 3));
  EXPECT_FALSE(IsHeldOut(9, 10, 3));
}

TEST(Dataset, OpensOurLayoutWithHoldOut) {
  const std::string dir = testing::FreshTempDir("dataset_exo");
  ExoLayoutWriter w(dir);
  for (uint64_t i = 0; i < 6; ++i) ASSERT_TRUE(w.Write(testing::MakeFrame(i)).ok());
  DatasetOptions o;
  o.format = "exo";
  o.hold_out_every = 3;  // frames 2 and 5 left out
  auto s = OpenDataset(dir, o);
  ASSERT_TRUE(s.ok()) << s.status();
  ASSERT_EQ((*s)->size(), 4u);
  auto f = (*s)->Load(2);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->sequence, 3u);
  EXPECT_FALSE((*s)->Load(4).ok());
}

TEST(Dataset, TumIntrinsicsFromFlagOrFileElseAWarning) {
  std::vector<std::string> warnings;
  DatasetOptions o;
  o.format = "tum";
  (void)OpenDataset("/nonexistent/tum", o, &warnings);
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("525"), std::string::npos);
  warnings.clear();
  o.intrinsics = {585, 585, 320, 240};
  (void)OpenDataset("/nonexistent/tum", o, &warnings);
  EXPECT_TRUE(warnings.empty());
  o.intrinsics = {585, 585};
  EXPECT_NE(o.Validate().message().find("fx,fy,cx,cy"), std::string::npos);
  o.intrinsics.clear();
  o.format = "7scenes";
  o.camera_file = "/x";
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.format = "kinect";
  EXPECT_NE(o.Validate().message().find("kinect"), std::string::npos);

  const std::string dir = testing::FreshTempDir("camera_file");
  std::ofstream(dir + "/cam.txt") << "# fx fy cx cy w h\n517.3 516.5 318.6 255.3 640 480\n";
  auto c = ReadCameraFile(dir + "/cam.txt");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->fy, 516.5);
  EXPECT_EQ(c->height, 480);
  std::ofstream(dir + "/bad.txt") << "517.3 516.5\n";
  EXPECT_NE(ReadCameraFile(dir + "/bad.txt").status().message().find("bad.txt"), std::string::npos);
}

}  // namespace
}  // namespace exo
