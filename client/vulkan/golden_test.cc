// Golden tests: the same frames through the CPU reference (common/lumigraph/cpu_renderer, the
// oracle) and the Vulkan path must agree on both synthetic scenes; plus the hard cases of
// SPEC §11 that touch the client renderer. On failure, actual/expected/diff PNGs are written to
// the build tree (<build>/client/vulkan/golden_out/).
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <optional>

#include <gtest/gtest.h>

#include "client/vulkan/vulkan_renderer.h"
#include "common/io/image_file.h"
#include "common/lumigraph/cpu_renderer.h"
#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace exo {
namespace {

constexpr int kW = 128, kH = 96;

struct Fixture {
  synth::SynthScene scene;
  LumigraphModel model;
  std::vector<Rigid3d> novel;
  PinholeCamera camera;
};

// Model: 2 of every 3 trajectory frames become stored views (the 3rd is a novel pose), the scene mesh is the proxy (one chunk
// per ~2000 triangles), refs = the views whose rendered cell-id buffer sees the cell (<= 16).
// eye_level_sky (village): instead of the fly-over (which looks 40 degrees down and barely sees
// sky), 60 eye-level poses along a street looking slightly up, the yaw sweeping 1.5 turns: about
// a third of each frame is sky, the case of the background-at-infinity pass.
absl::StatusOr<Fixture> MakeFixture(synth::SceneKind kind, bool eye_level_sky = false) {
  Fixture f;
  EXO_ASSIGN_OR_RETURN(f.scene, synth::MakeScene(kind, synth::SceneOptions{}));
  synth::RenderOptions ro;
  ro.width = kW;
  ro.height = kH;
  f.camera = ro.Camera();
  synth::TrajectoryOptions to;
  to.num_frames = 60;  // 40 stored views: many cells have more references than n = 3
  const auto tk = kind == synth::SceneKind::kVillage ? synth::TrajectoryKind::kFlyover
                                                     : synth::TrajectoryKind::kWalk;
  EXO_ASSIGN_OR_RETURN(auto traj, synth::MakeTrajectory(f.scene, tk, to));
  if (eye_level_sky) {
    const auto& nav = f.scene.navigable;
    glm::dvec3 eye = 0.5 * (nav.min + nav.max);
    eye.z = nav.min.z + 0.6;
    for (double dx = 0.0; !f.scene.IsFree(eye, 1.0) && dx < 40.0; dx += 0.7)
      eye.x = nav.min.x + 3.0 + dx;
    if (!f.scene.IsFree(eye, 1.0)) return absl::InternalError("no free eye-level position");
    for (size_t i = 0; i < traj.size(); ++i) {
      const double yaw = 3.0 * M_PI * double(i) / double(traj.size());
      const glm::dvec3 e = eye + glm::dvec3(0.02 * double(i), 0.01 * double(i), 0.1 * std::sin(yaw));
      traj[i].local_from_cam =
          synth::LookAt(e, e + glm::dvec3(std::cos(yaw), std::sin(yaw), 0.25 + 0.1 * std::cos(yaw)));
    }
  }
  f.model.grid.cell_size_m = std::max(0.3, f.scene.ExtentM() / 60.0);
  f.model.origin = f.scene.origin;
  // The synthetic scenes have floors/walls on integer coordinates, i.e. exactly on cell
  // boundaries, where float (GPU) and double (CPU) interpolation of the surface point round to
  // different cells. Shift the whole local frame (proxy and every pose) off the grid.
  const glm::dvec3 shift(0.0371, 0.0529, 0.0613);
  for (auto& p : f.scene.mesh.positions) p += glm::vec3(shift);
  for (auto& tp : traj) tp.local_from_cam.translation += shift;
  const TriangleMesh& mesh = f.scene.mesh;
  const size_t per_chunk = 2000;
  for (size_t t0 = 0, id = 0; t0 < mesh.num_triangles(); t0 += per_chunk, ++id) {
    MeshChunk c;
    c.id = id;
    c.version = 1;
    const size_t t1 = std::min(mesh.num_triangles(), t0 + per_chunk);
    for (size_t t = t0; t < t1; ++t)
      for (int k = 0; k < 3; ++k) {
        c.mesh.indices.push_back(uint32_t(c.mesh.positions.size()));
        c.mesh.positions.push_back(mesh.positions[mesh.indices[3 * t + k]]);
      }
    f.model.chunks[id] = std::move(c);
  }
  for (size_t i = 0; i < traj.size(); ++i) {
    if (i % 3 == 1) {
      f.novel.push_back(traj[i].local_from_cam);
      continue;
    }
    EXO_ASSIGN_OR_RETURN(auto frame, synth::RenderFrame(f.scene, traj[i].local_from_cam, ro));
    StoredView v;
    v.id = ViewId(100 + i);
    v.camera = frame.frame.color_camera;
    v.local_from_cam = traj[i].local_from_cam;
    v.color = frame.frame.color;
    v.depth_m = frame.frame.depth_m;
    v.exposure = (i % 2) ? 1.25f : 0.8f;  // exercise the exposure factor
    RasterOptions rop;
    rop.cell_id = true;
    rop.cell_grid = f.model.grid;
    EXO_ASSIGN_OR_RETURN(auto r, Rasterize(mesh, v.camera, v.local_from_cam, rop));
    for (CellId c : r.cell_id.span()) {
      if (c == kNoCell) continue;
      auto& refs = f.model.cell_refs[c];
      if (refs.size() < 16 && (refs.empty() || refs.back() != v.id)) refs.push_back(v.id);
    }
    f.model.views[v.id] = std::move(v);
  }
  return f;
}

// min_weight and both occlusion epsilons at their defaults (the Vulkan pipelines then bake them).
bool BlendOptionsHaveDefaultWeights(const blend::BlendOptions& bo) {
  const blend::BlendOptions d;
  return bo.min_weight == d.min_weight && bo.occlusion_epsilon_m == d.occlusion_epsilon_m &&
         bo.occlusion_epsilon_rel == d.occlusion_epsilon_rel;
}

int MaxDiff(const ImageU8& a, const ImageU8& b) {
  int m = 0;
  for (size_t i = 0; i < a.size(); ++i)
    m = std::max(m, std::abs(int(a.data()[i]) - int(b.data()[i])));
  return m;
}

struct Agreement {
  size_t compared = 0, within = 0, coverage_mismatch = 0, value_mismatch = 0;
  double psnr = 0;
  ImageU8 diff;
};

// Compared: pixels the CPU blended (coverage != 0) or filled at infinity (background != 0), and
// pixels the GPU blended (coverage 2) or filled at infinity (3). A pixel filled by one path and
// not the other (or blended by one and filled by the other) is a coverage mismatch.
Agreement Compare(const ImageU8& actual, const ImageU8& expected, const ImageU8& cpu_cov,
                  const ImageU8& gpu_cov, const ImageU8& cpu_bg) {
  Agreement a;
  a.diff = ImageU8(actual.width(), actual.height(), 3);
  double se = 0;
  for (int y = 0; y < actual.height(); ++y)
    for (int x = 0; x < actual.width(); ++x) {
      const bool cpu_blend = cpu_cov.at(x, y) != 0,
                 gpu_blend = gpu_cov.at(x, y) == 2 || gpu_cov.at(x, y) == 4;
      const bool cpu_fill = cpu_bg.at(x, y) != 0, gpu_fill = gpu_cov.at(x, y) == 3;
      if (!cpu_blend && !gpu_blend && !cpu_fill && !gpu_fill) continue;
      ++a.compared;
      int m = 0;
      for (int c = 0; c < 3; ++c) {
        const int d = std::abs(int(actual.at(x, y, c)) - int(expected.at(x, y, c)));
        m = std::max(m, d);
        se += double(d) * d;
        a.diff.at(x, y, c) = uint8_t(std::min(255, d * 16));
      }
      if (m <= 2) ++a.within;
      if (cpu_blend != gpu_blend || cpu_fill != gpu_fill) {
        ++a.coverage_mismatch;
        if (getenv("EXO_GOLDEN_DEBUG"))
          fprintf(stderr, "cov mismatch %d,%d cpu=%d gpu=%d\n", x, y, cpu_cov.at(x, y), gpu_cov.at(x, y));
      }
      else if (m > 2) ++a.value_mismatch;
    }
  const double mse = se / std::max<size_t>(1, 3 * a.compared);
  a.psnr = mse == 0 ? 99.0 : 10.0 * std::log10(255.0 * 255.0 / mse);
  return a;
}

void WriteFailure(const std::string& name, const ImageU8& actual, const ImageU8& expected,
                  const ImageU8& diff) {
  const std::string dir = std::filesystem::current_path().string() + "/golden_out";
  std::filesystem::create_directories(dir);
  (void)WriteColorImage(dir + "/" + name + "_actual.png", actual);
  (void)WriteColorImage(dir + "/" + name + "_expected.png", expected);
  (void)WriteColorImage(dir + "/" + name + "_diff.png", diff);
  ADD_FAILURE() << "wrote " << dir << "/" << name << "_{actual,expected,diff}.png";
}

class GoldenTest : public ::testing::TestWithParam<synth::SceneKind> {};

TEST_P(GoldenTest, VulkanMatchesCpuReference) {
  auto fx = MakeFixture(GetParam());
  ASSERT_TRUE(fx.ok()) << fx.status();
  // The best-n selection (and the shader's skip of references that cannot enter it) is only
  // exercised where a cell has more references than n = 3: require many such cells.
  size_t many = 0;
  for (const auto& [c, refs] : fx->model.cell_refs) many += refs.size() > 3;
  EXPECT_GT(many, fx->model.cell_refs.size() / 4) << "too few cells with > 3 references";
  fprintf(stderr, "[golden %s] %zu of %zu cells have > 3 references\n",
          synth::SceneKindName(GetParam()), many, fx->model.cell_refs.size());
  VulkanRendererOptions vo;
  vo.enable_validation = true;
  auto gpu = VulkanRenderer::Create(vo);
  ASSERT_TRUE(gpu.ok()) << gpu.status();
  ASSERT_TRUE((*gpu)->SyncModel(fx->model).ok());
  CpuRenderOptions co;
  auto cpu = CpuLumigraphRenderer::Create(fx->model, co);
  ASSERT_TRUE(cpu.ok()) << cpu.status();
  size_t compared = 0, within = 0;
  double min_psnr = 1e9;
  for (size_t i = 0; i < fx->novel.size(); i += 2) {
    auto e = (*cpu)->Render(fx->camera, fx->novel[i]);
    ASSERT_TRUE(e.ok()) << e.status();
    auto a = (*gpu)->Render(fx->camera, fx->novel[i], co.blend);
    ASSERT_TRUE(a.ok()) << a.status();
    const Agreement ag = Compare(a->color, e->color, e->coverage, a->coverage, e->background);
    compared += ag.compared;
    within += ag.within;
    min_psnr = std::min(min_psnr, ag.psnr);
    EXPECT_GE(ag.psnr, 40.0) << "frame " << i << ": " << ag.coverage_mismatch
                             << " coverage mismatches, " << ag.value_mismatch
                             << " value mismatches > 2/255 of " << ag.compared;
    if (ag.psnr < 40.0)
      WriteFailure(std::string(synth::SceneKindName(GetParam())) + "_" + std::to_string(i),
                   a->color, e->color, ag.diff);
  }
  EXPECT_GT(compared, size_t(kW * kH) * fx->novel.size() / 2 / 4) << "frames barely covered";
  const double frac = double(within) / std::max<size_t>(1, compared);
  fprintf(stderr, "[golden %s] %zu covered pixels, %.5f within 2/255, min PSNR %.1f dB\n",
          synth::SceneKindName(GetParam()), compared, frac, min_psnr);
  EXPECT_GE(frac, 0.999) << within << " of " << compared << " covered pixels within 2/255";
  const auto errs = (*gpu)->ValidationErrors();
  EXPECT_TRUE(errs.empty()) << errs.size() << " validation messages, first: " << errs[0];
}

// Other blend settings on the village fixture: every n of §3.1.4 (the shader is specialised per
// n, each a separate pipeline) and the printed positional weight with another lambda (the
// per-frame reference ranking bounds both positional modes). Same tolerance as above.
TEST(GoldenBlendOptionsTest, EveryNBestAndPositionalModeMatchCpuReference) {
  auto fx = MakeFixture(synth::SceneKind::kVillage);
  ASSERT_TRUE(fx.ok()) << fx.status();
  VulkanRendererOptions vo;
  vo.enable_validation = true;
  auto gpu = VulkanRenderer::Create(vo);
  ASSERT_TRUE(gpu.ok()) << gpu.status();
  ASSERT_TRUE((*gpu)->SyncModel(fx->model).ok());
  vo.blend_in_compute = true;  // the compute-dispatch blend (blend.comp), same tolerance
  auto gpu_cs = VulkanRenderer::Create(vo);
  ASSERT_TRUE(gpu_cs.ok()) << gpu_cs.status();
  ASSERT_TRUE((*gpu_cs)->SyncModel(fx->model).ok());
  // The last case keeps lambda 1 but changes min_weight and both occlusion epsilons: the
  // pipelines read them from the Frame block instead of the default values baked in as
  // specialisation constants (BlendVariant::default_weights); it must change the CPU reference
  // (checked below), so a GPU path that kept the baked defaults would fail it.
  struct Case {
    int n;
    blend::PositionalMode mode;
    float lambda;
    float min_weight = blend::BlendOptions{}.min_weight;
    float eps_m = blend::BlendOptions{}.occlusion_epsilon_m;
    float eps_rel = blend::BlendOptions{}.occlusion_epsilon_rel;
  };
  auto cpu_default = CpuLumigraphRenderer::Create(fx->model, CpuRenderOptions{});
  ASSERT_TRUE(cpu_default.ok()) << cpu_default.status();
  for (const Case& k : {Case{1, blend::PositionalMode::kUlrResolution, 0.5f},
                        Case{2, blend::PositionalMode::kPrinted, 0.3f},
                        Case{4, blend::PositionalMode::kUlrResolution, 0.8f},
                        Case{3, blend::PositionalMode::kUlrResolution, 1.0f, 0.2f, 0.005f, 0.0f}}) {
    CpuRenderOptions co;
    co.blend.n_best = k.n;
    co.blend.positional_mode = k.mode;
    co.blend.lambda = k.lambda;
    co.blend.min_weight = k.min_weight;
    co.blend.occlusion_epsilon_m = k.eps_m;
    co.blend.occlusion_epsilon_rel = k.eps_rel;
    const bool custom_weights = !BlendOptionsHaveDefaultWeights(co.blend);
    auto cpu = CpuLumigraphRenderer::Create(fx->model, co);
    ASSERT_TRUE(cpu.ok()) << cpu.status();
    size_t compared = 0, within = 0, changed_by_weights = 0;
    for (size_t i = 1; i < fx->novel.size(); i += 4) {
      auto e = (*cpu)->Render(fx->camera, fx->novel[i]);
      ASSERT_TRUE(e.ok()) << e.status();
      if (custom_weights) {
        auto d = (*cpu_default)->Render(fx->camera, fx->novel[i]);
        ASSERT_TRUE(d.ok()) << d.status();
        const Agreement ch = Compare(e->color, d->color, d->coverage, e->coverage, d->background);
        changed_by_weights += ch.compared - ch.within;
      }
      auto a = (*gpu)->Render(fx->camera, fx->novel[i], co.blend);
      ASSERT_TRUE(a.ok()) << a.status();
      const Agreement ag = Compare(a->color, e->color, e->coverage, a->coverage, e->background);
      compared += ag.compared;
      within += ag.within;
      EXPECT_GE(ag.psnr, 40.0) << "n " << k.n << " frame " << i;
      auto a_cs = (*gpu_cs)->Render(fx->camera, fx->novel[i], co.blend);
      ASSERT_TRUE(a_cs.ok()) << a_cs.status();
      const Agreement ag_cs = Compare(a_cs->color, e->color, e->coverage, a_cs->coverage, e->background);
      EXPECT_GE(double(ag_cs.within), 0.999 * double(ag_cs.compared)) << "compute, n " << k.n;
      EXPECT_GE(ag_cs.psnr, 40.0) << "compute, n " << k.n << " frame " << i;
      if (ag.psnr < 40.0)
        WriteFailure("village_n" + std::to_string(k.n) + "_" + std::to_string(i), a->color,
                     e->color, ag.diff);
    }
    const double frac = double(within) / std::max<size_t>(1, compared);
    fprintf(stderr,
            "[golden village n=%d mode=%d lambda=%.1f min_weight=%g eps=%g/%g] %zu px, %.5f "
            "within 2/255 (%zu px changed by the weights vs the defaults)\n",
            k.n, int(k.mode), k.lambda, k.min_weight, k.eps_m, k.eps_rel, compared, frac,
            changed_by_weights);
    if (custom_weights) EXPECT_GT(changed_by_weights, compared / 100) << "case not sensitive";
    EXPECT_GT(compared, size_t(kW * kH) / 4);
    EXPECT_GE(frac, 0.999) << "n " << k.n;
  }
  for (auto* r : {gpu->get(), gpu_cs->get()}) {
    const auto errs = r->ValidationErrors();
    EXPECT_TRUE(errs.empty()) << errs.size() << " validation messages, first: " << errs[0];
  }
}

// RenderApprox::max_candidates (the viewer window's moving frames): the references of a cell are
// ordered by an estimate (the weight at the cell centre; views that do not see it last) and at
// most K are evaluated. Not exact, so checked for closeness to the exact frame: K = 8 close
// (PSNR floor), K = 1 visibly different (the cap is applied), K < 0 rejected.
TEST(GoldenApproxTest, CandidateCapStaysCloseToTheExactBlend) {
  auto fx = MakeFixture(synth::SceneKind::kVillage);
  ASSERT_TRUE(fx.ok()) << fx.status();
  size_t max_refs = 0;
  for (const auto& [c, refs] : fx->model.cell_refs) max_refs = std::max(max_refs, refs.size());
  ASSERT_GT(max_refs, 8u);
  VulkanRendererOptions vo;
  vo.enable_validation = true;
  auto gpu = VulkanRenderer::Create(vo);
  ASSERT_TRUE(gpu.ok()) << gpu.status();
  ASSERT_TRUE((*gpu)->SyncModel(fx->model).ok());
  blend::BlendOptions bo;
  for (int cap : {8, 1}) {
    size_t changed = 0, covered = 0;
    double worst_psnr = 1e9;
    for (size_t i = 0; i < fx->novel.size(); i += 3) {
      auto exact = (*gpu)->Render(fx->camera, fx->novel[i], bo);
      ASSERT_TRUE(exact.ok()) << exact.status();
      auto capped = (*gpu)->Render(fx->camera, fx->novel[i], bo, {cap});
      ASSERT_TRUE(capped.ok()) << capped.status();
      const Agreement ag = Compare(capped->color, exact->color, exact->coverage,
                                   capped->coverage, exact->coverage);
      changed += ag.compared - ag.within;
      covered += ag.compared;
      worst_psnr = std::min(worst_psnr, ag.psnr);
    }
    fprintf(stderr, "[golden approx] cap %d (max refs %zu): %zu of %zu px differ by > 2/255, "
            "worst PSNR %.1f dB\n", cap, max_refs, changed, covered, worst_psnr);
    if (cap == 8) {
      EXPECT_GE(worst_psnr, 35.0);
    } else {
      EXPECT_GT(changed, covered / 20) << "a cap of 1 changed little: not applied?";
    }
  }
  // The exact blend is unchanged by an approximate frame before it.
  auto a = (*gpu)->Render(fx->camera, fx->novel[0], bo);
  ASSERT_TRUE((*gpu)->Render(fx->camera, fx->novel[0], bo, {1}).ok());
  auto b = (*gpu)->Render(fx->camera, fx->novel[0], bo);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(MaxDiff(a->color, b->color), 0);
  EXPECT_FALSE((*gpu)->Render(fx->camera, fx->novel[0], bo, {-1}).ok());
  const auto errs = (*gpu)->ValidationErrors();
  EXPECT_TRUE(errs.empty()) << errs.size() << " validation messages, first: " << errs[0];
}

// Background at infinity (sky) on eye-level village views with a third of the frame sky: CPU and
// Vulkan must agree on the per-frame background view list, on which pixels are filled, and on
// their colour (same tolerance as the surface blend), in the fragment and the compute path; with
// the option off the GPU leaves them at the background colour (coverage 0) as before.
TEST(GoldenBackgroundTest, VillageSkyMatchesCpuReference) {
  auto fx = MakeFixture(synth::SceneKind::kVillage, /*eye_level_sky=*/true);
  ASSERT_TRUE(fx.ok()) << fx.status();
  VulkanRendererOptions vo;
  vo.enable_validation = true;
  auto gpu = VulkanRenderer::Create(vo);
  ASSERT_TRUE(gpu.ok()) << gpu.status();
  ASSERT_TRUE((*gpu)->SyncModel(fx->model).ok());
  vo.blend_in_compute = true;
  auto gpu_cs = VulkanRenderer::Create(vo);
  ASSERT_TRUE(gpu_cs.ok()) << gpu_cs.status();
  ASSERT_TRUE((*gpu_cs)->SyncModel(fx->model).ok());
  CpuRenderOptions co;
  auto cpu = CpuLumigraphRenderer::Create(fx->model, co);
  ASSERT_TRUE(cpu.ok()) << cpu.status();
  size_t compared = 0, within = 0, filled = 0, mismatched = 0, sky_equal = 0, sky_px = 0;
  double listed_views = 0;
  for (size_t i = 0; i < fx->novel.size(); i += 2) {
    auto e = (*cpu)->Render(fx->camera, fx->novel[i]);
    ASSERT_TRUE(e.ok()) << e.status();
    std::optional<RenderResult> fragment;
    for (auto* r : {gpu->get(), gpu_cs->get()}) {
      auto a = r->Render(fx->camera, fx->novel[i], co.blend);
      ASSERT_TRUE(a.ok()) << a.status();
      // The fragment path walks each 16x16 tile's culled background-view list
      // (FrameRenderer::BuildSkyDraws), the compute path every view: same pixels at infinity.
      if (r == gpu->get()) {
        listed_views += a->sky_views_per_px;
        fragment = *a;
      } else {
        for (int y = 0; y < kH; ++y)
          for (int x = 0; x < kW; ++x) {
            if (a->coverage.at(x, y) != 3 && fragment->coverage.at(x, y) != 3) continue;
            ++sky_px;
            bool same = a->coverage.at(x, y) == fragment->coverage.at(x, y);
            for (int c = 0; c < 3; ++c) same &= a->color.at(x, y, c) == fragment->color.at(x, y, c);
            sky_equal += same;
          }
      }
      // The CPU reference skips the selection when no pixel lacks a proxy surface; the GPU
      // selects before it knows (the list is then unused).
      if (e->background_pixels > 0 || !e->background_views.empty()) {
        EXPECT_EQ(a->background_views, e->background_views) << "frame " << i;
      }
      const Agreement ag = Compare(a->color, e->color, e->coverage, a->coverage, e->background);
      compared += ag.compared;
      within += ag.within;
      mismatched += ag.coverage_mismatch;
      EXPECT_GE(ag.psnr, 40.0) << "frame " << i;
      if (ag.psnr < 40.0)
        WriteFailure("village_sky_" + std::to_string(i), a->color, e->color, ag.diff);
    }
    filled += 2 * e->background_pixels;
  }
  const double frac = double(within) / std::max<size_t>(1, compared);
  fprintf(stderr,
          "[golden village sky] %zu compared px (%zu filled at infinity), %.5f within 2/255, "
          "%zu coverage mismatches\n",
          compared, filled, frac, mismatched);
  EXPECT_GT(filled, compared / 5) << "too little sky to test the pass";
  // Tile lists exact (every sky pixel as with all views) and not trivial (views were culled).
  const double mean_listed = listed_views / double((fx->novel.size() + 1) / 2);
  fprintf(stderr, "[golden village sky] tile lists: %.2f views per pixel, %zu / %zu sky px equal\n",
          mean_listed, sky_equal, sky_px);
  EXPECT_EQ(sky_equal, sky_px);
  EXPECT_LT(mean_listed, 0.9 * co.blend.background_views);
  EXPECT_GE(frac, 0.999);
  EXPECT_LE(double(mismatched), 0.001 * double(compared));
  // Off: no pixel filled at infinity, every no-surface pixel at the background colour.
  blend::BlendOptions off = co.blend;
  off.background_views = 0;
  off.fill_holes = false;  // the raw output of the pass being switched off
  auto a = (*gpu)->Render(fx->camera, fx->novel[0], off);
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_TRUE(a->background_views.empty());
  size_t no_surface = 0;
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      ASSERT_NE(a->coverage.at(x, y), 3);
      if (a->coverage.at(x, y) != 0) continue;
      ++no_surface;
      for (int c = 0; c < 3; ++c) ASSERT_EQ(a->color.at(x, y, c), 0);
    }
  EXPECT_GT(no_surface, size_t(kW * kH / 10));
  // Hole fill (BlendOptions::fill_holes) without the sky pass: the no-surface pixels are filled
  // on the host from the read-back frame by the CPU oracle's FillHoles, so the two agree there
  // as closely as on the blended pixels they are filled from.
  {
    blend::BlendOptions fill = off;
    fill.fill_holes = true;
    CpuRenderOptions cf = co;
    cf.blend = fill;
    auto e = CpuLumigraphRenderer::Create(fx->model, cf).value()->Render(fx->camera, fx->novel[0]);
    ASSERT_TRUE(e.ok()) << e.status();
    auto g = (*gpu)->Render(fx->camera, fx->novel[0], fill);
    ASSERT_TRUE(g.ok()) << g.status();
    EXPECT_EQ(g->filled_pixels, e->filled_pixels);
    EXPECT_GE(e->filled_pixels, no_surface);
    size_t filled_px = 0, filled_within = 0, changed = 0;
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x) {
        if (e->coverage.at(x, y) != 0) continue;
        ++filled_px;
        int d = 0;
        for (int c = 0; c < 3; ++c) {
          d = std::max(d, std::abs(int(g->color.at(x, y, c)) - int(e->color.at(x, y, c))));
          changed += g->color.at(x, y, c) != 0;
        }
        filled_within += d <= 2;
      }
    fprintf(stderr, "[golden hole fill] %zu filled px, %.5f within 2/255\n", filled_px,
            double(filled_within) / std::max<size_t>(1, filled_px));
    EXPECT_GT(changed, filled_px);  // the holes no longer hold the background colour
    EXPECT_GE(double(filled_within), 0.99 * double(filled_px));
  }
  for (auto* r : {gpu->get(), gpu_cs->get()}) {
    const auto errs = r->ValidationErrors();
    EXPECT_TRUE(errs.empty()) << errs.size() << " validation messages, first: " << errs[0];
  }
}

INSTANTIATE_TEST_SUITE_P(Scenes, GoldenTest,
                         ::testing::Values(synth::SceneKind::kVillage,
                                           synth::SceneKind::kApartment),
                         [](const auto& info) {
                           return std::string(synth::SceneKindName(info.param));
                         });

}  // namespace
}  // namespace exo

namespace exo {
namespace {

// InpaintFusion (SPEC §7, 4.17-4.18): inpainted keyframes at three stored poses (colour inverted
// so that their contribution is visible, a ROI rectangle in the centre as labels). Inside a
// keyframe's ROI only inpainted keyframes contribute, outside only observations: CPU reference
// and Vulkan must agree as on the plain scenes, and the ROI must actually change pixels.
// The label rule's depth check (blend_math.h InpaintedLabelHolds, blend_shade.glsl): a label
// holds only where the surface point is not behind the keyframe's own surface. `depth_scale`
// scales the keyframes' depth: 1 = their true surface; 0.7 = a surface in front of everything the
// proxy has, so every point is behind it and no label holds (the render equals the one without
// inpainted views); 1.4 = behind everything, so every label holds (DR: a removed object in front
// of the keyframe's background is replaced).
void InpaintedKeyframesMatchCpuReference(float depth_scale) {
  auto fx = MakeFixture(synth::SceneKind::kApartment);
  ASSERT_TRUE(fx.ok()) << fx.status();
  CpuRenderOptions co;
  auto plain = CpuLumigraphRenderer::Create(fx->model, co);
  ASSERT_TRUE(plain.ok()) << plain.status();
  int k = 0;
  std::vector<StoredView> added;
  for (const auto& [id, v] : fx->model.views) {
    if (k++ % 12 != 3) continue;
    StoredView ip = v;
    ip.id = 0x40000000u + id;
    ip.inpainted = true;
    for (uint8_t& c : ip.color.span()) c = uint8_t(255 - c);
    for (float& z : ip.depth_m.span()) z *= depth_scale;
    ip.labels = ImageU8(kW, kH, 1, 0);
    for (int y = kH / 4; y < 3 * kH / 4; ++y)
      for (int x = kW / 4; x < 3 * kW / 4; ++x) ip.labels.at(x, y) = 255;
    added.push_back(std::move(ip));
  }
  ASSERT_GE(added.size(), 3u);
  for (auto& ip : added) fx->model.views[ip.id] = std::move(ip);
  VulkanRendererOptions vo;
  vo.enable_validation = true;
  auto gpu = VulkanRenderer::Create(vo);
  ASSERT_TRUE(gpu.ok()) << gpu.status();
  ASSERT_TRUE((*gpu)->SyncModel(fx->model).ok());
  auto cpu = CpuLumigraphRenderer::Create(fx->model, co);
  ASSERT_TRUE(cpu.ok()) << cpu.status();
  size_t compared = 0, within = 0, changed = 0, ip_cpu = 0, ip_both = 0, ip_gpu = 0;
  for (size_t i = 0; i < fx->novel.size(); i += 2) {
    auto e = (*cpu)->Render(fx->camera, fx->novel[i]);
    ASSERT_TRUE(e.ok()) << e.status();
    auto p = (*plain)->Render(fx->camera, fx->novel[i]);
    ASSERT_TRUE(p.ok());
    for (size_t j = 0; j < e->color.size(); ++j) changed += e->color.data()[j] != p->color.data()[j];
    auto a = (*gpu)->Render(fx->camera, fx->novel[i], co.blend);
    ASSERT_TRUE(a.ok()) << a.status();
    const Agreement ag = Compare(a->color, e->color, e->coverage, a->coverage, e->background);
    compared += ag.compared;
    within += ag.within;
    EXPECT_GE(ag.psnr, 40.0) << "frame " << i << ": " << ag.coverage_mismatch
                             << " coverage mismatches, " << ag.value_mismatch << " of "
                             << ag.compared;
    if (ag.psnr < 40.0) WriteFailure("inpainted_" + std::to_string(i), a->color, e->color, ag.diff);
    // The pixels blended from inpainted views (the window's tint): CPU mask vs GPU code 4.
    for (size_t j = 0; j < e->inpainted.size(); ++j) {
      const bool c = e->inpainted.data()[j] != 0, g = a->coverage.data()[j] == 4;
      ip_cpu += c;
      ip_gpu += g;
      ip_both += c && g;
    }
  }
  fprintf(stderr, "[golden inpainted, depth x%.1f] blended from inpainted views: %zu px (CPU), "
          "%zu (GPU), %zu both\n", depth_scale, ip_cpu, ip_gpu, ip_both);
  EXPECT_GE(double(ip_both), 0.999 * double(std::max(ip_cpu, ip_gpu)));
  if (depth_scale >= 1.0f) EXPECT_GT(ip_cpu, size_t(kW * kH / 10));
  const double frac = double(within) / std::max<size_t>(1, compared);
  fprintf(stderr, "[golden inpainted, depth x%.1f] %zu px, %.5f within 2/255, %zu channel values "
          "changed by ROIs\n", depth_scale, compared, frac, changed);
  if (depth_scale < 1.0f)  // every point behind the keyframes' surface: no label holds (what
    // still changes: proxy points 26 % nearer than the stored depth at depth edges; 219 of
    // 363 315 channel values measured, against 97 929 at x1.0)
    EXPECT_LT(changed * 100, compared * 3);
  else
    EXPECT_GT(changed, size_t(kW * kH));  // the ROIs took effect
  EXPECT_GE(frac, 0.999);
  const auto errs = (*gpu)->ValidationErrors();
  EXPECT_TRUE(errs.empty()) << errs.size() << " validation messages, first: " << errs[0];
}

TEST(GoldenInpaintedTest, InpaintedKeyframesMatchCpuReference) {
  InpaintedKeyframesMatchCpuReference(1.0f);
}
TEST(GoldenInpaintedTest, KeyframeSurfaceInFrontOfEverythingClaimsNothing) {
  InpaintedKeyframesMatchCpuReference(0.7f);
}
TEST(GoldenInpaintedTest, KeyframeSurfaceBehindEverythingClaimsItsWholeRoi) {
  InpaintedKeyframesMatchCpuReference(1.4f);
}

}  // namespace
}  // namespace exo
