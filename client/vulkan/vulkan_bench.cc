// vulkan_bench: ms per frame of the Vulkan lumigraph blend on lavapipe at 640x480, 1280x720 and
// 1920x1080 for 8/16/32/60 references per cell (village scene, stored views rendered by
// common/synth), first frame (shader JIT) separately, and SSIM of each configuration against the
// synthetic ground truth, one JSON object per configuration. Usage:
//   LP_NUM_THREADS=2 vulkan_bench [frames_per_config=5] [max_views=60]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>

#include "client/vulkan/vulkan_renderer.h"
#include "common/metrics/metrics.h"
#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

using namespace exo;

int main(int argc, char** argv) {
  const int frames = argc > 1 ? std::atoi(argv[1]) : 5;
  const int max_views = argc > 2 ? std::atoi(argv[2]) : 60;
  auto scene = synth::MakeScene(synth::SceneKind::kVillage, {});
  if (!scene.ok()) { fprintf(stderr, "%s\n", scene.status().ToString().c_str()); return 1; }
  synth::RenderOptions vro;  // stored views 320x240 (kept small: the bench measures the client)
  vro.width = 320; vro.height = 240;
  synth::TrajectoryOptions to;
  to.num_frames = max_views + 2 * frames;
  auto traj = synth::MakeTrajectory(*scene, synth::TrajectoryKind::kFlyover, to);
  if (!traj.ok()) { fprintf(stderr, "%s\n", traj.status().ToString().c_str()); return 1; }
  LumigraphModel model;
  model.grid.cell_size_m = std::max(0.3, scene->ExtentM() / 60.0);
  MeshChunk chunk; chunk.id = 0; chunk.version = 1; chunk.mesh = scene->mesh;
  model.chunks[0] = chunk;
  std::vector<Rigid3d> novel;
  std::unordered_map<CellId, std::vector<ViewId>> all_refs;
  for (size_t i = 0; i < traj->size(); ++i) {
    if (i % 2 == 1 && int(novel.size()) < frames) { novel.push_back((*traj)[i].local_from_cam); continue; }
    if (int(model.views.size()) >= max_views) continue;
    auto f = synth::RenderFrame(*scene, (*traj)[i].local_from_cam, vro);
    if (!f.ok()) return 1;
    StoredView v; v.id = ViewId(i); v.camera = f->frame.color_camera;
    v.local_from_cam = (*traj)[i].local_from_cam; v.color = f->frame.color; v.depth_m = f->frame.depth_m;
    RasterOptions rop; rop.cell_id = true; rop.cell_grid = model.grid; rop.width = 80; rop.height = 60;
    auto r = Rasterize(scene->mesh, v.camera, v.local_from_cam, rop);
    if (!r.ok()) return 1;
    for (CellId c : r->cell_id.span()) if (c != kNoCell) {
      auto& refs = all_refs[c];
      if (refs.empty() || refs.back() != v.id) refs.push_back(v.id);
    }
    model.views[v.id] = std::move(v);
  }
  const int sizes[3][2] = {{640, 480}, {1280, 720}, {1920, 1080}};
  for (int n_refs : {8, 16, 32, 60}) {
    model.cell_refs.clear();
    for (auto& [c, refs] : all_refs)
      model.cell_refs[c] = std::vector<ViewId>(refs.begin(), refs.begin() + std::min<size_t>(refs.size(), n_refs));
    for (auto& sz : sizes) {
      VulkanRendererOptions vo; vo.max_refs_per_cell = 60;
      auto rr = VulkanRenderer::Create(vo);
      if (!rr.ok()) { fprintf(stderr, "%s\n", rr.status().ToString().c_str()); return 1; }
      auto& r = *rr;
      if (!r->SyncModel(model).ok()) return 1;
      synth::RenderOptions gro; gro.width = sz[0]; gro.height = sz[1];
      const PinholeCamera cam = gro.Camera();
      blend::BlendOptions bo;
      double first_ms = 0, sum_ms = 0, sum_gpu = 0, ssim_sum = 0;
      for (int k = 0; k <= frames; ++k) {
        const Rigid3d& pose = novel[std::max(0, k - 1) % novel.size()];
        const auto t0 = std::chrono::steady_clock::now();
        auto out = r->Render(cam, pose, bo);
        const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
        if (!out.ok()) return 1;
        if (k == 0) { first_ms = ms; continue; }
        sum_ms += ms; sum_gpu += out->gpu_ms;
        if (k == 1 || sz[0] == 640) {
          auto gt = synth::RenderFrame(*scene, pose, gro);
          auto s = Ssim(out->color, gt->frame.color);
          ssim_sum += s.ok() ? *s : 0;
        }
      }
      const int ssim_n = sz[0] == 640 ? frames : 1;
      printf("{\"bench\":\"vulkan_blend\",\"device\":\"%s\",\"width\":%d,\"height\":%d,\"refs_per_cell\":%d,"
             "\"views\":%zu,\"triangles\":%zu,\"first_frame_ms\":%.1f,\"ms_per_frame\":%.2f,\"gpu_ms\":%.2f,"
             "\"ssim\":%.4f,\"ssim_frames\":%d,\"lp_num_threads\":\"%s\"}\n",
             r->DeviceName().c_str(), sz[0], sz[1], n_refs, model.views.size(), scene->mesh.num_triangles(),
             first_ms, sum_ms / frames, sum_gpu / frames, ssim_sum / ssim_n, ssim_n,
             getenv("LP_NUM_THREADS") ? getenv("LP_NUM_THREADS") : "default");
      fflush(stdout);
    }
  }
  return 0;
}
