// planning_bench: view planning speed per 640x480 frame (cell-id buffer render vs planning) on a
// synthetic scene, and optionally the lumigraph quality (MSSIM/PSNR/coverage) of the planned
// store rendered by the CPU lumigraph renderer at random test poses. One JSON line per run.
//
//   planning_bench --scene village --traj flyover --frames 600 --r_max 16 --store 200
//                  [--idw 160 --idh 120] [--quality 1 --test_views 50 --test_w 320 --test_h 240]
//                  [--proxy gt|tsdf --voxel M] [--lod F | --lod_m M] [--lod_keep 0.1]
//                  [--path renderer|concat] [--threads 1]
// --proxy gt: the scene's ground-truth mesh as one chunk (isolates planning from TSDF error);
// --proxy tsdf: the 640x480 synthetic depth frames fused into a TsdfVolume as eval does, its
// dirty chunks fed to the cell-id renderer every frame (integration is not timed; the LOD
// builds of the dirty chunks are, as cell-id time). --lod F: clusters of F x cell size
// (planning::CellIdRenderer); -1 = planning::DefaultCellIdLodM. --path concat: the session-1
// path (sphere-culled chunks concatenated, then Rasterize) for comparison.
// Times: wall (steady clock) and process CPU (CLOCK_PROCESS_CPUTIME_ID) per frame.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "common/cli/cli.h"
#include "common/lumigraph/cpu_renderer.h"
#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/geometry/cell_areas.h"
#include "server/geometry/scene_scale.h"
#include "server/geometry/tsdf_volume.h"
#include "server/planning/cell_id_proxy.h"
#include "server/planning/view_planner.h"

namespace exo {
namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}
double CpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}
// FNV-1a 64 over the bytes of a cell-id buffer, chained over the frames of a run: equal sums
// over a stream mean bit-identical buffers (used to prove that rasterizer speed-ups change
// nothing; docs/planning.md).
uint64_t Fnv1a(uint64_t h, const Image<uint64_t>& img) {
  const auto* p = reinterpret_cast<const unsigned char*>(img.data());
  for (size_t i = 0; i < img.size() * sizeof(uint64_t); ++i) {
    h ^= p[i];
    h *= 1099511628211ull;
  }
  return h;
}

using json = nlohmann::ordered_json;  // fields in the order written

// Rounds to `digits` decimals for the JSON lines.
double Round(double x, int digits) {
  const double f = std::pow(10.0, digits);
  return std::round(x * f) / f;
}

double Pct(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(p * (v.size() - 1) + 0.5))];
}

struct Args {
  std::string scene = "village", traj = "flyover";
  int frames = 600, r_max = 16, store = 200, idw = 160, idh = 120;
  double lambda = -1, cell = 0;
  int quality = 0, test_views = 50, test_w = 320, test_h = 240;
  std::string proxy = "gt", path = "renderer";
  double voxel = 0, lod = 0, lod_m = 0, lod_keep = 0;
  int threads = 1;
  int rerender = 0;  // after the run: render the final proxy from every pose this many times
  int checksum = 0;  // 1: FNV-1a 64 over every frame's cell-id buffer (identity checks)
};

// Fills `a` from the flags; an exit code when the program should stop (--help, a bad flag).
std::optional<int> ParseFlags(int argc, char** argv, Args* a) {
  CLI::App app{"View planning speed per frame (cell-id buffer render vs planning) on a synthetic "
               "scene, optionally the lumigraph quality of the planned store; one JSON line per run.",
               "planning_bench"};
  exo::cli::Setup(app);
  app.add_option("--scene", a->scene, "synthetic scene (village|apartment)");
  app.add_option("--traj", a->traj, "trajectory (flyover|walk)");
  app.add_option("--frames", a->frames, "frames of the trajectory")->check(CLI::PositiveNumber);
  app.add_option("--r_max", a->r_max, "planner r_max (references per cell)")
      ->check(CLI::PositiveNumber);
  app.add_option("--store", a->store, "store capacity in views")->check(CLI::PositiveNumber);
  app.add_option("--idw", a->idw, "cell-id buffer width")->check(CLI::PositiveNumber);
  app.add_option("--idh", a->idh, "cell-id buffer height")->check(CLI::PositiveNumber);
  app.add_option("--lambda", a->lambda, "planner lambda (-1: 0.5 on a fly-over, 0.4 on a walk)");
  app.add_option("--cell", a->cell, "cell size in m (0: from the scene scale)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--quality", a->quality, "1: render the planned store at test poses (MSSIM/PSNR)")
      ->check(CLI::Range(0, 1));
  app.add_option("--test_views", a->test_views, "test poses for --quality")
      ->check(CLI::PositiveNumber);
  app.add_option("--test_w", a->test_w, "test view width")->check(CLI::PositiveNumber);
  app.add_option("--test_h", a->test_h, "test view height")->check(CLI::PositiveNumber);
  app.add_option("--proxy", a->proxy, "gt: the scene mesh; tsdf: fused synthetic depth")
      ->check(CLI::IsMember({"gt", "tsdf"}));
  app.add_option("--path", a->path, "renderer: planning::CellIdRenderer; concat: culled chunks")
      ->check(CLI::IsMember({"renderer", "concat"}));
  app.add_option("--voxel", a->voxel, "TSDF voxel in m for --proxy tsdf (0: from the scene)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--lod", a->lod, "LOD clusters of F x cell size (-1: the default LOD)");
  app.add_option("--lod_m", a->lod_m, "LOD cluster size in m (0: off)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--lod_keep", a->lod_keep, "LOD keep fraction")->check(CLI::NonNegativeNumber);
  app.add_option("--threads", a->threads, "rasterizer threads")->check(CLI::PositiveNumber);
  app.add_option("--rerender", a->rerender, "render the final proxy from every pose N times")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--checksum", a->checksum, "1: FNV-1a 64 over every cell-id buffer")
      ->check(CLI::Range(0, 1));
  return exo::cli::Parse(app, argc, argv);
}

cv::Mat Luma(const ImageU8& img) {
  cv::Mat out(img.height(), img.width(), CV_32F);
  for (int y = 0; y < img.height(); ++y)
    for (int x = 0; x < img.width(); ++x)
      out.at<float>(y, x) = 0.299f * img.at(x, y, 0) + 0.587f * img.at(x, y, 1) + 0.114f * img.at(x, y, 2);
  return out;
}

// SSIM on luma (11x11 Gaussian, sigma 1.5, standard constants, L = 255), mean over the image.
double Ssim(const ImageU8& a, const ImageU8& b) {
  const cv::Mat x = Luma(a), y = Luma(b);
  const double c1 = std::pow(0.01 * 255, 2), c2 = std::pow(0.03 * 255, 2);
  cv::Mat mx, my, sxx, syy, sxy;
  const cv::Size k(11, 11);
  cv::GaussianBlur(x, mx, k, 1.5);
  cv::GaussianBlur(y, my, k, 1.5);
  cv::GaussianBlur(x.mul(x), sxx, k, 1.5);
  cv::GaussianBlur(y.mul(y), syy, k, 1.5);
  cv::GaussianBlur(x.mul(y), sxy, k, 1.5);
  cv::Mat mx2 = mx.mul(mx), my2 = my.mul(my), mxy = mx.mul(my);
  sxx -= mx2;
  syy -= my2;
  sxy -= mxy;
  cv::Mat num = (2 * mxy + c1).mul(2 * sxy + c2);
  cv::Mat den = (mx2 + my2 + c1).mul(sxx + syy + c2);
  cv::Mat s;
  cv::divide(num, den, s);
  return cv::mean(s)[0];
}

double Psnr(const ImageU8& a, const ImageU8& b) {
  double se = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double d = double(a.data()[i]) - b.data()[i];
    se += d * d;
  }
  const double mse = se / a.size();
  return mse <= 0 ? 99.0 : 10 * std::log10(255.0 * 255.0 / mse);
}

int Run(const Args& args) {
  auto kind = synth::ParseSceneKind(args.scene);
  auto tkind = synth::ParseTrajectoryKind(args.traj);
  if (!kind.ok() || !tkind.ok()) {
    std::fprintf(stderr, "bad scene/trajectory\n");
    return 2;
  }
  auto scene_or = synth::MakeScene(*kind, {});
  if (!scene_or.ok()) {
    std::fprintf(stderr, "%s\n", std::string(scene_or.status().message()).c_str());
    return 1;
  }
  const synth::SynthScene& scene = *scene_or;
  const SceneScale scale = DeriveSceneScale(scene.bounds.min, scene.bounds.max);
  synth::RenderOptions render_opt;  // 640x480, 65 deg
  const PinholeCamera cam = render_opt.Camera();
  const size_t frame_bytes = size_t(cam.width) * cam.height * (3 + 4) + sizeof(StoredView);

  planning::PlannerOptions po;
  po.r_max = args.r_max;
  po.max_views = args.store;
  po.max_bytes = size_t(args.store) * frame_bytes;
  po.cell_size_m = args.cell > 0 ? args.cell : scale.cell_size_m;
  po.d_max_m = scale.d_max_m;
  po.sigma_m = scale.sigma_m;
  po.lambda = args.lambda >= 0 ? args.lambda : (*tkind == synth::TrajectoryKind::kFlyover ? 0.5 : 0.4);
  auto planner_or = planning::ViewPlanner::Create(po);
  if (!planner_or.ok()) {
    std::fprintf(stderr, "%s\n", std::string(planner_or.status().message()).c_str());
    return 2;
  }
  planning::ViewPlanner& planner = *planner_or;
  CellAreas areas(planner.grid());
  MeshChunk chunk;
  chunk.id = 0;
  chunk.version = 1;
  chunk.mesh = scene.mesh;
  if (args.proxy != "tsdf") {  // tsdf: areas arrive with the TSDF chunks
    areas.UpdateChunk(chunk);
    for (const auto& [cell, a] : areas.areas()) (void)planner.SetCellArea(cell, a);
  }

  synth::TrajectoryOptions to;
  to.num_frames = args.frames;
  auto traj = synth::MakeTrajectory(scene, *tkind, to);
  if (!traj.ok()) {
    std::fprintf(stderr, "%s\n", std::string(traj.status().message()).c_str());
    return 1;
  }

  const bool tsdf_proxy = args.proxy == "tsdf";
  const double diameter = scene.ExtentM();
  const double voxel_m = args.voxel > 0 ? args.voxel : std::clamp(diameter / 600.0, 0.02, 0.15);
  const double max_range_m = std::max(6.0, diameter) * 1.5;
  std::unique_ptr<TsdfVolume> tsdf;
  if (tsdf_proxy) {
    TsdfOptions to_tsdf;
    to_tsdf.voxel_size_m = float(voxel_m);
    to_tsdf.max_depth_m = float(std::max(6.0, diameter));
    to_tsdf.min_depth_m = 0.1f;
    tsdf = std::make_unique<TsdfVolume>(to_tsdf);
  }
  planning::CellIdRendererOptions cro;
  cro.grid = planner.grid();
  cro.lod_cluster_m = args.lod_m > 0 ? args.lod_m
                      : args.lod < 0 ? planning::DefaultCellIdLodM(po.cell_size_m,
                                                                   tsdf_proxy ? voxel_m : 0.0)
                                     : args.lod * po.cell_size_m;
  cro.lod_keep_fraction = args.lod_keep;
  cro.max_range_m = max_range_m;
  cro.num_threads = args.threads;
  auto cid_or = planning::CellIdRenderer::Create(cro);
  if (!cid_or.ok()) {
    std::fprintf(stderr, "%s\n", std::string(cid_or.status().message()).c_str());
    return 2;
  }
  planning::CellIdRenderer& cid = *cid_or;
  // Session-1 path: per-chunk LOD (same cache) + bounding-sphere cull + concatenation + Rasterize.
  const bool concat_path = args.path == "concat";
  if (!tsdf_proxy) (void)cid.Update({chunk});

  std::vector<double> update_cpu, dirty_chunks;
  std::vector<double> cellid_ms, cellid_cpu, plan_ms, plan_cpu, total_ms, total_cpu, tris;
  std::map<ViewId, StoredView> stored;
  int accepted = 0, evicted = 0;
  uint64_t id_checksum = 14695981039346656037ull;
  double render_store_ms = 0, integrate_ms = 0;
  for (size_t i = 0; i < traj->size(); ++i) {
    const Rigid3d& pose = (*traj)[i].local_from_cam;
    std::vector<MeshChunk> dirty;
    std::vector<uint64_t> removed;
    std::optional<synth::RenderedFrame> frame;
    if (tsdf_proxy || args.quality) {
      const auto tf = Clock::now();
      auto f = synth::RenderFrame(scene, pose, render_opt, {}, i, (*traj)[i].timestamp_s);
      if (!f.ok()) continue;
      frame = std::move(*f);
      if (tsdf_proxy) {
        if (!tsdf->Integrate(frame->frame, scene.origin).ok()) continue;
        dirty = tsdf->ExtractDirtyChunks();
        removed = tsdf->TakeRemovedChunkIds();
        for (const MeshChunk& c : dirty) areas.UpdateChunk(c);
        for (uint64_t id : removed) areas.RemoveChunk(id);
        for (CellId k : areas.TakeChangedCells()) (void)planner.SetCellArea(k, areas.Area(k));
      }
      integrate_ms += Ms(tf, Clock::now());
    }
    const auto t0 = Clock::now();
    const double c0 = CpuMs();
    for (uint64_t id : removed) cid.Remove(id);
    if (!dirty.empty()) (void)cid.Update(dirty);
    const double c_upd = CpuMs();
    update_cpu.push_back(c_upd - c0);
    dirty_chunks.push_back(double(dirty.size()));
    PinholeCamera id_cam;
    Image<uint64_t> id_img;  // kept (outside the timed part) for --checksum
    std::vector<planning::CellPixelCount> cells;
    if (concat_path) {
      TriangleMesh m;
      for (const TriangleMesh* part : cid.RenderMeshes()) {
        glm::vec3 lo(1e30f), hi(-1e30f);
        for (const glm::vec3& p : part->positions) {
          lo = glm::min(lo, p);
          hi = glm::max(hi, p);
        }
        const glm::dvec3 c = glm::dvec3(0.5f * (lo + hi));
        const double r = 0.5 * glm::length(glm::dvec3(hi - lo));
        const glm::dvec3 pc = glm::transpose(pose.RotationMatrix()) * (c - pose.translation);
        if (pc.z < -r || pc.z > max_range_m + r) continue;
        const uint32_t base = uint32_t(m.positions.size());
        m.positions.insert(m.positions.end(), part->positions.begin(), part->positions.end());
        for (uint32_t k : part->indices) m.indices.push_back(base + k);
      }
      RasterOptions ro;
      ro.z_depth = false;
      ro.cell_id = true;
      ro.cell_grid = planner.grid();
      ro.width = args.idw;
      ro.height = args.idh;
      ro.num_threads = args.threads;
      auto r = Rasterize(m, cam, pose, ro);
      if (!r.ok()) continue;
      id_cam = r->camera;
      tris.push_back(double(m.num_triangles()));
      cells = planning::CountCellPixels(r->cell_id.data(), r->cell_id.size());
      if (args.checksum) id_img = std::move(r->cell_id);
    } else {
      auto r = cid.Render(pose, cam, args.idw, args.idh);
      if (!r.ok()) continue;
      id_cam = r->camera;
      tris.push_back(double(r->triangles_rendered));
      cells = planning::CountCellPixels(r->cell_id.data(), r->cell_id.size());
      if (args.checksum) id_img = std::move(r->cell_id);
    }
    const auto t1 = Clock::now();
    const double c1 = CpuMs();
    planning::Candidate c;
    c.id = ViewId(i + 1);
    c.local_from_cam = pose;
    c.id_camera = id_cam;
    c.cells = std::move(cells);
    c.bytes = frame_bytes;
    auto d = planner.Consider(c);
    const auto t2 = Clock::now();
    const double c2 = CpuMs();
    if (args.checksum) id_checksum = Fnv1a(id_checksum, id_img);
    cellid_ms.push_back(Ms(t0, t1));
    plan_ms.push_back(Ms(t1, t2));
    total_ms.push_back(Ms(t0, t2));
    cellid_cpu.push_back(c1 - c0);
    plan_cpu.push_back(c2 - c1);
    total_cpu.push_back(c2 - c0);
    if (!d.ok() || !d->accepted) continue;
    ++accepted;
    evicted += int(d->removed.size());
    if (args.quality && frame) {
      for (ViewId v : d->removed) stored.erase(v);
      StoredView sv;
      sv.id = c.id;
      sv.camera = cam;
      sv.local_from_cam = pose;
      sv.color = std::move(frame->frame.color);
      sv.depth_m = std::move(frame->frame.depth_m);
      stored[c.id] = std::move(sv);
    }
  }
  char checksum_hex[17];
  std::snprintf(checksum_hex, sizeof(checksum_hex), "%016llx",
                static_cast<unsigned long long>(args.checksum ? id_checksum : 0));
  const json line = {{"bench", "planning"},
                     {"scene", args.scene},
                     {"traj", args.traj},
                     {"frames", total_ms.size()},
                     {"r_max", po.r_max},
                     {"store", args.store},
                     {"lambda", Round(po.lambda, 2)},
                     {"cell_m", Round(po.cell_size_m, 3)},
                     {"d_max_m", Round(po.d_max_m, 2)},
                     {"sigma_m", Round(po.sigma_m, 2)},
                     {"idbuf", std::to_string(args.idw) + "x" + std::to_string(args.idh)},
                     {"proxy", args.proxy},
                     {"voxel_m", Round(tsdf_proxy ? voxel_m : 0.0, 3)},
                     {"path", args.path},
                     {"lod_m", Round(cro.lod_cluster_m, 3)},
                     {"lod_keep", Round(cro.lod_keep_fraction, 2)},
                     {"threads", args.threads},
                     {"tris_median", Round(Pct(tris, 0.5), 0)},
                     {"lod_builds", cid.lod_builds()},
                     {"dirty_chunks_median", Round(Pct(dirty_chunks, 0.5), 0)},
                     {"update_cpu_median", Round(Pct(update_cpu, 0.5), 3)},
                     {"cellid_ms_median", Round(Pct(cellid_ms, 0.5), 3)},
                     {"cellid_ms_p95", Round(Pct(cellid_ms, 0.95), 3)},
                     {"cellid_cpu_median", Round(Pct(cellid_cpu, 0.5), 3)},
                     {"cellid_cpu_p95", Round(Pct(cellid_cpu, 0.95), 3)},
                     {"plan_ms_median", Round(Pct(plan_ms, 0.5), 3)},
                     {"plan_ms_p95", Round(Pct(plan_ms, 0.95), 3)},
                     {"plan_cpu_median", Round(Pct(plan_cpu, 0.5), 3)},
                     {"plan_cpu_p95", Round(Pct(plan_cpu, 0.95), 3)},
                     {"total_ms_median", Round(Pct(total_ms, 0.5), 3)},
                     {"total_ms_p95", Round(Pct(total_ms, 0.95), 3)},
                     {"total_cpu_median", Round(Pct(total_cpu, 0.5), 3)},
                     {"total_cpu_p95", Round(Pct(total_cpu, 0.95), 3)},
                     {"integrate_s", Round(integrate_ms / 1e3, 1)},
                     {"accepted", accepted},
                     {"evicted", evicted},
                     {"views", planner.num_views()},
                     {"store_bytes", planner.bytes()},
                     {"cells", planner.num_cells()},
                     {"planner_bytes", planner.BookkeepingBytes()},
                     {"tau_sum", Round(planner.tau_sum(), 6)},
                     {"id_checksum", checksum_hex}};
  std::printf("%s\n", line.dump().c_str());
  std::fflush(stdout);
  if (args.rerender > 0) {  // render-only timing of the final proxy (profiling aid)
    std::vector<double> rr;
    for (int k = 0; k < args.rerender; ++k)
      for (const auto& tp : *traj) {
        const double r0 = CpuMs();
        auto r = cid.Render(tp.local_from_cam, cam, args.idw, args.idh);
        rr.push_back(CpuMs() - r0);
        if (!r.ok()) return 1;
      }
    const json rerender = {{"bench", "cellid_rerender"},
                           {"renders", rr.size()},
                           {"tris", cid.render_triangles()},
                           {"cpu_ms_median", Round(Pct(rr, 0.5), 3)}};
    std::printf("%s\n", rerender.dump().c_str());
  }
  if (!args.quality) return 0;
  (void)render_store_ms;

  LumigraphModel model;
  model.grid = planner.grid();
  model.chunks[0] = chunk;
  model.views = std::move(stored);
  model.cell_refs = planner.CellPublishedRefs();
  auto renderer = CpuLumigraphRenderer::Create(model, {});
  if (!renderer.ok()) {
    std::fprintf(stderr, "%s\n", std::string(renderer.status().message()).c_str());
    return 1;
  }
  synth::RenderOptions test_opt = render_opt;
  test_opt.width = args.test_w;
  test_opt.height = args.test_h;
  const PinholeCamera test_cam = test_opt.Camera();
  synth::TestPoseOptions tpo;
  tpo.count = args.test_views;
  auto poses = synth::MakeTestPoses(scene, test_cam, tpo);
  if (!poses.ok()) {
    std::fprintf(stderr, "%s\n", std::string(poses.status().message()).c_str());
    return 1;
  }
  std::vector<double> ssim, psnr, cov, render_ms;
  for (const Rigid3d& pose : *poses) {
    const auto t0 = Clock::now();
    auto out = (*renderer)->Render(test_cam, pose);
    render_ms.push_back(Ms(t0, Clock::now()));
    auto gt_lin = synth::RenderLinear(scene, pose, test_opt);
    if (!out.ok() || !gt_lin.ok()) continue;
    ImageU8 gt(test_cam.width, test_cam.height, 3);
    for (size_t k = 0; k < gt.size(); ++k) gt.data()[k] = synth::LinearToSrgb8(gt_lin->data()[k]);
    ssim.push_back(Ssim(out->color, gt));
    psnr.push_back(Psnr(out->color, gt));
    cov.push_back(double(out->covered_pixels) / (test_cam.width * test_cam.height));
  }
  auto mean = [](const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x;
    return v.empty() ? 0.0 : s / v.size();
  };
  const json quality = {
      {"bench", "planning_quality"},
      {"scene", args.scene},
      {"traj", args.traj},
      {"frames", total_ms.size()},
      {"r_max", po.r_max},
      {"store", args.store},
      {"views", model.views.size()},
      {"test_views", ssim.size()},
      {"test_res", std::to_string(test_cam.width) + "x" + std::to_string(test_cam.height)},
      {"mssim", Round(mean(ssim), 4)},
      {"psnr", Round(mean(psnr), 2)},
      {"coverage", Round(mean(cov), 4)},
      {"render_ms_median", Round(Pct(render_ms, 0.5), 1)},
      {"render_store_frame_ms_total", Round(render_store_ms, 0)}};
  std::printf("%s\n", quality.dump().c_str());
  return 0;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) {
  exo::Args args;
  if (auto rc = exo::ParseFlags(argc, argv, &args)) return *rc;
  return exo::Run(args);
}
