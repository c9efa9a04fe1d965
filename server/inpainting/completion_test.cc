// Scene completion (completion.h): a textured wall whose proxy ends at x = 0.6 m, two stored views
// that see it up to x = 0.51 m; a novel camera looking past both is completed: the holes (proxy
// no view sees, void past the proxy) and only they are inpainted, the void gets a mesh at the
// wall's depth, and the model with the completion keyframe covers the whole frame.
#include "server/inpainting/completion.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "common/lumigraph/blend_math.h"
#include "server/inpainting/test_scenes.h"

namespace exo::inpainting {
namespace {

using testing::RenderPlanes;
using testing::SmallCamera;
using testing::WorldPlane;

constexpr double kWallZ = 2.0;
constexpr double kProxyMaxX = 0.6;

Rigid3d At(double x) {
  Rigid3d p;
  p.translation = {x, 0.0, 0.0};
  return p;
}

std::vector<WorldPlane> Wall() { return {{glm::dvec3(0, 0, -1), -kWallZ, nullptr}}; }

// The proxy: the wall as a 5 cm grid for x in [-2, 0.6], |y| < 1.2; the model's views at
// x = -0.6 and -0.9, referenced by every cell of the wall.
LumigraphModel WallModel() {
  LumigraphModel m;
  m.grid.cell_size_m = 0.5;
  MeshChunk c;
  c.id = 1;
  c.version = 1;
  const double step = 0.05;
  const int nx = static_cast<int>(std::lround((kProxyMaxX + 2.0) / step)) + 1;
  const int ny = static_cast<int>(std::lround(2.4 / step)) + 1;
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i)
      c.mesh.positions.push_back(glm::vec3(-2.0 + i * step, -1.2 + j * step, kWallZ));
  for (int j = 0; j + 1 < ny; ++j)
    for (int i = 0; i + 1 < nx; ++i) {
      const uint32_t a = j * nx + i, b = a + 1, d = a + nx, e = d + 1;
      c.mesh.indices.insert(c.mesh.indices.end(), {a, d, b, b, d, e});
    }
  m.chunks[1] = std::move(c);
  ViewId id = 1;
  for (double x : {-0.6, -0.9}) {
    const RgbdKeyframe kf = RenderPlanes(Wall(), SmallCamera(), At(x));
    StoredView v;
    v.id = id++;
    v.camera = kf.camera;
    v.local_from_cam = kf.world_from_cam;
    v.color = kf.color;
    v.depth_m = kf.depth_m;
    m.views[v.id] = std::move(v);
  }
  for (double x = -2.0; x <= kProxyMaxX; x += 0.25)
    for (double y = -1.2; y <= 1.2; y += 0.25)
      for (double z : {kWallZ - 0.01, kWallZ + 0.01}) {  // the wall lies on a cell boundary
        auto& refs = m.cell_refs[m.grid.IdOf({x, y, z})];
        if (refs.empty()) refs = {1, 2};
      }
  return m;
}

CompletionOptions Options() {
  CompletionOptions o;
  o.inpaint.num_threads = 1;
  o.render.num_threads = 1;
  return o;
}

TEST(Completion, FillsOnlyTheHolesAndTheModelThenCoversTheFrame) {
  LumigraphModel model = WallModel();
  const PinholeCamera cam = SmallCamera();
  const Rigid3d pose = At(0.3);  // sees x in [-0.81, 1.41] on the wall
  auto r = CompleteView(model, cam, pose, Options());
  ASSERT_TRUE(r.ok()) << r.status();
  ASSERT_TRUE(r->completed);
  const CompletionHoles& h = r->before;
  EXPECT_GT(h.surface_hole_px, 0);  // proxy in x in (0.51, 0.6]: no view sees it
  EXPECT_GT(h.void_hole_px, 0);     // past x = 0.6: no proxy
  EXPECT_EQ(h.hole_px, h.surface_hole_px + h.void_hole_px);
  EXPECT_EQ(h.hole_px + h.covered_px + h.background_px, cam.width * cam.height);
  EXPECT_EQ(h.background_px, 0);
  // Labels = the holes; outside them the keyframe is the render, unchanged.
  int changed_outside = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      EXPECT_EQ(r->view.labels.at(x, y), h.holes.at(x, y));
      if (h.holes.at(x, y)) continue;
      for (int k = 0; k < 3; ++k) changed_outside += r->view.color.at(x, y, k) != h.color.at(x, y, k);
    }
  EXPECT_EQ(changed_outside, 0);
  // The void holes' depth: the wall's (the Poisson solve in inverse depth reproduces a plane
  // from its border), and the mesh lies on the wall.
  double max_err = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x)
      if (h.holes.at(x, y)) max_err = std::max(max_err, std::fabs(r->view.depth_m.at(x, y) - kWallZ));
  EXPECT_LT(max_err, 0.02 * kWallZ);
  ASSERT_FALSE(r->void_mesh.empty());
  for (const glm::vec3& p : r->void_mesh.positions) {
    EXPECT_NEAR(p.z, kWallZ, 0.04);
    EXPECT_GT(p.x, kProxyMaxX - 0.1);  // only around the void (one grid step of overlap)
  }

  // The model with the completion keyframe and its mesh: the same render covers every pixel,
  // and the pixels that were covered before are unchanged.
  CpuRenderOptions ro;
  ro.num_threads = 1;
  ro.blend.fill_holes = false;
  auto before = CpuLumigraphRenderer::Create(model, ro).value()->Render(cam, pose).value();
  StoredView v = r->view;
  v.id = 0x60000001u;
  model.views[v.id] = v;
  MeshChunk mc;
  mc.id = uint64_t{1} << 63;
  mc.version = 1;
  mc.mesh = r->void_mesh;
  model.chunks[mc.id] = mc;
  auto after = CpuLumigraphRenderer::Create(model, ro).value()->Render(cam, pose).value();
  EXPECT_LT(before.covered_pixels, size_t(cam.width) * cam.height);
  EXPECT_EQ(after.covered_pixels, size_t(cam.width) * cam.height);
  int differ = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      if (h.holes.at(x, y)) continue;
      for (int k = 0; k < 3; ++k)
        differ += std::abs(int(after.color.at(x, y, k)) - int(before.color.at(x, y, k))) > 1;
    }
  EXPECT_EQ(differ, 0);
  // Completing again at the same camera: nothing left.
  auto again = CompleteView(model, cam, pose, Options());
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_FALSE(again->completed);
  EXPECT_EQ(again->before.hole_px, 0);
}

// Session 16: the proxy's fused vertex colour is an observation: a surface hole takes it (the
// render of the wall's texture at the vertices, interpolated), PatchMatch / push-pull fill only
// the void; without vertex colours (or with use_vertex_color off) nothing is taken from it.
TEST(Completion, SurfaceHolesTakeTheProxysFusedColour) {
  LumigraphModel model = WallModel();
  TriangleMesh& mesh = model.chunks[1].mesh;
  for (const glm::vec3& p : mesh.positions) {  // the wall's texture, linear, as a TSDF stores it
    const glm::dvec3 t = testing::Texture(glm::dvec3(p)) / 255.0;
    mesh.colors.push_back(glm::vec3(blend::SrgbToLinear(float(std::clamp(t.x, 0.0, 1.0))),
                                    blend::SrgbToLinear(float(std::clamp(t.y, 0.0, 1.0))),
                                    blend::SrgbToLinear(float(std::clamp(t.z, 0.0, 1.0)))));
  }
  const PinholeCamera cam = SmallCamera();
  const Rigid3d pose = At(0.3);
  auto r = CompleteView(model, cam, pose, Options());
  ASSERT_TRUE(r.ok()) << r.status();
  const CompletionHoles& h = r->before;
  EXPECT_EQ(h.fused_color_px, h.surface_hole_px);
  ASSERT_GT(h.surface_hole_px, 20);
  // Against the true texture at those pixels (a 5 cm grid interpolates it: a few levels).
  const RgbdKeyframe truth = RenderPlanes(Wall(), cam, pose);
  double err = 0, err_off = 0;
  int n = 0;
  CompletionOptions off = Options();
  off.use_vertex_color = false;
  auto r_off = CompleteView(model, cam, pose, off);
  ASSERT_TRUE(r_off.ok()) << r_off.status();
  EXPECT_EQ(r_off->before.fused_color_px, 0);
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      if (!h.holes.at(x, y) || !(h.proxy_depth.at(x, y) > 0.0f)) continue;
      for (int k = 0; k < 3; ++k) {
        err += std::abs(int(r->view.color.at(x, y, k)) - int(truth.color.at(x, y, k)));
        err_off += std::abs(int(r_off->view.color.at(x, y, k)) - int(truth.color.at(x, y, k)));
      }
      n += 3;
    }
  std::printf("surface holes: mean abs error %.2f levels with the fused colour, %.2f without\n",
              err / n, err_off / n);
  EXPECT_LT(err / n, 6.0);
  EXPECT_LT(err / n, 0.5 * err_off / n);

  // The server's way: the model's chunks without colours (as on the wire), the coloured mesh
  // handed separately (the geometry stage's full-resolution chunks), 1 cm off the proxy: the
  // same pixels take it (within vertex_color_depth_tol_m).
  LumigraphModel plain = model;
  plain.chunks[1].mesh.colors.clear();
  auto r_plain = CompleteView(plain, cam, pose, Options());
  ASSERT_TRUE(r_plain.ok()) << r_plain.status();
  EXPECT_EQ(r_plain->before.fused_color_px, 0);
  TriangleMesh separate = mesh;
  for (glm::vec3& p : separate.positions) p.z += 0.01f;
  auto r_sep = CompleteView(plain, cam, pose, Options(), &separate);
  ASSERT_TRUE(r_sep.ok()) << r_sep.status();
  // (720 of 840 measured: the shifted mesh's edge at x = 0.6 m projects a few columns inwards)
  EXPECT_GE(r_sep->before.fused_color_px, h.surface_hole_px * 8 / 10);
  CompletionOptions tight = Options();
  tight.vertex_color_depth_tol_m = 0.0;  // 1 cm off at 2 m is beyond 0.1 % of the depth
  auto r_tight = CompleteView(plain, cam, pose, tight, &separate);
  ASSERT_TRUE(r_tight.ok()) << r_tight.status();
  EXPECT_EQ(r_tight->before.fused_color_px, 0);
}

TEST(Completion, NothingToCompleteWhereTheViewsSeeEverything) {
  const LumigraphModel model = WallModel();
  auto r = CompleteView(model, SmallCamera(), At(-0.6), Options());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_FALSE(r->completed);
  EXPECT_EQ(r->before.hole_px, 0);
  EXPECT_TRUE(r->view.color.empty());
  // A hole below min_hole_px is negligible too (2 cm sideways: a sliver past the views).
  CompletionOptions o = Options();
  o.min_hole_px = 500;
  auto slight = CompleteView(model, SmallCamera(), At(-0.58), o);
  ASSERT_TRUE(slight.ok()) << slight.status();
  EXPECT_GT(slight->before.hole_px, 0);
  EXPECT_LT(slight->before.hole_px, o.min_hole_px);
  EXPECT_FALSE(slight->completed);
}

TEST(Completion, NoSourceIsAClearStatus) {
  const LumigraphModel model = WallModel();
  Rigid3d away = At(0.0);
  away.rotation = glm::angleAxis(M_PI, glm::dvec3(0, 1, 0));  // looks at -z: nothing modelled
  auto r = CompleteView(model, SmallCamera(), away, Options());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kFailedPrecondition) << r.status();
  EXPECT_NE(std::string(r.status().message()).find("nothing modelled"), std::string::npos);
  // An empty model too.
  auto e = CompleteView(LumigraphModel{}, SmallCamera(), At(0.0), Options());
  ASSERT_FALSE(e.ok());
  EXPECT_EQ(e.status().code(), absl::StatusCode::kFailedPrecondition);
}

TEST(Completion, BadInput) {
  const LumigraphModel model = WallModel();
  Rigid3d nan = At(0.0);
  nan.translation.x = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(CompleteView(model, SmallCamera(), nan, Options()).status().code(),
            absl::StatusCode::kInvalidArgument);
  Rigid3d skew = At(0.0);
  skew.rotation = glm::dquat(2.0, 0.0, 0.0, 0.0);  // not unit
  EXPECT_EQ(CompleteView(model, SmallCamera(), skew, Options()).status().code(),
            absl::StatusCode::kInvalidArgument);
  PinholeCamera bad = SmallCamera();
  bad.fx = -1;
  EXPECT_EQ(CompleteView(model, bad, At(0.0), Options()).status().code(),
            absl::StatusCode::kInvalidArgument);
  CompletionOptions o = Options();
  o.mesh_step_px = 0;
  EXPECT_EQ(CompleteView(model, SmallCamera(), At(0.0), o).status().code(),
            absl::StatusCode::kInvalidArgument);
  for (double g : {std::numeric_limits<double>::quiet_NaN(), 5.0}) {
    o = Options();
    o.detail_gain = g;
    EXPECT_EQ(CompleteView(model, SmallCamera(), At(0.0), o).status().code(),
              absl::StatusCode::kInvalidArgument);
  }
  o = Options();
  o.detail_sigma_px = 0.0;
  EXPECT_EQ(CompleteView(model, SmallCamera(), At(0.0), o).status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(Completion, MeshFromDepthSkipsJumpsAndUnmaskedParts) {
  const PinholeCamera cam = SmallCamera(40, 30);
  ImageF depth(40, 30, 1, 2.0f);
  for (int y = 0; y < 30; ++y)
    for (int x = 20; x < 40; ++x) depth.at(x, y) = 1.0f;  // an occlusion edge at x = 20
  ImageU8 mask(40, 30, 1, 255);
  const TriangleMesh m = MeshFromDepth(depth, mask, cam, Rigid3d{}, 4, 0.1);
  ASSERT_FALSE(m.empty());
  for (uint32_t i = 0; i < m.indices.size(); i += 3) {
    const float z0 = m.positions[m.indices[i]].z, z1 = m.positions[m.indices[i + 1]].z,
                z2 = m.positions[m.indices[i + 2]].z;
    EXPECT_FLOAT_EQ(z0, z1);  // no triangle across the edge
    EXPECT_FLOAT_EQ(z1, z2);
  }
  EXPECT_TRUE(MeshFromDepth(depth, ImageU8(40, 30, 1, 0), cam, Rigid3d{}, 4, 0.1).empty());
}

}  // namespace
}  // namespace exo::inpainting
