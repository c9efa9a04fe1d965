#include "common/io/image_file.h"

#include <cstdio>
#include <fstream>
#include <memory>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "common/io/cv_adapter.h"
#include "common/io/jpeg.h"

namespace exo {
namespace {

bool IsJpegPath(const std::string& path) {
  const std::string lower = absl::AsciiStrToLower(path);
  return absl::EndsWith(lower, ".jpg") || absl::EndsWith(lower, ".jpeg");
}

absl::StatusOr<cv::Mat> DecodeWithCv(const std::string& path, int flags) {
  EXO_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, ReadFileBytes(path));
  cv::Mat m;
  try {
    m = cv::imdecode(cv::Mat(1, static_cast<int>(bytes.size()), CV_8UC1, bytes.data()), flags);
  } catch (const cv::Exception& e) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": cannot decode image: ", e.what()));
  }
  if (m.empty())
    return absl::InvalidArgumentError(absl::StrCat(path, ": corrupt or unsupported image file"));
  return m;
}

}  // namespace

absl::StatusOr<std::vector<uint8_t>> ReadFileBytes(const std::string& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return absl::NotFoundError(absl::StrCat("cannot open ", path));
  if (std::fseek(f.get(), 0, SEEK_END) != 0)
    return absl::InternalError(absl::StrCat("cannot seek ", path));
  const long size = std::ftell(f.get());  // NOLINT(runtime/int)
  if (size < 0) return absl::InternalError(absl::StrCat("cannot tell size of ", path));
  std::rewind(f.get());
  std::vector<uint8_t> bytes(static_cast<size_t>(size));
  if (size > 0 && std::fread(bytes.data(), 1, bytes.size(), f.get()) != bytes.size())
    return absl::InternalError(absl::StrCat("short read of ", path));
  return bytes;
}

absl::Status WriteFileBytes(const std::string& path, std::span<const uint8_t> bytes) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "wb"), &std::fclose);
  if (!f) return absl::PermissionDeniedError(absl::StrCat("cannot create ", path));
  if (!bytes.empty() && std::fwrite(bytes.data(), 1, bytes.size(), f.get()) != bytes.size())
    return absl::InternalError(absl::StrCat("short write to ", path));
  if (std::fclose(f.release()) != 0)
    return absl::InternalError(absl::StrCat("cannot close ", path));
  return absl::OkStatus();
}

absl::StatusOr<ImageU8> ReadColorImage(const std::string& path) {
  if (IsJpegPath(path)) {
    EXO_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, ReadFileBytes(path));
    auto img = DecodeJpeg(bytes);
    if (!img.ok())
      return absl::Status(img.status().code(), absl::StrCat(path, ": ", img.status().message()));
    return img;
  }
  EXO_ASSIGN_OR_RETURN(cv::Mat m, DecodeWithCv(path, cv::IMREAD_UNCHANGED));
  if (m.depth() != CV_8U)
    return absl::InvalidArgumentError(absl::StrCat(path, ": not an 8-bit image"));
  ImageU8 rgb(m.cols, m.rows, 3);
  cv::Mat dst = CvView(rgb);
  switch (m.channels()) {
    case 1: cv::cvtColor(m, dst, cv::COLOR_GRAY2RGB); break;
    case 3: cv::cvtColor(m, dst, cv::COLOR_BGR2RGB); break;
    case 4: cv::cvtColor(m, dst, cv::COLOR_BGRA2RGB); break;
    default:
      return absl::InvalidArgumentError(
          absl::StrCat(path, ": unsupported channel count ", m.channels()));
  }
  return rgb;
}

absl::Status WriteColorImage(const std::string& path, const ImageU8& rgb, int jpeg_quality) {
  if (rgb.empty() || (rgb.channels() != 3 && rgb.channels() != 1))
    return absl::InvalidArgumentError(absl::StrCat("WriteColorImage ", path,
                                                   ": need a non-empty 1- or 3-channel image"));
  if (IsJpegPath(path) && rgb.channels() == 3) {
    EXO_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, EncodeJpeg(rgb, jpeg_quality));
    return WriteFileBytes(path, bytes);
  }
  cv::Mat out;
  if (rgb.channels() == 3) cv::cvtColor(CvView(rgb), out, cv::COLOR_RGB2BGR);
  else out = CvView(rgb);
  std::vector<uint8_t> bytes;
  const std::string ext = IsJpegPath(path) ? ".jpg" : ".png";
  try {
    if (!cv::imencode(ext, out, bytes, {cv::IMWRITE_JPEG_QUALITY, jpeg_quality}))
      return absl::InternalError(absl::StrCat("cannot encode ", path));
  } catch (const cv::Exception& e) {
    return absl::InternalError(absl::StrCat("cannot encode ", path, ": ", e.what()));
  }
  return WriteFileBytes(path, bytes);
}

absl::StatusOr<ImageU16> ReadPng16(const std::string& path) {
  EXO_ASSIGN_OR_RETURN(cv::Mat m, DecodeWithCv(path, cv::IMREAD_UNCHANGED));
  if (m.type() != CV_16UC1)
    return absl::InvalidArgumentError(absl::StrCat(
        path, ": expected a 16-bit single-channel PNG, got depth ", m.depth(), " with ",
        m.channels(), " channel(s)"));
  return ImageFromCv<uint16_t>(m);
}

absl::Status WritePng16(const std::string& path, const ImageU16& image, int compression) {
  if (image.empty() || image.channels() != 1)
    return absl::InvalidArgumentError(absl::StrCat("WritePng16 ", path,
                                                   ": need a non-empty 1-channel image"));
  std::vector<uint8_t> bytes;
  try {
    if (!cv::imencode(".png", CvView(image), bytes, {cv::IMWRITE_PNG_COMPRESSION, compression}))
      return absl::InternalError(absl::StrCat("cannot encode ", path));
  } catch (const cv::Exception& e) {
    return absl::InternalError(absl::StrCat("cannot encode ", path, ": ", e.what()));
  }
  return WriteFileBytes(path, bytes);
}

}  // namespace exo
