// Image containers: a plain, owning, row-major interleaved buffer. Colour is RGB8 (3 channels,
// sRGB-encoded as delivered by cameras), depth is float z-depth in metres (0 = invalid).
// Zero-copy views for OpenCV live in common/io/cv_adapter.h so that this header stays light.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "common/status.h"

namespace exo {

template <typename T>
class Image {
 public:
  using value_type = T;
  Image() = default;
  Image(int width, int height, int channels = 1, T fill = T{})
      : width_(width), height_(height), channels_(channels),
        data_(static_cast<size_t>(width) * height * channels, fill) {
    EXO_CHECK(width >= 0 && height >= 0 && channels > 0);
  }

  int width() const { return width_; }
  int height() const { return height_; }
  int channels() const { return channels_; }
  bool empty() const { return data_.empty(); }
  size_t size() const { return data_.size(); }
  size_t bytes() const { return data_.size() * sizeof(T); }
  size_t stride() const { return static_cast<size_t>(width_) * channels_; }  // in elements

  T* data() { return data_.data(); }
  const T* data() const { return data_.data(); }
  std::span<T> span() { return data_; }
  std::span<const T> span() const { return data_; }
  T* row(int y) { return data_.data() + static_cast<size_t>(y) * stride(); }
  const T* row(int y) const { return data_.data() + static_cast<size_t>(y) * stride(); }
  T& at(int x, int y, int c = 0) { return data_[(static_cast<size_t>(y) * width_ + x) * channels_ + c]; }
  const T& at(int x, int y, int c = 0) const {
    return data_[(static_cast<size_t>(y) * width_ + x) * channels_ + c];
  }
  bool Contains(int x, int y) const { return x >= 0 && y >= 0 && x < width_ && y < height_; }
  bool SameShape(const Image& o) const {
    return width_ == o.width_ && height_ == o.height_ && channels_ == o.channels_;
  }
  bool operator==(const Image& o) const = default;

 private:
  int width_ = 0, height_ = 0, channels_ = 1;
  std::vector<T> data_;
};

using ImageU8 = Image<uint8_t>;    // RGB8 (3 ch) or grey/mask (1 ch)
using ImageU16 = Image<uint16_t>;  // raw sensor depth (scale given separately)
using ImageF = Image<float>;       // depth in metres, intensities, weights
using ImageU32 = Image<uint32_t>;  // ids

}  // namespace exo
