#include "common/lumigraph/cpu_renderer.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace exo {
namespace {

// A 20 m x 20 m plane at z = plane_z (keep it off cell boundaries: a surface exactly on a
// boundary flips between two cells with the last float bit of the interpolated position) (local frame), facing -z (towards a camera at the origin).
TriangleMesh Plane(float plane_z, glm::vec3 offset = glm::vec3(0)) {
  TriangleMesh m;
  m.positions = {offset + glm::vec3(-10, -10, plane_z), offset + glm::vec3(10, -10, plane_z),
                 offset + glm::vec3(10, 10, plane_z), offset + glm::vec3(-10, 10, plane_z)};
  m.indices = {0, 1, 2, 0, 2, 3};
  return m;
}

PinholeCamera SmallCam() { return PinholeCamera::FromFov(64, 48, 1.0); }

// A stored view of `mesh` at `local_from_cam` with a textured colour image and its true depth.
StoredView MakeView(ViewId id, const TriangleMesh& mesh, const Rigid3d& local_from_cam,
                    float exposure, bool uniform = false) {
  StoredView v;
  v.id = id;
  v.camera = SmallCam();
  v.local_from_cam = local_from_cam;
  v.exposure = exposure;
  RasterOptions ro;
  auto r = Rasterize(mesh, v.camera, local_from_cam, ro).value();
  v.depth_m = r.z_depth_m;
  v.color = ImageU8(64, 48, 3);
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      v.color.at(x, y, 0) = uniform ? 128 : uint8_t(x * 4);
      v.color.at(x, y, 1) = uniform ? 128 : uint8_t(y * 5);
      v.color.at(x, y, 2) = uniform ? 128 : uint8_t(((x / 4 + y / 4) % 2) * 200 + 20);
    }
  return v;
}

// Every cell the stored views see references all of them.
void ReferenceAllCells(LumigraphModel* model) {
  RasterOptions ro;
  ro.cell_id = true;
  ro.cell_grid = model->grid;
  const TriangleMesh mesh = model->ProxyMesh();
  for (const auto& [id, v] : model->views) {
    auto r = Rasterize(mesh, v.camera, v.local_from_cam, ro).value();
    for (uint64_t c : r.cell_id.span())
      if (c != kNoCell) {
        auto& refs = model->cell_refs[c];
        if (std::find(refs.begin(), refs.end(), id) == refs.end()) refs.push_back(id);
      }
  }
}

LumigraphModel OnePlaneModel(const TriangleMesh& mesh) {
  LumigraphModel m;
  m.grid.cell_size_m = 0.5;
  m.chunks[0].mesh = mesh;
  return m;
}

TEST(CpuRenderer, SamePoseReproducesTheStoredView) {
  LumigraphModel m = OnePlaneModel(Plane(2.1f));
  m.views[7] = MakeView(7, m.chunks[0].mesh, Rigid3d::Identity(), 1.0f);
  ReferenceAllCells(&m);
  auto r = CpuLumigraphRenderer::Create(m, {}).value();
  auto out = r->Render(SmallCam(), Rigid3d::Identity()).value();
  EXPECT_EQ(out.covered_pixels, 64u * 48u);
  int max_diff = 0;
  for (size_t i = 0; i < out.color.size(); ++i)
    max_diff = std::max(max_diff, std::abs(int(out.color.data()[i]) - int(m.views[7].color.data()[i])));
  EXPECT_LE(max_diff, 1);
}

TEST(CpuRenderer, TwoViewsWithExposureBlendInLinear) {
  LumigraphModel m = OnePlaneModel(Plane(2.1f));
  // Same pose, equal weights: the blend is lin(128) * mean(E) = lin(128) * 1.25.
  m.views[1] = MakeView(1, m.chunks[0].mesh, Rigid3d::Identity(), 0.5f, true);
  m.views[2] = MakeView(2, m.chunks[0].mesh, Rigid3d::Identity(), 2.0f, true);
  ReferenceAllCells(&m);
  CpuRenderOptions opt;
  opt.debug_weights = true;
  auto r = CpuLumigraphRenderer::Create(m, opt).value();
  auto out = r->Render(SmallCam(), Rigid3d::Identity()).value();
  const float lin = blend::SrgbToLinear(128.0f / 255.0f) * 1.25f;
  const int expected = blend::UnitToU8(blend::LinearToSrgb(lin));
  ASSERT_NE(expected, 128);
  EXPECT_EQ(out.color.at(32, 24, 0), expected);
  EXPECT_EQ(out.color.at(5, 40, 2), expected);
  EXPECT_EQ(out.num_views.at(32, 24), 2);
  // sRGB-space averaging would give 128 * 1.25 = 160; linear gives a different value.
  EXPECT_NE(expected, 160);
}

TEST(CpuRenderer, EmptyReferenceSetAndInvalidDepthGiveBackground) {
  LumigraphModel m = OnePlaneModel(Plane(2.1f));
  m.views[1] = MakeView(1, m.chunks[0].mesh, Rigid3d::Identity(), 1.0f);
  CpuRenderOptions opt;
  opt.blend.background_srgb = glm::vec3(0.0f, 1.0f, 0.0f);
  {
    // No cell references at all: every pixel is background, uncovered.
    auto r = CpuLumigraphRenderer::Create(m, opt).value();
    auto out = r->Render(SmallCam(), Rigid3d::Identity()).value();
    EXPECT_EQ(out.covered_pixels, 0u);
    EXPECT_EQ(out.surface_pixels, 64u * 48u);
    EXPECT_EQ(out.color.at(10, 10, 1), 255);
  }
  // References present but the stored depth is NaN / 0 everywhere: no valid view, background.
  ReferenceAllCells(&m);
  for (size_t i = 0; i < m.views[1].depth_m.size(); ++i)
    m.views[1].depth_m.data()[i] = (i % 2) ? std::numeric_limits<float>::quiet_NaN() : 0.0f;
  auto r = CpuLumigraphRenderer::Create(m, opt).value();
  auto out = r->Render(SmallCam(), Rigid3d::Identity()).value();
  EXPECT_EQ(out.covered_pixels, 0u);
  EXPECT_EQ(out.color.at(30, 20, 0), 0);
  EXPECT_EQ(out.color.at(30, 20, 1), 255);
}

// BlendOptions::fill_holes: a plane covering the left part of the view, no background pass. With
// the fill every uncovered pixel takes the stored views' colour (uniform here, so exactly it, to
// the sRGB rounding); covered pixels and coverage are bit-identical to the render without it,
// which leaves the uncovered pixels at the background colour.
TEST(CpuRenderer, HoleFillTakesCoveredColourAndChangesNothingElse) {
  LumigraphModel m = OnePlaneModel(Plane(2.1f, glm::vec3(-10.4f, 0.0f, 0.0f)));
  m.views[1] = MakeView(1, m.chunks[0].mesh, Rigid3d::Identity(), 1.0f, /*uniform=*/true);
  ReferenceAllCells(&m);
  CpuRenderOptions on, off;
  on.blend.background_views = off.blend.background_views = 0;
  on.blend.background_srgb = off.blend.background_srgb = glm::vec3(0.0f, 1.0f, 0.0f);
  off.blend.fill_holes = false;
  ASSERT_TRUE(on.blend.fill_holes);  // the default
  auto a = CpuLumigraphRenderer::Create(m, on).value()->Render(SmallCam(), Rigid3d::Identity()).value();
  auto b = CpuLumigraphRenderer::Create(m, off).value()->Render(SmallCam(), Rigid3d::Identity()).value();
  ASSERT_GT(a.covered_pixels, 300u);
  ASSERT_LT(a.covered_pixels, 64u * 48u - 300u);
  EXPECT_EQ(a.covered_pixels, b.covered_pixels);
  EXPECT_EQ(a.filled_pixels, 64u * 48u - a.covered_pixels);
  EXPECT_EQ(b.filled_pixels, 0u);
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      ASSERT_EQ(a.coverage.at(x, y), b.coverage.at(x, y));
      for (int k = 0; k < 3; ++k) {
        if (a.coverage.at(x, y) != 0) {
          ASSERT_EQ(a.color.at(x, y, k), b.color.at(x, y, k));
        } else {
          ASSERT_EQ(b.color.at(x, y, k), k == 1 ? 255 : 0);
          ASSERT_NEAR(a.color.at(x, y, k), 128, 1) << x << "," << y;
        }
      }
    }
}

// FillHoles alone: known pixels are kept, unknown ones fall between the colours around them;
// nothing happens when every pixel or no pixel is known.
TEST(FillHoles, FillsBetweenKnownColoursOnly) {
  ImageU8 rgb(40, 20, 3, 0), known(40, 20, 1, 0);
  for (int y = 0; y < 20; ++y)
    for (int x = 0; x < 40; ++x) {
      const bool k = x < 10 || x >= 30;
      known.at(x, y) = k ? 255 : 0;
      for (int c = 0; c < 3; ++c) rgb.at(x, y, c) = k ? (x < 10 ? 20 : 220) : 99;
    }
  ImageU8 filled = rgb;
  EXPECT_EQ(FillHoles(filled, known), 20u * 20u);
  for (int y = 0; y < 20; ++y)
    for (int x = 0; x < 40; ++x)
      for (int c = 0; c < 3; ++c) {
        if (known.at(x, y)) {
          ASSERT_EQ(filled.at(x, y, c), rgb.at(x, y, c));
        } else {
          ASSERT_GE(filled.at(x, y, c), 20);
          ASSERT_LE(filled.at(x, y, c), 220);
        }
      }
  EXPECT_LT(filled.at(12, 10, 0), filled.at(27, 10, 0));
  ImageU8 all(40, 20, 1, 255), none(40, 20, 1, 0);
  ImageU8 copy = rgb;
  EXPECT_EQ(FillHoles(copy, all), 0u);
  EXPECT_EQ(FillHoles(copy, none), 0u);
  EXPECT_EQ(copy, rgb);
}

TEST(CpuRenderer, OccludedViewIsNotUsed) {
  // View 1 sees the plane; view 2 is "occluded": its depth says a surface at 1 m in front.
  LumigraphModel m = OnePlaneModel(Plane(2.1f));
  m.views[1] = MakeView(1, m.chunks[0].mesh, Rigid3d::Identity(), 1.0f, true);
  m.views[2] = MakeView(2, m.chunks[0].mesh, Rigid3d::Identity(), 4.0f, true);
  for (float& d : m.views[2].depth_m.span()) d = 1.0f;
  ReferenceAllCells(&m);
  auto r = CpuLumigraphRenderer::Create(m, {}).value();
  auto out = r->Render(SmallCam(), Rigid3d::Identity()).value();
  EXPECT_EQ(out.covered_pixels, 64u * 48u);
  EXPECT_NEAR(out.color.at(32, 24, 0), 128, 1);  // only view 1 (E = 1), not brightened by view 2
}

// Scene 1e5 m from the world origin: expressed in the local frame (LocalOrigin, the guard) the
// render equals that of the same scene at the origin. Rendering the world coordinates as float
// directly would quantise positions to ~8 mm and change pixels.
TEST(CpuRenderer, SceneFarFromOrigin) {
  const glm::dvec3 far_origin(1e5, 2e5, -1e5);
  LocalOrigin origin{far_origin};
  LumigraphModel a = OnePlaneModel(Plane(2.1f));
  Rigid3d pose_a;
  pose_a.translation = {0.3, -0.2, 0.1};
  a.views[1] = MakeView(1, a.chunks[0].mesh, Rigid3d::Identity(), 1.0f);
  ReferenceAllCells(&a);
  // The far scene, built from world coordinates and converted to the local frame.
  LumigraphModel b = a;
  b.origin = origin;
  Rigid3d world_from_view;
  world_from_view.translation = far_origin;
  b.views[1].local_from_cam = origin.ToLocal(world_from_view);
  Rigid3d world_from_novel = pose_a;
  world_from_novel.translation += far_origin;
  auto ra = CpuLumigraphRenderer::Create(a, {}).value();
  auto rb = CpuLumigraphRenderer::Create(b, {}).value();
  auto oa = ra->Render(SmallCam(), pose_a).value();
  auto ob = rb->Render(SmallCam(), origin.ToLocal(world_from_novel)).value();
  EXPECT_GT(oa.covered_pixels, 1000u);
  // Equal up to the last bit of the double round trip 1e5 + 0.3 - 1e5.
  int max_diff = 0;
  for (size_t i = 0; i < oa.color.size(); ++i)
    max_diff = std::max(max_diff, std::abs(int(oa.color.data()[i]) - int(ob.color.data()[i])));
  EXPECT_LE(max_diff, 1);
  EXPECT_EQ(oa.covered_pixels, ob.covered_pixels);
}

TEST(CpuRenderer, RejectsBadInput) {
  LumigraphModel m = OnePlaneModel(Plane(2.1f));
  m.views[1] = MakeView(1, m.chunks[0].mesh, Rigid3d::Identity(), 1.0f);
  m.views[1].exposure = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(CpuLumigraphRenderer::Create(m, {}).ok());
  m.views[1].exposure = 1.0f;
  m.views[1].depth_m = ImageF(3, 3);
  EXPECT_FALSE(CpuLumigraphRenderer::Create(m, {}).ok());
  CpuRenderOptions o;
  o.num_threads = 0;
  EXPECT_FALSE(o.Validate().ok());
}

// ===================== background at infinity (sky) =====================

// Known sky: linear colour as a smooth function of the world direction only.
glm::vec3 SkyLinear(const glm::dvec3& dir) {
  const glm::dvec3 d = glm::normalize(dir);
  return glm::vec3(0.25 + 0.2 * d.x, 0.35 + 0.15 * d.y, 0.55 + 0.25 * d.z);
}

// A stored view seeing only sky: depth 0 everywhere, colour = SkyLinear(ray) * linear_scale
// (sRGB-encoded), to be undone by exposure = 1 / linear_scale.
StoredView SkyView(ViewId id, const Rigid3d& local_from_cam, float linear_scale) {
  StoredView v;
  v.id = id;
  v.camera = SmallCam();
  v.local_from_cam = local_from_cam;
  v.exposure = 1.0f / linear_scale;
  v.depth_m = ImageF(64, 48, 1, 0.0f);
  v.color = ImageU8(64, 48, 3);
  const glm::dmat3 R = local_from_cam.RotationMatrix();
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      const glm::vec3 c = SkyLinear(R * v.camera.RayZ1({double(x), double(y)}));
      for (int k = 0; k < 3; ++k)
        v.color.at(x, y, k) = blend::UnitToU8(blend::LinearToSrgb(c[k] * linear_scale));
    }
  return v;
}

Rigid3d Yawed(double yaw_rad, glm::dvec3 t = glm::dvec3(0)) {
  Rigid3d p;
  p.rotation = glm::angleAxis(yaw_rad, glm::dvec3(0, 1, 0));  // camera y axis (down)
  p.translation = t;
  return p;
}

TEST(BackgroundMask, GuardWindowAndImageBorder) {
  ImageF d(9, 7, 1, 0.0f);
  d.at(4, 3) = 2.0f;
  const ImageU8 m1 = BackgroundMask(d, 1), m2 = BackgroundMask(d, 2);
  for (int y = 0; y < 7; ++y)
    for (int x = 0; x < 9; ++x) {
      const int cheb = std::max(std::abs(x - 4), std::abs(y - 3));
      EXPECT_EQ(m1.at(x, y), cheb > 1 ? 1 : 0) << x << "," << y;
      EXPECT_EQ(m2.at(x, y), cheb > 2 ? 1 : 0) << x << "," << y;
    }
  // NaN / Inf are invalid depth (background); a fully valid image has no background pixel.
  ImageF n(5, 5, 1, std::numeric_limits<float>::quiet_NaN());
  n.at(0, 0) = std::numeric_limits<float>::infinity();
  const ImageU8 mn = BackgroundMask(n, 3), mv = BackgroundMask(ImageF(5, 5, 1, 1.0f), 1);
  for (uint8_t b : mn.span()) EXPECT_EQ(b, 1);
  for (uint8_t b : mv.span()) EXPECT_EQ(b, 0);
}

// Two stored views (different position, yaw and exposure) see only sky; a novel view between
// them (other position: a point at infinity has no parallax) must show the same sky.
TEST(CpuRendererBackground, KnownSkyFromTwoViewsIsReproduced) {
  LumigraphModel m;
  m.grid.cell_size_m = 0.5;
  m.views[1] = SkyView(1, Yawed(-0.25, {0.0, 0.0, 0.0}), 1.0f);
  m.views[2] = SkyView(2, Yawed(0.30, {3.0, -1.0, 2.0}), 0.5f);  // exposure 2: darker image
  auto r = CpuLumigraphRenderer::Create(m, {}).value();
  const Rigid3d novel = Yawed(0.05, {-5.0, 2.0, 7.0});
  auto out = r->Render(SmallCam(), novel).value();
  EXPECT_EQ(out.covered_pixels, 0u);
  EXPECT_EQ(out.surface_pixels, 0u);
  ASSERT_EQ(out.background_views.size(), 2u);
  EXPECT_EQ(out.background_views[0], 2u);  // optical axes 0.25 rad (view 2) and 0.30 rad apart
  EXPECT_GT(out.background_pixels, 64u * 48u * 9 / 10);
  const glm::dmat3 R = novel.RotationMatrix();
  int max_err = 0, filled = 0;
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      if (out.background.at(x, y) == 0) continue;
      ++filled;
      EXPECT_EQ(out.coverage.at(x, y), 0);
      const glm::vec3 truth = SkyLinear(R * SmallCam().RayZ1({double(x), double(y)}));
      for (int k = 0; k < 3; ++k)
        max_err = std::max(max_err, std::abs(int(out.color.at(x, y, k)) -
                                             int(blend::UnitToU8(blend::LinearToSrgb(truth[k])))));
    }
  EXPECT_GT(filled, 0);
  EXPECT_LE(max_err, 2);  // bilinear of a smooth gradient + 8-bit quantisation (view 2 at half)
  // The exposure factor is applied: without it view 2's half-bright samples would pull the
  // blend down by far more than 2 levels where both views overlap (checked: the centre).
  m.views[2].exposure = 1.0f;
  auto r2 = CpuLumigraphRenderer::Create(m, {}).value();
  auto dark = r2->Render(SmallCam(), novel).value();
  EXPECT_LT(int(dark.color.at(40, 24, 2)) + 5, int(out.color.at(40, 24, 2)));
}

// A sensor hole (depth 0, foreground colour) on the border of a surface must not leak into the
// sky. The stored view sees a red square (valid depth) whose 3 px rim lost its depth but keeps
// its red colour; everything else is blue sky with depth 0. The model has NO proxy, so every
// novel pixel (same pose as the stored view) is a background ray. Guard covered: the
// neighbourhood test of BackgroundMask (radius 3); with a per-pixel "depth == 0" test the red
// rim would be blended into the sky.
TEST(CpuRendererBackground, SensorHoleNextToSurfaceDoesNotLeak) {
  LumigraphModel m;
  m.grid.cell_size_m = 0.5;
  StoredView v;
  v.id = 4;
  v.camera = SmallCam();
  v.depth_m = ImageF(64, 48, 1, 0.0f);
  v.color = ImageU8(64, 48, 3);
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      const bool object = x >= 20 && x < 44 && y >= 14 && y < 34;
      const bool rim = object && (x < 23 || x >= 41 || y < 17 || y >= 31);
      if (object && !rim) v.depth_m.at(x, y) = 2.0f;
      v.color.at(x, y, 0) = object ? 230 : 20;
      v.color.at(x, y, 1) = 20;
      v.color.at(x, y, 2) = object ? 20 : 230;
    }
  m.views[4] = v;
  auto r = CpuLumigraphRenderer::Create(m, {}).value();
  auto out = r->Render(SmallCam(), Rigid3d::Identity()).value();
  int red = 0, blue = 0;
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      if (out.color.at(x, y, 0) > 40) ++red;
      if (out.background.at(x, y) != 0 && out.color.at(x, y, 2) >= 228) ++blue;
    }
  EXPECT_EQ(red, 0) << "foreground colour leaked into the background";
  EXPECT_GT(blue, 64 * 48 / 2);
  // Far from the object the sky is filled; on the rim and inside the object it is not.
  EXPECT_EQ(out.background.at(5, 5), 255);
  EXPECT_EQ(out.background.at(21, 20), 0);
  EXPECT_EQ(out.background.at(32, 24), 0);
}

// Option off reproduces the renderer without the pass: the no-surface pixels are exactly the
// background colour and nothing else changes (surface pixels, coverage, counts bit for bit).
TEST(CpuRendererBackground, OptionOffLeavesNoSurfacePixelsAtBackgroundColour) {
  LumigraphModel m = OnePlaneModel(Plane(2.1f, glm::vec3(-10.4f, 0.0f, 0.0f)));  // left part
  const Rigid3d id = Rigid3d::Identity();
  m.views[1] = MakeView(1, m.chunks[0].mesh, id, 1.0f);
  // The stored view's sky (where its depth is 0) gets a flat colour.
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x)
      if (m.views[1].depth_m.at(x, y) == 0.0f)
        for (int k = 0; k < 3; ++k) m.views[1].color.at(x, y, k) = 180;
  ReferenceAllCells(&m);
  CpuRenderOptions on, off;
  off.blend.background_views = 0;
  off.blend.background_srgb = on.blend.background_srgb = glm::vec3(0.2f, 0.4f, 0.6f);
  on.blend.fill_holes = off.blend.fill_holes = false;  // this test is about the background pass
  const Rigid3d novel = Yawed(0.05, {0.1, 0.0, 0.0});
  auto a = CpuLumigraphRenderer::Create(m, on).value()->Render(SmallCam(), novel).value();
  auto b = CpuLumigraphRenderer::Create(m, off).value()->Render(SmallCam(), novel).value();
  EXPECT_GT(a.background_pixels, 100u);
  EXPECT_EQ(b.background_pixels, 0u);
  EXPECT_TRUE(b.background_views.empty());
  EXPECT_GT(a.surface_pixels, 100u);
  EXPECT_LT(a.surface_pixels, 64u * 48u);
  EXPECT_EQ(a.surface_pixels, b.surface_pixels);
  EXPECT_EQ(a.covered_pixels, b.covered_pixels);
  EXPECT_EQ(a.coverage.span().size(), b.coverage.span().size());
  for (size_t i = 0; i < a.coverage.size(); ++i) ASSERT_EQ(a.coverage.data()[i], b.coverage.data()[i]);
  const uint8_t bg[3] = {blend::UnitToU8(0.2f), blend::UnitToU8(0.4f), blend::UnitToU8(0.6f)};
  int sky_changed = 0;
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      if (a.background.at(x, y) == 0) {
        for (int k = 0; k < 3; ++k) ASSERT_EQ(a.color.at(x, y, k), b.color.at(x, y, k));
      } else {
        sky_changed += a.color.at(x, y, 0) == 180;
      }
      for (int k = 0; k < 3; ++k)
        if (b.coverage.at(x, y) == 0) {
          ASSERT_EQ(b.color.at(x, y, k), bg[k]);
        }
    }
  EXPECT_EQ(size_t(sky_changed), a.background_pixels);
}

// Indoors (the camera inside a closed box): no ray misses the proxy, the pass changes nothing
// and selects no view.
TEST(CpuRendererBackground, ClosedRoomIsUnchanged) {
  TriangleMesh box;
  const float s = 3.0f;
  for (int i = 0; i < 8; ++i)
    box.positions.push_back(glm::vec3(i & 1 ? s : -s, i & 2 ? s : -s, i & 4 ? s : -s) +
                            glm::vec3(0.013f, 0.021f, 0.017f));
  const uint32_t faces[6][4] = {{0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1},
                                {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}};
  for (const auto& f : faces)
    for (uint32_t k : {f[0], f[1], f[2], f[0], f[2], f[3]}) box.indices.push_back(k);
  LumigraphModel m = OnePlaneModel(box);
  m.views[1] = MakeView(1, box, Yawed(0.0), 1.0f);
  m.views[2] = MakeView(2, box, Yawed(1.2), 1.3f);
  ReferenceAllCells(&m);
  CpuRenderOptions off;
  off.blend.background_views = 0;
  auto ra = CpuLumigraphRenderer::Create(m, {}).value();
  auto rb = CpuLumigraphRenderer::Create(m, off).value();
  for (double yaw : {0.3, 2.0}) {
    auto a = ra->Render(SmallCam(), Yawed(yaw, {0.2, 0.1, -0.3})).value();
    auto b = rb->Render(SmallCam(), Yawed(yaw, {0.2, 0.1, -0.3})).value();
    EXPECT_EQ(a.surface_pixels, 64u * 48u);
    EXPECT_EQ(a.background_pixels, 0u);
    EXPECT_TRUE(a.background_views.empty());
    ASSERT_EQ(a.color.size(), b.color.size());
    for (size_t i = 0; i < a.color.size(); ++i) ASSERT_EQ(a.color.data()[i], b.color.data()[i]);
  }
}

TEST(CpuRendererBackground, ViewSelectionByOpticalAxisWithinTheCones) {
  const PinholeCamera cam = SmallCam();  // hfov 1 rad: half-diagonal ~0.6 rad
  std::vector<blend::BlendView> views;
  std::vector<ViewId> ids;
  const double yaws[] = {0.9, -0.2, 3.0, 0.2, 0.5, 1.5};
  for (int i = 0; i < 6; ++i) {
    StoredView v;
    v.camera = cam;
    v.local_from_cam = Yawed(yaws[i]);
    views.push_back(MakeBlendView(v));
    ids.push_back(ViewId(10 + i));
  }
  const double half = HalfDiagonalFov(views[0].intrinsics, views[0].size);
  EXPECT_NEAR(half, std::atan(std::hypot(32.0 / cam.fx, 24.0 / cam.fy)), 1e-6);
  auto all = [](int) { return true; };
  // Yaw 3.0 (behind) and 1.5 (> 2 * half away) cannot overlap; ties (+-0.2) by id.
  EXPECT_EQ(SelectBackgroundViews(cam, Rigid3d::Identity(), views, ids, 8, all),
            (std::vector<int>{1, 3, 4, 0}));
  EXPECT_EQ(SelectBackgroundViews(cam, Rigid3d::Identity(), views, ids, 2, all),
            (std::vector<int>{1, 3}));
  // Views without background pixels are skipped (the next ranked one takes the slot).
  EXPECT_EQ(SelectBackgroundViews(cam, Rigid3d::Identity(), views, ids, 2,
                                  [](int i) { return i != 3; }),
            (std::vector<int>{1, 4}));
  EXPECT_TRUE(SelectBackgroundViews(cam, Rigid3d::Identity(), views, ids, 0, all).empty());
}

// The synthetic village (common/synth): its stored frames carry depth 0 exactly where the sky
// is (checked, not assumed), and the pass reproduces synth's sky (a function of direction only)
// in a novel view: the ground truth of the evaluation.
TEST(CpuRendererBackground, VillageSkyMatchesGroundTruth) {
  auto scene = synth::MakeScene(synth::SceneKind::kVillage, {});
  ASSERT_TRUE(scene.ok()) << scene.status();
  const auto& nav = scene->navigable;
  glm::dvec3 eye = 0.5 * (nav.min + nav.max);
  eye.z = nav.min.z + 0.6;
  for (double dx = 0.0; !scene->IsFree(eye, 1.0) && dx < 40.0; dx += 0.7) eye.x = nav.min.x + 3.0 + dx;
  ASSERT_TRUE(scene->IsFree(eye, 1.0));
  synth::RenderOptions ro;
  ro.width = 96;
  ro.height = 72;
  auto look = [&](double yaw, double up, glm::dvec3 offset) {
    return synth::LookAt(eye + offset, eye + offset + glm::dvec3(std::cos(yaw), std::sin(yaw), up));
  };
  LumigraphModel m;
  m.grid.cell_size_m = 1.0;
  m.chunks[0].mesh = scene->mesh;
  size_t sky_depth0 = 0;
  int k = 0;
  for (double yaw : {0.0, 0.6, 1.2, 1.8}) {
    auto f = synth::RenderFrame(*scene, look(yaw, 0.35, glm::dvec3(0.3 * k, -0.2 * k, 0.1)), ro);
    ASSERT_TRUE(f.ok()) << f.status();
    StoredView v;
    v.id = ViewId(++k);
    v.camera = f->frame.color_camera;
    v.local_from_cam = look(yaw, 0.35, glm::dvec3(0.3 * (k - 1), -0.2 * (k - 1), 0.1));
    v.color = f->frame.color;
    v.depth_m = f->frame.depth_m;
    for (float z : v.depth_m.span()) sky_depth0 += z == 0.0f;
    m.views[v.id] = std::move(v);
  }
  EXPECT_GT(sky_depth0, size_t(4 * 96 * 72 / 20)) << "stored village frames show no sky";
  ReferenceAllCells(&m);
  const Rigid3d novel = look(0.9, 0.3, glm::dvec3(0.5, 0.4, 0.3));
  auto r = CpuLumigraphRenderer::Create(m, {}).value();
  auto out = r->Render(ro.Camera(), novel).value();
  ImageF depth;
  auto gt = synth::RenderLinear(*scene, novel, ro, &depth);
  ASSERT_TRUE(gt.ok()) << gt.status();
  size_t sky = 0, filled = 0, within = 0;
  double abs_err = 0;
  for (int y = 0; y < 72; ++y)
    for (int x = 0; x < 96; ++x) {
      if (depth.at(x, y) != 0.0f) continue;  // ground truth: the ray hits nothing
      ++sky;
      if (out.background.at(x, y) == 0) continue;
      ++filled;
      int e = 0;
      for (int c = 0; c < 3; ++c)
        e = std::max(e, std::abs(int(out.color.at(x, y, c)) -
                                 int(synth::LinearToSrgb8(gt->at(x, y, c)))));
      abs_err += e;
      within += e <= 3;
    }
  fprintf(stderr, "[village sky] %zu sky px, %zu filled, mean max-channel error %.2f, %.4f within 3\n",
          sky, filled, abs_err / std::max<size_t>(1, filled), double(within) / std::max<size_t>(1, filled));
  EXPECT_GT(sky, size_t(96 * 72 / 10));
  // Not filled: sky within the guard radius (3 px) of geometry in every stored view.
  EXPECT_GT(filled, sky * 85 / 100);
  EXPECT_LT(abs_err / std::max<size_t>(1, filled), 1.5);
  EXPECT_GT(double(within), 0.97 * double(filled));
}

}  // namespace
}  // namespace exo

namespace exo {
namespace {

// InpaintFusion (SPEC §7, 4.17-4.18): an observed view (flat 60) and an inpainted keyframe (flat
// 200) whose ROI is the centre square. Inside the ROI only the inpainted keyframe contributes,
// outside it only the observation; the inpainted view is never a cell reference nor a background
// view. Without ROI labels (all 0) the inpainted view is ignored.
TEST(CpuRendererInpainted, InsideTheRoiOnlyInpaintedOutsideOnlyObserved) {
  LumigraphModel m = OnePlaneModel(Plane(2.1f));
  StoredView obs = MakeView(1, m.chunks[0].mesh, Rigid3d::Identity(), 1.0f, true);
  obs.color = ImageU8(64, 48, 3, 60);
  m.views[1] = obs;
  ReferenceAllCells(&m);  // only the observed view is referenced
  StoredView ip = MakeView(0x40000000u, m.chunks[0].mesh, Rigid3d::Identity(), 1.0f, true);
  ip.color = ImageU8(64, 48, 3, 200);
  ip.inpainted = true;
  ip.labels = ImageU8(64, 48, 1, 0);
  for (int y = 16; y < 32; ++y)
    for (int x = 24; x < 40; ++x) ip.labels.at(x, y) = 255;
  m.views[ip.id] = ip;
  CpuRenderOptions opt;
  opt.debug_weights = true;
  auto r = CpuLumigraphRenderer::Create(m, opt).value();
  // A slightly moved novel camera: the ROI re-projects through the proxy.
  Rigid3d pose;
  pose.translation = {0.05, 0.0, 0.0};
  auto out = r->Render(SmallCam(), pose).value();
  int inside = 0, outside = 0;
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      const int c = out.color.at(x, y, 0);
      ASSERT_TRUE(c == 60 || c == 200 || out.coverage.at(x, y) == 0) << x << "," << y << ": " << c;
      if (c == 200) ++inside;
      if (c == 60) ++outside;
      if (c == 200) EXPECT_EQ(out.num_views.at(x, y), 1);
    }
  EXPECT_NEAR(inside, 16 * 16, 40);  // the ROI's square, shifted
  EXPECT_GT(outside, 64 * 48 - 16 * 16 - 80);
  EXPECT_EQ(out.color.at(32, 24, 0), 200);
  EXPECT_EQ(out.color.at(5, 5, 0), 60);

  // Labels all observed: the inpainted view does not contribute anywhere.
  m.views[ip.id].labels = ImageU8(64, 48, 1, 0);
  auto r2 = CpuLumigraphRenderer::Create(m, opt).value();
  auto out2 = r2->Render(SmallCam(), pose).value();
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x)
      if (out2.coverage.at(x, y)) ASSERT_EQ(out2.color.at(x, y, 0), 60);

  // Labels of the wrong size are refused.
  m.views[ip.id].labels = ImageU8(10, 10, 1, 0);
  EXPECT_FALSE(CpuLumigraphRenderer::Create(m, opt).ok());
}

// A panel (x, y in [-0.25, 0.25] at z = 1.6) before a wall at z = 3.1.
TriangleMesh Panel() {
  TriangleMesh m;
  m.positions = {{-0.25f, -0.25f, 1.6f}, {0.25f, -0.25f, 1.6f}, {0.25f, 0.25f, 1.6f},
                 {-0.25f, 0.25f, 1.6f}};
  m.indices = {0, 1, 2, 0, 2, 3};
  return m;
}

// The label rule's depth check (blend::InpaintedLabelHolds), the same for every inpainted view:
// a scene completion whose labels are the panel (a hole: no observed view saw it) claims the
// panel, but NOT the observed wall that a novel camera off to the side sees behind the panel
// and that projects into the completion's labels (before: those pixels were taken from the
// completion, where the wall is hidden, i.e. left uncovered). A DR keyframe whose depth is the
// background behind a removed object still claims the object's surface in front of it.
TEST(CpuRendererInpainted, LabelsHoldOnlyWhereThePointIsNotBehindTheViewsSurface) {
  const TriangleMesh wall = Plane(3.1f), panel = Panel();
  TriangleMesh both = wall;
  both.Append(panel);
  LumigraphModel m;
  m.grid.cell_size_m = 0.5;
  m.chunks[0].mesh = both;
  // Observed: the wall (the panel is a hole: no observed depth or colour of it).
  StoredView obs = MakeView(1, wall, Rigid3d::Identity(), 1.0f, true);
  obs.color = ImageU8(64, 48, 3, 60);
  m.views[1] = obs;
  {  // its references: the cells of the wall it saw (also those behind the panel)
    RasterOptions ro;
    ro.cell_id = true;
    ro.cell_grid = m.grid;
    for (uint64_t cell : Rasterize(wall, obs.camera, obs.local_from_cam, ro)->cell_id.span())
      if (cell != kNoCell && m.cell_refs[cell].empty()) m.cell_refs[cell].push_back(1);
  }
  // The completion at the same camera: the panel's pixels labelled, its depth the proxy's.
  StoredView c = MakeView(0x60000000u, both, Rigid3d::Identity(), 1.0f, true);
  c.color = ImageU8(64, 48, 3, 200);
  c.inpainted = true;
  c.labels = ImageU8(64, 48, 1, 0);
  int labelled = 0;
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x)
      if (c.depth_m.at(x, y) < 2.0f) c.labels.at(x, y) = 255, ++labelled;
  ASSERT_GT(labelled, 40);
  m.views[c.id] = c;
  CpuRenderOptions opt;
  opt.blend.fill_holes = false;
  auto r = CpuLumigraphRenderer::Create(m, opt).value();
  Rigid3d novel;
  novel.translation = {0.6, 0.0, 0.0};
  auto out = r->Render(SmallCam(), novel).value();
  // Which pixels of the novel camera see the wall at a point inside the completion's labels.
  RasterOptions ro;
  auto nr = Rasterize(both, SmallCam(), novel, ro).value();
  const PinholeCamera cam = SmallCam();
  int behind = 0, behind_observed = 0, panel_px = 0, panel_completed = 0;
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      const float z = nr.z_depth_m.at(x, y);
      if (!(z > 0.0f)) continue;
      const glm::dvec3 p = novel * cam.Unproject(glm::dvec2(x, y), z);
      if (z < 2.5f) {  // the panel
        ++panel_px;
        panel_completed += out.coverage.at(x, y) && out.color.at(x, y, 0) == 200;
        continue;
      }
      glm::dvec2 uv;
      if (!cam.Project(p, &uv)) continue;  // the completion is at the origin: p is in its frame
      const int u = int(std::floor(uv.x + 0.5)), v = int(std::floor(uv.y + 0.5));
      if (u < 0 || v < 0 || u >= 64 || v >= 48 || c.labels.at(u, v) == 0) continue;
      ++behind;
      behind_observed += out.coverage.at(x, y) && out.color.at(x, y, 0) == 60;
    }
  std::printf("wall behind the completed panel: %d px, %d from the observation; panel %d px, %d "
              "completed\n", behind, behind_observed, panel_px, panel_completed);
  EXPECT_GT(behind, 30);
  EXPECT_GE(behind_observed, behind - 4);  // label edges: nearest-pixel rounding
  EXPECT_GT(panel_px, 40);
  EXPECT_GE(panel_completed, panel_px - 8);

  // DR: an object (the panel) still in the proxy, a keyframe whose depth is the background (the
  // wall) and whose labels are the object's pixels: the object's surface lies in front of the
  // keyframe's surface and is claimed (replaced), as before the depth check.
  LumigraphModel d;
  d.grid.cell_size_m = 0.5;
  d.chunks[0].mesh = both;
  StoredView seen = MakeView(1, both, Rigid3d::Identity(), 1.0f, true);
  seen.color = ImageU8(64, 48, 3, 60);
  d.views[1] = seen;
  ReferenceAllCells(&d);
  StoredView kf = MakeView(0x40000000u, wall, Rigid3d::Identity(), 1.0f, true);
  kf.color = ImageU8(64, 48, 3, 200);
  kf.inpainted = true;
  kf.labels = c.labels;
  d.views[kf.id] = kf;
  auto rd = CpuLumigraphRenderer::Create(d, opt).value();
  Rigid3d near;
  near.translation = {0.03, 0.0, 0.0};
  auto od = rd->Render(SmallCam(), near).value();
  EXPECT_EQ(od.color.at(32, 24, 0), 200);  // the object's centre: the keyframe's background
  EXPECT_EQ(od.color.at(5, 5, 0), 60);     // the wall: the observation
}

}  // namespace
}  // namespace exo
