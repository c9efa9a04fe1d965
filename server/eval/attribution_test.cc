#include "server/eval/attribution.h"

#include <gtest/gtest.h>

#include "common/lumigraph/blend_math.h"

namespace exo::eval {
namespace {

PinholeCamera Cam(int w, int h) {
  PinholeCamera c;
  c.fx = c.fy = 50;
  c.cx = (w - 1) / 2.0;
  c.cy = (h - 1) / 2.0;
  c.width = w;
  c.height = h;
  return c;
}

TEST(AttributionTest, MeshFromDepthPlaneAndJump) {
  const PinholeCamera cam = Cam(9, 9);
  ImageF depth(9, 9, 1, 2.0f);
  Rigid3d pose;
  pose.translation = glm::dvec3(1, 0, 0);
  TriangleMesh m = MeshFromDepth(depth, cam, pose, /*step=*/2);
  ASSERT_EQ(m.positions.size(), 25u);           // 5 x 5 vertices
  EXPECT_EQ(m.num_triangles(), 2u * 4 * 4);     // every quad
  for (const glm::vec3& p : m.positions) EXPECT_FLOAT_EQ(p.z, 2.0f);
  EXPECT_FLOAT_EQ(m.positions[12].x, 1.0f);     // centre pixel on the optical axis, moved by 1
  // A jump of 1 m between columns 4 and 6 (> 5 % of 2 m) cuts one column of quads; a hole
  // (depth 0) removes its vertex and the quads around it.
  for (int y = 0; y < 9; ++y)
    for (int x = 5; x < 9; ++x) depth.at(x, y) = 3.0f;
  depth.at(0, 0) = 0.0f;
  m = MeshFromDepth(depth, cam, pose, 2);
  EXPECT_EQ(m.positions.size(), 24u);
  EXPECT_EQ(m.num_triangles(), 2u * (4 * 4 - 4 - 1));
}

TEST(AttributionTest, FitGainRecoversExposure) {
  ImageU8 ref(16, 8, 3), render(16, 8, 3), mask(16, 8, 1, 255);
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 16; ++x)
      for (int c = 0; c < 3; ++c) {
        const float lin = 0.05f + 0.04f * x + 0.01f * c;
        ref.at(x, y, c) = blend::UnitToU8(blend::LinearToSrgb(lin));
        render.at(x, y, c) = blend::UnitToU8(blend::LinearToSrgb(lin * (c == 0 ? 0.5f : 0.8f)));
      }
  const glm::vec3 g = FitGainToReference(render, ref, mask);
  EXPECT_NEAR(g.x, 2.0f, 0.05f);
  EXPECT_NEAR(g.y, 1.25f, 0.03f);
  for (int x = 0; x < 16; ++x) EXPECT_NEAR(render.at(x, 3, 0), ref.at(x, 3, 0), 2);
  ImageU8 untouched = render;
  EXPECT_EQ(FitGainToReference(untouched, ref, ImageU8()), glm::vec3(1.0f));
  EXPECT_EQ(untouched.span()[5], render.span()[5]);
}

}  // namespace
}  // namespace exo::eval
