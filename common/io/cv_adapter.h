// Zero-copy cv::Mat views of exo::Image<T>, so OpenCV algorithms (filters, resize, codecs) run
// on our buffers without copies. Channel ORDER is not converted: an exo ImageU8 colour image is
// RGB, OpenCV's convention (imread/imwrite) is BGR. Convert explicitly (cv::cvtColor) at file
// boundaries; common/io/image_file.h does that for you.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <type_traits>

#include "common/image.h"
#include "common/status.h"

namespace exo {

template <typename T>
constexpr int CvDepthOf() {
  if constexpr (std::is_same_v<T, uint8_t>) return CV_8U;
  else if constexpr (std::is_same_v<T, uint16_t>) return CV_16U;
  else if constexpr (std::is_same_v<T, float>) return CV_32F;
  else if constexpr (std::is_same_v<T, double>) return CV_64F;
  else if constexpr (std::is_same_v<T, int32_t>) return CV_32S;
  else static_assert(sizeof(T) == 0, "no OpenCV depth for this pixel type");
}

// A cv::Mat header over the image's pixels (no copy). Valid while `image` lives and is not
// resized. An empty image gives an empty Mat.
template <typename T>
cv::Mat CvView(Image<T>& image) {
  if (image.empty()) return cv::Mat();
  return cv::Mat(image.height(), image.width(), CV_MAKETYPE(CvDepthOf<T>(), image.channels()),
                 image.data());
}
// Read-only by contract: OpenCV has no const Mat type, do not write through this view.
template <typename T>
cv::Mat CvView(const Image<T>& image) {
  return CvView(const_cast<Image<T>&>(image));
}

// Deep copy of a Mat into an Image<T> (the Mat's depth must match T). Continuous or not.
template <typename T>
absl::StatusOr<Image<T>> ImageFromCv(const cv::Mat& m) {
  if (m.empty()) return absl::InvalidArgumentError("ImageFromCv: empty cv::Mat");
  if (m.depth() != CvDepthOf<T>() || m.dims != 2)
    return absl::InvalidArgumentError(
        absl::StrCat("ImageFromCv: cv::Mat depth ", m.depth(), " does not match the pixel type"));
  Image<T> out(m.cols, m.rows, m.channels());
  m.copyTo(CvView(out));
  return out;
}

}  // namespace exo
