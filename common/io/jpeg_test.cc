#include "common/io/jpeg.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <tuple>
#include <filesystem>
#include <random>

#include "common/io/image_file.h"
#include "common/io/test_util.h"

namespace exo {
namespace {

double Psnr(const ImageU8& a, const ImageU8& b) {
  double se = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double d = double(a.data()[i]) - b.data()[i];
    se += d * d;
  }
  return 10 * std::log10(255.0 * 255.0 / (se / a.size()));
}

TEST(JpegTest, RoundTripKeepsSizeAndQuality) {
  const ImageU8 img = testing::MakeTestRgb(160, 120);
  auto bytes = EncodeJpeg(img, 90);
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  EXPECT_LT(bytes->size(), img.bytes());
  auto info = ReadJpegInfo(*bytes);
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->width, 160);
  EXPECT_EQ(info->height, 120);
  auto back = DecodeJpeg(*bytes);
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_TRUE(back->SameShape(img));
  EXPECT_GT(Psnr(img, *back), 35.0);
  // Channel order survives (guards RGB vs BGR): a pure red patch stays red.
  ImageU8 red(32, 32, 3);
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 32; ++x) red.at(x, y, 0) = 250;
  auto red_back = DecodeJpeg(*EncodeJpeg(red, 95));
  ASSERT_TRUE(red_back.ok());
  EXPECT_GT(red_back->at(16, 16, 0), 230);
  EXPECT_LT(red_back->at(16, 16, 2), 25);
}

TEST(JpegTest, EncodeRejectsBadInput) {
  EXPECT_FALSE(EncodeJpeg(ImageU8(), 90).ok());
  EXPECT_FALSE(EncodeJpeg(ImageU8(8, 8, 1), 90).ok());
  EXPECT_FALSE(EncodeJpeg(testing::MakeTestRgb(8, 8), 0).ok());
  EXPECT_FALSE(EncodeJpeg(testing::MakeTestRgb(8, 8), 101).ok());
}

// The publish encoder: optimised Huffman tables only, so exactly the pixels of EncodeJpeg, in
// fewer bytes, still a baseline (SOF0) JPEG the upload path's sequential-only decode accepts;
// odd sizes (partial MCUs) and quality extremes included.
TEST(JpegTest, OptimizedHuffmanDecodesToTheSamePixelsInFewerBytes) {
  for (const auto& [w, h, q] : {std::tuple{640, 480, 50}, std::tuple{161, 99, 50},
                                std::tuple{64, 48, 1}, std::tuple{64, 48, 100}}) {
    const ImageU8 img = testing::MakeTestRgb(w, h);
    auto plain = EncodeJpeg(img, q);
    auto opt = EncodeJpegOptimized(img, q);
    ASSERT_TRUE(plain.ok() && opt.ok()) << opt.status();
    EXPECT_LT(opt->size(), plain->size()) << w << "x" << h << " q" << q;
    auto info = ReadJpegInfo(*opt);
    ASSERT_TRUE(info.ok());
    EXPECT_EQ(info->sof_marker, 0xC0);
    auto a = DecodeJpeg(*plain), b = DecodeJpeg(*opt, JpegLimits{.sequential_only = true});
    ASSERT_TRUE(a.ok() && b.ok()) << b.status();
    ASSERT_TRUE(a->SameShape(*b));
    EXPECT_EQ(0, std::memcmp(a->data(), b->data(), a->bytes())) << w << "x" << h << " q" << q;
  }
  EXPECT_FALSE(EncodeJpegOptimized(ImageU8(), 90).ok());
  EXPECT_FALSE(EncodeJpegOptimized(ImageU8(8, 8, 1), 90).ok());
  EXPECT_FALSE(EncodeJpegOptimized(testing::MakeTestRgb(8, 8), 0).ok());
}

// Guard: warnings are errors. libjpeg only *warns* on a truncated stream (grey padding,
// TJERR_WARNING); code that accepted TJERR_WARNING results would return a padded image here.
TEST(JpegTest, TruncatedIsAnError) {
  const auto bytes = *EncodeJpeg(testing::MakeTestRgb(160, 120), 90);
  for (size_t len : {size_t{0}, size_t{1}, size_t{3}, size_t{50}, bytes.size() / 4,
                     bytes.size() / 2, bytes.size() - 10, bytes.size() - 2}) {
    auto r = DecodeJpeg(std::span<const uint8_t>(bytes.data(), len));
    EXPECT_FALSE(r.ok()) << "length " << len << " of " << bytes.size();
    if (!r.ok()) {
      EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
    }
  }
}

TEST(JpegTest, RandomGarbageIsAnError) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 50; ++trial) {
    std::vector<uint8_t> junk(1 + rng() % 4000);
    for (auto& b : junk) b = static_cast<uint8_t>(rng());
    if (trial % 2 == 0 && junk.size() >= 2) junk[0] = 0xFF, junk[1] = 0xD8;  // fake SOI
    EXPECT_FALSE(DecodeJpeg(junk).ok()) << "trial " << trial;
  }
}

// A header claiming a gigantic image must be refused before allocating (guards kMaxJpegPixels).
TEST(JpegTest, AbsurdHeaderSizeRefused) {
  auto bytes = *EncodeJpeg(testing::MakeTestRgb(16, 16), 90);
  for (size_t i = 0; i + 8 < bytes.size(); ++i)
    if (bytes[i] == 0xFF && bytes[i + 1] == 0xC0) {  // SOF0: len(2) prec(1) h(2) w(2)
      bytes[i + 5] = 0xC0, bytes[i + 6] = 0x00, bytes[i + 7] = 0xC0, bytes[i + 8] = 0x00;  // 49152^2
      break;
    }
  auto r = DecodeJpeg(bytes);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("limit"), std::string::npos) << r.status();
}

// Bit flips anywhere: never a crash; either a clear error or an image of the declared size.
TEST(JpegTest, BitFlipsNeverCrash) {
  const auto clean = *EncodeJpeg(testing::MakeTestRgb(96, 64), 90);
  std::mt19937 rng(11);
  int errors = 0;
  for (int trial = 0; trial < 300; ++trial) {
    auto bytes = clean;
    const int flips = 1 + trial % 4;
    for (int f = 0; f < flips; ++f) bytes[rng() % bytes.size()] ^= uint8_t(1u << (rng() % 8));
    auto r = DecodeJpeg(bytes);
    if (!r.ok()) {
      ++errors;
      EXPECT_FALSE(r.status().message().empty());
    } else {
      EXPECT_EQ(r->channels(), 3);
      EXPECT_GT(r->width(), 0);
    }
  }
  EXPECT_GT(errors, 0);  // some flips hit markers/Huffman codes and must be reported
}

TEST(JpegTest, Decodes7ScenesColour) {
  const std::string path = testing::SharedDir() + "/data/7scenes-redkitchen/frame-000000.color.jpg";
  if (!std::filesystem::exists(path)) GTEST_SKIP() << "7-Scenes data not found at " << path;
  auto img = ReadColorImage(path);
  ASSERT_TRUE(img.ok()) << img.status();
  EXPECT_EQ(img->width(), 640);
  EXPECT_EQ(img->height(), 480);
  EXPECT_EQ(img->channels(), 3);
}

}  // namespace
}  // namespace exo
