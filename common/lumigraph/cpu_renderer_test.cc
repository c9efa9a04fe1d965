#include "common/lumigraph/cpu_renderer.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "common/raster/rasterizer.h"

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

}  // namespace
}  // namespace exo
