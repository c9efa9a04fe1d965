// Test helpers for common/datasets tests: temp directories and small synthetic frames.
#pragma once

#include "exoview_source_dir.h"
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "common/frame.h"

namespace exo::testing {

// A fresh, empty temp directory unique to this process and `name`.
inline std::string FreshTempDir(const std::string& name) {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("exo_datasets_" + std::to_string(::getpid()) + "_" + name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir.string();
}

inline std::string SharedDir() {
  if (const char* env = std::getenv("EXOVIEW_SHARED_DIR"); env != nullptr && *env != '\0')
    return env;
  return std::string(EXOVIEW_SOURCE_DIR) + "/../shared";
}

// A small valid frame: textured colour, a depth ramp in metres, given pose.
inline Frame MakeFrame(uint64_t seq, int w = 16, int h = 12) {
  Frame f;
  f.sequence = seq;
  f.timestamp_s = 0.1 * seq + 1e-3;
  f.color_camera = PinholeCamera{20.0, 21.0, (w - 1) / 2.0, (h - 1) / 2.0, w, h};
  f.depth_camera = f.color_camera;
  f.world_from_cam = {glm::angleAxis(0.1 * seq + 0.3, glm::normalize(glm::dvec3(1, 2, 3))),
                      glm::dvec3(1e5 + seq, -2.0, 0.5)};
  f.color = ImageU8(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c)
        f.color.at(x, y, c) = static_cast<uint8_t>((x * 13 + y * 7 + c * 50 + seq * 3) % 256);
  f.depth_m = ImageF(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) f.depth_m.at(x, y) = 0.5f + 0.1f * x + 0.01f * y;
  f.depth_m.at(0, 0) = 0.0f;  // invalid
  return f;
}

}  // namespace exo::testing
