// refinement_bench: per-view refinement time at 640x480 and what refinement buys, on the
// synthetic scenes (common/synth) with exposure changes and pose noise injected into the stored
// views. A first JSON line records the run (commit, build, machine, load: common/run_info),
// then one JSON object per configuration (speed and error side by side):
//  - ms per refined view (median, p95), pose error (deg, mm) and exposure error before/after,
//    rejections, refusals;
//  - MSSIM / PSNR of CPU lumigraph renders (common/lumigraph/cpu_renderer, ground-truth proxy
//    mesh) at held-out trajectory poses with refinement off, on, and with the true poses and
//    exposures (oracle).
//
//   refinement_bench [--scene apartment|village|all] [--frames N] [--stride S]
//                    [--rot-deg D] [--trans-m M] [--exposure-jitter X] [--width W --height H]
//                    [--seed S] [--heldout N] [--levels L] [--samples N] [--oracle-refs 1]
//                    [--outlier-rel X] [--depth-weight W]
//   refinement_bench --scene 7scenes [--register 0|1 (default 1: depth registered to colour)]
//   refinement_bench --help (every flag)
// The first stored view is the gauge anchor (true pose, E = 1); views are refined in order, each
// against the views stored (and refined) before it, as the planner does online.
#include "exoview_source_dir.h"
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <numeric>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/cli/cli.h"
#include "common/datasets/seven_scenes.h"
#include "common/lumigraph/cpu_renderer.h"
#include "common/metrics/metrics.h"
#include "common/run_info/run_info.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/geometry/tsdf_volume.h"
#include "server/refinement/view_refiner.h"

namespace exo {
namespace {

std::string DefaultDataDir() {
  const char* env = std::getenv("EXOVIEW_SHARED_DIR");
  return std::string(env ? env : EXOVIEW_SOURCE_DIR "/../shared") + "/data/7scenes-redkitchen";
}

struct Args {
  std::string scene = "all";
  int frames = 64, stride = 4, heldout = 12;
  double rot_deg = 1.5, trans_m = 0.015, exposure_jitter = 0.7;  // exposure = 2^U(-X, X)
  int width = 640, height = 480;
  uint64_t seed = 1;
  int levels = 0, samples = 0;  // 0: RefinementOptions defaults
  double outlier_rel = 0;       // 0: default
  bool oracle_refs = false;     // refine each view against true-pose references (diagnostic)
  int freeze = -1, rot_only_level = -1;  // -1: defaults
  double min_info = -1;
  int iters = 0, outer = 0;
  double depth_weight = -1, min_tinfo = -1;
  bool refine_pose = true;
  int reg = 1;     // 7scenes: register depth to colour (common/datasets rgbd_registration)
  bool keep_rejected = false;  // 7scenes: keep outlier views at their input pose
  double multistart_step = -1;  // RefinementOptions::multistart_step_m (0: off; <0: default)
  int multistart_level = -1;    // RefinementOptions::multistart_from_level (<0: default)
  double egate = -1;            // RefinementOptions::min_exposure_gain_over_disagreement
  double gate = -1;             // RefinementOptions::min_pose_gain_over_disagreement (<0: default)
  double conv_px = -1;          // RefinementOptions::convergence_px (<0: default)
  double ftol = -1;             // RefinementOptions::function_tolerance (<0: default)
  bool cache = true;            // RefinementCache for the references' pyramids (--cache 0: off)
  bool render = true;           // held-out MSSIM/PSNR (slow); --render 0 for pose diagnostics
  bool verbose = false;         // per-view diagnostics on stderr
  bool stages = false;          // per-stage energies on stderr
  std::string data_dir = DefaultDataDir();  // 7-Scenes redkitchen
};

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(p * (v.size() - 1) + 0.5))];
}

StoredView ToStored(const Frame& f, ViewId id) {
  StoredView v;
  v.id = id;
  v.camera = f.color_camera;
  v.local_from_cam = f.world_from_cam;  // scene origin is 0: local == world
  v.color = f.color;
  v.depth_m = f.depth_m;
  v.exposure = 1.0f;
  return v;
}

// Every stored view referenced by every cell the proxy touches (the renderer picks the best 3
// per pixel); cells found by sampling each triangle at a quarter of the cell size.
void FillCellRefs(const TriangleMesh& mesh, LumigraphModel* model) {
  std::vector<ViewId> ids;
  for (const auto& [id, v] : model->views) ids.push_back(id);
  const double step = 0.25 * model->grid.cell_size_m;
  for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
    const glm::dvec3 a(mesh.positions[mesh.indices[t]]), b(mesh.positions[mesh.indices[t + 1]]),
        c(mesh.positions[mesh.indices[t + 2]]);
    const int n = std::max(1, static_cast<int>(std::ceil(std::max(glm::length(b - a), glm::length(c - a)) / step)));
    for (int i = 0; i <= n; ++i)
      for (int j = 0; i + j <= n; ++j) {
        const glm::dvec3 p = a + (b - a) * (double(i) / n) + (c - a) * (double(j) / n);
        auto& r = model->cell_refs[model->grid.IdOf(p)];
        if (r.empty()) r = ids;
      }
  }
}

struct Quality {
  double mssim = 0, psnr = 0, coverage = 0, render_ms = 0;
};

absl::StatusOr<Quality> RenderQuality(const TriangleMesh& mesh, std::vector<StoredView> views,
                                      const std::vector<Rigid3d>& poses,
                                      const std::vector<ImageU8>& truth, const PinholeCamera& cam) {
  LumigraphModel model;
  model.grid.cell_size_m = 1.0;
  for (auto& v : views) model.views[v.id] = std::move(v);
  FillCellRefs(mesh, &model);
  model.chunks[0].mesh = mesh;
  CpuRenderOptions ro;
  EXO_ASSIGN_OR_RETURN(auto renderer, CpuLumigraphRenderer::Create(model, ro));
  Quality q;
  std::vector<ImageU8> out;
  double psnr = 0;
  for (size_t i = 0; i < poses.size(); ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    EXO_ASSIGN_OR_RETURN(CpuRenderOutput r, renderer->Render(cam, poses[i]));
    q.render_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    EXO_ASSIGN_OR_RETURN(double p, MaskedPsnr(r.color, truth[i], r.coverage));
    psnr += std::min(p, 99.0);
    q.coverage += double(r.covered_pixels) / (cam.width * cam.height);
    out.push_back(std::move(r.color));
  }
  EXO_ASSIGN_OR_RETURN(q.mssim, MeanSsim(out, truth));
  q.psnr = psnr / poses.size();
  q.coverage /= poses.size();
  q.render_ms /= poses.size();
  return q;
}

// 7-Scenes redkitchen (real data): every `stride`-th of the first `frames` frames is a stored
// view with the dataset pose (KinectFusion) and the camera's own auto-exposure; held-out frames
// lie half-way between, minus those whose colour is byte-identical to a stored view's (the
// dataset repeats colour frames, see data/README.md). Proxy: TSDF (server/geometry, 2 cm) of the
// stored views' depth. Colour and depth are NOT registered there (10-20 px offset, the poses and
// K are the depth camera's): refinement runs photometric-only (depth_weight 0), the samples'
// 3-D positions still come from the unregistered depth. "off": dataset poses, E = 1; "on":
// chain refinement (outliers dropped). No ground truth pose, so only held-out SSIM/PSNR.
absl::Status RunSevenScenes(const Args& a) {
  const std::string& dir = a.data_dir;
  SevenScenesOptions so;
  so.register_depth = a.reg != 0;
  EXO_ASSIGN_OR_RETURN(auto reader, SevenScenesReader::Open(dir, so));
  const int n = std::min<int>(a.frames, static_cast<int>(reader->size()));
  std::vector<StoredView> views;
  TsdfOptions to;
  to.voxel_size_m = 0.02f;
  TsdfVolume tsdf(to);
  const LocalOrigin origin;
  for (int i = 0; i < n; i += a.stride) {
    EXO_ASSIGN_OR_RETURN(Frame f, reader->Load(i));
    EXO_RETURN_IF_ERROR(tsdf.Integrate(f, origin).status());
    StoredView v = ToStored(f, static_cast<ViewId>(views.size() + 1));
    views.push_back(std::move(v));
  }
  const TriangleMesh mesh = tsdf.ExtractAll();
  std::vector<Rigid3d> held;
  std::vector<ImageU8> held_truth;
  int dropped = 0;
  for (int i = a.stride / 2; i < n; i += a.stride) {
    EXO_ASSIGN_OR_RETURN(Frame f, reader->Load(i));
    bool dup = false;
    for (const auto& v : views)
      dup = dup || std::equal(v.color.data(), v.color.data() + v.color.bytes(), f.color.data());
    if (dup) {
      ++dropped;
      continue;
    }
    held.push_back(f.world_from_cam);
    held_truth.push_back(std::move(f.color));
  }
  RefinementOptions opt;
  // Registered: the depth term is valid (the library default); raw: photometric only.
  opt.depth_weight = a.depth_weight >= 0 ? a.depth_weight : (a.reg ? opt.depth_weight : 0.0);
  opt.refine_pose = a.refine_pose;
  if (a.samples > 0) opt.max_samples = a.samples;
  if (a.gate >= 0) opt.min_pose_gain_over_disagreement = a.gate;
  if (a.multistart_step >= 0) opt.multistart_step_m = a.multistart_step;
  if (a.multistart_level >= 0) opt.multistart_from_level = a.multistart_level;
  if (a.egate >= 0) opt.min_exposure_gain_over_disagreement = a.egate;
  RefinementStats stats;
  RefinementCache cache(64);  // stored views' pyramids, kept between calls (--cache 0: off)
  std::vector<StoredView> refined;
  refined.push_back(views[0]);
  std::vector<double> cpu_ms, moved_deg, moved_mm, expo;
  for (size_t i = 1; i < views.size(); ++i) {
    std::vector<const StoredView*> refs;
    for (const auto& r : refined) refs.push_back(&r);
    auto res = RefineView(views[i], refs, opt, a.cache ? &cache : nullptr);
    if (!res.ok()) {
      std::fprintf(stderr, "view %zu: %s\n", i, std::string(res.status().message()).c_str());
      refined.push_back(views[i]);
      continue;
    }
    stats.Add(*res);
    cpu_ms.push_back(res->cpu_ms);
    if (res->rejected_outlier) {
      if (a.keep_rejected) refined.push_back(views[i]);
      continue;
    }
    StoredView v = views[i];
    moved_deg.push_back(RotationAngleRad(v.local_from_cam.rotation, res->local_from_cam.rotation) * 180 / M_PI);
    moved_mm.push_back(1000 * glm::length(v.local_from_cam.translation - res->local_from_cam.translation));
    expo.push_back(res->exposure);
    v.local_from_cam = res->local_from_cam;
    v.exposure = static_cast<float>(res->exposure);
    refined.push_back(std::move(v));
  }
  const PinholeCamera cam = views[0].camera;
  EXO_ASSIGN_OR_RETURN(Quality q_off, RenderQuality(mesh, views, held, held_truth, cam));
  EXO_ASSIGN_OR_RETURN(Quality q_on, RenderQuality(mesh, refined, held, held_truth, cam));
  const nlohmann::json row = {
      {"bench", "refinement"},
      {"scene", "7scenes-redkitchen"},
      {"frames", n},
      {"stride", a.stride},
      {"registered", a.reg != 0 ? 1 : 0},
      {"refine_pose", a.refine_pose ? 1 : 0},
      {"keep_rejected", a.keep_rejected ? 1 : 0},
      {"stored", views.size()},
      {"heldout", held.size()},
      {"heldout_dropped_duplicate_colour", dropped},
      {"depth_weight", opt.depth_weight},
      {"cpu_ms_median", Percentile(cpu_ms, 0.5)},
      {"cpu_ms_p95", Percentile(cpu_ms, 0.95)},
      {"pose_change_deg_median", Percentile(moved_deg, 0.5)},
      {"pose_change_deg_p95", Percentile(moved_deg, 0.95)},
      {"pose_change_mm_median", Percentile(moved_mm, 0.5)},
      {"pose_change_mm_p95", Percentile(moved_mm, 0.95)},
      {"exposure_min", Percentile(expo, 0.0)},
      {"exposure_max", Percentile(expo, 1.0)},
      {"rejected_outlier", stats.rejected_outlier},
      {"pose_refused", stats.pose_refused},
      {"mssim_off", q_off.mssim},
      {"mssim_on", q_on.mssim},
      {"psnr_off", q_off.psnr},
      {"psnr_on", q_on.psnr},
      {"coverage_on", q_on.coverage}};
  std::printf("%s\n", row.dump().c_str());
  std::fflush(stdout);
  return absl::OkStatus();
}

absl::Status RunScene(synth::SceneKind kind, const Args& a) {
  synth::SceneOptions so;
  so.seed = a.seed;
  EXO_ASSIGN_OR_RETURN(synth::SynthScene scene, synth::MakeScene(kind, so));
  synth::TrajectoryOptions to;
  to.num_frames = a.frames;
  const auto traj_kind = scene.indoor ? synth::TrajectoryKind::kWalk : synth::TrajectoryKind::kFlyover;
  EXO_ASSIGN_OR_RETURN(auto traj, synth::MakeTrajectory(scene, traj_kind, to));
  synth::RenderOptions ro;
  ro.width = a.width;
  ro.height = a.height;
  const PinholeCamera cam = ro.Camera();
  std::mt19937_64 rng(a.seed * 1000 + static_cast<int>(kind));
  std::uniform_real_distribution<double> uni(-a.exposure_jitter, a.exposure_jitter);

  // Stored views: every stride-th frame; exposure k_i and pose noise (not on the anchor).
  std::vector<StoredView> noisy;
  std::vector<Rigid3d> truth_pose;
  std::vector<double> k;
  for (int i = 0, n = 0; i < static_cast<int>(traj.size()); i += a.stride, ++n) {
    synth::FrameNoise fn;
    fn.exposure = n == 0 ? 1.0 : std::exp2(uni(rng));
    fn.rotation_deg = n == 0 ? 0.0 : a.rot_deg;
    fn.translation_m = n == 0 ? 0.0 : a.trans_m;
    fn.seed = a.seed * 7777 + n;
    EXO_ASSIGN_OR_RETURN(auto rf, synth::RenderFrame(scene, traj[i].local_from_cam, ro, fn, n));
    noisy.push_back(ToStored(rf.frame, static_cast<ViewId>(n + 1)));
    truth_pose.push_back(rf.true_world_from_cam);
    k.push_back(fn.exposure);
  }
  // Held-out poses between stored frames; ground truth at the anchor's exposure (1).
  std::vector<Rigid3d> held;
  std::vector<ImageU8> held_truth;
  const int hstep = std::max(1, static_cast<int>(traj.size()) / std::max(1, a.heldout));
  for (int i = a.stride / 2; i < static_cast<int>(traj.size()) && static_cast<int>(held.size()) < a.heldout;
       i += hstep) {
    EXO_ASSIGN_OR_RETURN(auto rf, synth::RenderFrame(scene, traj[i].local_from_cam, ro));
    held.push_back(traj[i].local_from_cam);
    held_truth.push_back(std::move(rf.frame.color));
  }

  // Refinement, online order.
  RefinementOptions opt;
  if (a.levels > 0) opt.pyramid_levels = a.levels;
  if (a.samples > 0) opt.max_samples = a.samples;
  if (a.outlier_rel > 0) opt.outlier_max_relative_residual = a.outlier_rel;
  if (a.iters > 0) opt.max_solver_iterations = a.iters;
  if (a.depth_weight >= 0) opt.depth_weight = a.depth_weight;
  if (a.min_tinfo >= 0) opt.min_translation_information = a.min_tinfo;
  if (a.outer > 0) opt.max_outer_iterations = a.outer;
  if (a.freeze >= 0) opt.freeze_weak_directions = a.freeze != 0;
  if (a.rot_only_level >= 0) opt.rotation_only_from_level = a.rot_only_level;
  if (a.min_info >= 0) opt.min_pose_information = a.min_info;
  if (a.multistart_step >= 0) opt.multistart_step_m = a.multistart_step;
  if (a.multistart_level >= 0) opt.multistart_from_level = a.multistart_level;
  if (a.egate >= 0) opt.min_exposure_gain_over_disagreement = a.egate;
  if (a.ftol > 0) opt.function_tolerance = a.ftol;
  if (a.conv_px > 0) opt.convergence_px = a.conv_px;
  if (a.gate >= 0) opt.min_pose_gain_over_disagreement = a.gate;
  RefinementStats stats;
  RefinementCache cache(64);  // stored views' pyramids, kept between calls (--cache 0: off)
  std::vector<StoredView> refined;
  refined.push_back(noisy[0]);
  int converged = 0;  // kept views within 0.2 deg and 5 mm of the truth (the target)
  std::vector<double> ms, cpu_ms, rot_before, rot_after, tr_before, tr_after, e_before, e_after;
  std::vector<double> cpu_pyr, cpu_samples, cpu_solve;  // per-phase CPU ms
  std::vector<double> solver_iters;  // solver iterations per view, all stages (deterministic)
  for (size_t i = 1; i < noisy.size(); ++i) {
    std::vector<const StoredView*> refs;
    std::vector<StoredView> oracle_refs;
    if (a.oracle_refs) {
      for (size_t j = 0; j < i; ++j) {
        oracle_refs.push_back(noisy[j]);
        oracle_refs.back().local_from_cam = truth_pose[j];
        oracle_refs.back().exposure = static_cast<float>(1.0 / k[j]);
      }
      for (const auto& r : oracle_refs) refs.push_back(&r);
    } else {
      for (const auto& r : refined) refs.push_back(&r);
    }
    auto res = RefineView(noisy[i], refs, opt, a.cache ? &cache : nullptr);
    StoredView v = noisy[i];
    rot_before.push_back(RotationAngleRad(v.local_from_cam.rotation, truth_pose[i].rotation) * 180 / M_PI);
    tr_before.push_back(1000 * glm::length(v.local_from_cam.translation - truth_pose[i].translation));
    e_before.push_back(std::abs(1.0 * k[i] - 1.0));
    bool keep = true;
    if (res.ok()) {
      if (a.verbose)
        std::fprintf(stderr,
                     "view %zu k=%.3f E=%.3f rot %.3f->%.3f trans %.1f->%.1f mm n=%d valid=%d "
                     "lmin=%.3g tinfo=%.3g cond=%.3g free=%d refused=%d outlier=%d attempts=%d rel=%.3f thr=%.3f "
                     "disagree=%.3f %.1f ms (cpu %.1f: pyr %.1f samples %.1f solve %.1f)\n",
                     i, k[i], res->exposure, rot_before.back(),
                     RotationAngleRad(res->local_from_cam.rotation, truth_pose[i].rotation) * 180 / M_PI,
                     tr_before.back(),
                     1000 * glm::length(res->local_from_cam.translation - truth_pose[i].translation),
                     res->num_samples, res->num_valid_final, res->pose_min_eigenvalue, res->pose_translation_information,
                     res->pose_condition, res->pose_free_directions, res->pose_refused_rank_deficient, res->rejected_outlier,
                     res->attempts, res->relative_residual, res->outlier_threshold, res->reference_disagreement, res->ms, res->cpu_ms,
                     res->cpu_ms_pyramids, res->cpu_ms_samples, res->cpu_ms_solve);
      if (a.verbose) {
        const glm::dvec3 d_cam = glm::conjugate(truth_pose[i].rotation) *
                                 (res->local_from_cam.translation - truth_pose[i].translation);
        std::fprintf(stderr, "   camera-centre error in the true camera frame: (%.1f, %.1f, %.1f) mm\n",
                     1000 * d_cam.x, 1000 * d_cam.y, 1000 * d_cam.z);
      }
      if (a.stages)
        for (const auto& st : res->stages)
          std::fprintf(stderr, "   L%d %s %.4g -> %.4g %s rot %.3f deg trans %.1f mm E %.3f\n", st.level,
                       st.pose ? "pose" : "expo", st.before, st.after, st.accepted ? "" : "UNDONE",
                       RotationAngleRad(st.local_from_cam.rotation, truth_pose[i].rotation) * 180 / M_PI,
                       1000 * glm::length(st.local_from_cam.translation - truth_pose[i].translation),
                       st.exposure * k[i]);
      stats.Add(*res);
      ms.push_back(res->ms);
      cpu_ms.push_back(res->cpu_ms);
      cpu_pyr.push_back(res->cpu_ms_pyramids);
      cpu_samples.push_back(res->cpu_ms_samples);
      cpu_solve.push_back(res->cpu_ms_solve);
      solver_iters.push_back(res->iterations);
      if (!res->rejected_outlier) {
        v.local_from_cam = res->local_from_cam;
        v.exposure = static_cast<float>(res->exposure);
      } else {
        keep = false;  // pose outliers are discarded (thesis §3.1.3), as the planner does
      }
    } else {
      std::fprintf(stderr, "view %zu: %s\n", i, std::string(res.status().message()).c_str());
    }
    if (!keep) continue;  // errors "on" are over the views kept in the store
    const double rot_err = RotationAngleRad(v.local_from_cam.rotation, truth_pose[i].rotation) * 180 / M_PI;
    const double tr_err = 1000 * glm::length(v.local_from_cam.translation - truth_pose[i].translation);
    converged += rot_err < 0.2 && tr_err < 5.0;
    rot_after.push_back(RotationAngleRad(v.local_from_cam.rotation, truth_pose[i].rotation) * 180 / M_PI);
    tr_after.push_back(1000 * glm::length(v.local_from_cam.translation - truth_pose[i].translation));
    e_after.push_back(std::abs(v.exposure * k[i] - 1.0));
    refined.push_back(std::move(v));
  }
  std::vector<StoredView> oracle = noisy;
  for (size_t i = 0; i < oracle.size(); ++i) {
    oracle[i].local_from_cam = truth_pose[i];
    oracle[i].exposure = static_cast<float>(1.0 / k[i]);
  }
  Quality q_off, q_on, q_true;
  if (a.render) {
    EXO_ASSIGN_OR_RETURN(q_off, RenderQuality(scene.mesh, noisy, held, held_truth, cam));
    EXO_ASSIGN_OR_RETURN(q_on, RenderQuality(scene.mesh, refined, held, held_truth, cam));
    EXO_ASSIGN_OR_RETURN(q_true, RenderQuality(scene.mesh, oracle, held, held_truth, cam));
  }
  const nlohmann::json row = {
      {"bench", "refinement"},
      {"scene", synth::SceneKindName(kind)},
      {"width", a.width},
      {"height", a.height},
      {"views_refined", noisy.size() - 1},
      {"refs_max", opt.max_reference_views},
      {"outlier_rel", opt.outlier_max_relative_residual},
      {"max_samples", opt.max_samples},
      {"noise_rot_deg", a.rot_deg},
      {"noise_trans_m", a.trans_m},
      {"exposure_jitter_log2", a.exposure_jitter},
      {"oracle_refs", a.oracle_refs ? 1 : 0},
      {"converged_0p2deg_5mm", converged},
      {"ms_median", Percentile(ms, 0.5)},
      {"ms_p95", Percentile(ms, 0.95)},
      {"cpu_ms_median", Percentile(cpu_ms, 0.5)},
      {"cpu_ms_p95", Percentile(cpu_ms, 0.95)},
      {"rot_err_deg_median_off", Percentile(rot_before, 0.5)},
      {"rot_err_deg_median_on", Percentile(rot_after, 0.5)},
      {"rot_err_deg_p95_on", Percentile(rot_after, 0.95)},
      {"trans_err_mm_median_off", Percentile(tr_before, 0.5)},
      {"trans_err_mm_median_on", Percentile(tr_after, 0.5)},
      {"trans_err_mm_p95_on", Percentile(tr_after, 0.95)},
      {"exposure_relerr_median_off", Percentile(e_before, 0.5)},
      {"exposure_relerr_median_on", Percentile(e_after, 0.5)},
      {"exposure_relerr_p95_on", Percentile(e_after, 0.95)},
      {"stored_on", refined.size()},
      {"rejected_outlier", stats.rejected_outlier},
      {"pose_refused", stats.pose_refused},
      {"heldout_views", held.size()},
      {"mssim_off", q_off.mssim},
      {"mssim_on", q_on.mssim},
      {"mssim_true_poses", q_true.mssim},
      {"psnr_off", q_off.psnr},
      {"psnr_on", q_on.psnr},
      {"psnr_true_poses", q_true.psnr},
      {"coverage", q_on.coverage},
      {"render_ms", q_on.render_ms},
      {"cpu_ms_pyramids_median", Percentile(cpu_pyr, 0.5)},
      {"cpu_ms_samples_median", Percentile(cpu_samples, 0.5)},
      {"cpu_ms_solve_median", Percentile(cpu_solve, 0.5)},
      {"cpu_ms_sum", std::accumulate(cpu_ms.begin(), cpu_ms.end(), 0.0)},
      {"iterations_median", Percentile(solver_iters, 0.5)},
      {"iterations_p95", Percentile(solver_iters, 0.95)},
      {"iterations_total", std::accumulate(solver_iters.begin(), solver_iters.end(), 0.0)},
      {"cache", a.cache ? 1 : 0},
      {"pose_solver", "ceres_batched"}};
  std::printf("%s\n", row.dump().c_str());
  std::fflush(stdout);
  return absl::OkStatus();
}

int Main(int argc, char** argv) {
  Args a;
  int oracle_refs = 0, render = 1, pose = 1, cache = 1, keep_rejected = 0;
  CLI::App app{"Per-view refinement time and what refinement buys on the synthetic scenes (pose "
               "noise, exposure changes) or on 7-Scenes: one JSON line per scene after a run_info "
               "line.",
               "refinement_bench"};
  cli::Setup(app);
  app.add_option("--scene", a.scene, "apartment | village | all | 7scenes")
      ->check(CLI::IsMember({"apartment", "village", "all", "7scenes"}));
  app.add_option("--data", a.data_dir, "7-Scenes redkitchen folder (--scene 7scenes)");
  app.add_option("--frames", a.frames, "trajectory frames")->check(CLI::PositiveNumber);
  app.add_option("--stride", a.stride, "every stride-th frame is a stored view")->check(CLI::PositiveNumber);
  app.add_option("--heldout", a.heldout, "held-out render poses")->check(CLI::NonNegativeNumber);
  app.add_option("--rot-deg", a.rot_deg, "pose noise, rotation (deg)");
  app.add_option("--trans-m", a.trans_m, "pose noise, translation (m)");
  app.add_option("--exposure-jitter", a.exposure_jitter, "exposure = 2^U(-X, X)");
  app.add_option("--width", a.width, "image width")->check(CLI::PositiveNumber);
  app.add_option("--height", a.height, "image height")->check(CLI::PositiveNumber);
  app.add_option("--seed", a.seed, "scene and noise seed");
  app.add_option("--levels", a.levels, "RefinementOptions::pyramid_levels (0: default)");
  app.add_option("--samples", a.samples, "RefinementOptions::max_samples (0: default)");
  app.add_option("--outlier-rel", a.outlier_rel, "outlier_max_relative_residual (0: default)");
  app.add_option("--oracle-refs", oracle_refs, "1: refine against true-pose references")->check(CLI::Range(0, 1));
  app.add_option("--render", render, "0: skip the held-out renders")->check(CLI::Range(0, 1));
  app.add_option("--freeze", a.freeze, "freeze_weak_directions 0|1 (-1: default)");
  app.add_option("--iters", a.iters, "max_solver_iterations (0: default)");
  app.add_option("--outer", a.outer, "max_outer_iterations (0: default)");
  app.add_option("--depth-weight", a.depth_weight, "depth_weight (<0: default)");
  app.add_option("--pose", pose, "0: exposure only")->check(CLI::Range(0, 1));
  app.add_option("--cache", cache, "0: no RefinementCache")->check(CLI::Range(0, 1));
  app.add_option("--multistart-step", a.multistart_step, "multistart_step_m (<0: default)");
  app.add_option("--multistart-level", a.multistart_level, "multistart_from_level (<0: default)");
  app.add_option("--egate", a.egate, "min_exposure_gain_over_disagreement (<0: default)");
  app.add_option("--gate", a.gate, "min_pose_gain_over_disagreement (<0: default)");
  app.add_option("--ftol", a.ftol, "function_tolerance (<=0: default)");
  app.add_option("--conv-px", a.conv_px, "convergence_px (<=0: default)");
  app.add_option("--register", a.reg, "7scenes: 1 registers depth to colour")->check(CLI::Range(0, 1));
  app.add_option("--keep-rejected", keep_rejected, "7scenes: 1 keeps outliers at their input pose")
      ->check(CLI::Range(0, 1));
  app.add_option("--min-tinfo", a.min_tinfo, "min_translation_information (<0: default)");
  app.add_option("--rot-only-level", a.rot_only_level, "rotation_only_from_level (<0: default)");
  app.add_option("--min-info", a.min_info, "min_pose_information (<0: default)");
  app.add_flag("--verbose", a.verbose, "per-view diagnostics on stderr");
  app.add_flag("--stages", a.stages, "per-stage energies on stderr");
  if (auto rc = cli::Parse(app, argc, argv)) return *rc;
  a.oracle_refs = oracle_refs != 0;
  a.render = render != 0;
  a.refine_pose = pose != 0;
  a.cache = cache != 0;
  a.keep_rejected = keep_rejected != 0;
  std::printf("%s\n", nlohmann::json{{"bench", "refinement"}, {"run_info", RunInfo()}}.dump().c_str());
  if (a.scene == "7scenes") {
    const absl::Status s = RunSevenScenes(a);
    if (!s.ok()) std::fprintf(stderr, "7scenes: %s\n", std::string(s.message()).c_str());
    return s.ok() ? 0 : 1;
  }
  for (auto kind : {synth::SceneKind::kApartment, synth::SceneKind::kVillage}) {
    if (a.scene != "all" && a.scene != synth::SceneKindName(kind)) continue;
    const absl::Status s = RunScene(kind, a);
    if (!s.ok()) {
      std::fprintf(stderr, "%s: %s\n", synth::SceneKindName(kind), std::string(s.message()).c_str());
      return 1;
    }
  }
  return 0;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) { return exo::Main(argc, argv); }
