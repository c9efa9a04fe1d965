#include "common/io/jpeg.h"

#include <turbojpeg.h>

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

}  // namespace

absl::StatusOr<std::vector<uint8_t>> EncodeJpeg(const ImageU8& rgb, int quality) {
  if (rgb.empty() || rgb.channels() != 3)
    return absl::InvalidArgumentError(absl::StrCat("EncodeJpeg needs a non-empty RGB8 image, got ",
                                                   rgb.width(), "x", rgb.height(), "x",
                                                   rgb.channels()));
  if (quality < 1 || quality > 100)
    return absl::InvalidArgumentError(absl::StrCat("JPEG quality ", quality, " not in [1, 100]"));
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

absl::StatusOr<JpegInfo> ReadJpegInfo(std::span<const uint8_t> bytes) {
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
  if (w <= 0 || hgt <= 0 || int64_t{w} * hgt > kMaxJpegPixels)
    return absl::InvalidArgumentError(
        absl::StrCat("JPEG header claims ", w, "x", hgt, " pixels (limit ", kMaxJpegPixels, ")"));
  return JpegInfo{w, hgt};
}

absl::StatusOr<ImageU8> DecodeJpeg(std::span<const uint8_t> bytes) {
  EXO_ASSIGN_OR_RETURN(const JpegInfo info, ReadJpegInfo(bytes));
  TjHandle h(tjInitDecompress());
  if (!h) return absl::InternalError("tjInitDecompress failed");
  ImageU8 rgb(info.width, info.height, 3);
  // A truncated stream is only a libjpeg *warning* ("Premature end of JPEG file"; libjpeg fills
  // the rest with grey and TurboJPEG 2.1 returns -1 with TJERR_WARNING). We treat any nonzero
  // return, warning or fatal, as an error; TJFLAG_STOPONWARNING stops the decode at the first
  // warning instead of finishing a useless image.
  const int rc = tjDecompress2(h.get(), bytes.data(), bytes.size(), rgb.data(), info.width, 0,
                               info.height, TJPF_RGB,
                               TJFLAG_STOPONWARNING);
  if (rc != 0) {
    const bool warning = tjGetErrorCode(h.get()) == TJERR_WARNING;
    return absl::InvalidArgumentError(absl::StrCat(warning ? "corrupt or truncated JPEG data: "
                                                           : "JPEG decode failed: ",
                                                   TjError(h.get())));
  }
  return rgb;
}

}  // namespace exo
