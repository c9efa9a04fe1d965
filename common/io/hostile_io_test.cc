// The decoding attacks of issue 20 against common/io directly: a depth header claiming more than
// the caller's limit is refused before anything is allocated, the PNG depth codec decodes only
// 16-bit greyscale PNG (no PGM, no TIFF, no size other than the header's), the signed-overflow
// size check, and the JPEG scan limit / sequential-only mode.
#include <gtest/gtest.h>

#include <cstring>

#include "common/io/depth_codec.h"
#include "common/io/hostile_inputs.h"
#include "common/io/jpeg.h"
#include "common/io/test_util.h"

namespace exo {
namespace {

std::span<const uint8_t> Span(const std::string& s) {
  return {reinterpret_cast<const uint8_t*>(s.data()), s.size()};
}
std::span<const uint8_t> Span(const std::vector<uint8_t>& v) { return {v.data(), v.size()}; }

TEST(HostileDepth, HeaderAboveTheCallersLimitIsRefusedBeforeDecoding) {
  // 8192 x 8192 of zeros compresses to a few KB; the header alone must stop it.
  ImageU16 big(8192, 8192);
  const std::vector<uint8_t> bytes = EncodeDepth(big);
  ASSERT_LT(bytes.size(), 64u << 10);
  auto info = ReadDepthInfo(Span(bytes));
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->width, 8192);
  auto r = DecodeDepth(Span(bytes), int64_t{1} << 20);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("above the limit of 1048576 pixels"), std::string::npos)
      << r.status();
}

TEST(HostileDepth, HugeSidesDoNotOverflowTheSizeCheck) {
  // w * h = 2^64 - ... would overflow a signed 64-bit product (the sanitizer abort of issue 20).
  const std::string s = hostile::DepthStream(3, 0xFFFFFFFFu, 0xFFFFFFFFu, "x");
  auto r = DecodeDepth(Span(s));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("invalid size 4294967295x4294967295"), std::string::npos);
}

TEST(HostileDepth, PgmInsideThePngCodecIsRefused) {
  const std::string s = hostile::DepthStream(4, 8, 6, hostile::Pgm16(8, 6));
  auto r = DecodeDepth(Span(s));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("no PNG signature"), std::string::npos) << r.status();
}

TEST(HostileDepth, PngClaimingAnotherSizeIsRefusedFromItsHeader) {
  const std::string s = hostile::DepthStream(4, 64, 48, hostile::PngHeader(16384, 16384));
  auto r = DecodeDepth(Span(s));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(
      r.status().message().find("PNG depth payload is 16384x16384, the depth header says 64x48"),
      std::string::npos)
      << r.status();
}

TEST(HostileDepth, EightBitOrColourPngIsRefused) {
  for (auto [bits, type] : {std::pair{8, 0}, std::pair{16, 2}}) {
    const std::string s = hostile::DepthStream(4, 64, 48, hostile::PngHeader(64, 48, bits, type));
    auto r = DecodeDepth(Span(s));
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("must be 16-bit greyscale"), std::string::npos)
        << r.status();
  }
}

TEST(HostileDepth, CorruptPngBodyIsAnErrorAndAValidOneDecodesWithLibpng) {
  ImageU16 d(37, 21);
  for (int y = 0; y < 21; ++y)
    for (int x = 0; x < 37; ++x) d.at(x, y) = static_cast<uint16_t>(x * 1000 + y * 7 + 1);
  DepthCodecOptions o;
  o.codec = DepthCodec::kPng;
  auto enc = EncodeDepth(d, o);
  ASSERT_TRUE(enc.ok());
  auto back = DecodeDepth(Span(*enc));
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(std::memcmp(back->data(), d.data(), d.size() * 2), 0);
  // A valid header and garbage after it: libpng's error, no crash.
  std::vector<uint8_t> bad = *enc;
  for (size_t i = kDepthHeaderBytes + 40; i < bad.size(); ++i) bad[i] ^= 0x5A;
  auto r = DecodeDepth(Span(bad));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("PNG depth payload"), std::string::npos) << r.status();
}

TEST(HostileJpeg, ManyScanProgressiveIsRefusedByTheScanLimit) {
  const std::vector<uint8_t> j = hostile::ManyScanProgressiveJpeg(64, 64);
  ASSERT_EQ(hostile::CountJpegScans(j), 640);
  auto r = DecodeJpeg(Span(j));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("500 scans"), std::string::npos) << r.status();
}

TEST(HostileJpeg, SequentialOnlyRefusesProgressiveFromTheHeader) {
  const std::vector<uint8_t> j = hostile::ManyScanProgressiveJpeg(32, 16);
  JpegLimits l;
  l.sequential_only = true;
  auto info = ReadJpegInfo(Span(j), l);
  ASSERT_FALSE(info.ok());
  EXPECT_NE(info.status().message().find("SOF marker 0xc2"), std::string::npos) << info.status();
  // A baseline JPEG passes the same limits.
  auto base = EncodeJpeg(testing::MakeTestRgb(32, 16));
  ASSERT_TRUE(base.ok());
  auto ok = DecodeJpeg(Span(*base), l);
  ASSERT_TRUE(ok.ok()) << ok.status();
  EXPECT_EQ(ok->width(), 32);
}

TEST(HostileJpeg, PixelCapIsTheCallers) {
  auto base = EncodeJpeg(testing::MakeTestRgb(64, 48));
  ASSERT_TRUE(base.ok());
  JpegLimits l;
  l.max_pixels = 1000;
  auto r = DecodeJpeg(Span(*base), l);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("64x48 pixels (limit 1000)"), std::string::npos)
      << r.status();
}

}  // namespace
}  // namespace exo
