#include "server/eval/eval.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <map>
#include <memory>
#include <numbers>
#include <queue>
#include <random>
#include <unordered_map>
#include <unordered_set>

#include <absl/strings/str_cat.h>
#include <absl/strings/str_format.h>
#include <nlohmann/json.hpp>

#include "common/datasets/dataset.h"
#include "common/io/image_file.h"
#include "common/lumigraph/cpu_renderer.h"
#include "common/lumigraph/model.h"
#include "common/metrics/metrics.h"
#include "common/metrics/perceptual.h"
#include "common/metrics/view_scores.h"
#include "common/lumigraph/vertex_color.h"
#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/core/online_model.h"
#include "server/eval/attribution.h"
#include "server/planning/online_baselines.h"
#include "server/geometry/cell_areas.h"
#include "server/geometry/scene_scale.h"
#include "server/planning/cell_id_proxy.h"
#include "server/planning/view_planner.h"

namespace exo::eval {
namespace {

using planning::KeyframeSelector;
using planning::MinDistanceSelector;
using planning::OnlineSelector;
using planning::ProgressiveEveryN;
using planning::ReservoirSampler;

using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}
// CPU time of the calling thread (ms): steadier than wall time on a shared machine. The planning
// path (LOD, concat, 160x120 raster, Consider) runs on this thread only.
double ThreadCpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}
// CPU time of the whole process (ms): integration runs on TsdfOptions::num_threads threads, so
// its CPU cost is the process's (every other stage of Step() runs on the calling thread alone).
double ProcessCpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}
double Pct(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(p * (v.size() - 1) + 0.5))];
}
double Mean(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? 0.0 : s / v.size();
}

std::vector<planning::CellPixelCount> CellCounts(const TriangleMesh& mesh, const CellGrid& grid,
                                                 const PinholeCamera& cam, const Rigid3d& pose,
                                                 int w, int h, PinholeCamera* id_cam) {
  RasterOptions ro;
  ro.z_depth = false;
  ro.cell_id = true;
  ro.cell_grid = grid;
  ro.width = w;
  ro.height = h;
  ro.num_threads = 1;  // a 160x120 buffer: thread start-up costs more than it saves
  *id_cam = cam.Scaled(w, h);
  if (mesh.empty()) return {};
  auto r = Rasterize(mesh, cam, pose, ro);
  if (!r.ok()) return {};
  *id_cam = r->camera;
  return planning::CountCellPixels(r->cell_id.data(), r->cell_id.size());
}

// The cell-id buffer of a frame from the planner's CellIdRenderer (frustum-culled chunk LODs).
absl::StatusOr<std::vector<planning::CellPixelCount>> CellCounts(
    const planning::CellIdRenderer& cid, const PinholeCamera& cam, const Rigid3d& pose, int w,
    int h, PinholeCamera* id_cam, size_t* triangles = nullptr) {
  EXO_ASSIGN_OR_RETURN(planning::CellIdBuffer b, cid.Render(pose, cam, w, h));
  *id_cam = b.camera;
  if (triangles != nullptr) *triangles = b.triangles_rendered;
  return planning::CountCellPixels(b.cell_id.data(), b.cell_id.size());
}

// ---- policies other than the online planner ----

// Gain of a candidate against the current store: τ_sum(F ∪ I) - τ_sum(F) (store not full).
double GainOf(const planning::ViewPlanner& p, const Rigid3d& pose, const PinholeCamera& id_cam,
              const std::vector<planning::CellPixelCount>& cells) {
  const double sr = id_cam.PixelSolidAngle(), tmax = p.options().tau_max;
  double g = 0;
  for (const auto& c : cells) {
    const double phi = p.CoverageOf(pose.translation, c.cell, c.pixels, sr);
    if (!(phi > 0)) continue;
    const double t = p.CellTau(c.cell);
    g += std::min(t + phi, tmax) - std::min(t, tmax);
  }
  return g;
}

// ---- the shared engine: one stream, many configurations ----

struct Source {
  PinholeCamera camera;                       // input frames' camera
  size_t frame_bytes = 0;
  std::vector<Rigid3d> poses;                 // local_from_cam per input frame
  SceneScale scale;
  ScaleMode scale_mode = ScaleMode::kBounds;
  double view_depth_m = 0;                    // median valid depth of the first input frame
  double default_lambda = 0.5;
  double metres_per_rad = 1.0;                // min-distance policy
  std::string dataset;                        // "village/flyover", "7scenes/redkitchen"
  // Loads frame i as a stored view (colour + depth). Called on demand.
  std::function<absl::StatusOr<StoredView>(int)> load_view;
  // Test pose sets ("scene" | "near" | "held_out"), each with its ground-truth images; every
  // configuration is evaluated on every set (one JSON line per set).
  PinholeCamera test_camera;
  struct TestSet {
    std::string label;
    std::vector<Rigid3d> poses;
    std::vector<ImageU8> gt;
    std::vector<ImageF> depth;   // issue 15 own-depth proxy: the test frames' depth (or empty)
    PinholeCamera depth_camera;  // of `depth`
  };
  std::vector<TestSet> test_sets;
};

struct Group {  // configurations sharing one cell size
  CellGrid grid;
  std::unique_ptr<CellAreas> areas;
  // Offline / baseline policies only (the online ones use the core's): final areas and, with
  // --ids proxy, the cell-id renderer of the final proxy.
  std::unique_ptr<planning::CellIdRenderer> cid;
  bool needs_final = false;
  std::vector<std::vector<planning::CellPixelCount>> final_cells;  // per frame, final proxy
                                                                   // (or the frame's depth)
  PinholeCamera id_cam;
};

// An online configuration: the core's planner (server/core, what the server runs), fed the same
// geometry updates as every other online configuration.
struct OnlineState {
  std::unique_ptr<core::OnlinePlanner> planner;
  std::vector<double> consider_ms, consider_cpu_ms;  // core Plan() (cell ids + Consider)
  std::vector<double> plan_ms, plan_cpu_ms;          // + applying the geometry update (+ LOD)
  size_t accepted = 0;
  size_t group = 0;
};

planning::PlannerOptions PlannerFor(const PolicyConfig& c, const Source& src, double cell_m,
                                    size_t frame_bytes) {
  planning::PlannerOptions po;
  po.r_max = c.r_max;
  po.render_refs_max = c.render_refs_max;
  po.max_views = static_cast<size_t>(std::max(1, c.store));
  po.max_bytes = po.max_views * frame_bytes;
  po.lambda = c.lambda >= 0 ? c.lambda : src.default_lambda;
  if (c.delta_tau_sum >= 0) po.delta_tau_sum = c.delta_tau_sum;
  if (c.tau_max > 0) po.tau_max = c.tau_max;
  po.cell_size_m = cell_m;
  po.novelty_positional = c.novelty_positional;
  po.soft_saturation = c.soft_saturation;
  const core::OnlineModelOptions product;  // unset options: the server's defaults
  po.dispersion = c.dispersion >= 0 ? static_cast<planning::PlannerOptions::Dispersion>(c.dispersion)
                                    : product.dispersion;
  po.dispersion_m_per_rad =
      c.dispersion_m_per_rad >= 0 ? c.dispersion_m_per_rad : product.dispersion_m_per_rad;
  po.dispersion_rotation_scale = c.dispersion_rotation_scale > 0
                                     ? c.dispersion_rotation_scale
                                     : product.dispersion_rotation_scale;
  po.dispersion_turn_overlap_rad = c.dispersion_turn_overlap_deg >= 0
                                       ? c.dispersion_turn_overlap_deg * (std::numbers::pi / 180.0)
                                       : product.dispersion_turn_overlap_rad;
  po.dispersion_turn_overlap_scale = c.dispersion_turn_overlap_scale > 0
                                         ? c.dispersion_turn_overlap_scale
                                         : product.dispersion_turn_overlap_scale;
  po.dispersion_turn_axis = c.dispersion_turn_axis >= 0 ? c.dispersion_turn_axis != 0
                                                        : product.dispersion_turn_axis;
  po.dispersion_guard = c.dispersion_guard >= 0 ? c.dispersion_guard : product.dispersion_guard;
  po.dispersion_guard_relative = c.dispersion_guard_relative >= 0
                                     ? c.dispersion_guard_relative
                                     : product.dispersion_guard_relative;
  po.dispersion_guard_unique = c.dispersion_guard_unique >= 0 ? c.dispersion_guard_unique != 0
                                                              : product.dispersion_guard_unique;
  po.dispersion_guard_unique_after = c.dispersion_guard_unique_after >= 0
                                         ? c.dispersion_guard_unique_after
                                         : product.dispersion_guard_unique_after;
  po.dispersion_weight_exponent = c.dispersion_weight_exponent >= 0
                                      ? c.dispersion_weight_exponent
                                      : product.dispersion_weight_exponent;
  po.dispersion_weight_after = c.dispersion_weight_after >= 0 ? c.dispersion_weight_after
                                                              : product.dispersion_weight_after;
  po.dispersion_weight_until = c.dispersion_weight_until >= 0 ? c.dispersion_weight_until
                                                              : product.dispersion_weight_until;
  po.dispersion_keep_nearest = c.dispersion_keep_nearest >= 0 ? c.dispersion_keep_nearest != 0
                                                              : product.dispersion_keep_nearest;
  po.dispersion_recency =
      c.dispersion_recency >= 0 ? c.dispersion_recency : product.dispersion_recency;
  po.dispersion_drop_older = c.dispersion_drop_older >= 0 ? c.dispersion_drop_older != 0
                                                          : product.dispersion_drop_older;
  po.dispersion_time_steps = c.dispersion_time_steps >= 0
                                     ? c.dispersion_time_steps
                                     : product.dispersion_time_steps;
  po.dispersion_time_max = c.dispersion_time_max >= 0 ? c.dispersion_time_max != 0
                                                      : product.dispersion_time_max;
  po.dispersion_time_arc = c.dispersion_time_arc >= 0 ? c.dispersion_time_arc != 0
                                                      : product.dispersion_time_arc;
  po.dispersion_time_auto_ref = c.dispersion_time_auto_ref >= 0
                                    ? c.dispersion_time_auto_ref
                                    : product.dispersion_time_auto_ref;
  po.observe_zero_coverage = c.observe_zero_coverage >= 0 ? c.observe_zero_coverage != 0
                                                          : product.observe_zero_coverage;
  po.d_max_m = src.scale.d_max_m;
  po.sigma_m = src.scale.sigma_m;
  if (src.scale_mode != ScaleMode::kBounds && src.view_depth_m > 0) {
    const planning::PlannerOptions f =
        planning::PlannerOptions::ForScene(src.scale.diameter_m, src.view_depth_m);
    po.d_max_m = f.d_max_m;
    po.sigma_m = f.sigma_m;
  }
  return po;
}

ImageU8 Hstack(const std::vector<const ImageU8*>& imgs) {
  int w = 0, h = 0;
  for (auto* i : imgs) {
    w += i->width();
    h = std::max(h, i->height());
  }
  ImageU8 out(w, h, 3, 0);
  int x0 = 0;
  for (auto* i : imgs) {
    for (int y = 0; y < i->height(); ++y)
      for (int x = 0; x < i->width(); ++x)
        for (int c = 0; c < 3; ++c) out.at(x0 + x, y, c) = i->at(x, y, i->channels() == 3 ? c : 0);
    x0 += i->width();
  }
  return out;
}

struct EvalSink {
  std::vector<double> ssim, psnr, cov, ssim_cov, render_ms, surface;
  std::vector<double> ssim_unfilled, psnr_unfilled;
  std::vector<double> ms_ssim, gmsd;  // issue 15 (filled frame)
  std::vector<double> ssim_gain_fit, psnr_gain_fit;  // issue 15 attribution
  Quality Finish() const {
    Quality q;
    q.mssim = Mean(ssim);
    q.psnr = Mean(psnr);
    q.coverage = Mean(cov);
    q.mssim_covered = Mean(ssim_cov);
    q.surface = Mean(surface);
    q.mssim_unfilled = Mean(ssim_unfilled);
    q.psnr_unfilled = Mean(psnr_unfilled);
    q.ms_ssim = ms_ssim.empty() ? std::nan("") : Mean(ms_ssim);
    q.gmsd = Mean(gmsd);
    q.mssim_gain_fit = Mean(ssim_gain_fit);
    q.psnr_gain_fit = Mean(psnr_gain_fit);
    q.views = int(ssim.size());
    return q;
  }
  // `img` as rendered without the hole fill; `mask` = covered (blended) pixels, `known` =
  // covered or filled at infinity. The headline metrics are of the frame the product shows:
  // `img` with its unknown pixels filled by FillHoles (BlendOptions::fill_holes, the renderers'
  // default); *_unfilled and mssim_covered are of `img` as it is (the metrics of sessions 1-4).
  absl::Status Add(const ImageU8& img, const ImageU8& gt, const ImageU8& mask,
                   const ImageU8& known, double ms) {
    ImageU8 filled = img;
    FillHoles(filled, known);
    EXO_ASSIGN_OR_RETURN(const ViewScores v, ScoreView(filled, img, gt, mask));
    ssim.push_back(v.ssim);
    psnr.push_back(v.psnr);
    ssim_unfilled.push_back(v.ssim_unfilled);
    psnr_unfilled.push_back(v.psnr_unfilled);
    cov.push_back(v.coverage);
    if (v.ms_ssim) ms_ssim.push_back(*v.ms_ssim);  // issue 15: MS-SSIM and GMSD, filled frame
    gmsd.push_back(v.gmsd);
    {
      ImageU8 fitted = filled;
      FitGainToReference(fitted, gt, mask);
      EXO_ASSIGN_OR_RETURN(double sf, Ssim(fitted, gt));
      EXO_ASSIGN_OR_RETURN(double mf, Mse(fitted, gt));
      ssim_gain_fit.push_back(sf);
      psnr_gain_fit.push_back(std::min(99.0, PsnrFromMse(mf)));
    }
    if (v.ssim_covered) ssim_cov.push_back(*v.ssim_covered);
    render_ms.push_back(ms);
    return absl::OkStatus();
  }
};

// A value rounded to `digits` decimals (JSON numbers stay short: 0.7081, not 0.70812345...).
double Round(double v, int digits) {
  const double k = std::pow(10.0, digits);
  return std::isfinite(v) ? std::round(v * k) / k : 0.0;
}
nlohmann::json RoundedArray(const std::vector<double>& v, int digits) {
  nlohmann::json a = nlohmann::json::array();
  for (double x : v) a.push_back(Round(x, digits));
  return a;
}

// One JSON line per configuration and test set (field names read by eval_charts, eval_tables.py
// and docs/evaluation.md; keep them).
std::string ConfigJson(const std::string& dataset, const std::string& test_poses,
                       const std::string& proxy, double voxel_m,
                       int frames, const PolicyConfig& c, double lambda, double cell_m,
                       double dts, const ConfigResult& r, int idw, int idh,
                       const planning::PlannerOptions& po, const std::string& scale,
                       double lod_m, const char* ids) {
  const bool baseline = PolicyIsBaseline(c.policy);
  const char* refs = c.policy == Policy::kVertexColor ? "none"
                     : baseline && c.uncapped_refs    ? "uncapped"
                                                      : "preselect";
  nlohmann::ordered_json j;
  j["bench"] = "eval";
  j["dataset"] = dataset;
  j["test_poses"] = test_poses;
  j["proxy"] = proxy;
  j["tag"] = c.tag;
  j["config"] = {{"policy", PolicyName(c.policy)},
                 {"refs", refs},
                 {"frames", frames},
                 {"store", c.store},
                 {"r_max", c.r_max},
                 {"lambda", Round(lambda, 2)},
                 {"blend_lambda", Round(c.blend_lambda >= 0 ? c.blend_lambda : c.blend ? c.blend->lambda : blend::BlendOptions{}.lambda, 2)},
                 {"cell_m", Round(cell_m, 3)},
                 {"voxel_m", Round(voxel_m, 4)},
                 {"delta_tau_sum", Round(dts, 3)},
                 {"idbuf", absl::StrCat(idw, "x", idh)},
                 {"ids", ids},
                 {"scale", scale},
                 {"d_max_m", Round(po.d_max_m, 2)},
                 {"sigma_m", Round(po.sigma_m, 2)},
                 {"cellid_lod_m", Round(lod_m, 3)},
                 {"face_areas", int(c.face_areas)},
                 {"online", int(PolicyIsOnline(c.policy))},
                 {"novelty_positional", int(c.novelty_positional)},
                 {"soft_saturation", int(c.soft_saturation)},
                 {"dispersion", int(po.dispersion)},
                 {"dispersion_m_per_rad", po.dispersion_m_per_rad},
                 {"dispersion_rotation_scale", po.dispersion_rotation_scale},
                 {"dispersion_turn_overlap_deg", Round(po.dispersion_turn_overlap_rad * 180.0 / std::numbers::pi, 2)},
                 {"dispersion_turn_overlap_scale", po.dispersion_turn_overlap_scale},
                 {"dispersion_turn_axis", int(po.dispersion_turn_axis)},
                 {"dispersion_guard", po.dispersion_guard},
                 {"dispersion_guard_relative", po.dispersion_guard_relative},
                 {"dispersion_guard_unique", int(po.dispersion_guard_unique)},
                 {"dispersion_guard_unique_after", po.dispersion_guard_unique_after},
                 {"dispersion_weight_exponent", po.dispersion_weight_exponent},
                 {"dispersion_weight_after", po.dispersion_weight_after},
                 {"dispersion_weight_until", po.dispersion_weight_until},
                 {"dispersion_keep_nearest", int(po.dispersion_keep_nearest)},
                 {"dispersion_recency", po.dispersion_recency},
                 {"dispersion_drop_older", int(po.dispersion_drop_older)},
                 {"dispersion_time_steps", po.dispersion_time_steps},
                 {"dispersion_time_max", int(po.dispersion_time_max)},
                 {"dispersion_time_arc", int(po.dispersion_time_arc)},
                 {"dispersion_time_auto_ref", po.dispersion_time_auto_ref},
                 {"observe_zero_coverage", int(po.observe_zero_coverage)},
                 {"sharp_gamma", c.sharp_gamma}};
  j["quality"] = {{"mssim", Round(r.quality.mssim, 4)},
                  {"psnr", Round(r.quality.psnr, 2)},
                  {"coverage", Round(r.quality.coverage, 4)},
                  {"mssim_covered", Round(r.quality.mssim_covered, 4)},
                  {"surface", Round(r.quality.surface, 4)},
                  {"mssim_unfilled", Round(r.quality.mssim_unfilled, 4)},
                  {"psnr_unfilled", Round(r.quality.psnr_unfilled, 2)},
                  {"test_views", r.quality.views}};
  j["speed"] = {{"integrate_ms_median", Round(r.integrate_ms_median, 2)},
                {"integrate_ms_p95", Round(r.integrate_ms_p95, 2)},
                {"plan_ms_median", Round(r.plan_ms_median, 2)},
                {"plan_ms_p95", Round(r.plan_ms_p95, 2)},
                {"consider_ms_median", Round(r.consider_ms_median, 3)},
                {"render_ms_median", Round(r.render_ms_median, 1)}};
  j["memory"] = {{"store_bytes", r.store_bytes},
                 {"geometry_bytes", r.geometry_bytes},
                 {"planner_bytes", r.planner_bytes}};
  j["views"] = r.store_views;
  j["accepted"] = r.accepted;
  j["tau_sum"] = Round(r.tau_sum, 2);
  j["mean_refs"] = Round(r.mean_refs, 2);
  j["max_refs"] = r.max_refs;
  if (r.plan_cpu_ms_median > 0)
    j["plan_cpu_ms"] = {{"median", Round(r.plan_cpu_ms_median, 2)},
                        {"p95", Round(r.plan_cpu_ms_p95, 2)}};
  // Integration CPU (process CPU ms per input frame) and the final proxy's size.
  j["integrate_cpu"] = {{"integrate_cpu_ms_median", Round(r.integrate_cpu_ms_median, 2)},
                        {"integrate_cpu_ms_p95", Round(r.integrate_cpu_ms_p95, 2)}};
  j["proxy_triangles"] = r.proxy_triangles;
  if (PolicyIsOnline(c.policy))
    j["stream_drift"] = {{"near", Round(r.drift_near, 5)},
                         {"far", Round(r.drift_far, 5)},
                         {"time_scale", Round(r.time_scale, 3)}};
  // Issue 15: MS-SSIM and GMSD of the filled frame; the attribution oracles of the config.
  j["perceptual"] = {{"ms_ssim", std::isfinite(r.quality.ms_ssim)
                                     ? nlohmann::ordered_json(Round(r.quality.ms_ssim, 4))
                                     : nlohmann::ordered_json(nullptr)},
                     {"gmsd", Round(r.quality.gmsd, 4)}};
  j["attribution"] = {{"own_depth_proxy", int(c.own_depth_proxy)},
                      {"mssim_gain_fit", Round(r.quality.mssim_gain_fit, 4)},
                      {"psnr_gain_fit", Round(r.quality.psnr_gain_fit, 2)}};
  if (c.policy == Policy::kOnline) {
    // The online model's state, comparable with the server's (stats counters *.digest).
    j["model_digest"] = core::DigestHex(r.model_digest);
    j["geometry_digest"] = core::DigestHex(r.geometry_digest);
    j["planner_digest"] = core::DigestHex(r.planner_digest);
    nlohmann::ordered_json ids = nlohmann::ordered_json::array();
    for (int i : r.selected) ids.push_back(i + 1);
    j["view_ids"] = ids;
  }
  // Per-test-view diagnostics (only when requested).
  if (!r.per_view_ssim.empty()) {
    nlohmann::ordered_json pv;
    pv["ssim"] = RoundedArray(r.per_view_ssim, 4);
    if (!r.per_view_coverage.empty()) pv["coverage"] = RoundedArray(r.per_view_coverage, 4);
    if (!r.per_view_near_m.empty()) {
      pv["near_m"] = RoundedArray(r.per_view_near_m, 3);
      pv["near_deg"] = RoundedArray(r.per_view_near_deg, 1);
      pv["near_frame"] = RoundedArray(r.per_view_near_frame, 0);
      pv["ref_hit"] = RoundedArray(r.per_view_ref_hit, 3);
    }
    if (!r.selected.empty()) pv["selected"] = r.selected;
    j["per_view"] = std::move(pv);
  }
  return j.dump();
}

struct EngineOptions {
  ProxyKind proxy = ProxyKind::kTsdf;
  // The online model's geometry options (max/min depth, threads); its voxel and origin below.
  core::OnlineModelOptions model;
  double voxel_m = 0.02;
  LocalOrigin origin;
  int id_w = 160, id_h = 120;
  double max_range_m = 100;
  blend::BlendOptions blend;
  bool vertex_color = true;
  std::function<void(const std::string&)> emit;
  std::string dump_dir;
  int dump_views = 0;
  TriangleMesh gt_mesh;  // used when proxy == kGroundTruth
  bool per_view = false;  // per-test-view diagnostics in the JSON
  // Cell-id LOD: cluster size as a fraction of the (smallest) cell size; 0 = full proxy mesh;
  // < 0 = planning::DefaultCellIdLodM.
  double cellid_lod_frac = -1;
  double cellid_lod_m = 0;       // > 0: cluster size in metres (wins over cellid_lod_frac)
  double cellid_lod_keep = 0.1;  // planning::CellIdRendererOptions::lod_keep_fraction
  CellIdSource cell_ids = CellIdSource::kFrameDepth;
};

class Engine {
 public:
  Engine(Source src, std::vector<PolicyConfig> configs, EngineOptions opt)
      : src_(std::move(src)), configs_(std::move(configs)), opt_(std::move(opt)) {}

  absl::Status Init() {
    if (opt_.cellid_lod_m > 0) {
      lod_cluster_m_ = opt_.cellid_lod_m;
    } else if (opt_.cellid_lod_frac > 0) {
      double min_cell = 1e30;
      for (const PolicyConfig& c : configs_)
        min_cell = std::min(min_cell, c.cell_m > 0 ? c.cell_m : src_.scale.cell_size_m);
      if (configs_.empty()) min_cell = src_.scale.cell_size_m;
      lod_cluster_m_ = opt_.cellid_lod_frac * min_cell;
    } else if (opt_.cellid_lod_frac < 0) {  // planning::DefaultCellIdLodM of the smallest cell
      double min_cell = src_.scale.cell_size_m;
      for (const PolicyConfig& c : configs_)
        min_cell = std::min(min_cell, c.cell_m > 0 ? c.cell_m : src_.scale.cell_size_m);
      lod_cluster_m_ = planning::DefaultCellIdLodM(
          min_cell, opt_.proxy == ProxyKind::kTsdf ? opt_.voxel_m : 0.0);
    }
    MeshChunk gt;  // the ground-truth proxy as one chunk
    gt.id = 0;
    gt.version = 1;
    gt.mesh = opt_.gt_mesh;
    core::SceneSetup setup;
    setup.origin = opt_.origin;
    setup.voxel_m = opt_.voxel_m;
    if (opt_.proxy == ProxyKind::kTsdf) {
      EXO_ASSIGN_OR_RETURN(geometry_, core::OnlineGeometry::Create(opt_.model, setup));
    } else {
      proxy_.Set(gt);
    }
    for (size_t i = 0; i < configs_.size(); ++i) {
      const PolicyConfig& c = configs_[i];
      const double cell = c.cell_m > 0 ? c.cell_m : src_.scale.cell_size_m;
      size_t g = 0;
      for (; g < groups_.size(); ++g)
        if (std::abs(groups_[g].grid.cell_size_m - cell) < 1e-9) break;
      if (g == groups_.size()) {
        Group gr;
        gr.grid.cell_size_m = cell;
        gr.areas = std::make_unique<CellAreas>(gr.grid);
        planning::CellIdRendererOptions co;
        co.grid = gr.grid;
        co.lod_cluster_m = lod_cluster_m_;
        co.lod_keep_fraction = opt_.cellid_lod_keep;
        co.max_range_m = opt_.max_range_m;
        EXO_ASSIGN_OR_RETURN(auto cid, planning::CellIdRenderer::Create(co));
        gr.cid = std::make_unique<planning::CellIdRenderer>(std::move(cid));
        groups_.push_back(std::move(gr));
        if (opt_.proxy == ProxyKind::kGroundTruth) {
          groups_[g].areas->UpdateChunk(gt);
          EXO_RETURN_IF_ERROR(groups_[g].cid->Update({gt}));
          (void)groups_[g].areas->TakeChangedCells();
        }
      }
      cfg_group_.push_back(g);
      OnlineState st;
      st.group = g;
      if (c.policy == Policy::kOnline) {
        // The server's online model with this config's planner options.
        const planning::PlannerOptions po = PlannerFor(c, src_, cell, src_.frame_bytes);
        core::OnlineModelOptions mo = opt_.model;
        mo.r_max = po.r_max;
        mo.render_refs_max = po.render_refs_max;
        mo.max_views = po.max_views;
        mo.max_bytes = po.max_bytes;
        mo.lambda = po.lambda;
        mo.tau_max = po.tau_max;
        mo.delta_tau_sum = po.delta_tau_sum;
        mo.novelty_positional = po.novelty_positional;
        mo.soft_saturation = po.soft_saturation;
        mo.dispersion = po.dispersion;
        mo.dispersion_m_per_rad = po.dispersion_m_per_rad;
        mo.dispersion_rotation_scale = po.dispersion_rotation_scale;
        mo.dispersion_turn_overlap_rad = po.dispersion_turn_overlap_rad;
        mo.dispersion_turn_overlap_scale = po.dispersion_turn_overlap_scale;
        mo.dispersion_turn_axis = po.dispersion_turn_axis;
        mo.dispersion_guard = po.dispersion_guard;
        mo.dispersion_guard_relative = po.dispersion_guard_relative;
        mo.dispersion_guard_unique = po.dispersion_guard_unique;
        mo.dispersion_guard_unique_after = po.dispersion_guard_unique_after;
        mo.dispersion_weight_exponent = po.dispersion_weight_exponent;
        mo.dispersion_weight_after = po.dispersion_weight_after;
        mo.dispersion_keep_nearest = po.dispersion_keep_nearest;
        mo.dispersion_recency = po.dispersion_recency;
        mo.dispersion_drop_older = po.dispersion_drop_older;
        mo.dispersion_time_steps = po.dispersion_time_steps;
        mo.dispersion_time_max = po.dispersion_time_max;
        mo.dispersion_time_arc = po.dispersion_time_arc;
        mo.dispersion_time_auto_ref = po.dispersion_time_auto_ref;
        mo.observe_zero_coverage = po.observe_zero_coverage;
        mo.dispersion_weight_until = po.dispersion_weight_until;
        mo.frame_quality.gamma = c.sharp_gamma;
        mo.cell_areas = !c.face_areas;
        mo.id_buffer_stride = IdStride();
        mo.id_from_proxy = opt_.cell_ids == CellIdSource::kProxy;
        mo.cellid_lod_m = lod_cluster_m_;
        mo.cellid_lod_keep = opt_.cellid_lod_keep;
        mo.cellid_max_range_m = opt_.max_range_m;
        core::SceneSetup ps = setup;
        ps.cell_m = cell;
        ps.d_max_m = po.d_max_m;
        ps.sigma_m = po.sigma_m;
        EXO_ASSIGN_OR_RETURN(st.planner, core::OnlinePlanner::Create(mo, ps));
        if (opt_.proxy == ProxyKind::kGroundTruth) {
          core::GeometryUpdate u;
          u.chunks.push_back(gt);
          EXO_RETURN_IF_ERROR(st.planner->Apply(u));
        }
        if (c.replay_refs) groups_[g].needs_final = true;
      } else if (c.policy == Policy::kOfflineGreedy || PolicyIsBaseline(c.policy) ||
                 c.policy == Policy::kOnlineFinalAreas) {
        groups_[g].needs_final = true;
      }
      if (auto sel = MakeSelector(c)) selectors_.emplace(i, std::move(sel));
      online_.push_back(std::move(st));
    }
    return absl::OkStatus();
  }

  // The online baselines that pick views from poses as the stream goes (null for the others).
  std::unique_ptr<OnlineSelector> MakeSelector(const PolicyConfig& c) const {
    const size_t cap = size_t(std::max(1, c.store));
    switch (c.policy) {
      case Policy::kMinDistance:
        return std::make_unique<MinDistanceSelector>(cap, src_.metres_per_rad);
      case Policy::kEveryNOnline: return std::make_unique<ProgressiveEveryN>(cap);
      case Policy::kReservoir: return std::make_unique<ReservoirSampler>(cap, c.policy_seed);
      case Policy::kKeyframe:
        return std::make_unique<KeyframeSelector>(cap, c.keyframe_threshold, src_.metres_per_rad);
      default: return nullptr;
    }
  }

  // Cell-id buffer = 1/stride of the input frames (160x120 of 640x480).
  int IdStride() const { return std::max(1, src_.camera.width / opt_.id_w); }

  // The cell-id LOD in the JSON: 0 when the ids come from frame depth (no cell-id meshes).
  double ReportedLodM() const {
    return opt_.cell_ids == CellIdSource::kProxy ? lod_cluster_m_ : 0.0;
  }

  // One input frame (frame may be null for the ground-truth proxy): the core's geometry, then
  // every online configuration's core planner; the offline policies' final areas / cell ids.
  absl::Status Step(int idx, const Frame* frame) {
    const Rigid3d& pose = src_.poses[idx];
    double lod_ms = 0, lod_cpu_ms = 0;
    auto t0 = Clock::now();
    const double p0 = ProcessCpuMs();
    core::GeometryUpdate update;
    if (geometry_ != nullptr) {
      if (frame == nullptr) return absl::InternalError("TSDF proxy needs frames");
      EXO_ASSIGN_OR_RETURN(update, geometry_->Integrate(*frame));
      double lod_proc_cpu_ms = 0;
      for (auto& g : groups_) {
        if (!g.needs_final) continue;
        for (const MeshChunk& c : update.chunks) g.areas->UpdateChunk(c);
        for (uint64_t id : update.removed) g.areas->RemoveChunk(id);
        if (opt_.cell_ids != CellIdSource::kProxy) continue;
        // The offline cell-id renderers' LOD cache update is planning time, not integration.
        const auto t_lod = Clock::now();
        const double c_lod = ThreadCpuMs(), p_lod = ProcessCpuMs();
        EXO_RETURN_IF_ERROR(g.cid->Update(update.chunks));
        for (uint64_t id : update.removed) g.cid->Remove(id);
        lod_ms += MsSince(t_lod);
        lod_cpu_ms += ThreadCpuMs() - c_lod;
        lod_proc_cpu_ms += ProcessCpuMs() - p_lod;
      }
      proxy_.Apply(update);
      integrate_ms_.push_back(MsSince(t0) - lod_ms);
      integrate_cpu_ms_.push_back(ProcessCpuMs() - p0 - lod_proc_cpu_ms);
    } else {
      integrate_ms_.push_back(0.0);
      integrate_cpu_ms_.push_back(0.0);
    }
    for (auto& g : groups_) {
      if (!g.needs_final || opt_.cell_ids != CellIdSource::kFrameDepth) continue;
      // ψ_vis from the frame's own depth, kept for the offline / baseline policies.
      if (frame == nullptr) return absl::InvalidArgumentError("cell ids from depth need frames");
      EXO_ASSIGN_OR_RETURN(planning::Candidate cand,
                           core::CandidateFromDepth(ViewId(idx + 1), frame->depth_m,
                                                    frame->depth_camera,
                                                    pose * frame->color_from_depth, pose, g.grid,
                                                    IdStride(), src_.frame_bytes));
      g.final_cells.resize(src_.poses.size());
      g.final_cells[idx] = std::move(cand.cells);
      g.id_cam = cand.id_camera;
    }
    core::PlanFrame pf;
    if (frame != nullptr) pf = core::PlanFrame::Of(*frame, opt_.origin);
    pf.local_from_cam = pose;
    if (frame != nullptr) pf.local_from_depth = pose * frame->color_from_depth;
    else pf.camera = src_.camera;
    pf.bytes = src_.frame_bytes;
    for (OnlineState& st : online_) {
      if (!st.planner) continue;
      auto t1 = Clock::now();
      const double c1 = ThreadCpuMs();
      EXO_RETURN_IF_ERROR(st.planner->Apply(update));
      auto t2 = Clock::now();
      const double c2 = ThreadCpuMs();
      EXO_ASSIGN_OR_RETURN(const core::HandOff h, st.planner->Plan(pf));
      st.consider_ms.push_back(MsSince(t2));
      st.consider_cpu_ms.push_back(ThreadCpuMs() - c2);
      st.plan_ms.push_back(MsSince(t1) + lod_ms);
      st.plan_cpu_ms.push_back(ThreadCpuMs() - c1 + lod_cpu_ms);
      if (h.accepted) ++st.accepted;
    }
    for (auto& [ci, sel] : selectors_) {
      const double c0 = ThreadCpuMs();
      sel->Offer(idx, pose);
      selector_cpu_ms_[ci].push_back(ThreadCpuMs() - c0);
    }
    return absl::OkStatus();
  }

  absl::StatusOr<std::vector<ConfigResult>> Finish(const std::string& proxy_name, double voxel_m) {
    const int n = int(src_.poses.size());
    // Final proxy cell lists for the offline/baseline policies.
    for (auto& g : groups_) {
      if (!g.needs_final || opt_.cell_ids == CellIdSource::kFrameDepth) continue;
      g.final_cells.resize(n);
      for (int i = 0; i < n; ++i) {
        EXO_ASSIGN_OR_RETURN(g.final_cells[i], CellCounts(*g.cid, src_.camera, src_.poses[i],
                                                          opt_.id_w, opt_.id_h, &g.id_cam));
      }
    }
    const core::OnlinePlanner* first_online = nullptr;
    for (const OnlineState& st : online_)
      if (st.planner && first_online == nullptr) first_online = st.planner.get();
    if (first_online != nullptr && first_online->cell_id_renderer() != nullptr)
      std::fprintf(stderr, "cell-id meshes: %zu triangles (full proxy %zu)\n",
                   first_online->cell_id_renderer()->render_triangles(), proxy_.triangles());
    const TriangleMesh proxy_mesh = proxy_.All();
    const size_t geometry_bytes = (geometry_ ? geometry_->volume().bytes() : 0) + proxy_.bytes();
    std::vector<ConfigResult> results;
    if (opt_.vertex_color && geometry_ != nullptr) {
      for (const Source::TestSet& ts : src_.test_sets) {
        ConfigResult r;
        r.config.policy = Policy::kVertexColor;
        r.config.store = 0;
        r.config.tag = "baseline";
        r.test_poses = ts.label;
        EvalSink sink;
        EXO_ASSIGN_OR_RETURN(r.quality, EvalVertexColor(proxy_mesh, ts, &r.render_ms_median, &sink));
        if (opt_.per_view) r.per_view_ssim = sink.ssim;
        r.integrate_ms_median = Pct(integrate_ms_, 0.5);
        r.integrate_ms_p95 = Pct(integrate_ms_, 0.95);
        r.integrate_cpu_ms_median = Pct(integrate_cpu_ms_, 0.5);
        r.integrate_cpu_ms_p95 = Pct(integrate_cpu_ms_, 0.95);
        r.proxy_triangles = proxy_.triangles();
        r.geometry_bytes = geometry_bytes;
        r.json = ConfigJson(src_.dataset, ts.label, proxy_name, voxel_m, n, r.config, 0, 0, 0, r, opt_.id_w,
                            opt_.id_h, PlannerFor(r.config, src_, src_.scale.cell_size_m, src_.frame_bytes),
                            ScaleModeName(src_.scale_mode), ReportedLodM(),
                            CellIdSourceName(opt_.cell_ids));
        if (opt_.emit) opt_.emit(r.json);
        results.push_back(std::move(r));
      }
    }
    for (size_t ci = 0; ci < configs_.size(); ++ci) {
      const PolicyConfig& c = configs_[ci];
      Group& g = groups_[cfg_group_[ci]];
      ConfigResult r;
      r.config = c;
      r.integrate_ms_median = Pct(integrate_ms_, 0.5);
      r.integrate_ms_p95 = Pct(integrate_ms_, 0.95);
      r.integrate_cpu_ms_median = Pct(integrate_cpu_ms_, 0.5);
      r.integrate_cpu_ms_p95 = Pct(integrate_cpu_ms_, 0.95);
      r.proxy_triangles = proxy_.triangles();
      r.geometry_bytes = geometry_bytes;
      const planning::PlannerOptions po = PlannerFor(c, src_, g.grid.cell_size_m, src_.frame_bytes);
      std::vector<int> selected;
      std::unordered_map<CellId, std::vector<ViewId>> refs;
      // Frame i as a candidate with the cell ids it was planned with (offline passes).
      auto final_candidate = [&](int i) {
        planning::Candidate cand;
        cand.id = ViewId(i + 1);
        cand.local_from_cam = src_.poses[i];
        cand.id_camera = g.id_cam;
        cand.cells = g.final_cells[i];
        cand.bytes = src_.frame_bytes;
        return cand;
      };
      // A planner for an offline pass: the final proxy's cell areas from the start (none with
      // --face_areas 1).
      auto offline_planner = [&](const planning::PlannerOptions& opts)
          -> absl::StatusOr<planning::ViewPlanner> {
        EXO_ASSIGN_OR_RETURN(auto p, planning::ViewPlanner::Create(opts));
        if (!c.face_areas)
          for (const auto& [cell, a] : g.areas->areas()) EXO_RETURN_IF_ERROR(p.SetCellArea(cell, a));
        return p;
      };
      // Fair rule: the planner's pre-selection (§3.1.4) with the same options, every selected
      // view accepted (τ_max huge and Δτ_sum 0 make the gain Σφ > 0 for any view that covers a
      // cell; φ and R(b_k) do not depend on τ_max), in frame order.
      auto replayed_refs = [&](const std::vector<int>& sel)
          -> absl::StatusOr<std::unordered_map<CellId, std::vector<ViewId>>> {
        planning::PlannerOptions pre = po;
        pre.max_views = std::max<size_t>(1, sel.size());
        pre.max_bytes = std::max<size_t>(1, sel.size()) * src_.frame_bytes;
        pre.tau_max = 1e30;
        pre.delta_tau_sum = 0;
        EXO_ASSIGN_OR_RETURN(auto p, offline_planner(pre));
        for (int i : sel) EXO_RETURN_IF_ERROR(p.Consider(final_candidate(i)).status());
        return p.CellPublishedRefs();
      };
      if (c.policy == Policy::kOnline) {
        OnlineState& st = online_[ci];
        const std::vector<double>& plan = st.plan_ms;
        r.plan_ms_median = Pct(plan, 0.5);
        r.plan_ms_p95 = Pct(plan, 0.95);
        const std::vector<double>& plan_cpu = st.plan_cpu_ms;
        r.plan_cpu_ms_median = Pct(plan_cpu, 0.5);
        r.plan_cpu_ms_p95 = Pct(plan_cpu, 0.95);
        r.consider_ms_median = Pct(st.consider_ms, 0.5);
        const planning::ViewPlanner& p = st.planner->planner();
        for (ViewId v : p.ViewIds()) selected.push_back(int(v) - 1);
        refs = p.CellPublishedRefs();
        r.planner_bytes = p.BookkeepingBytes();
        r.geometry_digest = geometry_ ? geometry_->Digest() : 0;
        r.planner_digest = st.planner->Digest();
        r.model_digest = core::ModelDigest(r.geometry_digest, r.planner_digest);
        r.accepted = st.accepted;
        r.tau_sum = p.tau_sum();
        r.drift_near = st.planner->drift().Near();
        r.drift_far = st.planner->drift().Far();
        r.time_scale = p.time_scale();
        if (c.replay_refs) {  // diagnostic: the baselines' references for the same store
          std::sort(selected.begin(), selected.end());
          EXO_ASSIGN_OR_RETURN(refs, replayed_refs(selected));
        }
      } else {
        auto t0 = Clock::now();
        if (c.policy == Policy::kEveryN) {
          // Evenly over the WHOLE stream: index floor(k n / store), k = 0..store-1 (an integer
          // step n / store would leave the tail unsampled when store does not divide n).
          const int m = std::min(n, c.store);
          for (int k = 0; k < m; ++k) selected.push_back(int((int64_t(k) * n) / m));
        } else if (selectors_.count(ci)) {
          for (int64_t k : selectors_.at(ci)->Selected()) selected.push_back(int(k));
        } else if (c.policy == Policy::kAll) {
          for (int i = 0; i < n; ++i) selected.push_back(i);
        } else if (c.policy == Policy::kOfflineGreedy) {
          EXO_ASSIGN_OR_RETURN(auto p, offline_planner(po));
          using QE = std::pair<double, int>;
          std::priority_queue<QE> pq;
          for (int i = 0; i < n; ++i)
            pq.push({GainOf(p, src_.poses[i], g.id_cam, g.final_cells[i]), i});
          while (!pq.empty() && p.num_views() < size_t(c.store)) {
            auto [gain_old, i] = pq.top();
            pq.pop();
            const double gnew = GainOf(p, src_.poses[i], g.id_cam, g.final_cells[i]);
            if (!pq.empty() && gnew < pq.top().first - 1e-12) {
              pq.push({gnew, i});
              continue;
            }
            if (!(gnew > 0)) break;
            EXO_RETURN_IF_ERROR(p.Consider(final_candidate(i)).status());
          }
          for (ViewId v : p.ViewIds()) selected.push_back(int(v) - 1);
          refs = p.CellPublishedRefs();
          r.tau_sum = p.tau_sum();
          r.planner_bytes = p.BookkeepingBytes();
        } else if (c.policy == Policy::kOnlineFinalAreas) {
          // The online rules in stream order, every frame's cell ids as the online policy saw
          // them, but the final proxy's areas from the start (diagnostic).
          EXO_ASSIGN_OR_RETURN(auto p, offline_planner(po));
          size_t accepted = 0;
          for (int i = 0; i < n; ++i) {
            EXO_ASSIGN_OR_RETURN(const planning::Decision dec, p.Consider(final_candidate(i)));
            if (dec.accepted) ++accepted;
          }
          for (ViewId v : p.ViewIds()) selected.push_back(int(v) - 1);
          refs = p.CellPublishedRefs();
          r.tau_sum = p.tau_sum();
          r.planner_bytes = p.BookkeepingBytes();
          r.accepted = accepted;
        }
        const double ms = MsSince(t0);
        r.plan_ms_median = r.plan_ms_p95 = ms / std::max(1, n);
        if (selectors_.count(ci)) {  // the online baselines' own per-frame decision (CPU ms)
          r.plan_ms_median = r.plan_cpu_ms_median = Pct(selector_cpu_ms_[ci], 0.5);
          r.plan_ms_p95 = r.plan_cpu_ms_p95 = Pct(selector_cpu_ms_[ci], 0.95);
        }
        if (c.policy != Policy::kOnlineFinalAreas) r.accepted = selected.size();
        if (c.policy == Policy::kOnlineFinalAreas) {
          // R(b_k) is the replayed planner's own.
        } else if (c.policy != Policy::kOfflineGreedy && c.uncapped_refs) {
          for (int i : selected)
            for (const auto& cc : g.final_cells[i])
              if (cc.pixels > 0) refs[cc.cell].push_back(ViewId(i + 1));
        } else if (c.policy != Policy::kOfflineGreedy) {
          EXO_ASSIGN_OR_RETURN(refs, replayed_refs(selected));
        }
      }
      double ref_sum = 0;
      for (const auto& [cell, rs] : refs) {
        r.max_refs = std::max(r.max_refs, rs.size());
        ref_sum += double(rs.size());
      }
      r.mean_refs = refs.empty() ? 0.0 : ref_sum / double(refs.size());
      r.store_views = selected.size();
      r.store_bytes = selected.size() * src_.frame_bytes;
      r.selected = selected;
      for (const Source::TestSet& ts : src_.test_sets) {
        ConfigResult rt = r;
        rt.test_poses = ts.label;
        double render_ms = 0;
        EvalSink sink;
        EXO_ASSIGN_OR_RETURN(rt.quality, EvalStore(selected, refs, g.grid, proxy_mesh, ts,
                                                   c.test_views, ci == 0, &render_ms,
                                                   // The product's blend lambda
                                                   // (BlendOptions) unless a policy option
                                                   // sets it; no longer the planner's.
                                                   c.blend_lambda >= 0 ? c.blend_lambda
                                                   : c.blend           ? c.blend->lambda
                                                                       : opt_.blend.lambda,
                                                   &sink, c.blend ? *c.blend : opt_.blend,
                                                   c.own_depth_proxy));
        rt.render_ms_median = render_ms;
        if (opt_.per_view) {
          rt.per_view_ssim = sink.ssim;
          rt.per_view_coverage = sink.cov;
          PerViewDiagnostics(selected, refs, g.grid, proxy_mesh, ts, int(sink.ssim.size()), &rt);
        }
        rt.json = ConfigJson(src_.dataset, ts.label, proxy_name, voxel_m, n, c, po.lambda,
                             g.grid.cell_size_m, po.delta_tau_sum, rt, opt_.id_w, opt_.id_h, po,
                             ScaleModeName(src_.scale_mode), ReportedLodM(),
                            CellIdSourceName(opt_.cell_ids));
        if (opt_.emit) opt_.emit(rt.json);
        results.push_back(std::move(rt));
      }
    }
    return results;
  }

  size_t proxy_triangles() const { return proxy_.triangles(); }

 private:
  absl::StatusOr<Quality> EvalStore(const std::vector<int>& selected,
                                    const std::unordered_map<CellId, std::vector<ViewId>>& refs,
                                    const CellGrid& grid, const TriangleMesh& proxy_mesh,
                                    const Source::TestSet& ts, int test_views, bool dump,
                                    double* render_ms_median, double lambda, EvalSink* sink_out,
                                    const blend::BlendOptions& blend_options,
                                    bool own_depth_proxy = false) {
    if (own_depth_proxy && ts.depth.size() != ts.poses.size())
      return absl::InvalidArgumentError("own_depth_proxy needs the test frames' depth (7-Scenes)");
    // Bring the selected views into the cache (evict others when it grows large).
    std::unordered_set<int> need(selected.begin(), selected.end());
    if (cache_.size() + selected.size() > kMaxCache)
      for (auto it = cache_.begin(); it != cache_.end();)
        it = need.count(it->first) ? std::next(it) : cache_.erase(it);
    LumigraphModel model;
    model.grid = grid;
    MeshChunk chunk;
    chunk.id = 0;
    chunk.version = 1;
    chunk.mesh.positions = proxy_mesh.positions;
    chunk.mesh.indices = proxy_mesh.indices;
    model.chunks[0] = std::move(chunk);
    for (int i : selected) {
      auto it = cache_.find(i);
      if (it == cache_.end()) {
        EXO_ASSIGN_OR_RETURN(StoredView v, src_.load_view(i));
        v.id = ViewId(i + 1);
        it = cache_.emplace(i, std::move(v)).first;
      }
      model.views.emplace(ViewId(i + 1), std::move(it->second));
    }
    model.cell_refs = refs;
    CpuRenderOptions ro;
    ro.blend = blend_options;  // the config's (issue 15 blend variants) or the run's
    ro.blend.lambda = float(lambda);
    ro.blend.fill_holes = false;  // EvalSink::Add fills (FillHoles) so both versions are measured
    auto restore = [&] {
      for (auto& [id, v] : model.views) cache_[int(id) - 1] = std::move(v);
    };
    auto renderer = CpuLumigraphRenderer::Create(model, ro);
    if (!renderer.ok()) {
      restore();
      return renderer.status();
    }
    EvalSink& sink = *sink_out;
    const int nt = test_views < 0 ? int(ts.poses.size())
                                  : std::min<int>(test_views, ts.poses.size());
    absl::Status st;
    for (int t = 0; t < nt && st.ok(); ++t) {
      if (own_depth_proxy) {  // issue 15 attribution: this view's depth is the proxy
        model.chunks[0].mesh = MeshFromDepth(ts.depth[t], ts.depth_camera, ts.poses[t]);
        renderer->reset();
        auto r = CpuLumigraphRenderer::Create(model, ro);
        if (!r.ok()) {
          st = r.status();
          break;
        }
        *renderer = std::move(*r);
      }
      auto t0 = Clock::now();
      auto out = (*renderer)->Render(src_.test_camera, ts.poses[t]);
      const double ms = MsSince(t0);
      if (!out.ok()) {
        st = out.status();
        break;
      }
      {
        ImageU8 known = out->coverage;  // blended or filled at infinity
        for (size_t i = 0; i < known.size(); ++i) known.data()[i] |= out->background.data()[i];
        st = sink.Add(out->color, ts.gt[t], out->coverage, known, ms);
      }
      sink.surface.push_back(double(out->surface_pixels) / (out->color.width() * out->color.height()));
      if (dump && !opt_.dump_dir.empty() && t < opt_.dump_views) {
        std::filesystem::create_directories(opt_.dump_dir);
        const ImageU8 img = Hstack({&out->color, &ts.gt[t], &out->coverage});
        (void)WriteColorImage(absl::StrCat(opt_.dump_dir, "/", ts.label, "_view_", t, ".png"), img);
      }
    }
    renderer->reset();
    restore();
    EXO_RETURN_IF_ERROR(st);
    *render_ms_median = Pct(sink.render_ms, 0.5);
    return sink.Finish();
  }

  // See ConfigResult::per_view_*: for each of the first nt test poses, the nearest stored view
  // (camera-centre distance) and whether the cells the test view sees reference it.
  void PerViewDiagnostics(const std::vector<int>& selected,
                          const std::unordered_map<CellId, std::vector<ViewId>>& refs,
                          const CellGrid& grid, const TriangleMesh& proxy_mesh,
                          const Source::TestSet& ts, int nt, ConfigResult* r) {
    for (int t = 0; t < nt; ++t) {
      const Rigid3d& pose = ts.poses[t];
      double best = 1e300;
      int best_i = -1;
      for (int i : selected) {
        const double d = glm::length(src_.poses[i].translation - pose.translation);
        if (d < best) {
          best = d;
          best_i = i;
        }
      }
      if (best_i < 0) {
        r->per_view_near_m.push_back(-1);
        r->per_view_near_deg.push_back(-1);
        r->per_view_near_frame.push_back(-1);
        r->per_view_ref_hit.push_back(0);
        continue;
      }
      const glm::dvec3 za = pose.RotationMatrix() * glm::dvec3(0, 0, 1);
      const glm::dvec3 zb = src_.poses[best_i].RotationMatrix() * glm::dvec3(0, 0, 1);
      r->per_view_near_m.push_back(best);
      r->per_view_near_deg.push_back(
          glm::degrees(std::acos(std::clamp(glm::dot(za, zb), -1.0, 1.0))));
      r->per_view_near_frame.push_back(best_i);
      PinholeCamera id_cam;
      const auto cells =
          CellCounts(proxy_mesh, grid, src_.test_camera, pose, opt_.id_w, opt_.id_h, &id_cam);
      double hit = 0, total = 0;
      for (const auto& c : cells) {
        total += c.pixels;
        auto it = refs.find(c.cell);
        if (it != refs.end() &&
            std::find(it->second.begin(), it->second.end(), ViewId(best_i + 1)) != it->second.end())
          hit += c.pixels;
      }
      r->per_view_ref_hit.push_back(total > 0 ? hit / total : 0.0);
    }
  }

  absl::StatusOr<Quality> EvalVertexColor(const TriangleMesh& mesh, const Source::TestSet& ts,
                                          double* render_ms_median, EvalSink* sink_out) {
    EvalSink& sink = *sink_out;
    const PinholeCamera& cam = src_.test_camera;
    for (size_t t = 0; t < ts.poses.size(); ++t) {
      auto t0 = Clock::now();
      ImageU8 img, mask;
      EXO_RETURN_IF_ERROR(RenderVertexColor(mesh, cam, ts.poses[t], &img, &mask));
      EXO_RETURN_IF_ERROR(sink.Add(img, ts.gt[t], mask, mask, MsSince(t0)));
      sink.surface.push_back(sink.cov.back());
    }
    *render_ms_median = Pct(sink.render_ms, 0.5);
    return sink.Finish();
  }

  static constexpr size_t kMaxCache = 700;
  Source src_;
  std::vector<PolicyConfig> configs_;
  EngineOptions opt_;
  std::unique_ptr<core::OnlineGeometry> geometry_;  // null with the ground-truth proxy
  core::ProxyMesh proxy_;
  std::vector<Group> groups_;
  std::vector<size_t> cfg_group_;
  std::vector<OnlineState> online_;
  std::map<size_t, std::unique_ptr<OnlineSelector>> selectors_;  // config -> online baseline
  std::map<size_t, std::vector<double>> selector_cpu_ms_;          // its Offer() per frame
  std::vector<double> integrate_ms_;
  std::vector<double> integrate_cpu_ms_;  // process CPU ms (TSDF worker threads included)
  double lod_cluster_m_ = 0;  // cell-id LOD cluster size (0: full chunk meshes)
  std::unordered_map<int, StoredView> cache_;
};

// See TestPoseMode::kNearTrajectory. Same acceptance rule as synth::MakeTestPoses (>= 90 % of a
// 64-px-wide depth render hits geometry, nothing closer than 0.4 m, eye 0.5 m from solids).
absl::StatusOr<std::vector<Rigid3d>> NearTrajectoryPoses(const synth::SynthScene& scene,
                                                         const std::vector<Rigid3d>& input,
                                                         const PinholeCamera& camera, int count,
                                                         uint64_t seed, bool flyover) {
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ull + 3);
  auto uni = [&](double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); };
  RasterOptions ro;
  ro.z_depth = true;
  ro.width = 64;
  ro.height = std::max(8, int(std::lround(64.0 * camera.height / camera.width)));
  ro.num_threads = 1;
  ro.near_m = 0.05;
  const double r_h = 0.1 * scene.ExtentM(), r_v = flyover ? 2.0 : 0.3;
  std::vector<Rigid3d> out;
  for (int attempt = 0; attempt < 400 * count && int(out.size()) < count; ++attempt) {
    const Rigid3d& base = input[rng() % input.size()];
    const glm::dvec3 eye = base.translation + glm::dvec3(uni(-r_h, r_h), uni(-r_h, r_h), uni(-r_v, r_v));
    if (!scene.IsFree(eye, 0.5)) continue;
    const glm::dvec3 fwd = base.RotationMatrix() * glm::dvec3(0, 0, 1);
    const double yaw = std::atan2(fwd.y, fwd.x) + glm::radians(uni(-45, 45));
    const double pitch = std::asin(std::clamp(fwd.z, -1.0, 1.0)) + glm::radians(uni(-10, 10));
    const glm::dvec3 dir(std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw),
                         std::sin(pitch));
    const Rigid3d pose = synth::LookAt(eye, eye + dir);
    EXO_ASSIGN_OR_RETURN(RasterOutput r, Rasterize(scene.mesh, camera, pose, ro));
    int hits = 0;
    float min_z = 1e30f;
    for (float z : r.z_depth_m.span())
      if (z > 0) {
        ++hits;
        min_z = std::min(min_z, z);
      }
    if (double(hits) / r.z_depth_m.size() < 0.9 || min_z < 0.4) continue;
    out.push_back(pose);
  }
  if (int(out.size()) < count)
    return absl::FailedPreconditionError(absl::StrCat("found only ", out.size(), " of ", count,
                                                      " near-trajectory test poses"));
  return out;
}

}  // namespace

const char* CellIdSourceName(CellIdSource s) {
  return s == CellIdSource::kProxy ? "proxy" : "depth";
}

const char* ScaleModeName(ScaleMode m) {
  return m == ScaleMode::kBounds ? "bounds" : m == ScaleMode::kServer ? "server" : "view_depth";
}

bool ParseScaleMode(std::string_view name, ScaleMode* out) {
  if (name == "bounds") *out = ScaleMode::kBounds;
  else if (name == "depth") *out = ScaleMode::kViewDepth;
  else if (name == "server") *out = ScaleMode::kServer;
  else return false;
  return true;
}

const char* PolicyName(Policy p) {
  switch (p) {
    case Policy::kOnline: return "online";
    case Policy::kOfflineGreedy: return "offline_greedy";
    case Policy::kEveryN: return "every_n";
    case Policy::kMinDistance: return "min_distance";
    case Policy::kAll: return "all_frames";
    case Policy::kVertexColor: return "vertex_color";
    case Policy::kOnlineFinalAreas: return "online_final_areas";
    case Policy::kEveryNOnline: return "every_n_online";
    case Policy::kReservoir: return "reservoir";
    case Policy::kKeyframe: return "keyframe";
  }
  return "?";
}

bool PolicyIsOnline(Policy p) {
  return p == Policy::kOnline || p == Policy::kMinDistance || p == Policy::kEveryNOnline ||
         p == Policy::kReservoir || p == Policy::kKeyframe;
}

bool PolicyIsBaseline(Policy p) {
  return p == Policy::kEveryN || p == Policy::kMinDistance || p == Policy::kAll ||
         p == Policy::kEveryNOnline || p == Policy::kReservoir || p == Policy::kKeyframe;
}

absl::Status SynthRunOptions::Validate() const {
  if (frames < 2) return absl::InvalidArgumentError("eval: frames must be >= 2");
  if (test_views < 1) return absl::InvalidArgumentError("eval: test_views must be >= 1");
  if (frame_width < 16 || frame_height < 16)
    return absl::InvalidArgumentError("eval: frame_width / frame_height must be >= 16");
  if (id_width < 8 || id_height < 8) return absl::InvalidArgumentError("eval: id buffer too small");
  if (voxel_m < 0 || !std::isfinite(voxel_m)) return absl::InvalidArgumentError("eval: bad voxel_m");
  if (cellid_lod_m < 0 || !std::isfinite(cellid_lod_m))
    return absl::InvalidArgumentError("eval: cellid_lod_m must be finite and >= 0");
  for (const PolicyConfig& c : configs) {
    if (c.policy == Policy::kVertexColor)
      return absl::InvalidArgumentError("eval: vertex_color is a per-run baseline, not a config");
    if (c.store < 1) return absl::InvalidArgumentError("eval: store must be >= 1");
    if (c.cell_m < 0) return absl::InvalidArgumentError("eval: cell_m must be >= 0");
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<ConfigResult>> RunSynthetic(const SynthRunOptions& o) {
  EXO_RETURN_IF_ERROR(o.Validate());
  EXO_ASSIGN_OR_RETURN(synth::SceneKind kind, synth::ParseSceneKind(o.scene));
  EXO_ASSIGN_OR_RETURN(synth::TrajectoryKind tkind, synth::ParseTrajectoryKind(o.traj));
  synth::SceneOptions sco;
  sco.seed = o.scene_seed;
  EXO_ASSIGN_OR_RETURN(synth::SynthScene scene, synth::MakeScene(kind, sco));
  synth::TrajectoryOptions to;
  to.num_frames = o.frames;
  to.seed = o.traj_seed >= 0 ? uint64_t(o.traj_seed) : o.scene_seed;
  if (o.walk_look_around_deg >= 0) to.walk_look_around_deg = o.walk_look_around_deg;
  // Aerial streams (fly-over, outdoor drone): λ 0.5 and near test poses +-2 m vertically.
  const bool aerial = tkind == synth::TrajectoryKind::kFlyover ||
                      (tkind == synth::TrajectoryKind::kDrone && !scene.indoor);
  EXO_ASSIGN_OR_RETURN(std::vector<synth::TimedPose> traj, synth::MakeTrajectory(scene, tkind, to));

  synth::RenderOptions rop;
  rop.width = o.frame_width;
  rop.height = o.frame_height;
  Source src;
  src.camera = rop.Camera();
  src.frame_bytes = size_t(src.camera.width) * src.camera.height * (3 + 4) + sizeof(StoredView);
  for (const auto& tp : traj) src.poses.push_back(tp.local_from_cam);
  src.scale = DeriveSceneScale(scene.bounds.min, scene.bounds.max);
  src.scale_mode = o.scale_mode;
  if (o.scale_mode == ScaleMode::kViewDepth) {
    EXO_ASSIGN_OR_RETURN(synth::RenderedFrame f0, synth::RenderFrame(scene, src.poses[0], rop));
    src.view_depth_m = core::MedianDepth(f0.frame.depth_m);
  } else if (o.scale_mode == ScaleMode::kServer) {
    // What the server derives from this stream's first frame (issue 22, session 17): the depth
    // range is the one the engine below fuses with (a deployment for this scene sets it so).
    EXO_ASSIGN_OR_RETURN(synth::RenderedFrame f0, synth::RenderFrame(scene, src.poses[0], rop));
    core::OnlineModelOptions mo;
    mo.voxel_m = o.voxel_m;
    mo.max_depth_m = std::max(6.0, scene.ExtentM());
    mo.min_depth_m = 0.1;
    EXO_ASSIGN_OR_RETURN(const core::SceneSetup setup, core::ChooseSceneSetup(f0.frame, mo));
    src.scale = setup.scale;
    src.view_depth_m = setup.view_depth_m;
  }
  // The product's λ (the server has one for every scene; the thesis used 0.5 aerial, 0.4 indoor).
  src.default_lambda = core::OnlineModelOptions{}.lambda;
  src.metres_per_rad = std::max(0.5, 0.05 * scene.ExtentM());
  src.dataset = absl::StrCat(o.scene, "/", o.traj);
  if (o.scene_seed != 1) absl::StrAppend(&src.dataset, "/seed", o.scene_seed);
  if (o.traj_seed >= 0 && uint64_t(o.traj_seed) != o.scene_seed)
    absl::StrAppend(&src.dataset, "/traj_seed", o.traj_seed);
  const synth::SynthScene* sp = &scene;
  std::vector<Rigid3d> poses_copy = src.poses;
  src.load_view = [sp, rop, poses_copy](int i) -> absl::StatusOr<StoredView> {
    EXO_ASSIGN_OR_RETURN(synth::RenderedFrame f, synth::RenderFrame(*sp, poses_copy[i], rop));
    StoredView v;
    v.camera = rop.Camera();
    v.local_from_cam = poses_copy[i];
    v.color = std::move(f.frame.color);
    v.depth_m = std::move(f.frame.depth_m);
    return v;
  };
  synth::RenderOptions top = rop;
  top.width = o.test_width;
  top.height = o.test_height;
  src.test_camera = top.Camera();
  synth::TestPoseOptions tpo;
  tpo.count = o.test_views;
  tpo.seed = o.test_seed;
  std::vector<TestPoseMode> modes = o.test_pose_modes;
  if (modes.empty()) modes.push_back(o.test_pose_mode);
  for (TestPoseMode mode : modes) {
    Source::TestSet ts;
    if (mode == TestPoseMode::kSceneWide) {
      ts.label = "scene";
      EXO_ASSIGN_OR_RETURN(ts.poses, synth::MakeTestPoses(scene, src.test_camera, tpo));
    } else {
      ts.label = "near";
      EXO_ASSIGN_OR_RETURN(ts.poses, NearTrajectoryPoses(scene, src.poses, src.test_camera,
                                                         o.test_views, o.test_seed, aerial));
    }
    for (const Rigid3d& p : ts.poses) {
      EXO_ASSIGN_OR_RETURN(ImageF lin, synth::RenderLinear(scene, p, top));
      ImageU8 gt(top.width, top.height, 3);
      for (size_t k = 0; k < gt.size(); ++k) gt.data()[k] = synth::LinearToSrgb8(lin.data()[k]);
      ts.gt.push_back(std::move(gt));
    }
    src.test_sets.push_back(std::move(ts));
  }

  EngineOptions eo;
  eo.proxy = o.proxy;
  const double diameter = scene.ExtentM();
  const double voxel = o.voxel_m > 0 ? o.voxel_m : std::clamp(diameter / 600.0, 0.02, 0.15);
  eo.voxel_m = voxel;
  eo.origin = scene.origin;
  eo.model.max_depth_m = std::max(6.0, diameter);
  eo.model.min_depth_m = 0.1;
  eo.max_range_m = std::max(6.0, diameter) * 1.5;
  eo.id_w = o.id_width;
  eo.id_h = o.id_height;
  eo.blend = o.blend;
  eo.vertex_color = o.vertex_color_baseline && o.proxy == ProxyKind::kTsdf;
  eo.emit = o.emit;
  eo.dump_dir = o.dump_dir;
  eo.dump_views = o.dump_views;
  eo.cellid_lod_frac = o.cellid_lod_frac;
  eo.cellid_lod_m = o.cellid_lod_m;
  eo.cellid_lod_keep = o.cellid_lod_keep;
  eo.cell_ids = o.cell_ids;
  eo.per_view = o.per_view;
  if (o.proxy == ProxyKind::kGroundTruth) eo.gt_mesh = scene.mesh;
  Engine engine(std::move(src), o.configs, std::move(eo));
  EXO_RETURN_IF_ERROR(engine.Init());
  for (int i = 0; i < int(traj.size()); ++i) {
    // Frames are rendered for the TSDF and for cell ids from depth (the ground-truth proxy with
    // proxy-rendered ids needs poses only).
    if (o.proxy == ProxyKind::kTsdf || o.cell_ids == CellIdSource::kFrameDepth) {
      EXO_ASSIGN_OR_RETURN(synth::RenderedFrame f,
                           synth::RenderFrame(scene, traj[i].local_from_cam, rop, {}, i,
                                              traj[i].timestamp_s));
      EXO_RETURN_IF_ERROR(engine.Step(i, &f.frame));
    } else {
      EXO_RETURN_IF_ERROR(engine.Step(i, nullptr));
    }
  }
  return engine.Finish(o.proxy == ProxyKind::kTsdf ? "tsdf" : "ground_truth",
                       o.proxy == ProxyKind::kTsdf ? voxel : 0.0);
}

absl::StatusOr<SevenScenesReport> RunSevenScenes(const SevenScenesRunOptions& o) {
  if (o.hold_out_every < 2) return absl::InvalidArgumentError("hold_out_every must be >= 2");
  // The reader exoview_uploader --format=7scenes uses (common/datasets OpenDataset).
  DatasetOptions reader_options;
  reader_options.format = "7scenes";
  reader_options.register_depth = o.register_depth;
  EXO_ASSIGN_OR_RETURN(auto reader, OpenDataset(o.dir, reader_options));
  const size_t total = o.max_frames > 0 ? std::min<size_t>(o.max_frames, reader->size())
                                        : reader->size();
  SevenScenesReport rep;
  // Split: frame i is never ingested when i % hold_out_every == offset (default k - 1: frames 9,
  // 19, ...; IsHeldOut; exoview_uploader --hold_out_every/--hold_out_offset sends exactly the
  // others).
  const int offset = o.holdout_offset < 0 ? o.hold_out_every - 1 : o.holdout_offset;
  if (offset >= o.hold_out_every)
    return absl::InvalidArgumentError(absl::StrCat("holdout_offset ", offset, " must be < ",
                                                   o.hold_out_every));
  std::vector<size_t> input, held;
  for (size_t i = 0; i < total; ++i)
    (IsHeldOut(i, o.hold_out_every, offset) ? held : input).push_back(i);
  rep.held_out = int(held.size());
  // Load the input frames (kept: the stored views of every policy come from them).
  std::vector<Frame> frames;
  frames.reserve(input.size());
  std::unordered_map<std::string, int> colour_hash;
  for (size_t i : input) {
    EXO_ASSIGN_OR_RETURN(Frame f, reader->Load(i));
    colour_hash[std::string(reinterpret_cast<const char*>(f.color.data()), f.color.bytes())] = 1;
    frames.push_back(std::move(f));
  }
  std::vector<Frame> test;
  for (size_t i : held) {
    EXO_ASSIGN_OR_RETURN(Frame f, reader->Load(i));
    if (colour_hash.count(std::string(reinterpret_cast<const char*>(f.color.data()),
                                      f.color.bytes()))) {
      ++rep.dropped_duplicates;
      continue;
    }
    test.push_back(std::move(f));
  }
  colour_hash.clear();
  rep.ingested = int(frames.size());
  if (frames.empty() || test.empty()) return absl::FailedPreconditionError("7-Scenes: no frames");
  // Origin, voxel, cell size and view distance from the first frame: the online model's rule
  // (server/core ChooseSceneSetup), the same the server applies to its first frame.
  core::OnlineModelOptions mo;
  mo.voxel_m = o.voxel_m;
  mo.max_depth_m = o.max_depth_m;
  EXO_ASSIGN_OR_RETURN(const core::SceneSetup setup, core::ChooseSceneSetup(frames[0], mo));
  const LocalOrigin origin = setup.origin;
  SceneScale scale = setup.scale;
  Source src;
  src.camera = frames[0].depth_camera;
  src.frame_bytes = size_t(src.camera.width) * src.camera.height * (3 + 4) + sizeof(StoredView);
  for (const Frame& f : frames) src.poses.push_back(origin.ToLocal(f.world_from_cam));
  src.scale = scale;
  src.scale_mode = o.scale_mode;
  src.view_depth_m = setup.view_depth_m;
  src.default_lambda = core::OnlineModelOptions{}.lambda;  // the product's λ
  src.metres_per_rad = 1.0;
  src.dataset = "7scenes/redkitchen";
  const std::vector<Frame>* fp = &frames;
  const LocalOrigin org = origin;
  src.load_view = [fp, org](int i) -> absl::StatusOr<StoredView> {
    const Frame& f = (*fp)[i];
    StoredView v;
    v.camera = f.color_camera;
    v.local_from_cam = org.ToLocal(f.world_from_cam);
    v.color = f.color;
    v.depth_m = f.depth_m;
    return v;
  };
  src.test_camera = frames[0].color_camera;
  if (o.test_width != src.test_camera.width)
    src.test_camera = src.test_camera.Scaled(o.test_width, o.test_height);
  src.test_sets.emplace_back();
  Source::TestSet& ts = src.test_sets.back();
  ts.label = "held_out";
  ts.depth_camera = frames[0].color_camera;
  for (const Frame& f : test) {
    ts.poses.push_back(origin.ToLocal(f.world_from_cam));
    ts.depth.push_back(f.depth_m);  // issue 15 own-depth proxy (attribution)
    if (o.test_width != f.color.width()) {
      ImageU8 small(o.test_width, o.test_height, 3);
      const int fx = f.color.width() / o.test_width, fy = f.color.height() / o.test_height;
      if (o.test_box && fx >= 1 && fy >= 1 && fx * o.test_width == f.color.width() &&
          fy * o.test_height == f.color.height()) {
        for (int y = 0; y < o.test_height; ++y)
          for (int x = 0; x < o.test_width; ++x)
            for (int c = 0; c < 3; ++c) {
              int s = 0;
              for (int v = 0; v < fy; ++v)
                for (int u = 0; u < fx; ++u) s += f.color.at(x * fx + u, y * fy + v, c);
              small.at(x, y, c) = uint8_t((s + fx * fy / 2) / (fx * fy));
            }
      } else {
        // Nearest resample (the historical smoke protocol).
        for (int y = 0; y < o.test_height; ++y)
          for (int x = 0; x < o.test_width; ++x)
            for (int c = 0; c < 3; ++c)
              small.at(x, y, c) = f.color.at(x * f.color.width() / o.test_width,
                                             y * f.color.height() / o.test_height, c);
      }
      ts.gt.push_back(std::move(small));
    } else {
      ts.gt.push_back(f.color);
    }
  }
  EngineOptions eo;
  eo.proxy = ProxyKind::kTsdf;
  eo.model = mo;
  eo.voxel_m = setup.voxel_m;
  eo.origin = origin;
  eo.max_range_m = o.max_depth_m * 2;
  eo.id_w = o.id_width;
  eo.id_h = o.id_height;
  eo.blend = o.blend;
  eo.vertex_color = o.vertex_color_baseline;
  eo.emit = o.emit;
  eo.dump_dir = o.dump_dir;
  eo.dump_views = o.dump_views;
  eo.cellid_lod_frac = o.cellid_lod_frac;
  eo.cellid_lod_m = o.cellid_lod_m;
  eo.cellid_lod_keep = o.cellid_lod_keep;
  eo.cell_ids = o.cell_ids;
  eo.per_view = o.per_view;
  Engine engine(std::move(src), o.configs, std::move(eo));
  EXO_RETURN_IF_ERROR(engine.Init());
  for (int i = 0; i < int(frames.size()); ++i) EXO_RETURN_IF_ERROR(engine.Step(i, &frames[i]));
  EXO_ASSIGN_OR_RETURN(rep.results, engine.Finish("tsdf", setup.voxel_m));
  return rep;
}

}  // namespace exo::eval
