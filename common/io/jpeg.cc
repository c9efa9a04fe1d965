#include "common/io/jpeg.h"

#include <turbojpeg.h>

#include <csetjmp>
#include <cstdlib>
#include <cstdio>  // jpeglib.h needs FILE

#include <jpeglib.h>

#include <algorithm>
#include <memory>
#include <string>

namespace exo {
namespace {

struct TjDeleter {
  void operator()(void* h) const {
    if (h != nullptr) tjDestroy(h);
  }
};
using TjHandle = std::unique_ptr<void, TjDeleter>;

std::string TjError(tjhandle h) {
  const char* msg = tjGetErrorStr2(h);
  return msg != nullptr ? std::string(msg) : std::string("unknown TurboJPEG error");
}

// The first start-of-frame marker (SOFn) found by walking the marker segments; 0 if none.
int FindSofMarker(std::span<const uint8_t> b) {
  size_t i = 2;  // after SOI
  while (i + 1 < b.size()) {
    if (b[i] != 0xFF) return 0;  // not at a marker: corrupt (the decoder says more)
    while (i + 1 < b.size() && b[i + 1] == 0xFF) ++i;  // fill bytes
    if (i + 1 >= b.size()) return 0;
    const int m = b[i + 1];
    i += 2;
    if (m >= 0xC0 && m <= 0xCF && m != 0xC4 && m != 0xC8 && m != 0xCC) return m;
    if (m == 0x01 || (m >= 0xD0 && m <= 0xD7)) continue;  // standalone markers
    if (m == 0xD9 || m == 0xDA) return 0;                  // EOI / SOS before any SOF
    if (i + 1 >= b.size()) return 0;
    i += (size_t{b[i]} << 8) | b[i + 1];  // segment length includes its own two bytes
  }
  return 0;
}

absl::Status CheckEncodeInput(const ImageU8& rgb, int quality) {
  if (rgb.empty() || rgb.channels() != 3)
    return absl::InvalidArgumentError(absl::StrCat("EncodeJpeg needs a non-empty RGB8 image, got ",
                                                   rgb.width(), "x", rgb.height(), "x",
                                                   rgb.channels()));
  if (quality < 1 || quality > 100)
    return absl::InvalidArgumentError(absl::StrCat("JPEG quality ", quality, " not in [1, 100]"));
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::vector<uint8_t>> EncodeJpeg(const ImageU8& rgb, int quality) {
  EXO_RETURN_IF_ERROR(CheckEncodeInput(rgb, quality));
  TjHandle h(tjInitCompress());
  if (!h) return absl::InternalError("tjInitCompress failed");
  unsigned char* out = nullptr;
  unsigned long out_size = 0;  // NOLINT(runtime/int): TurboJPEG's type
  const int rc = tjCompress2(h.get(), rgb.data(), rgb.width(), 0, rgb.height(), TJPF_RGB, &out,
                             &out_size, TJSAMP_420, quality, 0);
  if (rc != 0) {
    const std::string err = TjError(h.get());
    if (out != nullptr) tjFree(out);
    return absl::InternalError(absl::StrCat("JPEG encode failed: ", err));
  }
  std::vector<uint8_t> bytes(out, out + out_size);
  tjFree(out);
  return bytes;
}

namespace {
struct JpegErrorJump {
  jpeg_error_mgr mgr;
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX];
};
}  // namespace

absl::StatusOr<std::vector<uint8_t>> EncodeJpegOptimized(const ImageU8& rgb, int quality) {
  EXO_RETURN_IF_ERROR(CheckEncodeInput(rgb, quality));
  // libjpeg reports errors by longjmp out of error_exit: nothing with a destructor lives
  // between setjmp and the last libjpeg call.
  jpeg_compress_struct cinfo{};
  JpegErrorJump err{};
  cinfo.err = jpeg_std_error(&err.mgr);
  err.mgr.error_exit = [](j_common_ptr c) {
    auto* e = reinterpret_cast<JpegErrorJump*>(c->err);
    (*c->err->format_message)(c, e->message);
    std::longjmp(e->jump, 1);
  };
  unsigned char* out = nullptr;
  unsigned long out_size = 0;  // NOLINT(runtime/int): libjpeg's type
  if (setjmp(err.jump)) {
    jpeg_destroy_compress(&cinfo);
    std::free(out);
    return absl::InternalError(absl::StrCat("JPEG encode failed: ", err.message));
  }
  jpeg_create_compress(&cinfo);
  jpeg_mem_dest(&cinfo, &out, &out_size);
  cinfo.image_width = static_cast<JDIMENSION>(rgb.width());
  cinfo.image_height = static_cast<JDIMENSION>(rgb.height());
  cinfo.input_components = 3;
  cinfo.in_color_space = JCS_RGB;
  jpeg_set_defaults(&cinfo);  // YCbCr, luma 2x2 (4:2:0)
  jpeg_set_quality(&cinfo, quality, TRUE);
  // What tjCompress2 does without TJFLAG_ACCURATEDCT: the fast integer DCT below quality 96
  // (libjpeg-turbo's turbojpeg.c setCompDefaults), so the coefficients are EncodeJpeg's.
  cinfo.dct_method = quality >= 96 ? JDCT_ISLOW : JDCT_FASTEST;
  cinfo.optimize_coding = TRUE;
  jpeg_start_compress(&cinfo, TRUE);
  while (cinfo.next_scanline < cinfo.image_height) {
    JSAMPROW row = const_cast<JSAMPROW>(rgb.data() + size_t{cinfo.next_scanline} * rgb.width() * 3);
    jpeg_write_scanlines(&cinfo, &row, 1);
  }
  jpeg_finish_compress(&cinfo);
  jpeg_destroy_compress(&cinfo);
  std::vector<uint8_t> bytes(out, out + out_size);
  std::free(out);
  return bytes;
}

absl::StatusOr<JpegInfo> ReadJpegInfo(std::span<const uint8_t> bytes, const JpegLimits& limits) {
  if (bytes.size() < 4) return absl::InvalidArgumentError(
      absl::StrCat("JPEG data too short (", bytes.size(), " bytes)"));
  if (bytes[0] != 0xFF || bytes[1] != 0xD8)
    return absl::InvalidArgumentError("not a JPEG: missing SOI marker (FF D8)");
  TjHandle h(tjInitDecompress());
  if (!h) return absl::InternalError("tjInitDecompress failed");
  int w = 0, hgt = 0, subsamp = 0, colorspace = 0;
  if (tjDecompressHeader3(h.get(), bytes.data(), bytes.size(), &w, &hgt, &subsamp, &colorspace) !=
      0)
    return absl::InvalidArgumentError(absl::StrCat("corrupt JPEG header: ", TjError(h.get())));
  const int64_t max_pixels = std::min(limits.max_pixels, kMaxJpegPixels);
  if (w <= 0 || hgt <= 0 || int64_t{w} * hgt > max_pixels)
    return absl::InvalidArgumentError(
        absl::StrCat("JPEG header claims ", w, "x", hgt, " pixels (limit ", max_pixels, ")"));
  const int sof = FindSofMarker(bytes);
  if (limits.sequential_only && sof != 0xC0 && sof != 0xC1)
    return absl::InvalidArgumentError(absl::StrCat(
        "JPEG frame type (SOF marker 0x", absl::Hex(sof, absl::kZeroPad2),
        ") is not sequential (baseline 0xc0 / extended 0xc1): progressive, lossless and "
        "arithmetic-coded JPEGs are refused"));
  return JpegInfo{w, hgt, sof};
}

absl::StatusOr<ImageU8> DecodeJpeg(std::span<const uint8_t> bytes, const JpegLimits& limits) {
  EXO_ASSIGN_OR_RETURN(const JpegInfo info, ReadJpegInfo(bytes, limits));
  TjHandle h(tjInitDecompress());
  if (!h) return absl::InternalError("tjInitDecompress failed");
  ImageU8 rgb(info.width, info.height, 3);
  // A truncated stream is only a libjpeg *warning* ("Premature end of JPEG file"; libjpeg fills
  // the rest with grey and TurboJPEG 2.1 returns -1 with TJERR_WARNING). We treat any nonzero
  // return, warning or fatal, as an error; TJFLAG_STOPONWARNING stops the decode at the first
  // warning instead of finishing a useless image. TJFLAG_LIMITSCANS: more than 500 scans (a
  // progressive-JPEG CPU bomb) is an error.
  const int rc = tjDecompress2(h.get(), bytes.data(), bytes.size(), rgb.data(), info.width, 0,
                               info.height, TJPF_RGB,
                               TJFLAG_STOPONWARNING | TJFLAG_LIMITSCANS);
  if (rc != 0) {
    const bool warning = tjGetErrorCode(h.get()) == TJERR_WARNING;
    return absl::InvalidArgumentError(absl::StrCat(warning ? "corrupt or truncated JPEG data: "
                                                           : "JPEG decode failed: ",
                                                   TjError(h.get())));
  }
  return rgb;
}

}  // namespace exo
