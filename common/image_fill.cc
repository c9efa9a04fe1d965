#include "common/image_fill.h"

#include "common/image_fill_impl.h"

namespace exo {

bool PushPullFill(std::span<float> data, int channels, std::span<const uint8_t> known, int width,
                  int height, PullFilter filter) {
  EXO_CHECK(channels > 0 && channels <= kPushPullMaxChannels && width > 0 && height > 0);
  const size_t n = static_cast<size_t>(width) * height;
  EXO_CHECK(data.size() == n * channels && known.size() == n);
  return image_fill_internal::PushPull<kPushPullMaxChannels>(
      width, height, channels, filter, [&](size_t i) { return known[i] != 0; },
      [&](size_t i, int k) { return data[i * channels + k]; },
      [&](size_t i, int k, float v) { data[i * channels + k] = v; });
}

}  // namespace exo
