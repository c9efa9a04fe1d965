#include "common/io/depth_codec.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <random>

#include "common/io/image_file.h"
#include "common/io/test_util.h"

namespace exo {
namespace {

// Synthetic depth: a slanted plane in mm with holes (0), a box edge and sensor-like noise.
ImageU16 MakeDepth(int w, int h, uint32_t seed = 1) {
  std::mt19937 rng(seed);
  ImageU16 d(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double z = 1500 + 2.0 * x + 1.0 * y;
      if (x > w / 3 && x < w / 2 && y > h / 4 && y < h / 2) z = 900;  // box in front
      z += static_cast<int>(rng() % 5) - 2;
      if ((x * 7 + y * 13) % 97 == 0 || x < 4) z = 0;  // holes
      d.at(x, y) = static_cast<uint16_t>(z);
    }
  d.at(w - 1, h - 1) = 65535;  // extremes survive
  d.at(w - 2, h - 1) = 1;
  return d;
}

const DepthCodec kAll[] = {DepthCodec::kRawZstd, DepthCodec::kDeltaZstd,
                           DepthCodec::kDeltaPlanesZstd, DepthCodec::kPng};

TEST(DepthCodecTest, LosslessRoundTripEveryCodec) {
  const ImageU16 d = MakeDepth(97, 61);  // odd sizes
  for (DepthCodec c : kAll) {
    DepthCodecOptions o;
    o.codec = c;
    auto bytes = EncodeDepth(d, o);
    ASSERT_TRUE(bytes.ok()) << DepthCodecName(c) << ": " << bytes.status();
    EXPECT_LT(bytes->size(), d.bytes()) << DepthCodecName(c);
    auto back = DecodeDepth(*bytes);
    ASSERT_TRUE(back.ok()) << DepthCodecName(c) << ": " << back.status();
    EXPECT_TRUE(*back == d) << DepthCodecName(c);
  }
  auto def = DecodeDepth(EncodeDepth(d));
  ASSERT_TRUE(def.ok());
  EXPECT_TRUE(*def == d);
}

// Wrap-around residuals (0 <-> 65535 neighbours) must be exact (guards the u16 modular maths).
TEST(DepthCodecTest, ExtremeNeighboursRoundTrip) {
  ImageU16 d(9, 5);
  for (size_t i = 0; i < d.size(); ++i) d.data()[i] = (i % 2) ? 65535 : 0;
  for (DepthCodec c : kAll) {
    DepthCodecOptions o;
    o.codec = c;
    auto back = DecodeDepth(*EncodeDepth(d, o));
    ASSERT_TRUE(back.ok()) << back.status();
    EXPECT_TRUE(*back == d) << DepthCodecName(c);
  }
}

TEST(DepthCodecTest, TruncatedIsAnError) {
  const ImageU16 d = MakeDepth(64, 48);
  for (DepthCodec c : kAll) {
    DepthCodecOptions o;
    o.codec = c;
    const auto bytes = *EncodeDepth(d, o);
    for (size_t len = 0; len < bytes.size(); len += 1 + len / 3) {
      auto r = DecodeDepth(std::span<const uint8_t>(bytes.data(), len));
      EXPECT_FALSE(r.ok()) << DepthCodecName(c) << " len " << len;
    }
    // Truncated payload with a header fixed up to match: the codec itself must notice.
    auto cut = bytes;
    cut.resize(bytes.size() - 7);
    const uint32_t p = static_cast<uint32_t>(cut.size() - kDepthHeaderBytes);
    for (int i = 0; i < 4; ++i) cut[16 + i] = static_cast<uint8_t>(p >> (8 * i));
    EXPECT_FALSE(DecodeDepth(cut).ok()) << DepthCodecName(c);
  }
}

// Guard: zstd content checksum. Without ZSTD_c_checksumFlag a flipped residual bit decodes to a
// wrong depth image without any error.
TEST(DepthCodecTest, PayloadBitFlipIsDetected) {
  const ImageU16 d = MakeDepth(64, 48);
  const auto clean = EncodeDepth(d);
  std::mt19937 rng(3);
  for (int trial = 0; trial < 100; ++trial) {
    auto bytes = clean;
    const size_t pos = kDepthHeaderBytes + rng() % (bytes.size() - kDepthHeaderBytes);
    bytes[pos] ^= uint8_t(1u << (rng() % 8));
    auto r = DecodeDepth(bytes);
    if (r.ok()) {
      EXPECT_TRUE(*r == d) << "flip at " << pos << " decoded to a different image silently";
    }
  }
}

TEST(DepthCodecTest, HeaderErrorsAreClear) {
  const auto good = EncodeDepth(MakeDepth(32, 24));
  auto bad_magic = good;
  bad_magic[0] = 'X';
  auto r = DecodeDepth(bad_magic);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("magic"), std::string::npos);
  auto bad_version = good;
  bad_version[4] = 9;
  EXPECT_NE(DecodeDepth(bad_version).status().message().find("version"), std::string::npos);
  auto bad_codec = good;
  bad_codec[5] = 77;
  EXPECT_NE(DecodeDepth(bad_codec).status().message().find("codec"), std::string::npos);
  // Wrong size in the header (payload intact): decoded byte count disagrees.
  auto wrong_size = good;
  wrong_size[8] = 33;
  EXPECT_FALSE(DecodeDepth(wrong_size).ok());
  auto zero_size = good;
  zero_size[8] = zero_size[9] = zero_size[10] = zero_size[11] = 0;
  EXPECT_NE(DecodeDepth(zero_size).status().message().find("size"), std::string::npos);
  auto padded = good;
  padded.push_back(0);
  EXPECT_FALSE(DecodeDepth(padded).ok());
  std::mt19937 rng(5);
  for (int t = 0; t < 50; ++t) {
    std::vector<uint8_t> junk(rng() % 300);
    for (auto& b : junk) b = static_cast<uint8_t>(rng());
    if (junk.size() >= 4 && t % 2) junk[0] = 'E', junk[1] = 'X', junk[2] = 'D', junk[3] = '1';
    EXPECT_FALSE(DecodeDepth(junk).ok());
  }
}

TEST(DepthCodecTest, EncodeRejectsBadInput) {
  EXPECT_FALSE(EncodeDepth(ImageU16(), DepthCodecOptions{}).ok());
  EXPECT_FALSE(EncodeDepth(ImageU16(4, 4, 2), DepthCodecOptions{}).ok());
  DepthCodecOptions o;
  o.zstd_level = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.codec = DepthCodec::kPng;
  o.png_compression = 10;
  EXPECT_FALSE(o.Validate().ok());
}

// SPEC §11 "zero/NaN/inf depth" and "depth in mm vs m".
TEST(DepthConversionTest, MetresAndUnits) {
  ImageF m(8, 1);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  const float vals[8] = {1.2345f, 0.0f, nan, inf, -1.0f, 70.0f, 0.0004f, 65.535f};
  for (int i = 0; i < 8; ++i) m.at(i, 0) = vals[i];
  const ImageU16 mm = DepthU16FromMeters(m, 0.001);
  EXPECT_EQ(mm.at(0, 0), 1235);  // rounded to nearest mm
  EXPECT_EQ(mm.at(1, 0), 0);
  EXPECT_EQ(mm.at(2, 0), 0);      // NaN -> invalid
  EXPECT_EQ(mm.at(3, 0), 0);      // inf -> invalid
  EXPECT_EQ(mm.at(4, 0), 0);      // negative -> invalid
  EXPECT_EQ(mm.at(5, 0), 0);      // 70 m does not fit in u16 mm: dropped, not wrapped (4464)
  EXPECT_EQ(mm.at(6, 0), 0);      // rounds to 0 units -> invalid
  EXPECT_EQ(mm.at(7, 0), 65535);  // the largest representable value
  const ImageF back = DepthMetersFromU16(mm, 0.001);
  EXPECT_NEAR(back.at(0, 0), 1.235f, 1e-6);
  EXPECT_EQ(back.at(1, 0), 0.0f);
  // TUM scale: 5000 units per metre.
  ImageU16 tum(1, 1);
  tum.at(0, 0) = 5000;
  EXPECT_FLOAT_EQ(DepthMetersFromU16(tum, 1.0 / 5000).at(0, 0), 1.0f);
}

TEST(DepthCodecTest, Real7ScenesDepthRoundTrip) {
  const std::string path = testing::SharedDir() + "/data/7scenes-redkitchen/frame-000000.depth.png";
  if (!std::filesystem::exists(path)) GTEST_SKIP() << "7-Scenes data not found at " << path;
  auto d = ReadPng16(path);
  ASSERT_TRUE(d.ok()) << d.status();
  const auto bytes = EncodeDepth(*d);
  EXPECT_LT(bytes.size(), d->bytes() / 2);
  auto back = DecodeDepth(bytes);
  ASSERT_TRUE(back.ok());
  EXPECT_TRUE(*back == *d);
}

}  // namespace
}  // namespace exo
