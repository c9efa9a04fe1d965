// Small synthetic frames for the wire tests (proto/ and server/service ingest): a colour ramp,
// a depth ramp in x and a generic pose, and their exoview.v1 encoding.
#pragma once

#include <gtest/gtest.h>

#include <cstdint>

#include "common/frame.h"
#include "proto/frame_proto.h"

namespace exo::wire_test {

inline Frame SmallFrame(int w = 32, int h = 24, uint64_t seq = 1) {
  Frame f;
  f.sequence = seq;
  f.timestamp_s = 0.1 * seq;
  f.color_camera = PinholeCamera::FromFov(w, h, 1.0);
  f.depth_camera = f.color_camera;
  f.color = ImageU8(w, h, 3);
  f.depth_m = ImageF(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c)
        f.color.at(x, y, c) = static_cast<uint8_t>((x * 7 + y * 3 + c * 50) % 256);
      f.depth_m.at(x, y) = 1.0f + 0.01f * x;
    }
  f.world_from_cam.translation = {1.0, 2.0, 3.0};
  f.world_from_cam.rotation = glm::normalize(glm::dquat(0.9, 0.1, 0.2, 0.3));
  return f;
}

inline v1::Frame Wire(const Frame& f) {
  auto m = FrameToProto(f, {});
  EXPECT_TRUE(m.ok()) << m.status();
  return *m;
}

}  // namespace exo::wire_test
