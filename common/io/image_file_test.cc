#include "common/io/image_file.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <opencv2/imgcodecs.hpp>

#include "common/io/cv_adapter.h"
#include "common/io/test_util.h"

namespace exo {
namespace {

std::string TempPath(const std::string& name) {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("exo_io_test_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  return (dir / name).string();
}

TEST(CvAdapterTest, ViewIsZeroCopy) {
  ImageU8 img(4, 3, 3);
  cv::Mat v = CvView(img);
  EXPECT_EQ(v.data, img.data());
  EXPECT_EQ(v.type(), CV_8UC3);
  v.at<cv::Vec3b>(2, 1)[2] = 77;  // row 2, col 1, channel 2
  EXPECT_EQ(img.at(1, 2, 2), 77);
  ImageF f(5, 2);
  EXPECT_EQ(CvView(f).type(), CV_32FC1);
  EXPECT_TRUE(CvView(ImageU16()).empty());
  auto copy = ImageFromCv<uint8_t>(v);
  ASSERT_TRUE(copy.ok());
  EXPECT_TRUE(*copy == img);
  EXPECT_FALSE(ImageFromCv<uint16_t>(v).ok());  // depth mismatch
}

// Guards the RGB<->BGR conversion at the file boundary: a file written by OpenCV with a BGR
// blue pixel must read back as RGB blue, and our PNG writer must produce a file OpenCV sees
// as BGR.
TEST(ImageFileTest, PngKeepsRgbOrder) {
  ImageU8 img(2, 1, 3);
  img.at(0, 0, 0) = 255;  // red
  img.at(1, 0, 2) = 255;  // blue
  const std::string path = TempPath("rgb.png");
  ASSERT_TRUE(WriteColorImage(path, img).ok());
  cv::Mat bgr = cv::imread(path, cv::IMREAD_COLOR);
  ASSERT_FALSE(bgr.empty());
  EXPECT_EQ(bgr.at<cv::Vec3b>(0, 0)[2], 255);  // red lives in BGR channel 2
  EXPECT_EQ(bgr.at<cv::Vec3b>(0, 0)[0], 0);
  auto back = ReadColorImage(path);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_TRUE(*back == img);
}

TEST(ImageFileTest, JpegFileRoundTrip) {
  const ImageU8 img = testing::MakeTestRgb(64, 48);
  const std::string path = TempPath("c.jpg");
  ASSERT_TRUE(WriteColorImage(path, img, 95).ok());
  auto back = ReadColorImage(path);
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_TRUE(back->SameShape(img));
  int max_err = 0;
  for (size_t i = 0; i < img.size(); ++i)
    max_err = std::max(max_err, std::abs(int(img.data()[i]) - back->data()[i]));
  EXPECT_LT(max_err, 40);
}

TEST(ImageFileTest, Png16RoundTripAndTypeChecks) {
  ImageU16 d(7, 5);
  for (size_t i = 0; i < d.size(); ++i) d.data()[i] = static_cast<uint16_t>(i * 1000 + 1);
  const std::string path = TempPath("d.png");
  ASSERT_TRUE(WritePng16(path, d).ok());
  auto back = ReadPng16(path);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_TRUE(*back == d);
  // An 8-bit colour PNG is not depth.
  const std::string c = TempPath("c8.png");
  ASSERT_TRUE(WriteColorImage(c, testing::MakeTestRgb(4, 4)).ok());
  EXPECT_FALSE(ReadPng16(c).ok());
  // ... and 16-bit depth is not colour.
  EXPECT_FALSE(ReadColorImage(path).ok());
}

TEST(ImageFileTest, MissingAndCorruptFiles) {
  auto r = ReadColorImage("/nonexistent/x.png");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(r.status().message().find("/nonexistent/x.png"), std::string::npos);
  EXPECT_EQ(ReadPng16("/nonexistent/d.png").status().code(), absl::StatusCode::kNotFound);
  const std::string junk = TempPath("junk.png");
  const std::vector<uint8_t> bytes = {0x89, 'P', 'N', 'G', 1, 2, 3};
  ASSERT_TRUE(WriteFileBytes(junk, bytes).ok());
  EXPECT_FALSE(ReadPng16(junk).ok());
  EXPECT_FALSE(ReadColorImage(junk).ok());
  const std::string jj = TempPath("junk.jpg");
  ASSERT_TRUE(WriteFileBytes(jj, bytes).ok());
  EXPECT_FALSE(ReadColorImage(jj).ok());
}

}  // namespace
}  // namespace exo
