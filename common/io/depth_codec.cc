#include "common/io/depth_codec.h"

#include <png.h>
#include <zstd.h>

#include <bit>
#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <memory>
#include <opencv2/imgcodecs.hpp>

#include "common/io/zstd.h"
#include "common/io/cv_adapter.h"

namespace exo {
namespace {

constexpr char kMagic[4] = {'E', 'X', 'D', '1'};
constexpr uint8_t kVersion = 1;

void PutU32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
uint32_t GetU32(const uint8_t* p) {
  return uint32_t{p[0]} | uint32_t{p[1]} << 8 | uint32_t{p[2]} << 16 | uint32_t{p[3]} << 24;
}

inline uint16_t ZigZag(uint16_t residual) {
  const int16_t s = static_cast<int16_t>(residual);
  return static_cast<uint16_t>((static_cast<uint16_t>(s) << 1) ^ static_cast<uint16_t>(s >> 15));
}
inline uint16_t UnZigZag(uint16_t z) {
  return static_cast<uint16_t>((z >> 1) ^ static_cast<uint16_t>(-(z & 1)));
}

// Predictor: left neighbour; first column: the pixel above; (0,0): 0.
template <typename Emit>
void ForEachResidual(const ImageU16& d, Emit emit) {
  const int w = d.width(), h = d.height();
  size_t i = 0;
  for (int y = 0; y < h; ++y) {
    const uint16_t* row = d.row(y);
    const uint16_t first_pred = y > 0 ? d.row(y - 1)[0] : 0;
    emit(i++, ZigZag(static_cast<uint16_t>(row[0] - first_pred)));
    for (int x = 1; x < w; ++x) emit(i++, ZigZag(static_cast<uint16_t>(row[x] - row[x - 1])));
  }
}

// Residual stream (index -> zig-zag residual) back to pixels.
template <typename Get>
void Reconstruct(ImageU16* d, Get get) {
  const int w = d->width(), h = d->height();
  size_t i = 0;
  for (int y = 0; y < h; ++y) {
    uint16_t* row = d->row(y);
    const uint16_t first_pred = y > 0 ? d->row(y - 1)[0] : 0;
    row[0] = static_cast<uint16_t>(first_pred + UnZigZag(get(i++)));
    for (int x = 1; x < w; ++x) row[x] = static_cast<uint16_t>(row[x - 1] + UnZigZag(get(i++)));
  }
}

// ---- 16-bit greyscale PNG through libpng (never a general image decoder) ----
constexpr uint8_t kPngSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
uint32_t GetU32Be(const uint8_t* p) {
  return uint32_t{p[0]} << 24 | uint32_t{p[1]} << 16 | uint32_t{p[2]} << 8 | uint32_t{p[3]};
}

// The IHDR chunk, which the PNG format requires right after the signature: read and checked
// before anything is allocated.
absl::Status CheckPngHeader(std::span<const uint8_t> png, uint32_t w, uint32_t h) {
  if (png.size() < 33 || std::memcmp(png.data(), kPngSignature, 8) != 0)
    return absl::InvalidArgumentError("PNG depth payload has no PNG signature");
  if (GetU32Be(png.data() + 8) != 13 || std::memcmp(png.data() + 12, "IHDR", 4) != 0)
    return absl::InvalidArgumentError("PNG depth payload does not start with an IHDR chunk");
  const uint32_t pw = GetU32Be(png.data() + 16), ph = GetU32Be(png.data() + 20);
  const int bit_depth = png[24], colour_type = png[25], interlace = png[28];
  if (pw != w || ph != h)
    return absl::InvalidArgumentError(absl::StrCat("PNG depth payload is ", pw, "x", ph,
                                                   ", the depth header says ", w, "x", h));
  if (bit_depth != 16 || colour_type != 0 || interlace != 0)
    return absl::InvalidArgumentError(absl::StrCat(
        "PNG depth payload must be 16-bit greyscale, not interlaced; got bit depth ", bit_depth,
        ", colour type ", colour_type, ", interlace ", interlace));
  return absl::OkStatus();
}

struct PngSource {
  const uint8_t* data;
  size_t size;
  size_t pos;
  char error[200];
};

void PngReadFn(png_structp png, png_bytep out, png_size_t n) {
  auto* src = static_cast<PngSource*>(png_get_io_ptr(png));
  if (n > src->size - src->pos) png_error(png, "truncated PNG data");
  std::memcpy(out, src->data + src->pos, n);
  src->pos += n;
}
void PngErrorFn(png_structp png, png_const_charp msg) {
  auto* src = static_cast<PngSource*>(png_get_error_ptr(png));
  std::snprintf(src->error, sizeof(src->error), "%s", msg);
  png_longjmp(png, 1);
}
void PngWarningFn(png_structp, png_const_charp) {}

// libpng reports errors by longjmp: only trivially destructible locals live in this function.
// `out` is w*h u16 (little-endian host), already allocated by the caller.
bool DecodePng16(PngSource* src, uint32_t w, uint32_t h, uint16_t* out) {
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, src, PngErrorFn, PngWarningFn);
  if (png == nullptr) {
    std::snprintf(src->error, sizeof(src->error), "libpng: cannot create a reader");
    return false;
  }
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    std::snprintf(src->error, sizeof(src->error), "libpng: cannot create an info struct");
    return false;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, nullptr);
    return false;
  }
  png_set_user_limits(png, w, h);
  png_set_chunk_malloc_max(png, 1 << 20);  // ancillary chunks (text, ICC) at most 1 MB
  png_set_read_fn(png, src, PngReadFn);
  png_read_info(png, info);
  png_uint_32 pw = 0, ph = 0;
  int bit_depth = 0, colour_type = 0, interlace = 0;
  png_get_IHDR(png, info, &pw, &ph, &bit_depth, &colour_type, &interlace, nullptr, nullptr);
  if (pw != w || ph != h || bit_depth != 16 || colour_type != PNG_COLOR_TYPE_GRAY ||
      interlace != PNG_INTERLACE_NONE)
    png_error(png, "PNG header changed between the checks");
  png_set_swap(png);  // PNG samples are big-endian
  for (uint32_t y = 0; y < h; ++y) png_read_row(png, reinterpret_cast<png_bytep>(out + size_t{y} * w), nullptr);
  png_read_end(png, nullptr);
  png_destroy_read_struct(&png, &info, nullptr);
  return true;
}

}  // namespace

std::string_view DepthCodecName(DepthCodec codec) {
  switch (codec) {
    case DepthCodec::kRawZstd: return "raw_zstd";
    case DepthCodec::kDeltaZstd: return "delta_zstd";
    case DepthCodec::kDeltaPlanesZstd: return "delta_planes_zstd";
    case DepthCodec::kPng: return "png16";
  }
  return "unknown";
}

absl::Status DepthCodecOptions::Validate() const {
  switch (codec) {
    case DepthCodec::kRawZstd:
    case DepthCodec::kDeltaZstd:
    case DepthCodec::kDeltaPlanesZstd:
      if (zstd_level < 1 || zstd_level > 19)
        return absl::InvalidArgumentError(absl::StrCat("zstd_level ", zstd_level, " not in [1, 19]"));
      return absl::OkStatus();
    case DepthCodec::kPng:
      if (png_compression < 0 || png_compression > 9)
        return absl::InvalidArgumentError(
            absl::StrCat("png_compression ", png_compression, " not in [0, 9]"));
      return absl::OkStatus();
  }
  return absl::InvalidArgumentError(
      absl::StrCat("unknown depth codec ", static_cast<int>(codec)));
}

absl::StatusOr<std::vector<uint8_t>> EncodeDepth(const ImageU16& depth,
                                                 const DepthCodecOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  if (depth.empty() || depth.channels() != 1)
    return absl::InvalidArgumentError(absl::StrCat("EncodeDepth needs a non-empty 1-channel image, got ",
                                                   depth.width(), "x", depth.height(), "x",
                                                   depth.channels()));
  if (int64_t{depth.width()} * depth.height() > kMaxDepthPixels)
    return absl::InvalidArgumentError("depth image too large");
  std::vector<uint8_t> out(kDepthHeaderBytes, 0);
  std::memcpy(out.data(), kMagic, 4);
  out[4] = kVersion;
  out[5] = static_cast<uint8_t>(options.codec);
  PutU32(out.data() + 8, static_cast<uint32_t>(depth.width()));
  PutU32(out.data() + 12, static_cast<uint32_t>(depth.height()));
  const size_t n = depth.size();
  switch (options.codec) {
    case DepthCodec::kRawZstd: {
      std::vector<uint8_t> raw(2 * n);
      for (size_t i = 0; i < n; ++i) {
        raw[2 * i] = static_cast<uint8_t>(depth.data()[i]);
        raw[2 * i + 1] = static_cast<uint8_t>(depth.data()[i] >> 8);
      }
      EXO_ASSIGN_OR_RETURN(out, ZstdCompress(raw.data(), raw.size(), options.zstd_level,
                                             std::move(out)));
      break;
    }
    case DepthCodec::kDeltaZstd: {
      std::vector<uint8_t> raw(2 * n);
      ForEachResidual(depth, [&](size_t i, uint16_t z) {
        raw[2 * i] = static_cast<uint8_t>(z);
        raw[2 * i + 1] = static_cast<uint8_t>(z >> 8);
      });
      EXO_ASSIGN_OR_RETURN(out, ZstdCompress(raw.data(), raw.size(), options.zstd_level,
                                             std::move(out)));
      break;
    }
    case DepthCodec::kDeltaPlanesZstd: {
      std::vector<uint8_t> raw(2 * n);
      uint8_t* hi = raw.data();
      uint8_t* lo = raw.data() + n;
      ForEachResidual(depth, [&](size_t i, uint16_t z) {
        hi[i] = static_cast<uint8_t>(z >> 8);
        lo[i] = static_cast<uint8_t>(z);
      });
      EXO_ASSIGN_OR_RETURN(out, ZstdCompress(raw.data(), raw.size(), options.zstd_level,
                                             std::move(out)));
      break;
    }
    case DepthCodec::kPng: {
      std::vector<uint8_t> png;
      try {
        if (!cv::imencode(".png", CvView(depth), png,
                          {cv::IMWRITE_PNG_COMPRESSION, options.png_compression}))
          return absl::InternalError("OpenCV PNG encode failed");
      } catch (const cv::Exception& e) {
        return absl::InternalError(absl::StrCat("OpenCV PNG encode failed: ", e.what()));
      }
      out.insert(out.end(), png.begin(), png.end());
      break;
    }
  }
  PutU32(out.data() + 16, static_cast<uint32_t>(out.size() - kDepthHeaderBytes));
  return out;
}

std::vector<uint8_t> EncodeDepth(const ImageU16& depth) {
  auto r = EncodeDepth(depth, DepthCodecOptions{});
  EXO_CHECK(r.ok());
  return *std::move(r);
}

absl::StatusOr<DepthInfo> ReadDepthInfo(std::span<const uint8_t> bytes) {
  if (bytes.size() < kDepthHeaderBytes)
    return absl::InvalidArgumentError(absl::StrCat("depth data truncated: ", bytes.size(),
                                                   " bytes, the header alone is ",
                                                   kDepthHeaderBytes));
  if (std::memcmp(bytes.data(), kMagic, 4) != 0)
    return absl::InvalidArgumentError("not an Exoview depth stream (bad magic, expected EXD1)");
  if (bytes[4] != kVersion)
    return absl::InvalidArgumentError(
        absl::StrCat("unsupported depth stream version ", int{bytes[4]}, " (this build reads ",
                     int{kVersion}, ")"));
  const uint8_t codec_byte = bytes[5];
  if (codec_byte < static_cast<uint8_t>(DepthCodec::kRawZstd) ||
      codec_byte > static_cast<uint8_t>(DepthCodec::kPng))
    return absl::InvalidArgumentError(absl::StrCat("unknown depth codec id ", int{codec_byte}));
  const uint32_t w = GetU32(bytes.data() + 8);
  const uint32_t h = GetU32(bytes.data() + 12);
  const uint32_t payload = GetU32(bytes.data() + 16);
  // Sides first: their product is then at most 2^40 (no overflow).
  if (w == 0 || h == 0 || w > (1u << 20) || h > (1u << 20) ||
      uint64_t{w} * uint64_t{h} > static_cast<uint64_t>(kMaxDepthPixels))
    return absl::InvalidArgumentError(absl::StrCat("depth header has invalid size ", w, "x", h,
                                                   " (limit ", kMaxDepthPixels, " pixels)"));
  if (payload != bytes.size() - kDepthHeaderBytes)
    return absl::InvalidArgumentError(
        absl::StrCat("depth data truncated or padded: header says ", payload,
                     " payload bytes, got ", bytes.size() - kDepthHeaderBytes));
  return DepthInfo{static_cast<DepthCodec>(codec_byte), static_cast<int>(w), static_cast<int>(h)};
}

absl::StatusOr<ImageU16> DecodeDepth(std::span<const uint8_t> bytes, int64_t max_pixels) {
  EXO_ASSIGN_OR_RETURN(const DepthInfo info, ReadDepthInfo(bytes));
  const uint32_t w = static_cast<uint32_t>(info.width), h = static_cast<uint32_t>(info.height);
  if (int64_t{info.width} * info.height > max_pixels)
    return absl::InvalidArgumentError(absl::StrCat("depth header claims ", w, "x", h,
                                                   ", above the limit of ", max_pixels,
                                                   " pixels"));
  const auto body = bytes.subspan(kDepthHeaderBytes);
  if (info.codec == DepthCodec::kPng) EXO_RETURN_IF_ERROR(CheckPngHeader(body, w, h));
  ImageU16 depth(static_cast<int>(w), static_cast<int>(h), 1);
  const size_t n = depth.size();
  switch (info.codec) {
    case DepthCodec::kRawZstd: {
      std::vector<uint8_t> raw(2 * n);
      EXO_RETURN_IF_ERROR(ZstdDecompress(body, raw.data(), raw.size(), "depth payload"));
      for (size_t i = 0; i < n; ++i)
        depth.data()[i] = static_cast<uint16_t>(raw[2 * i] | raw[2 * i + 1] << 8);
      return depth;
    }
    case DepthCodec::kDeltaZstd: {
      std::vector<uint8_t> raw(2 * n);
      EXO_RETURN_IF_ERROR(ZstdDecompress(body, raw.data(), raw.size(), "depth payload"));
      Reconstruct(&depth, [&](size_t i) {
        return static_cast<uint16_t>(raw[2 * i] | raw[2 * i + 1] << 8);
      });
      return depth;
    }
    case DepthCodec::kDeltaPlanesZstd: {
      std::vector<uint8_t> raw(2 * n);
      EXO_RETURN_IF_ERROR(ZstdDecompress(body, raw.data(), raw.size(), "depth payload"));
      const uint8_t* hi = raw.data();
      const uint8_t* lo = raw.data() + n;
      Reconstruct(&depth, [&](size_t i) { return static_cast<uint16_t>(hi[i] << 8 | lo[i]); });
      return depth;
    }
    case DepthCodec::kPng: {
      static_assert(std::endian::native == std::endian::little);
      PngSource src{body.data(), body.size(), 0, {}};
      if (!DecodePng16(&src, w, h, depth.data()))
        return absl::InvalidArgumentError(
            absl::StrCat("corrupt or truncated PNG depth payload: ", src.error));
      return depth;
    }
  }
  return absl::InvalidArgumentError(
      absl::StrCat("unknown depth codec id ", static_cast<int>(info.codec)));
}

ImageF DepthMetersFromU16(const ImageU16& depth_raw, double metres_per_unit) {
  EXO_CHECK(depth_raw.channels() == 1 && metres_per_unit > 0.0);
  ImageF out(depth_raw.width(), depth_raw.height(), 1);
  const float s = static_cast<float>(metres_per_unit);
  for (size_t i = 0; i < depth_raw.size(); ++i)
    out.data()[i] = static_cast<float>(depth_raw.data()[i]) * s;
  return out;
}

ImageU16 DepthU16FromMeters(const ImageF& depth_m, double metres_per_unit) {
  EXO_CHECK(depth_m.channels() == 1 && metres_per_unit > 0.0);
  ImageU16 out(depth_m.width(), depth_m.height(), 1);
  const double inv = 1.0 / metres_per_unit;
  for (size_t i = 0; i < depth_m.size(); ++i) {
    const double v = depth_m.data()[i];
    if (!std::isfinite(v) || v <= 0.0) continue;  // 0 = invalid
    const double units = std::nearbyint(v * inv);
    if (units < 1.0 || units > 65535.0) continue;  // not representable -> invalid, never wrapped
    out.data()[i] = static_cast<uint16_t>(units);
  }
  return out;
}

}  // namespace exo
