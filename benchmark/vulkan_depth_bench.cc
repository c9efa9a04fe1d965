// vulkan_depth_bench: should stored views carry SENSOR depth for the occlusion test (3.4), or
// should the client render each view's depth from the proxy mesh? Measures both on a synthetic
// scene where the truth is known:
//   sensor depth = the synthetic z-depth with a Kinect-like axial noise model
//                  sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 m (Nguyen et al. 2012) and 3 % dropout
//   proxy        = TSDF (server/geometry) fused from those sensor depths, marching-cubes mesh
//   proxy depth  = VulkanRenderer::RenderProxyDepth of that mesh from each stored view
// and prints, per variant, SSIM / PSNR of the blended novel views against ground truth, plus
// the cost of the proxy-depth pass per view (what every proxy update would cost per affected
// view). Usage: LP_NUM_THREADS=2 vulkan_depth_bench [--scene=apartment|village] [--views=40]
//   [--frames=8] [--voxel=0.04] (--help lists the flags).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "client/vulkan/vulkan_renderer.h"
#include "common/cli/cli.h"
#include "common/metrics/metrics.h"
#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/geometry/tsdf_volume.h"

using namespace exo;

int main(int argc, char** argv) {
  std::string scene_name = "apartment";
  int max_views = 40, frames = 8;
  double voxel = 0.04;
  CLI::App app{"Sensor depth vs proxy depth for the client's occlusion test: SSIM / PSNR of "
               "blended novel views against ground truth, and the proxy-depth pass cost per view "
               "(JSON on stdout).",
               "vulkan_depth_bench"};
  cli::Setup(app);
  app.add_option("--scene", scene_name, "synthetic scene (apartment|village)")->capture_default_str();
  app.add_option("--views", max_views, "stored views")->check(CLI::Range(2, 100000))
      ->capture_default_str();
  app.add_option("--frames", frames, "novel frames rendered")->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--voxel", voxel, "TSDF voxel size of the proxy (m)")
      ->check(CLI::Range(0.005, 1.0))->capture_default_str();
  if (auto rc = cli::Parse(app, argc, argv)) return *rc;
  auto kind = synth::ParseSceneKind(scene_name);
  if (!kind.ok()) {
    std::fprintf(stderr, "vulkan_depth_bench: %s\n", kind.status().ToString().c_str());
    return 2;
  }
  auto scene = synth::MakeScene(*kind, {});
  if (!scene.ok()) { std::fprintf(stderr, "%s\n", scene.status().ToString().c_str()); return 1; }
  synth::RenderOptions vro;  // stored views 320x240
  vro.width = 320; vro.height = 240;
  synth::TrajectoryOptions to;
  to.num_frames = 2 * max_views;
  auto traj = synth::MakeTrajectory(*scene, scene->indoor ? synth::TrajectoryKind::kWalk
                                                         : synth::TrajectoryKind::kFlyover, to);
  if (!traj.ok()) { std::fprintf(stderr, "%s\n", traj.status().ToString().c_str()); return 1; }

  TsdfOptions topt;
  topt.voxel_size_m = float(voxel);
  topt.max_depth_m = scene->indoor ? 6.0f : 60.0f;
  TsdfVolume tsdf(topt);
  std::mt19937 rng(7);
  LumigraphModel model;
  model.grid.cell_size_m = std::max(0.3, scene->ExtentM() / 40.0);
  std::vector<Rigid3d> novel;
  for (size_t i = 0; i < traj->size(); ++i) {
    const Rigid3d& pose = (*traj)[i].local_from_cam;
    if (i % 2 == 1) { if (int(novel.size()) < frames) novel.push_back(pose); continue; }
    auto f = synth::RenderFrame(*scene, pose, vro);
    if (!f.ok()) return 1;
    StoredView v;
    v.id = ViewId(i);
    v.camera = f->frame.color_camera;
    v.local_from_cam = pose;
    v.color = f->frame.color;
    v.depth_m = f->frame.depth_m;
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::normal_distribution<float> n01(0.0f, 1.0f);
    for (float& z : v.depth_m.span()) {
      if (!(z > 0.0f)) continue;
      if (u(rng) < 0.03f) { z = 0.0f; continue; }
      const float sigma = 0.0012f + 0.0019f * (z - 0.4f) * (z - 0.4f);
      z = std::max(0.0f, z + sigma * n01(rng));
    }
    auto st = tsdf.IntegrateDepth(v.depth_m, v.camera, v.local_from_cam, &v.color);
    if (!st.ok()) { std::fprintf(stderr, "%s\n", st.status().ToString().c_str()); return 1; }
    model.views[v.id] = std::move(v);
  }
  MeshChunk chunk;
  chunk.id = 0;
  chunk.version = 1;
  chunk.mesh = tsdf.ExtractAll();
  chunk.mesh.normals.clear();
  chunk.mesh.colors.clear();
  model.chunks[0] = chunk;
  // References: every stored view that sees a cell (through the proxy), at most 16.
  for (const auto& [id, v] : model.views) {
    RasterOptions rop; rop.cell_id = true; rop.cell_grid = model.grid; rop.width = 80; rop.height = 60;
    auto r = Rasterize(chunk.mesh, v.camera, v.local_from_cam, rop);
    if (!r.ok()) return 1;
    for (CellId c : r->cell_id.span()) if (c != kNoCell) {
      auto& refs = model.cell_refs[c];
      if (refs.size() < 16 && (refs.empty() || refs.back() != id)) refs.push_back(id);
    }
  }
  VulkanRendererOptions vo;
  auto rr = VulkanRenderer::Create(vo);
  if (!rr.ok()) { std::fprintf(stderr, "%s\n", rr.status().ToString().c_str()); return 1; }
  auto& r = *rr;
  // Proxy depth of every view (timed) into a second model.
  if (!r->SyncModel(model).ok()) return 1;
  LumigraphModel proxy_model = model;
  std::vector<double> depth_ms;
  double mae_sensor = 0, mae_proxy = 0;
  size_t n_cmp = 0;
  for (auto& [id, v] : proxy_model.views) {
    const auto t0 = std::chrono::steady_clock::now();
    auto d = r->RenderProxyDepth(v.camera, v.local_from_cam);
    depth_ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    if (!d.ok()) return 1;
    auto truth = synth::RenderFrame(*scene, v.local_from_cam, vro);
    if (!truth.ok()) return 1;
    for (size_t k = 0; k < d->size(); ++k) {
      const float t = truth->frame.depth_m.data()[k], s = model.views.at(id).depth_m.data()[k], p = d->data()[k];
      if (t > 0 && s > 0 && p > 0) { mae_sensor += std::abs(s - t); mae_proxy += std::abs(p - t); ++n_cmp; }
    }
    v.depth_m = std::move(*d);
  }
  std::sort(depth_ms.begin(), depth_ms.end());
  synth::RenderOptions gro;  // 640x480 novel views
  const PinholeCamera cam = gro.Camera();
  for (int variant = 0; variant < 2; ++variant) {
    const LumigraphModel& m = variant == 0 ? model : proxy_model;
    if (!r->SyncModel(m).ok()) return 1;
    double ssim = 0, psnr = 0;
    std::vector<double> ms;
    for (const Rigid3d& pose : novel) {
      const auto t0 = std::chrono::steady_clock::now();
      auto out = r->Render(cam, pose, blend::BlendOptions{});
      ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      if (!out.ok()) return 1;
      auto gt = synth::RenderFrame(*scene, pose, gro);
      if (!gt.ok()) return 1;
      auto s = Ssim(out->color, gt->frame.color);
      auto p = Psnr(out->color, gt->frame.color);
      ssim += s.ok() ? *s : 0;
      psnr += p.ok() ? *p : 0;
    }
    std::sort(ms.begin(), ms.end());
    std::printf("{\"bench\":\"vulkan_depth\",\"scene\":\"%s\",\"occlusion_depth\":\"%s\",\"views\":%zu,"
                "\"proxy_triangles\":%zu,\"voxel_m\":%.3f,\"novel_frames\":%zu,\"ssim\":%.4f,\"psnr_db\":%.2f,"
                "\"median_render_ms\":%.1f,\"depth_mae_vs_truth_m\":%.4f,"
                "\"proxy_depth_ms_per_view_median\":%.2f,\"proxy_depth_ms_per_view_max\":%.2f}\n",
                scene_name.c_str(), variant == 0 ? "sensor" : "proxy", model.views.size(),
                chunk.mesh.num_triangles(), voxel, novel.size(), ssim / novel.size(),
                psnr / novel.size(), ms[ms.size() / 2],
                (variant == 0 ? mae_sensor : mae_proxy) / std::max<size_t>(1, n_cmp),
                depth_ms[depth_ms.size() / 2], depth_ms.back());
    std::fflush(stdout);
  }
  return 0;
}
