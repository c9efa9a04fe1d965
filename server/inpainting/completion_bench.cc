// Scene completion benchmark (issue 18 item 4; docs/inpainting.md "Session 15"): the synthetic
// apartment walked for --frames frames; the first --observed frames are what the server saw
// (the proxy = the scene triangles any of them saw, like a TSDF of those frames; stored views =
// every --views_every-th of them, cell references from their rasterised cells). Viewers stand at
// the walk's later poses (where it goes next: partly unobserved) and ask for a completion. Per
// pose: the hole fraction before / after (after = the model with the completion view and its
// void mesh, rendered again), the completion's wall and CPU time, and inside the holes PSNR /
// SSIM against the ground truth (the scene rendered at the pose) of what the viewer sees after
// the completion vs the renderer's push-pull hole fill (what it shows today). Prints JSON.
#include <time.h>

#include <chrono>
#include <cstdio>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/cli/cli.h"
#include "common/io/image_file.h"
#include "common/metrics/metrics.h"
#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/geometry/tsdf_volume.h"
#include "server/inpainting/completion.h"

namespace {

using namespace exo;

int Main(int argc, char** argv) {
  int frames = 120, observed = 60, views_every = 3, width = 320, height = 240, pose_every = 6;
  double min_hole = 0.02, max_hole = 0.8;
  uint64_t seed = 1;
  std::string pose_set = "walk";
  int near_count = 16;
  double w = -1, kappa = -1;
  std::string dump_dir;
  CLI::App app{"Scene completion on the synthetic apartment: holes before / after, time, PSNR / "
               "SSIM in the holes vs push-pull; prints JSON"};
  exo::cli::Setup(app);
  app.add_option("--frames", frames, "walk frames")->check(CLI::Range(4, 100000));
  app.add_option("--observed", observed, "the first N frames are what the server saw")
      ->check(CLI::Range(1, 100000));
  app.add_option("--views_every", views_every, "every Nth observed frame is a stored view")
      ->check(CLI::Range(1, 1000));
  app.add_option("--pose_every", pose_every, "every Nth later frame is a viewer pose")
      ->check(CLI::Range(1, 1000));
  app.add_option("--width", width, "viewer / frame width")->check(CLI::Range(16, 4096));
  app.add_option("--height", height, "viewer / frame height")->check(CLI::Range(16, 4096));
  app.add_option("--min_hole", min_hole, "poses with a smaller hole fraction are skipped");
  app.add_option("--max_hole", max_hole, "poses with a larger hole fraction are skipped");
  app.add_option("--seed", seed, "scene seed");
  app.add_option("--poses", pose_set,
                 "walk: the walk's later frames (every --pose_every-th); near: --near_count poses "
                 "near the observed frames (synth::MakeNearTestPoses: +-45 deg yaw, +-10 % of the "
                 "scene extent)")
      ->check(CLI::IsMember({"walk", "near"}));
  app.add_option("--near_count", near_count, "near poses")->check(CLI::Range(1, 1000));
  app.add_option("--dump_dir", dump_dir, "writes gt / pushpull / ours / holes PNGs per pose");
  app.add_option("--w", w, "InpaintOptions::w (default: the library's)");
  app.add_option("--kappa", kappa, "InpaintOptions::kappa (default: the library's)");
  std::string proxy_kind = "triangles";
  double tsdf_voxel = 0.03;
  bool vertex_color = true;
  app.add_option("--proxy", proxy_kind,
                 "triangles: the scene triangles the observed frames saw (session 15); tsdf: the "
                 "observed frames fused into a TSDF (--tsdf_voxel), its mesh with fused vertex "
                 "colours, as the server's geometry stage holds it")
      ->check(CLI::IsMember({"triangles", "tsdf"}));
  app.add_option("--tsdf_voxel", tsdf_voxel, "TSDF voxel (m) of --proxy=tsdf");
  app.add_option("--vertex_color", vertex_color, "CompletionOptions::use_vertex_color");
  double detail_gain = -2, detail_sigma = -1;
  app.add_option("--detail_gain", detail_gain,
                 "CompletionOptions::detail_gain (< 0: PatchMatch's colour; default: the library's)");
  app.add_option("--detail_sigma", detail_sigma, "CompletionOptions::detail_sigma_px");
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  if (observed >= frames) {
    std::fprintf(stderr, "--observed must be < --frames\n");
    return 2;
  }
  synth::SceneOptions so;
  so.seed = seed;
  auto scene = synth::MakeApartment(so);
  if (!scene.ok()) return std::fprintf(stderr, "%s\n", scene.status().ToString().c_str()), 1;
  synth::TrajectoryOptions to;
  to.num_frames = frames;
  auto traj = synth::MakeTrajectory(*scene, synth::TrajectoryKind::kWalk, to);
  if (!traj.ok()) return std::fprintf(stderr, "%s\n", traj.status().ToString().c_str()), 1;
  synth::RenderOptions ro;
  ro.width = width;
  ro.height = height;
  ro.num_threads = 1;
  const PinholeCamera cam = ro.Camera();

  // The model as the server would hold it after the observed frames.
  LumigraphModel model;
  model.origin = scene->origin;
  model.grid.cell_size_m = 0.5;
  std::set<uint32_t> seen;
  for (int i = 0; i < observed; ++i) {
    const Rigid3d& pose = (*traj)[i].local_from_cam;
    RasterOptions rop;
    rop.triangle_id = true;
    rop.cell_id = true;
    rop.cell_grid = model.grid;
    rop.num_threads = 1;
    auto r = Rasterize(scene->mesh, cam, pose, rop);
    if (!r.ok()) return std::fprintf(stderr, "%s\n", r.status().ToString().c_str()), 1;
    for (uint32_t t : r->triangle_id.span())
      if (t != kNoTriangle) seen.insert(t);
    if (i % views_every != 0) continue;
    auto f = synth::RenderFrame(*scene, pose, ro);
    if (!f.ok()) return std::fprintf(stderr, "%s\n", f.status().ToString().c_str()), 1;
    StoredView v;
    v.id = ViewId(1 + i);
    v.camera = cam;
    v.local_from_cam = pose;
    v.color = f->frame.color;
    v.depth_m = f->frame.depth_m;
    for (CellId c : r->cell_id.span()) {
      if (c == kNoCell) continue;
      auto& refs = model.cell_refs[c];
      if (refs.size() < 16 && (refs.empty() || refs.back() != v.id)) refs.push_back(v.id);
    }
    model.views[v.id] = std::move(v);
  }
  MeshChunk proxy;
  proxy.id = 1;
  proxy.version = 1;
  if (proxy_kind == "tsdf") {
    TsdfOptions topt;
    topt.voxel_size_m = static_cast<float>(tsdf_voxel);
    topt.num_threads = 1;
    TsdfVolume vol(topt);
    for (int i = 0; i < observed; ++i) {
      auto f = synth::RenderFrame(*scene, (*traj)[i].local_from_cam, ro);
      if (!f.ok()) return std::fprintf(stderr, "%s\n", f.status().ToString().c_str()), 1;
      auto st = vol.IntegrateDepth(f->frame.depth_m, cam, (*traj)[i].local_from_cam, &f->frame.color,
                                   &cam);
      if (!st.ok()) return std::fprintf(stderr, "%s\n", st.status().ToString().c_str()), 1;
    }
    proxy.mesh = vol.ExtractAll();
    proxy.mesh.normals.clear();
  } else {
    for (uint32_t t : seen)
      for (int k = 0; k < 3; ++k) {
        proxy.mesh.indices.push_back(uint32_t(proxy.mesh.positions.size()));
        proxy.mesh.positions.push_back(scene->mesh.positions[scene->mesh.indices[3 * t + k]]);
      }
  }
  const size_t proxy_triangles = proxy.mesh.num_triangles();
  model.chunks[1] = std::move(proxy);

  inpainting::CompletionOptions co;
  co.inpaint.num_threads = 1;
  co.render.num_threads = 1;
  if (w > 0) co.inpaint.w = w;
  if (kappa > 0) co.inpaint.kappa = kappa;
  if (detail_gain > -2) co.detail_gain = detail_gain;
  if (detail_sigma > 0) co.detail_sigma_px = detail_sigma;
  co.use_vertex_color = vertex_color;
  std::vector<std::pair<int, Rigid3d>> viewer_poses;
  if (pose_set == "walk") {
    for (int i = observed; i < frames; i += pose_every) viewer_poses.push_back({i, (*traj)[i].local_from_cam});
  } else {
    std::vector<Rigid3d> input;
    for (int i = 0; i < observed; ++i) input.push_back((*traj)[i].local_from_cam);
    auto near = synth::MakeNearTestPoses(*scene, input, cam, near_count, seed, false);
    if (!near.ok()) return std::fprintf(stderr, "%s\n", near.status().ToString().c_str()), 1;
    for (size_t i = 0; i < near->size(); ++i) viewer_poses.push_back({int(i), (*near)[i]});
  }
  CpuRenderOptions plain;
  plain.num_threads = 1;
  plain.blend.fill_holes = true;  // what the renderer shows today for holes
  CpuRenderOptions nofill = plain;
  nofill.blend.fill_holes = false;
  const double n = double(width) * height;
  nlohmann::json poses = nlohmann::json::array();
  double sum_before = 0, sum_after = 0, sum_ms = 0, sum_cpu = 0, sum_psnr = 0, sum_psnr_pp = 0,
         sum_ssim = 0, sum_ssim_pp = 0;
  int counted = 0, skipped = 0, failed = 0;
  for (const auto& [i, pose] : viewer_poses) {
    auto r = inpainting::CompleteView(model, cam, pose, co);
    if (!r.ok()) {
      ++failed;
      poses.push_back({{"frame", i}, {"error", std::string(r.status().message())}});
      continue;
    }
    const double before = r->before.hole_px / n;
    if (!r->completed || before < min_hole || before > max_hole) {
      ++skipped;
      continue;
    }
    LumigraphModel after_model = model;
    StoredView v = r->view;
    v.id = 0x60000000u;
    after_model.views[v.id] = v;
    if (!r->void_mesh.empty()) {
      MeshChunk mc;
      mc.id = uint64_t{1} << 63;
      mc.version = 1;
      mc.mesh = r->void_mesh;
      // A coloured proxy's chunks and this uncoloured one cannot be merged (ProxyMesh): grey.
      if (!model.chunks.at(1).mesh.colors.empty())
        mc.mesh.colors.assign(mc.mesh.positions.size(), glm::vec3(0.5f));
      after_model.chunks[mc.id] = std::move(mc);
    }
    auto after_raw = CpuLumigraphRenderer::Create(after_model, nofill).value()->Render(cam, pose);
    auto ours = CpuLumigraphRenderer::Create(after_model, plain).value()->Render(cam, pose);
    auto pushpull = CpuLumigraphRenderer::Create(model, plain).value()->Render(cam, pose);
    auto gt = synth::RenderFrame(*scene, pose, ro);
    if (!after_raw.ok() || !ours.ok() || !pushpull.ok() || !gt.ok()) return 1;
    const double after =
        1.0 - double(after_raw->covered_pixels + after_raw->background_pixels) / n;
    const ImageU8& holes = r->before.holes;
    const double psnr = MaskedPsnr(ours->color, gt->frame.color, holes).value_or(0.0);
    const double psnr_pp = MaskedPsnr(pushpull->color, gt->frame.color, holes).value_or(0.0);
    const double ssim = MaskedSsim(ours->color, gt->frame.color, holes).value_or(0.0);
    const double ssim_pp = MaskedSsim(pushpull->color, gt->frame.color, holes).value_or(0.0);
    const double psnr_kf = MaskedPsnr(r->view.color, gt->frame.color, holes).value_or(0.0);
    if (!dump_dir.empty()) {
      const std::string b = dump_dir + "/pose" + std::to_string(i) + "_";
      (void)WriteColorImage(b + "gt.png", gt->frame.color);
      (void)WriteColorImage(b + "pushpull.png", pushpull->color);
      (void)WriteColorImage(b + "ours.png", ours->color);
      {
        ImageU8 h3(holes.width(), holes.height(), 3, 0);
        for (int y = 0; y < holes.height(); ++y)
          for (int x = 0; x < holes.width(); ++x)
            for (int c = 0; c < 3; ++c) h3.at(x, y, c) = holes.at(x, y);
        (void)WriteColorImage(b + "holes.png", h3);
      }
    }
    poses.push_back({{"frame", i},
                     {"hole_fraction_before", before},
                     {"hole_fraction_after", after},
                     {"surface_hole_px", r->before.surface_hole_px},
                     {"void_hole_px", r->before.void_hole_px},
                     {"fused_color_px", r->before.fused_color_px},
                     {"mesh_triangles", r->void_mesh.num_triangles()},
                     {"ms", r->total_ms},
                     {"cpu_ms", r->total_cpu_ms},
                     {"render_ms", r->render_ms},
                     {"inpaint_ms", r->inpaint_ms},
                     {"psnr_holes", psnr},
                     {"psnr_holes_pushpull", psnr_pp},
                     {"psnr_holes_keyframe", psnr_kf},
                     {"ssim_holes", ssim},
                     {"ssim_holes_pushpull", ssim_pp}});
    ++counted;
    sum_before += before;
    sum_after += after;
    sum_ms += r->total_ms;
    sum_cpu += r->total_cpu_ms;
    sum_psnr += psnr;
    sum_psnr_pp += psnr_pp;
    sum_ssim += ssim;
    sum_ssim_pp += ssim_pp;
  }
  const double k = counted ? 1.0 / counted : 0.0;
  nlohmann::json out = {{"scene", "apartment"},
                        {"pose_set", pose_set},
                        {"width", width},
                        {"height", height},
                        {"frames", frames},
                        {"observed_frames", observed},
                        {"stored_views", model.views.size()},
                        {"proxy_triangles", proxy_triangles},
                        {"proxy", proxy_kind},
                        {"vertex_color", co.use_vertex_color},
                        {"detail_gain", co.detail_gain},
                        {"detail_sigma_px", co.detail_sigma_px},
                        {"poses", counted},
                        {"poses_skipped", skipped},
                        {"poses_failed", failed},
                        {"mean",
                         {{"hole_fraction_before", sum_before * k},
                          {"hole_fraction_after", sum_after * k},
                          {"ms", sum_ms * k},
                          {"cpu_ms", sum_cpu * k},
                          {"psnr_holes", sum_psnr * k},
                          {"psnr_holes_pushpull", sum_psnr_pp * k},
                          {"ssim_holes", sum_ssim * k},
                          {"ssim_holes_pushpull", sum_ssim_pp * k}}},
                        {"per_pose", poses}};
  std::printf("%s\n", out.dump(1).c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) { return Main(argc, argv); }
