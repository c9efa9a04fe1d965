// vulkan_bench: ms per frame of the Vulkan lumigraph blend on lavapipe at 640x480, 1280x720 and
// 1920x1080 for 8/16/32/60 references per cell (village scene, stored views rendered by
// common/synth), first frame (pipeline JIT) separately, and SSIM of each configuration against
// the synthetic ground truth, one JSON object per configuration (median and min of the timed
// frames, the 1-minute load average, since the machine is shared). Beside every configuration
// it times the floor (VulkanRenderer::RenderFloor: a forward draw of the same proxy with one
// bilinear fetch per pixel + the same read-back), interleaved frame by frame with the blend, and
// prints both with their ratio (floor_*, ratio_wall, ratio_cpu: issue 16's floor, kForward;
// floor_proj_*, ratio_*_proj: the heavier per-fragment projective floor of session 9). Usage:
//   LP_NUM_THREADS=2 vulkan_bench [--frames=5] [--views=60] [--refs=8,16,32,60]
//       [--sizes=640x480,1280x720,1920x1080] [--scene=village|apartment] [--view_size=320x240]
//       [--pose=k (all frames from novel pose k)] [--background_views=N (sky pass; 0 = off)]
//       [--fill_holes=0|1 (push-pull fill of uncovered pixels; default 1)] [--n_best=1..4]
//       [--max_candidates=K (RenderApprox: at most K references per pixel; 0 = exact)]
// Env: EXO_VULKAN_BENCH_DUMP=<dir> writes every frame + ground truth as PNG.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include <sys/resource.h>

#include <nlohmann/json.hpp>

#include "client/vulkan/vulkan_renderer.h"
#include "common/cli/cli.h"
#include "common/io/image_file.h"
#include "common/metrics/metrics.h"
#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

using namespace exo;

namespace {

using json = nlohmann::ordered_json;  // fields in the order written

// Positive integers separated by ',' or `sep` ("8,16,32", "640x480,1280x720"). Empty on any
// malformed or non-positive entry.
std::vector<int> ParseInts(const std::string& text, char sep) {
  std::vector<int> out;
  const char* s = text.c_str();
  while (*s) {
    char* end;
    const long v = std::strtol(s, &end, 10);
    if (end == s || v <= 0 || v > 1 << 20) return {};
    out.push_back(int(v));
    s = end;
    if (*s == sep || *s == ',') {
      if (!*++s) return {};
    } else if (*s) {
      return {};
    }
  }
  return out;
}

// A CLI11 check: `text` is a list of positive integers with `count` entries a multiple of
// `multiple` (2 for WxH sizes), at most `max_count` when given.
CLI::Validator IntList(char sep, size_t multiple, size_t max_count, const std::string& what) {
  return CLI::Validator(
      [=](std::string& text) -> std::string {
        const std::vector<int> v = ParseInts(text, sep);
        if (v.empty() || v.size() % multiple != 0 || (max_count && v.size() > max_count))
          return "expected " + what + ", got '" + text + "'";
        return "";
      },
      what);
}

double Round(double x, int digits) {
  const double f = std::pow(10.0, digits);
  return std::round(x * f) / f;
}

// CPU time of the whole process (all llvmpipe threads), ms: robust to other load on the machine.
double ProcessCpuMs() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return (u.ru_utime.tv_sec + u.ru_stime.tv_sec) * 1e3 + (u.ru_utime.tv_usec + u.ru_stime.tv_usec) * 1e-3;
}

double Load1() {
  double l[3] = {0, 0, 0};
  return getloadavg(l, 3) > 0 ? l[0] : -1.0;
}

}  // namespace

int main(int argc, char** argv) {
  int frames = 5, max_views = 60;
  int fixed_pose = -1;  // --pose=k: every frame from novel pose k (profiling)
  int background_views = blend::BlendOptions{}.background_views;
  bool fill_holes = blend::BlendOptions{}.fill_holes;
  int n_best = blend::BlendOptions{}.n_best;
  int max_candidates = 0;  // RenderApprox::max_candidates (0 = exact)
  std::string scene_name = "village";
  std::string refs_text = "8,16,32,60", sizes_text = "640x480,1280x720,1920x1080",
              view_size_text = "320x240";
  CLI::App app{"Vulkan lumigraph blend: ms per frame and SSIM against the synthetic ground truth "
               "for each resolution and references per cell; one JSON object per configuration.",
               "vulkan_bench"};
  exo::cli::Setup(app);
  app.add_option("--frames", frames, "timed frames per configuration")->check(CLI::PositiveNumber);
  app.add_option("--views", max_views, "stored views rendered from the trajectory")
      ->check(CLI::PositiveNumber);
  app.add_option("--refs", refs_text, "references per cell to measure")
      ->check(IntList(',', 1, 0, "N,N,..."));
  app.add_option("--sizes", sizes_text, "output resolutions")
      ->check(IntList('x', 2, 0, "WxH,WxH,..."));
  app.add_option("--scene", scene_name, "synthetic scene")
      ->check(CLI::IsMember({"village", "apartment"}));
  app.add_option("--view_size", view_size_text, "stored views' resolution")
      ->check(IntList('x', 2, 2, "WxH"));
  app.add_option("--pose", fixed_pose, "every frame from novel pose k (-1: walk the poses)")
      ->check(CLI::Range(-1, 1 << 20));
  app.add_option("--background_views", background_views, "sky pass views (0 = off)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--fill_holes", fill_holes, "push-pull fill of uncovered pixels (0|1)");
  app.add_option("--n_best", n_best, "views blended per pixel")
      ->check(CLI::Range(1, blend::kMaxBlendViews));
  app.add_option("--max_candidates", max_candidates,
                 "RenderApprox::max_candidates: references a pixel evaluates (0 = all, exact)")
      ->check(CLI::NonNegativeNumber);
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  const std::vector<int> refs_list = ParseInts(refs_text, ',');
  const std::vector<int> sizes = ParseInts(sizes_text, 'x');
  const std::vector<int> view_size = ParseInts(view_size_text, 'x');
  const synth::SceneKind kind =
      scene_name == "apartment" ? synth::SceneKind::kApartment : synth::SceneKind::kVillage;
  auto scene = synth::MakeScene(kind, {});
  if (!scene.ok()) { fprintf(stderr, "%s\n", scene.status().ToString().c_str()); return 1; }
  synth::RenderOptions vro;  // stored views (kept small by default: the bench measures the client)
  vro.width = view_size[0]; vro.height = view_size[1];
  synth::TrajectoryOptions to;
  to.num_frames = max_views + 2 * frames;
  auto traj = synth::MakeTrajectory(*scene, kind == synth::SceneKind::kVillage
                                                ? synth::TrajectoryKind::kFlyover
                                                : synth::TrajectoryKind::kWalk, to);
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
  for (int n_refs : refs_list) {
    model.cell_refs.clear();
    double mean_refs = 0;
    size_t max_refs = 0;
    for (auto& [c, refs] : all_refs) {
      model.cell_refs[c] = std::vector<ViewId>(refs.begin(), refs.begin() + std::min<size_t>(refs.size(), n_refs));
      mean_refs += model.cell_refs[c].size();
      max_refs = std::max(max_refs, model.cell_refs[c].size());
    }
    mean_refs /= std::max<size_t>(1, all_refs.size());
    for (size_t si = 0; si + 1 < sizes.size(); si += 2) {
      VulkanRendererOptions vo; vo.max_refs_per_cell = std::max(16, n_refs);
      const auto tc = std::chrono::steady_clock::now();
      auto rr = VulkanRenderer::Create(vo);
      if (!rr.ok()) { fprintf(stderr, "%s\n", rr.status().ToString().c_str()); return 1; }
      auto& r = *rr;
      const double create_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - tc).count();
      const auto ts = std::chrono::steady_clock::now();
      if (auto st = r->SyncModel(model); !st.ok()) { fprintf(stderr, "%s\n", st.ToString().c_str()); return 1; }
      const double sync_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - ts).count();
      synth::RenderOptions gro; gro.width = sizes[si]; gro.height = sizes[si + 1];
      const PinholeCamera cam = gro.Camera();
      blend::BlendOptions bo;
      bo.background_views = background_views;
      bo.fill_holes = fill_holes;
      bo.n_best = n_best;
      double first_ms = 0, ssim_sum = 0, floor_first_ms = 0;
      std::vector<double> ms_v, cpu_v, gpu_v, rb_v, rank_v, fill_v, filled_v, floor_ms_v,
          floor_cpu_v, proj_ms_v, proj_cpu_v, sky_v, sky_tiles_v, sky_views_v;
      int ssim_n = 0;
      for (int k = 0; k <= frames; ++k) {
        const Rigid3d& pose =
            novel[fixed_pose >= 0 ? fixed_pose % novel.size() : std::max(0, k - 1) % novel.size()];
        const auto t0 = std::chrono::steady_clock::now();
        const double c0 = ProcessCpuMs();
        auto out = r->Render(cam, pose, bo, RenderApprox{max_candidates});
        const double cpu_ms = ProcessCpuMs() - c0;
        const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
        if (!out.ok()) { fprintf(stderr, "%s\n", out.status().ToString().c_str()); return 1; }
        // EXO_VULKAN_BENCH_DUMP=<dir>: every frame and its ground truth as PNGs (docs, debugging).
        if (const char* dir = getenv("EXO_VULKAN_BENCH_DUMP"); dir && *dir) {
          const std::string base = std::string(dir) + "/" + scene_name + "_" +
                                   std::to_string(sizes[si]) + "_r" + std::to_string(n_refs) +
                                   "_f" + std::to_string(k);
          (void)WriteColorImage(base + "_vulkan.png", out->color);
          if (auto gt = synth::RenderFrame(*scene, pose, gro); gt.ok())
            (void)WriteColorImage(base + "_gt.png", gt->frame.color);
        }
        // The floors on the same pose right after (interleaved, so all see the same load): the
        // issue's forward draw with its texture made resident first (untimed), then the
        // session-9 per-fragment projective one.
        if (auto st = r->PrepareFloor(cam, pose); !st.ok()) {
          fprintf(stderr, "%s\n", st.ToString().c_str());
          return 1;
        }
        double floor_ms = 0, floor_cpu_ms = 0, proj_ms = 0, proj_cpu_ms = 0;
        for (const auto kind : {VulkanRenderer::FloorKind::kForward,
                                VulkanRenderer::FloorKind::kProjective}) {
          const auto tf0 = std::chrono::steady_clock::now();
          const double cf0 = ProcessCpuMs();
          auto floor_out = r->RenderFloor(cam, pose, kind);
          const double fc = ProcessCpuMs() - cf0;
          const double fm = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - tf0).count();
          if (!floor_out.ok()) { fprintf(stderr, "%s\n", floor_out.status().ToString().c_str()); return 1; }
          (kind == VulkanRenderer::FloorKind::kForward ? floor_ms : proj_ms) = fm;
          (kind == VulkanRenderer::FloorKind::kForward ? floor_cpu_ms : proj_cpu_ms) = fc;
        }
        if (k == 0) { first_ms = ms; floor_first_ms = floor_ms; continue; }
        floor_ms_v.push_back(floor_ms); floor_cpu_v.push_back(floor_cpu_ms);
        proj_ms_v.push_back(proj_ms); proj_cpu_v.push_back(proj_cpu_ms);
        ms_v.push_back(ms); cpu_v.push_back(cpu_ms); gpu_v.push_back(out->gpu_ms); rb_v.push_back(out->readback_ms); rank_v.push_back(out->rank_ms);
        sky_tiles_v.push_back(out->sky_tiles_ms); sky_views_v.push_back(out->sky_views_per_px);
        fill_v.push_back(out->fill_ms); filled_v.push_back(double(out->filled_pixels));
        double sky = 0;  // pixels filled at infinity (coverage 3)
        for (uint8_t c : out->coverage.span()) sky += c == 3;
        sky_v.push_back(sky);
        // SSIM on every timed frame at the smallest size, on the first one otherwise (GT
        // rendering of 1080p frames on the CPU is slower than the bench itself).
        if (k == 1 || si == 0) {
          auto gt = synth::RenderFrame(*scene, pose, gro);
          if (!gt.ok()) return 1;
          auto s = Ssim(out->color, gt->frame.color);
          if (s.ok()) { ssim_sum += *s; ++ssim_n; }
        }
      }
      auto med = [](std::vector<double> v) { std::sort(v.begin(), v.end()); return v[v.size() / 2]; };
      auto mn = [](const std::vector<double>& v) { return *std::min_element(v.begin(), v.end()); };
      json frame_ms = json::array();
      for (double v : ms_v) frame_ms.push_back(int(v + 0.5));
      const char* lp_threads = getenv("LP_NUM_THREADS");
      const json line = {
          {"bench", "vulkan_blend"},
          {"scene", scene_name},
          {"device", r->DeviceName()},
          {"width", sizes[si]},
          {"height", sizes[si + 1]},
          {"refs_per_cell", n_refs},
          {"mean_refs_per_cell", Round(mean_refs, 1)},
          {"max_refs_per_cell", max_refs},
          {"views", model.views.size()},
          {"view_size", std::to_string(view_size[0]) + "x" + std::to_string(view_size[1])},
          {"triangles", scene->mesh.num_triangles()},
          {"create_ms", Round(create_ms, 1)},
          {"upload_ms", Round(sync_ms, 1)},
          {"first_frame_ms", Round(first_ms, 1)},
          {"median_ms", Round(med(ms_v), 2)},
          {"min_ms", Round(mn(ms_v), 2)},
          {"median_cpu_ms", Round(med(cpu_v), 1)},
          {"floor_first_frame_ms", Round(floor_first_ms, 1)},
          {"floor_median_ms", Round(med(floor_ms_v), 2)},
          {"floor_min_ms", Round(mn(floor_ms_v), 2)},
          {"floor_median_cpu_ms", Round(med(floor_cpu_v), 1)},
          {"ratio_wall", Round(med(ms_v) / std::max(1e-3, med(floor_ms_v)), 2)},
          {"ratio_cpu", Round(med(cpu_v) / std::max(1e-3, med(floor_cpu_v)), 2)},
          {"floor_proj_median_ms", Round(med(proj_ms_v), 2)},
          {"floor_proj_median_cpu_ms", Round(med(proj_cpu_v), 1)},
          {"ratio_wall_proj", Round(med(ms_v) / std::max(1e-3, med(proj_ms_v)), 2)},
          {"ratio_cpu_proj", Round(med(cpu_v) / std::max(1e-3, med(proj_cpu_v)), 2)},
          {"median_gpu_ms", Round(med(gpu_v), 2)},
          {"median_readback_ms", Round(med(rb_v), 2)},
          {"median_rank_ms", Round(med(rank_v), 2)},
          {"n_best", n_best},
          {"max_candidates", max_candidates},
          {"fill_holes", int(fill_holes)},
          {"median_fill_ms", Round(med(fill_v), 2)},
          {"median_filled_px", Round(med(filled_v), 0)},
          {"background_views", background_views},
          {"median_sky_px", Round(med(sky_v), 0)},
          {"median_sky_tiles_ms", Round(med(sky_tiles_v), 2)},
          {"median_sky_views_per_px", Round(med(sky_views_v), 3)},
          {"frames", frames},
          {"ssim", Round(ssim_n ? ssim_sum / ssim_n : 0.0, 4)},
          {"ssim_frames", ssim_n},
          {"lp_num_threads", lp_threads ? lp_threads : "default"},
          {"load1", Round(Load1(), 2)},
          {"frame_ms", frame_ms}};
      printf("%s\n", line.dump().c_str());
      fflush(stdout);
    }
  }
  return 0;
}
