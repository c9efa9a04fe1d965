// planning_bench: view planning speed per 640x480 frame (cell-id buffer render vs planning) on a
// synthetic scene, and optionally the lumigraph quality (MSSIM/PSNR/coverage) of the planned
// store rendered by the CPU lumigraph renderer at random test poses. One JSON line per run.
//
//   planning_bench --scene village --traj flyover --frames 600 --r_max 16 --store 200
//                  [--idw 160 --idh 120] [--quality 1 --test_views 50 --test_w 320 --test_h 240]
// The proxy is the scene's ground-truth mesh (isolates planning from TSDF error).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "common/lumigraph/cpu_renderer.h"
#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/geometry/cell_areas.h"
#include "server/geometry/scene_scale.h"
#include "server/planning/view_planner.h"

namespace exo {
namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
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
};

Args Parse(int argc, char** argv) {
  Args a;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--scene") a.scene = v;
    else if (k == "--traj") a.traj = v;
    else if (k == "--frames") a.frames = std::stoi(v);
    else if (k == "--r_max") a.r_max = std::stoi(v);
    else if (k == "--store") a.store = std::stoi(v);
    else if (k == "--idw") a.idw = std::stoi(v);
    else if (k == "--idh") a.idh = std::stoi(v);
    else if (k == "--lambda") a.lambda = std::stod(v);
    else if (k == "--cell") a.cell = std::stod(v);
    else if (k == "--quality") a.quality = std::stoi(v);
    else if (k == "--test_views") a.test_views = std::stoi(v);
    else if (k == "--test_w") a.test_w = std::stoi(v);
    else if (k == "--test_h") a.test_h = std::stoi(v);
    else std::fprintf(stderr, "unknown flag %s\n", k.c_str());
  }
  return a;
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
  areas.UpdateChunk(chunk);
  for (const auto& [cell, a] : areas.areas()) (void)planner.SetCellArea(cell, a);

  synth::TrajectoryOptions to;
  to.num_frames = args.frames;
  auto traj = synth::MakeTrajectory(scene, *tkind, to);
  if (!traj.ok()) {
    std::fprintf(stderr, "%s\n", std::string(traj.status().message()).c_str());
    return 1;
  }

  RasterOptions ro;
  ro.cell_id = true;
  ro.cell_grid = planner.grid();
  ro.width = args.idw;
  ro.height = args.idh;
  std::vector<double> cellid_ms, plan_ms, total_ms;
  std::map<ViewId, StoredView> stored;
  int accepted = 0, evicted = 0;
  double render_store_ms = 0;
  for (size_t i = 0; i < traj->size(); ++i) {
    const Rigid3d& pose = (*traj)[i].local_from_cam;
    const auto t0 = Clock::now();
    auto r = Rasterize(scene.mesh, cam, pose, ro);
    if (!r.ok()) continue;
    const auto t1 = Clock::now();
    planning::Candidate c;
    c.id = ViewId(i + 1);
    c.local_from_cam = pose;
    c.id_camera = r->camera;
    c.cells = planning::CountCellPixels(r->cell_id.data(), r->cell_id.size());
    c.bytes = frame_bytes;
    auto d = planner.Consider(c);
    const auto t2 = Clock::now();
    cellid_ms.push_back(Ms(t0, t1));
    plan_ms.push_back(Ms(t1, t2));
    total_ms.push_back(Ms(t0, t2));
    if (!d.ok() || !d->accepted) continue;
    ++accepted;
    evicted += int(d->removed.size());
    if (args.quality) {
      for (ViewId v : d->removed) stored.erase(v);
      const auto t3 = Clock::now();
      auto f = synth::RenderFrame(scene, pose, render_opt);
      render_store_ms += Ms(t3, Clock::now());
      if (!f.ok()) continue;
      StoredView sv;
      sv.id = c.id;
      sv.camera = cam;
      sv.local_from_cam = pose;
      sv.color = std::move(f->frame.color);
      sv.depth_m = std::move(f->frame.depth_m);
      stored[c.id] = std::move(sv);
    }
  }
  std::printf(
      "{\"bench\":\"planning\",\"scene\":\"%s\",\"traj\":\"%s\",\"frames\":%zu,\"r_max\":%d,"
      "\"store\":%d,\"lambda\":%.2f,\"cell_m\":%.3f,\"d_max_m\":%.2f,\"sigma_m\":%.2f,"
      "\"idbuf\":\"%dx%d\",\"cellid_ms_median\":%.3f,\"cellid_ms_p95\":%.3f,"
      "\"plan_ms_median\":%.3f,\"plan_ms_p95\":%.3f,\"total_ms_median\":%.3f,\"total_ms_p95\":%.3f,"
      "\"accepted\":%d,\"evicted\":%d,\"views\":%zu,\"store_bytes\":%zu,\"cells\":%zu,"
      "\"planner_bytes\":%zu,\"tau_sum\":%.2f}\n",
      args.scene.c_str(), args.traj.c_str(), total_ms.size(), po.r_max, args.store, po.lambda,
      po.cell_size_m, po.d_max_m, po.sigma_m, args.idw, args.idh, Pct(cellid_ms, 0.5),
      Pct(cellid_ms, 0.95), Pct(plan_ms, 0.5), Pct(plan_ms, 0.95), Pct(total_ms, 0.5),
      Pct(total_ms, 0.95), accepted, evicted, planner.num_views(), planner.bytes(),
      planner.num_cells(), planner.BookkeepingBytes(), planner.tau_sum());
  std::fflush(stdout);
  if (!args.quality) return 0;

  LumigraphModel model;
  model.grid = planner.grid();
  model.chunks[0] = chunk;
  model.views = std::move(stored);
  model.cell_refs = planner.CellRefs();
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
  std::printf(
      "{\"bench\":\"planning_quality\",\"scene\":\"%s\",\"traj\":\"%s\",\"frames\":%zu,"
      "\"r_max\":%d,\"store\":%d,\"views\":%zu,\"test_views\":%zu,\"test_res\":\"%dx%d\","
      "\"mssim\":%.4f,\"psnr\":%.2f,\"coverage\":%.4f,\"render_ms_median\":%.1f,"
      "\"render_store_frame_ms_total\":%.0f}\n",
      args.scene.c_str(), args.traj.c_str(), total_ms.size(), po.r_max, args.store,
      model.views.size(), ssim.size(), test_cam.width, test_cam.height, mean(ssim), mean(psnr),
      mean(cov), Pct(render_ms, 0.5), render_store_ms);
  return 0;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) { return exo::Run(exo::Parse(argc, argv)); }
