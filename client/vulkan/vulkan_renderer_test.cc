#include "client/vulkan/vulkan_renderer.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "common/raster/rasterizer.h"

namespace exo {
namespace {

VulkanRendererOptions ValidatedOptions() {
  VulkanRendererOptions o;
  o.enable_validation = true;
  return o;
}

TEST(VulkanRendererTest, CreatesOnLavapipeWithValidation) {
  auto r = VulkanRenderer::Create(ValidatedOptions());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NE((*r)->DeviceName().find("llvmpipe"), std::string::npos) << (*r)->DeviceName();
  EXPECT_TRUE((*r)->ValidationErrors().empty());
}

TEST(VulkanRendererTest, NoDeviceGivesClearError) {
  // Point the loader at an ICD file that does not exist: no driver, no device.
  const char* old_drv = std::getenv("VK_DRIVER_FILES");
  const char* old_icd = std::getenv("VK_ICD_FILENAMES");
  std::string saved_drv = old_drv ? old_drv : "", saved_icd = old_icd ? old_icd : "";
  setenv("VK_DRIVER_FILES", "/nonexistent/icd.json", 1);
  setenv("VK_ICD_FILENAMES", "/nonexistent/icd.json", 1);
  auto r = VulkanRenderer::Create(VulkanRendererOptions{});
  if (old_drv) setenv("VK_DRIVER_FILES", saved_drv.c_str(), 1); else unsetenv("VK_DRIVER_FILES");
  if (old_icd) setenv("VK_ICD_FILENAMES", saved_icd.c_str(), 1); else unsetenv("VK_ICD_FILENAMES");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kUnavailable) << r.status();
  EXPECT_NE(r.status().message().find("Vulkan"), std::string::npos) << r.status();
}

// ---- an analytic scene: a textured plane z = 2 m in front of the origin (camera looks +z) ----
constexpr int kW = 64, kH = 48;

PinholeCamera Cam() { return PinholeCamera::FromFov(kW, kH, 1.2); }

MeshChunk Plane(uint64_t id, float half = 3.0f, float z = 2.0f) {
  MeshChunk c;
  c.id = id;
  c.version = 1;
  c.mesh.positions = {{-half, -half, z}, {half, -half, z}, {half, half, z}, {-half, half, z}};
  c.mesh.indices = {0, 1, 2, 0, 2, 3};
  return c;
}

StoredView PlaneView(ViewId id, const Rigid3d& pose, float exposure = 1.0f) {
  StoredView v;
  v.id = id;
  v.camera = Cam();
  v.local_from_cam = pose;
  v.exposure = exposure;
  v.color = ImageU8(kW, kH, 3);
  v.depth_m = ImageF(kW, kH, 1, 0.0f);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      v.color.at(x, y, 0) = uint8_t(40 + 2 * x);
      v.color.at(x, y, 1) = uint8_t(60 + 3 * y);
      v.color.at(x, y, 2) = uint8_t(((x / 8 + y / 8) % 2) ? 200 : 30);
    }
  // Depth of the plane z = 2 seen from `pose` (pure translation poses only in these tests).
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) v.depth_m.at(x, y) = float(2.0 - pose.translation.z);
  return v;
}

LumigraphModel PlaneModel(double cell = 0.5) {
  LumigraphModel m;
  m.grid.cell_size_m = cell;
  m.chunks[7] = Plane(7);
  m.views[1] = PlaneView(1, Rigid3d::Identity());
  // Every cell of the plane references view 1.
  for (int x = -6; x < 6; ++x)
    for (int y = -6; y < 6; ++y) m.cell_refs[PackCell({x, y, 4})] = {1};
  return m;
}

std::unique_ptr<VulkanRenderer> Make(const LumigraphModel& m) {
  auto r = VulkanRenderer::Create(ValidatedOptions());
  EXPECT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE((*r)->SyncModel(m).ok());
  return std::move(*r);
}

// The ray through pixel (x, y) of Cam() at the identity pose, scaled to z = 1.
glm::dvec3 PixelRay(int x, int y) {
  const PinholeCamera c = Cam();
  return {(x - c.cx) / c.fx, (y - c.cy) / c.fy, 1.0};
}

int MaxDiff(const ImageU8& a, const ImageU8& b) {
  int m = 0;
  for (size_t i = 0; i < a.size(); ++i) m = std::max(m, std::abs(int(a.data()[i]) - int(b.data()[i])));
  return m;
}

TEST(VulkanRendererTest, SamePoseReproducesStoredView) {
  // Projection convention (pixel centres at integers, y down) and the sRGB round trip: the
  // novel camera equal to the stored camera must give back the stored pixels.
  const LumigraphModel m = PlaneModel();
  auto r = Make(m);
  auto out = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(out.ok()) << out.status();
  EXPECT_LE(MaxDiff(out->color, m.views.at(1).color), 1);
  for (uint8_t c : out->coverage.span()) EXPECT_EQ(c, 2);
  EXPECT_TRUE(r->ValidationErrors().empty()) << r->ValidationErrors()[0];
}

TEST(VulkanRendererTest, FloorPassReproducesTheNearestView) {
  // The benchmark's floors (one fetch per pixel from the nearest view: the forward draw with
  // per-vertex texture coordinates, and the per-fragment projective one) are real renders: from
  // the stored pose they give back the stored pixels; from a pose nearer to a second,
  // differently exposed view they sample that one, and follow its re-upload (the forward
  // floor's texture is cached per view and fingerprint); without views it is an error.
  using Kind = VulkanRenderer::FloorKind;
  for (const Kind kind : {Kind::kForward, Kind::kProjective}) {
    SCOPED_TRACE(kind == Kind::kForward ? "forward" : "projective");
    LumigraphModel m = PlaneModel();
    auto r = Make(m);
    auto out = r->RenderFloor(Cam(), Rigid3d::Identity(), kind);
    ASSERT_TRUE(out.ok()) << out.status();
    EXPECT_LE(MaxDiff(out->color, m.views.at(1).color), 1);
    for (uint8_t c : out->coverage.span()) EXPECT_EQ(c, 2);
    StoredView dark = PlaneView(2, Rigid3d::Identity());
    for (uint8_t& c : dark.color.span()) c = uint8_t(c / 2);
    m.views[2] = dark;
    m.views[2].local_from_cam.translation = glm::dvec3(0.0, 0.0, 0.5);
    ASSERT_TRUE(r->SyncModel(m).ok());
    Rigid3d near2 = Rigid3d::Identity();
    near2.translation = glm::dvec3(0.0, 0.0, 0.45);
    out = r->RenderFloor(Cam(), near2, kind);
    ASSERT_TRUE(out.ok()) << out.status();
    // The centre pixel sees the plane point on view 2's optical axis: view 2's centre colour.
    const int cx = kW / 2, cy = kH / 2;
    EXPECT_NEAR(out->color.at(cx, cy, 0), dark.color.at(cx, cy, 0), 2);
    EXPECT_NEAR(out->color.at(cx, cy, 1), dark.color.at(cx, cy, 1), 2);
    // View 2 re-uploaded darker still (same id): the floor samples the new colour.
    for (uint8_t& c : m.views[2].color.span()) c = uint8_t(c / 2);
    ASSERT_TRUE(r->SyncModel(m).ok());
    out = r->RenderFloor(Cam(), near2, kind);
    ASSERT_TRUE(out.ok()) << out.status();
    EXPECT_NEAR(out->color.at(cx, cy, 0), m.views[2].color.at(cx, cy, 0), 2);
    EXPECT_NEAR(out->color.at(cx, cy, 1), m.views[2].color.at(cx, cy, 1), 2);
    EXPECT_TRUE(r->ValidationErrors().empty()) << r->ValidationErrors()[0];
  }
  auto empty = VulkanRenderer::Create(ValidatedOptions());
  ASSERT_TRUE(empty.ok());
  EXPECT_EQ((*empty)->RenderFloor(Cam(), Rigid3d::Identity()).status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ((*empty)->PrepareFloor(Cam(), Rigid3d::Identity()).code(),
            absl::StatusCode::kFailedPrecondition);
}

TEST(VulkanRendererTest, CellWithNoReferencesGivesBackground) {
  // Hard case: empty reference set. Guard: the count == 0 path of the hash lookup and
  // Resolve()'s sum_weight > 0 test (without it: 0/0 = NaN colour).
  LumigraphModel m = PlaneModel();
  m.cell_refs.clear();
  auto r = Make(m);
  blend::BlendOptions bo;
  bo.background_srgb = {0.2f, 0.4f, 0.6f};
  auto out = r->Render(Cam(), Rigid3d::Identity(), bo);
  ASSERT_TRUE(out.ok());
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      EXPECT_EQ(out->color.at(x, y, 0), 51);
      EXPECT_EQ(out->color.at(x, y, 1), 102);
      EXPECT_EQ(out->color.at(x, y, 2), 153);
      EXPECT_EQ(out->coverage.at(x, y), 1);  // surface hit, no view
    }
}

TEST(VulkanRendererTest, ViewWithAllInvalidDepthIsNeverUsed) {
  // Hard case: depth all invalid (0 and NaN). Guard: ValidDepth() in Validity and the NaN -> 0
  // mapping of BakeDiscontinuities.
  LumigraphModel m = PlaneModel();
  auto& d = m.views.at(1).depth_m;
  for (int i = 0; i < int(d.size()); ++i) d.data()[i] = (i % 2) ? 0.0f : std::nanf("");
  auto r = Make(m);
  auto out = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(out.ok());
  for (uint8_t c : out->coverage.span()) EXPECT_EQ(c, 1);
  for (uint8_t c : out->color.span()) EXPECT_EQ(c, 0);
}

TEST(VulkanRendererTest, FragmentOutsideEveryFrustumIsBackground) {
  // Hard case: surface outside every stored view's field of view. The novel camera is moved
  // 1.5 m to the right: its right part sees plane points no stored pixel covers. Guard:
  // InsideImage() (without it, edge texels would be smeared over the uncovered part).
  const LumigraphModel m = PlaneModel();
  auto r = Make(m);
  Rigid3d pose;
  pose.translation = {1.5, 0.0, 0.0};
  auto out = r->Render(Cam(), pose, blend::BlendOptions{});
  ASSERT_TRUE(out.ok());
  // Stored view covers x in [-2 tan(0.6), 2 tan(0.6)] = [-1.37, 1.37] at z = 2.
  const double fx = Cam().fx, cx = Cam().cx;
  int blended = 0, outside = 0;
  for (int x = 0; x < kW; ++x) {
    const double x_world = 1.5 + (x - cx) / fx * 2.0;
    if (std::abs(std::abs(x_world) - 1.37) < 0.08) continue;  // edge pixel
    const bool inside = std::abs(x_world) < 1.37;
    EXPECT_EQ(out->coverage.at(x, kH / 2), inside ? 2 : 1) << "x=" << x << " at " << x_world;
    (inside ? blended : outside)++;
  }
  EXPECT_GT(blended, 5);
  EXPECT_GT(outside, 5);
}

TEST(VulkanRendererTest, IncrementalUploadsOnlyWhatChanged) {
  // Store changes between frames; each change uploads only itself (byte counts are exact).
  LumigraphModel m = PlaneModel();
  auto r = Make(m);
  auto before = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(before.ok());
  const uint64_t view_bytes = uint64_t(kW) * kH * 12 + 80;  // linear RGBA16 + R32F + record

  // 1. Exposure of one view changes: one view upload, the output doubles in linear light.
  r->ResetStats();
  m.views.at(1).exposure = 2.0f;
  ASSERT_TRUE(r->SyncModel(m).ok());
  EXPECT_EQ(r->stats().view_uploads, 1u);
  EXPECT_EQ(r->stats().bytes, view_bytes);
  auto brighter = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(brighter.ok());
  const float lin = blend::SrgbToLinear(blend::U8ToUnit(before->color.at(10, 10, 0)));
  EXPECT_NEAR(brighter->color.at(10, 10, 0),
              blend::UnitToU8(blend::LinearToSrgb(2.0f * lin)), 1);

  // 2. Nothing changed: nothing uploaded.
  r->ResetStats();
  ASSERT_TRUE(r->SyncModel(m).ok());
  EXPECT_EQ(r->stats().bytes, 0u);

  // 3. One cell's refs change: 4 bytes per ref + one 16-byte table entry.
  r->ResetStats();
  const CellId c = PackCell({0, 0, 4});
  m.cell_refs[c] = {1, 2};
  ASSERT_TRUE(r->SyncModel(m).ok());
  EXPECT_EQ(r->stats().cell_uploads, 1u);
  EXPECT_EQ(r->stats().bytes, 2u * 4 + 16);

  // 4. View 2 arrives later: its upload + the slab of the one cell that already referenced it.
  r->ResetStats();
  Rigid3d p2;
  p2.translation = {0.2, 0.0, 0.0};
  m.views[2] = PlaneView(2, p2);
  ASSERT_TRUE(r->SyncModel(m).ok());
  EXPECT_EQ(r->stats().view_uploads, 1u);
  EXPECT_EQ(r->stats().cell_uploads, 1u);
  EXPECT_EQ(r->stats().bytes, view_bytes + 2 * 4);

  // 5. One chunk re-extracted (new version): only its vertex + index bytes.
  r->ResetStats();
  m.chunks[8] = Plane(8, 0.5f, 1.0f);
  ASSERT_TRUE(r->SyncModel(m).ok());
  EXPECT_EQ(r->stats().chunk_uploads, 1u);
  EXPECT_EQ(r->stats().bytes, 4u * 12 + 6 * 4);

  // 6. Removing view 1 (and its refs): its pixels are no longer blended from it.
  m.views.erase(1);
  m.chunks.erase(8);
  for (auto& [id, refs] : m.cell_refs) std::erase(refs, ViewId{1});
  std::erase_if(m.cell_refs, [](const auto& kv) { return kv.second.empty(); });
  ASSERT_TRUE(r->SyncModel(m).ok());
  EXPECT_EQ(r->num_views(), 1u);
  EXPECT_EQ(r->num_cells(), 1u);
  auto after = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(after.ok());
  int blended = 0;
  for (uint8_t cv : after->coverage.span()) blended += cv == 2;
  EXPECT_GT(blended, 0);       // cell (0,0,4) still blends from view 2
  EXPECT_LT(blended, kW * kH / 4);
  EXPECT_TRUE(r->ValidationErrors().empty()) << r->ValidationErrors()[0];
}

TEST(VulkanRendererTest, ManyCellsGrowTheHashTable) {
  // 14400 cells force several table rebuilds and slab regrowths; every cell stays findable.
  // Guard: fails if inserts do not raise the lookup bound max_probe (displaced keys missed).
  LumigraphModel m = PlaneModel(0.05);  // 0.05 m cells: the plane spans 120 x 120 cells
  m.cell_refs.clear();
  for (int x = -60; x < 60; ++x)
    for (int y = -60; y < 60; ++y) m.cell_refs[PackCell({x, y, 40})] = {1};
  auto r = Make(m);
  EXPECT_EQ(r->num_cells(), 14400u);
  auto out = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(out.ok());
  EXPECT_LE(MaxDiff(out->color, m.views.at(1).color), 1);
}

TEST(VulkanRendererTest, RemovedAndReinsertedCellsStayFindable) {
  // Removal (tombstones) and re-insertion into tombstones with the bounded lookup (the shader
  // probes at most max_probe + 1 slots). The displacement bound itself is guarded by
  // ManyCellsGrowTheHashTable (it fails when inserts do not update max_probe).
  LumigraphModel m = PlaneModel(0.05);
  m.cell_refs.clear();
  for (int x = -60; x < 60; ++x)
    for (int y = -60; y < 60; ++y) m.cell_refs[PackCell({x, y, 40})] = {1};
  auto r = Make(m);
  // Remove every other column of cells: those pixels become "surface, no view" (background).
  for (int x = -60; x < 60; x += 2)
    for (int y = -60; y < 60; ++y) ASSERT_TRUE(r->SetCellRefs(PackCell({x, y, 40}), {}).ok());
  EXPECT_EQ(r->num_cells(), 7200u);
  auto half = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(half.ok());
  int blended = 0, surface_only = 0;
  for (size_t i = 0; i < half->coverage.size(); ++i) {
    blended += half->coverage.data()[i] == 2;
    surface_only += half->coverage.data()[i] == 1;
  }
  EXPECT_GT(blended, kW * kH / 3);
  EXPECT_GT(surface_only, kW * kH / 3);
  // Re-insert them (into tombstones): everything is found again.
  const ViewId one[] = {1};
  for (int x = -60; x < 60; x += 2)
    for (int y = -60; y < 60; ++y) ASSERT_TRUE(r->SetCellRefs(PackCell({x, y, 40}), one).ok());
  auto full = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(full.ok());
  EXPECT_LE(MaxDiff(full->color, m.views.at(1).color), 1);
  EXPECT_TRUE(r->ValidationErrors().empty());
}

TEST(VulkanRendererTest, ProxyDepthPassGivesPlaneDepth) {
  // The plane z = 2 from cameras at z = 0 and z = 0.5 (looking +z): z-depth 2 and 1.5 where the
  // plane is seen, 0 (invalid) where it is not (a camera turned away sees nothing).
  auto r = Make(PlaneModel());
  for (double tz : {0.0, 0.5}) {
    Rigid3d pose;
    pose.translation = {0.1, -0.2, tz};
    auto d = r->RenderProxyDepth(Cam(), pose);
    ASSERT_TRUE(d.ok()) << d.status();
    for (float z : d->span()) EXPECT_NEAR(z, 2.0 - tz, 1e-5);
  }
  Rigid3d away;
  away.rotation = glm::angleAxis(M_PI, glm::dvec3(0, 1, 0));  // looks -z
  auto d = r->RenderProxyDepth(Cam(), away);
  ASSERT_TRUE(d.ok());
  for (float z : d->span()) EXPECT_EQ(z, 0.0f);
  EXPECT_TRUE(r->ValidationErrors().empty());
}

// The viewer's X-ray cut-away (issue 19): a near plane behind the front plane (z = 2) shows the
// plane behind it (z = 4) in every pass; back to the default, the front one again.
TEST(VulkanRendererTest, NearPlaneCutsAwayTheFrontSurface) {
  LumigraphModel m = PlaneModel();
  m.chunks[8] = Plane(8, 6.0f, 4.0f);
  auto r = Make(m);
  const float default_near = r->near_plane();
  auto depth_at = [&](float near_m) {
    EXPECT_TRUE(r->SetNearPlane(near_m).ok());
    auto d = r->RenderProxyDepth(Cam(), Rigid3d::Identity());
    EXPECT_TRUE(d.ok()) << d.status();
    return d.ok() ? d->at(kW / 2, kH / 2) : -1.0f;
  };
  EXPECT_NEAR(depth_at(default_near), 2.0, 1e-5);
  EXPECT_NEAR(depth_at(2.5f), 4.0, 1e-5);
  auto ids = r->RenderCellIds(Cam(), Rigid3d::Identity());
  ASSERT_TRUE(ids.ok());
  EXPECT_EQ(ids->at(kW / 2, kH / 2), m.grid.IdOf({0, 0, 4.0}));
  auto frame = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(frame.ok()) << frame.status();
  EXPECT_NE(frame->coverage.at(kW / 2, kH / 2), 0);  // a surface is drawn there (the far plane)
  EXPECT_NEAR(depth_at(4.5f), 0.0, 1e-6);            // nothing beyond both planes
  EXPECT_NEAR(depth_at(default_near), 2.0, 1e-5);
  EXPECT_FALSE(r->SetNearPlane(0.0f).ok());
  EXPECT_FALSE(r->SetNearPlane(1e9f).ok());
  EXPECT_EQ(r->near_plane(), default_near);
  EXPECT_TRUE(r->ValidationErrors().empty());
}

// The X-ray cut-away as a hole (issue 19, thesis 5.2.7 "a virtual hole in the wall"): the front
// plane z = 2 (view 1's colours) and a far plane z = 4 seen by view 2 (other colours). With a
// hole (clip 2.5 m, a disc off the centre) every pass shows the far plane inside the disc and
// exactly the normal picture outside it; no hole again: the normal picture everywhere.
TEST(VulkanRendererTest, XrayHoleCutsOnlyInsideTheDisc) {
  LumigraphModel m = PlaneModel();
  m.chunks[8] = Plane(8, 6.0f, 4.0f);
  StoredView far = PlaneView(2, Rigid3d::Identity());
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      far.depth_m.at(x, y) = 4.0f;
      for (int c = 0; c < 3; ++c) far.color.at(x, y, c) = uint8_t(255 - far.color.at(x, y, c));
    }
  m.views[2] = far;
  for (int x = -12; x < 12; ++x)
    for (int y = -12; y < 12; ++y) m.cell_refs[PackCell({x, y, 8})] = {2};
  auto r = Make(m);
  const Rigid3d at = Rigid3d::Identity();
  auto normal = r->Render(Cam(), at, blend::BlendOptions{});
  ASSERT_TRUE(normal.ok()) << normal.status();
  EXPECT_LE(MaxDiff(normal->color, m.views.at(1).color), 1);

  XrayHole hole;
  hole.clip_m = 2.5;
  hole.centre_x = 0.3;
  hole.centre_y = 0.6;
  hole.radius = 0.25;  // 12 px of 48
  ASSERT_TRUE(r->SetXrayHole(hole).ok());
  ASSERT_TRUE(r->xray_hole().has_value());
  auto holed = r->Render(Cam(), at, blend::BlendOptions{});
  auto depth = r->RenderProxyDepth(Cam(), at);
  auto ids = r->RenderCellIds(Cam(), at);
  ASSERT_TRUE(holed.ok() && depth.ok() && ids.ok());
  int inside = 0, outside = 0;
  const double r_px = hole.radius * kH;
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      const double d = std::hypot(x + 0.5 - hole.centre_x * kW, y + 0.5 - hole.centre_y * kH);
      if (std::abs(d - r_px) < 0.5) continue;  // on the rim: either
      const bool in = d < r_px;
      (in ? inside : outside) += 1;
      const StoredView& want = m.views.at(in ? 2 : 1);
      for (int c = 0; c < 3; ++c)
        ASSERT_LE(std::abs(int(holed->color.at(x, y, c)) - int(want.color.at(x, y, c))), 1)
            << x << "," << y << (in ? " inside" : " outside");
      EXPECT_NEAR(depth->at(x, y), in ? 4.0 : 2.0, 1e-5) << x << "," << y;
      const glm::dvec3 p = PixelRay(x, y) * (in ? 4.0 : 2.0);
      const auto near_edge = [](double v) { return std::abs(v / 0.5 - std::round(v / 0.5)) < 1e-3; };
      if (!near_edge(p.x) && !near_edge(p.y)) {  // float vs double at a cell's border: either
        EXPECT_EQ(ids->at(x, y), m.grid.IdOf(p)) << x << "," << y;
      }
    }
  EXPECT_GT(inside, 300);  // pi 12^2 = 452
  EXPECT_GT(outside, 2000);

  // Bad holes are refused with the reason; the hole in place stays.
  XrayHole bad = hole;
  bad.clip_m = 0;
  EXPECT_EQ(r->SetXrayHole(bad).code(), absl::StatusCode::kInvalidArgument);
  bad = hole;
  bad.radius = 0;
  EXPECT_EQ(r->SetXrayHole(bad).code(), absl::StatusCode::kInvalidArgument);
  bad = hole;
  bad.centre_x = std::nan("");
  EXPECT_EQ(r->SetXrayHole(bad).code(), absl::StatusCode::kInvalidArgument);
  ASSERT_TRUE(r->xray_hole().has_value());
  EXPECT_EQ(r->xray_hole()->clip_m, 2.5);

  ASSERT_TRUE(r->SetXrayHole(std::nullopt).ok());
  auto again = r->Render(Cam(), at, blend::BlendOptions{});
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(MaxDiff(again->color, normal->color), 0);
  EXPECT_TRUE(r->ValidationErrors().empty());
}

TEST(VulkanRendererTest, CellIdPassMatchesCpuRasterizer) {
  const LumigraphModel m = PlaneModel(0.3);  // z = 2 m is not on a cell boundary
  auto r = Make(m);
  Rigid3d pose;
  pose.translation = {0.1, -0.2, 0.3};
  auto ids = r->RenderCellIds(Cam(), pose);
  ASSERT_TRUE(ids.ok()) << ids.status();
  RasterOptions ro;
  ro.cell_id = true;
  ro.cell_grid = m.grid;
  auto cpu = Rasterize(m.chunks.at(7).mesh, Cam(), pose, ro);
  ASSERT_TRUE(cpu.ok());
  int same = 0;
  for (size_t i = 0; i < ids->size(); ++i) same += ids->data()[i] == cpu->cell_id.data()[i];
  EXPECT_GE(same, int(0.99 * kW * kH));
  EXPECT_TRUE(r->ValidationErrors().empty()) << r->ValidationErrors()[0];
}

TEST(VulkanRendererTest, BakeDiscontinuitiesInvalidatesNearJumps) {
  ImageF d(10, 1, 1, 2.0f);
  for (int x = 5; x < 10; ++x) d.at(x, 0) = 4.0f;  // 2 m jump between x = 4 and 5
  const ImageF b = BakeDiscontinuities(d, 2, 0.1f, 0.05f);
  // Pixels whose +-2 neighbour crosses the jump: x = 3, 4 (see 5, 6) and 5, 6 (see 3, 4).
  for (int x = 0; x < 10; ++x) EXPECT_EQ(b.at(x, 0) == 0.0f, x >= 3 && x <= 6) << x;
}

// A random unit direction (rejection sampling in the unit ball) and options alternating the
// positional mode, for the bound tests below.
glm::dvec3 RandomUnit(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  glm::dvec3 d;
  do d = {u(rng), u(rng), u(rng)}; while (glm::length(d) < 0.1 || glm::length(d) > 1.0);
  return glm::normalize(d);
}
blend::BlendOptions AlternatingPositionalMode(int t) {
  blend::BlendOptions bo;
  bo.positional_mode =
      t % 2 ? blend::PositionalMode::kPrinted : blend::PositionalMode::kUlrResolution;
  return bo;
}

// The per-frame reference ranking is exact only if BlendWeightUpperBound is a true upper bound of
// the weight blend_math.h computes (in float) for every surface point in the cell's ball. Samples
// points on the ball's surface (where the extremes lie) and inside, for random cameras near and
// far, both positional modes and random lambda. Guards: without the asin(r/D) turn terms of the
// directional bound, or with the positional bound taken at the centre distances, sampled weights
// exceed the bound (checked by mutation). The tightness check guards against a trivial bound.
TEST(BlendWeightUpperBoundTest, BoundsEveryPointOfTheCellBallAndIsInformative) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0), u01(0.0, 1.0);
  auto unit = [&] { return RandomUnit(rng); };
  int configs = 0, informative = 0;
  double slack_sum = 0.0;
  for (int t = 0; t < 2000; ++t) {
    blend::BlendOptions bo = AlternatingPositionalMode(t);
    bo.lambda = float(u01(rng));
    const glm::dvec3 m(20.0 * u(rng), 20.0 * u(rng), 5.0 * u(rng));
    const double r = 0.05 + 1.5 * u01(rng);
    // Cameras from inside the ball (bound 1) to 40 m away; c_i often near c_o's direction.
    const glm::dvec3 c_o = m + unit() * (r * 0.5 + 40.0 * u01(rng));
    const glm::dvec3 dir_i = t % 3 ? glm::normalize(c_o - m + 0.3 * glm::length(c_o - m) * unit())
                                   : unit();
    const glm::dvec3 c_i = m + dir_i * (r * 0.5 + 40.0 * u01(rng));
    const float bound = BlendWeightUpperBound(m, r, c_o, c_i, bo);
    const glm::vec3 fo(c_o), fi(c_i);
    float max_w = 0.0f;
    for (int k = 0; k < 400; ++k) {
      const double radius = k % 4 == 0 ? r * std::cbrt(u01(rng)) : r;  // mostly on the surface
      const glm::vec3 x(m + unit() * radius);
      const float w = blend::CombinedWeight(1.0f, blend::DirectionalWeight(x, fo, fi),
                                            blend::PositionalWeight(x, fo, fi, bo.positional_mode),
                                            bo.lambda, bo.min_weight);
      max_w = std::max(max_w, w);
      ASSERT_LE(w, bound) << "config " << t << " sample " << k << " r " << r;
    }
    ++configs;
    if (bound < 0.999f) ++informative;
    slack_sum += bound - max_w;
  }
  // Informative: most configurations bound below 1, and the bound is close to the sampled max.
  EXPECT_GT(informative, configs / 2);
  EXPECT_LT(slack_sum / configs, 0.05) << "mean bound - sampled max";
}

// CellWeightBound over a CellRegion with a box: every sampled point of the box (corners, faces,
// interior) gets a weight below it, and for flat or thin boxes it is below the bound over the
// box's ball alone in most configurations (the corner turns are smaller seen edge-on). Guard:
// with the corner cosine taken as the maximum instead of the minimum, sampled weights exceed it.
TEST(BlendWeightUpperBoundTest, BoxRegionBoundsEveryPointOfTheBoxAndIsTighter) {
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(-1.0, 1.0), u01(0.0, 1.0);
  auto unit = [&] { return RandomUnit(rng); };
  int configs = 0, tighter = 0;
  for (int t = 0; t < 2000; ++t) {
    blend::BlendOptions bo = AlternatingPositionalMode(t);
    bo.lambda = t % 3 ? 1.0f : float(u01(rng));
    const glm::dvec3 centre(20.0 * u(rng), 20.0 * u(rng), 5.0 * u(rng));
    glm::dvec3 half(0.05 + 0.3 * u01(rng), 0.05 + 0.3 * u01(rng), 0.05 + 0.3 * u01(rng));
    half[t % 3] *= t % 4 == 0 ? 1.0 : 1e-3;  // mostly flat boxes
    CellRegion g;
    g.m = centre;
    g.r = glm::length(half);
    g.has_box = true;
    g.lo = centre - half;
    g.hi = centre + half;
    const glm::dvec3 c_o = centre + unit() * (g.r * 0.5 + 30.0 * u01(rng));
    const glm::dvec3 dir_i = t % 3 ? glm::normalize(c_o - centre + 0.3 * glm::length(c_o - centre) * unit())
                                   : unit();
    const glm::dvec3 c_i = centre + dir_i * (g.r * 0.5 + 30.0 * u01(rng));
    // The renderer's mode (box turn for the novel camera only) and both rays' box turns.
    const float bound = CellWeightBound(g, c_o, /*box_turn_refs=*/t % 2 == 0)(c_i, bo);
    const float ball = BlendWeightUpperBound(g.m, g.r, c_o, c_i, bo);
    ASSERT_LE(bound, ball) << "config " << t;
    const glm::vec3 fo(c_o), fi(c_i);
    for (int k = 0; k < 400; ++k) {
      glm::dvec3 s(u(rng), u(rng), u(rng));
      if (k < 8) s = glm::dvec3(k & 1 ? 1 : -1, k & 2 ? 1 : -1, k & 4 ? 1 : -1);  // corners
      else if (k % 2) s[k % 3] = s[k % 3] < 0 ? -1.0 : 1.0;                  // on a face
      const glm::vec3 x(centre + s * half);
      const float w = blend::CombinedWeight(1.0f, blend::DirectionalWeight(x, fo, fi),
                                            blend::PositionalWeight(x, fo, fi, bo.positional_mode),
                                            bo.lambda, bo.min_weight);
      ASSERT_LE(w, bound) << "config " << t << " sample " << k;
    }
    ++configs;
    if (bound < ball) ++tighter;
  }
  EXPECT_GT(tighter, configs / 2);
}

// Background at infinity without any proxy: a stored view that saw nothing within range (depth 0
// everywhere) fills every pixel of the same pose with its own colour (coverage 3); a removed view
// is no longer a background view; the guard radius must match the baked one.
TEST(VulkanRendererTest, BackgroundAtInfinityFromASkyOnlyView) {
  LumigraphModel m;
  m.grid.cell_size_m = 0.5;
  StoredView v = PlaneView(5, Rigid3d::Identity());
  for (float& z : v.depth_m.span()) z = 0.0f;
  m.views[5] = v;
  auto r = Make(m);
  auto out = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(out.ok()) << out.status();
  EXPECT_EQ(out->background_views, std::vector<ViewId>{5});
  for (uint8_t c : out->coverage.span()) ASSERT_EQ(c, 3);
  EXPECT_LE(MaxDiff(out->color, v.color), 1);
  blend::BlendOptions bad;
  bad.background_guard_radius_px = 2;
  EXPECT_EQ(r->Render(Cam(), Rigid3d::Identity(), bad).status().code(),
            absl::StatusCode::kInvalidArgument);
  bad.background_views = 0;  // off: the baked radius does not matter
  auto off = r->Render(Cam(), Rigid3d::Identity(), bad);
  ASSERT_TRUE(off.ok()) << off.status();
  for (uint8_t c : off->coverage.span()) ASSERT_EQ(c, 0);
  ASSERT_TRUE(r->RemoveView(5).ok());
  auto gone = r->Render(Cam(), Rigid3d::Identity(), blend::BlendOptions{});
  ASSERT_TRUE(gone.ok()) << gone.status();
  EXPECT_TRUE(gone->background_views.empty());
  for (uint8_t c : gone->coverage.span()) ASSERT_EQ(c, 0);
  EXPECT_TRUE(r->ValidationErrors().empty());
}

TEST(VulkanRendererTest, RejectsBadInput) {
  auto r = Make(PlaneModel());
  StoredView v = PlaneView(9, Rigid3d::Identity());
  v.depth_m = ImageF(3, 3);
  EXPECT_EQ(r->UpsertView(v).code(), absl::StatusCode::kInvalidArgument);
  MeshChunk c = Plane(3);
  c.mesh.indices[0] = 99;
  EXPECT_EQ(r->UpsertChunk(c).code(), absl::StatusCode::kInvalidArgument);
  std::vector<ViewId> too_many(65, 1);  // max_refs_per_cell 64
  EXPECT_EQ(r->SetCellRefs(PackCell({0, 0, 0}), too_many).code(),
            absl::StatusCode::kInvalidArgument);
  Rigid3d nan_pose;
  nan_pose.translation.x = std::nan("");
  EXPECT_FALSE(r->Render(Cam(), nan_pose, blend::BlendOptions{}).ok());
}

}  // namespace
}  // namespace exo
