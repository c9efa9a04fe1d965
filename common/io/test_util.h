// Test helpers for common/io tests (not part of the library).
#pragma once

#include "exoview_source_dir.h"
#include <cmath>
#include <cstdlib>
#include <string>

#include "common/image.h"

namespace exo::testing {

// A smooth, textured RGB test image (gradients + sinusoids): compresses like a photo.
inline ImageU8 MakeTestRgb(int w, int h) {
  ImageU8 img(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      img.at(x, y, 0) = static_cast<uint8_t>(128 + 100 * std::sin(x * 0.05));
      img.at(x, y, 1) = static_cast<uint8_t>(255 * y / std::max(1, h - 1));
      img.at(x, y, 2) = static_cast<uint8_t>(128 + 60 * std::cos((x + y) * 0.03));
    }
  return img;
}

// Directory of the shared test data (EXOVIEW_SHARED_DIR or <source>/../shared).
inline std::string SharedDir() {
  if (const char* env = std::getenv("EXOVIEW_SHARED_DIR"); env != nullptr && *env != '\0')
    return env;
  return std::string(EXOVIEW_SOURCE_DIR) + "/../shared";
}

}  // namespace exo::testing
