// Self-calibration of a depth + colour RGB-D pair from posed frames (see rgbd_registration.h):
// multi-view photometric consistency + depth-edge / colour-edge alignment, Ceres, coarse to fine.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <memory>
#include <string_view>
#include <unordered_map>
#include <vector>

#include <ceres/ceres.h>
#include <ceres/cubic_interpolation.h>
#include <ceres/rotation.h>
#include <opencv2/imgproc.hpp>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "common/datasets/rgbd_registration.h"
#include "common/io/cv_adapter.h"

namespace exo {
namespace {

using Grid = ceres::Grid2D<float, 1>;
using Interp = ceres::BiCubicInterpolator<Grid>;

// Parameter blocks: intrinsics fx fy cx cy (full-resolution px), quaternion w x y z, translation.
struct Params {
  double intr[4];
  double q[4];
  double t[3];
  void Set(const DepthColorCalibration& c) {
    intr[0] = c.color_camera.fx, intr[1] = c.color_camera.fy;
    intr[2] = c.color_camera.cx, intr[3] = c.color_camera.cy;
    const glm::dquat r = glm::normalize(c.color_from_depth.rotation);
    q[0] = r.w, q[1] = r.x, q[2] = r.y, q[3] = r.z;
    t[0] = c.color_from_depth.translation.x, t[1] = c.color_from_depth.translation.y;
    t[2] = c.color_from_depth.translation.z;
  }
  DepthColorCalibration Get(int w, int h, bool same_focal) const {
    DepthColorCalibration c;
    c.color_camera = PinholeCamera{intr[0], same_focal ? intr[0] : intr[1], intr[2], intr[3], w, h};
    c.color_from_depth.rotation = glm::normalize(glm::dquat(q[0], q[1], q[2], q[3]));
    c.color_from_depth.translation = {t[0], t[1], t[2]};
    return c;
  }
};

// Projects a depth-camera point into colour pixel (col, row) at a pyramid level with `scale` =
// 2^-level (pixel centres: u_level = (u + 0.5) * scale - 0.5). False when behind the camera.
template <typename T>
bool ProjectToLevel(const T* intr, const T* q, const T* t, const double* p_in_depth, double scale,
                    bool same_focal, T* col, T* row) {
  const T pd[3] = {T(p_in_depth[0]), T(p_in_depth[1]), T(p_in_depth[2])};
  T p[3];
  ceres::QuaternionRotatePoint(q, pd, p);
  p[0] += t[0], p[1] += t[1], p[2] += t[2];
  if (!(p[2] > T(1e-6))) return false;
  const T fy = same_focal ? intr[0] : intr[1];
  *col = (intr[0] * p[0] / p[2] + intr[2] + 0.5) * scale - 0.5;
  *row = (fy * p[1] / p[2] + intr[3] + 0.5) * scale - 0.5;
  return true;
}

template <typename T>
double Scalar(const T& x) {
  if constexpr (std::is_same_v<T, double>) return x;
  else return x.a;
}

bool InsideLevel(double col, double row, int w, int h, double margin) {
  return col >= margin && row >= margin && col <= w - 1 - margin && row <= h - 1 - margin;
}

struct PhotoCost {
  double p_i[3], p_j[3];  // the same world point in depth frames i and j
  const Interp* grey_i;
  const Interp* grey_j;
  int w, h;
  double scale, factor;  // factor = sqrt(weight) / sigma
  bool same_focal;
  template <typename T>
  bool operator()(const T* intr, const T* q, const T* t, T* r) const {
    T ci, ri, cj, rj;
    if (!ProjectToLevel(intr, q, t, p_i, scale, same_focal, &ci, &ri) ||
        !ProjectToLevel(intr, q, t, p_j, scale, same_focal, &cj, &rj) ||
        !InsideLevel(Scalar(ci), Scalar(ri), w, h, 2.0) ||
        !InsideLevel(Scalar(cj), Scalar(rj), w, h, 2.0)) {
      r[0] = T(0.0);
      return true;
    }
    T gi, gj;
    grey_i->Evaluate(ri, ci, &gi);
    grey_j->Evaluate(rj, cj, &gj);
    r[0] = (gi - gj) * factor;
    return true;
  }
};

struct EdgeCost {
  double p[3];
  const Interp* dist;
  int w, h;
  double scale, factor;  // factor = sqrt(weight) / sigma_px / scale (level px -> full px)
  double truncation_level;
  bool same_focal;
  template <typename T>
  bool operator()(const T* intr, const T* q, const T* t, T* r) const {
    T c, rw;
    if (!ProjectToLevel(intr, q, t, p, scale, same_focal, &c, &rw) ||
        !InsideLevel(Scalar(c), Scalar(rw), w, h, 1.0)) {
      r[0] = T(truncation_level * factor);  // outside: as far as the truncation
      return true;
    }
    T d;
    dist->Evaluate(rw, c, &d);
    r[0] = d * factor;
    return true;
  }
};

struct TzPrior {
  double tz0, inv_sigma;
  template <typename T>
  bool operator()(const T* t, T* r) const {
    r[0] = (t[2] - tz0) * inv_sigma;
    return true;
  }
};

// Small-angle prior on the rotation: 2 * vec(q * conj(q0)) / sigma (radians).
struct RotationPrior {
  double q0_conj[4], inv_sigma;
  template <typename T>
  bool operator()(const T* q, T* r) const {
    const T q0c[4] = {T(q0_conj[0]), T(q0_conj[1]), T(q0_conj[2]), T(q0_conj[3])};
    T rel[4];
    ceres::QuaternionProduct(q, q0c, rel);
    const double sign = Scalar(rel[0]) < 0 ? -2.0 : 2.0;
    for (int k = 0; k < 3; ++k) r[k] = rel[k + 1] * (sign * inv_sigma);
    return true;
  }
};

struct PreparedFrame {
  Rigid3d world_from_depth, depth_from_world;
  const ImageF* depth = nullptr;
  cv::Mat grey;   // CV_32F, grey in [0, 1] (sRGB-encoded), full resolution
  cv::Mat grey8;  // CV_8U, for edges
  std::vector<glm::dvec3> photo_points;  // depth-camera coordinates
  std::vector<glm::dvec3> edge_points;
};

struct PhotoSample {
  int i, j;
  glm::dvec3 p_i, p_j;
};

struct LevelImages {
  cv::Mat grey, dist;  // CV_32F, continuous
  std::unique_ptr<Grid> grey_grid, dist_grid;
  std::unique_ptr<Interp> grey_interp, dist_interp;
  int w = 0, h = 0;
};

// Every frame at one pyramid level: blurred grey and the truncated distance to the
// nearest colour edge (truncation <= 0: untruncated).
std::vector<LevelImages> BuildLevel(const std::vector<PreparedFrame>& frames, int level,
                                    double truncation_level) {
  std::vector<LevelImages> out(frames.size());
  for (size_t k = 0; k < frames.size(); ++k) {
    cv::Mat g = frames[k].grey, g8 = frames[k].grey8;
    for (int l = 0; l < level; ++l) {
      cv::pyrDown(g, g);
      cv::pyrDown(g8, g8);
    }
    LevelImages& li = out[k];
    cv::GaussianBlur(g, li.grey, cv::Size(0, 0), 1.0);
    cv::Mat blurred, edges;
    cv::GaussianBlur(g8, blurred, cv::Size(0, 0), 1.0);
    cv::Canny(blurred, edges, 20, 50, 3, true);
    cv::Mat not_edges = edges == 0;
    cv::distanceTransform(not_edges, li.dist, cv::DIST_L2, cv::DIST_MASK_PRECISE, CV_32F);
    if (truncation_level > 0) cv::min(li.dist, truncation_level, li.dist);
    li.w = g.cols, li.h = g.rows;
    li.grey = li.grey.clone();
    li.dist = li.dist.clone();
    li.grey_grid = std::make_unique<Grid>(li.grey.ptr<float>(), 0, li.h, 0, li.w);
    li.dist_grid = std::make_unique<Grid>(li.dist.ptr<float>(), 0, li.h, 0, li.w);
    li.grey_interp = std::make_unique<Interp>(*li.grey_grid);
    li.dist_interp = std::make_unique<Interp>(*li.dist_grid);
  }
  return out;
}

// Evenly spaced subset of at most n elements.
template <typename V>
V EvenSubset(const V& v, int n) {
  if (n <= 0 || static_cast<int>(v.size()) <= n) return v;
  V out;
  out.reserve(n);
  const double step = double(v.size()) / n;
  for (int k = 0; k < n; ++k) out.push_back(v[static_cast<size_t>(k * step)]);
  return out;
}

struct Prepared {
  std::vector<PreparedFrame> frames;
  std::vector<PhotoSample> photo;
  size_t dropped_duplicates = 0, pairs = 0;
  int color_w = 0, color_h = 0;
};

absl::StatusOr<Prepared> Prepare(const std::vector<Frame>& raw_frames,
                                 const PinholeCamera& depth_camera,
                                 const CalibrationOptions& o) {
  EXO_RETURN_IF_ERROR(o.Validate());
  if (raw_frames.empty()) return absl::InvalidArgumentError("calibration: no frames given");
  if (auto s = depth_camera.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("calibration depth camera: ", s.message()));
  Prepared P;
  P.color_w = raw_frames[0].color.width();
  P.color_h = raw_frames[0].color.height();
  for (size_t k = 0; k < raw_frames.size(); ++k) {
    const Frame& f = raw_frames[k];
    if (auto s = f.Validate(); !s.ok())
      return absl::InvalidArgumentError(absl::StrCat("calibration frame ", k, ": ", s.message()));
    if (f.depth_m.width() != depth_camera.width || f.depth_m.height() != depth_camera.height)
      return absl::InvalidArgumentError(absl::StrCat(
          "calibration frame ", k, ": depth is ", f.depth_m.width(), "x", f.depth_m.height(),
          ", depth camera is ", depth_camera.width, "x", depth_camera.height));
    if (f.color.width() != P.color_w || f.color.height() != P.color_h || f.color.channels() != 3)
      return absl::InvalidArgumentError(absl::StrCat(
          "calibration frame ", k, ": colour is ", f.color.width(), "x", f.color.height(), "x",
          f.color.channels(), ", frame 0's is ", P.color_w, "x", P.color_h, "x3"));
    for (float z : f.depth_m.span())
      if (!std::isfinite(z) || z < 0)
        return absl::InvalidArgumentError(
            absl::StrCat("calibration frame ", k, ": depth has NaN/Inf/negative values"));
  }
  // Frames whose colour image is byte-identical to another's (7-Scenes repeats colour frames
  // under a different pose): their colour does not belong to their pose; drop all of them.
  std::unordered_map<size_t, std::vector<size_t>> by_hash;
  for (size_t k = 0; k < raw_frames.size(); ++k) {
    const auto& c = raw_frames[k].color;
    by_hash[std::hash<std::string_view>{}(std::string_view(
                reinterpret_cast<const char*>(c.data()), c.bytes()))].push_back(k);
  }
  std::vector<bool> duplicate(raw_frames.size(), false);
  for (const auto& [h, ks] : by_hash)
    for (size_t a = 0; a < ks.size(); ++a)
      for (size_t b = a + 1; b < ks.size(); ++b)
        if (raw_frames[ks[a]].color == raw_frames[ks[b]].color)
          duplicate[ks[a]] = duplicate[ks[b]] = true;

  const float rel = static_cast<float>(o.depth_jump_relative);
  const float jump_min = static_cast<float>(o.depth_jump_min_m);
  for (size_t k = 0; k < raw_frames.size(); ++k) {
    if (duplicate[k]) {
      ++P.dropped_duplicates;
      continue;
    }
    const Frame& f = raw_frames[k];
    PreparedFrame pf;
    pf.world_from_depth = f.world_from_cam;
    pf.depth_from_world = f.world_from_cam.Inverse();
    pf.depth = &f.depth_m;
    cv::Mat rgb = CvView(f.color);
    cv::cvtColor(rgb, pf.grey8, cv::COLOR_RGB2GRAY);
    pf.grey8.convertTo(pf.grey, CV_32F, 1.0 / 255.0);
    const ImageF& d = f.depth_m;
    const int W = d.width(), H = d.height();
    std::vector<glm::dvec3> photo, edge;
    for (int v = 3; v < H - 3; ++v) {
      for (int u = 3; u < W - 3; ++u) {
        const float z = d.at(u, v);
        if (z <= 0) continue;
        bool smooth = true, is_edge = false;
        for (int dv = -1; dv <= 1; ++dv)
          for (int du = -1; du <= 1; ++du) {
            const float n = d.at(u + du, v + dv);
            if (n <= 0 || std::abs(n - z) > rel * z) smooth = false;
            if ((du == 0) != (dv == 0) && n > 0 && n - z > std::max(jump_min, rel * z))
              is_edge = true;
          }
        const glm::dvec3 p = depth_camera.Unproject({double(u), double(v)}, z);
        if (is_edge) edge.push_back(p);
        else if (smooth) photo.push_back(p);
      }
    }
    pf.photo_points = EvenSubset(photo, o.photometric_samples_per_frame);
    pf.edge_points = EvenSubset(edge, o.edge_samples_per_frame);
    P.frames.push_back(std::move(pf));
  }
  // Pairs (i -> j) with parallax, nearest in sequence order first.
  const int n = static_cast<int>(P.frames.size());
  for (int i = 0; i < n; ++i) {
    std::vector<int> cand;
    for (int j = 0; j < n; ++j) {
      if (j == i) continue;
      const Rigid3d& a = P.frames[i].world_from_depth;
      const Rigid3d& b = P.frames[j].world_from_depth;
      const double ang = RotationAngleRad(a.rotation, b.rotation) * 180.0 / M_PI;
      const double base = glm::length(a.translation - b.translation);
      if (ang > o.max_pair_rotation_deg || base > o.max_pair_baseline_m) continue;
      if (ang < o.min_pair_rotation_deg && base < o.min_pair_baseline_m) continue;
      cand.push_back(j);
    }
    std::sort(cand.begin(), cand.end(),
              [i](int a, int b) { return std::abs(a - i) < std::abs(b - i); });
    if (static_cast<int>(cand.size()) > o.neighbours_per_frame) cand.resize(o.neighbours_per_frame);
    for (int j : cand) {
      ++P.pairs;
      const PreparedFrame& fi = P.frames[i];
      const PreparedFrame& fj = P.frames[j];
      for (const glm::dvec3& p_i : fi.photo_points) {
        const glm::dvec3 p_j = fj.depth_from_world * (fi.world_from_depth * p_i);
        glm::dvec2 uv;
        if (!depth_camera.Project(p_j, &uv) || !depth_camera.InImage(uv, 1.0)) continue;
        const float zj = fj.depth->at(static_cast<int>(std::lround(uv.x)),
                                      static_cast<int>(std::lround(uv.y)));
        if (zj <= 0 || std::abs(zj - p_j.z) > 0.03 * p_j.z + 0.02) continue;  // occluded
        P.photo.push_back({i, j, p_i, p_j});
      }
    }
  }
  size_t edges = 0;
  for (const auto& f : P.frames) edges += f.edge_points.size();
  if (P.photo.empty() && edges == 0)
    return absl::InvalidArgumentError(absl::StrCat(
        "calibration: no usable samples (", P.frames.size(), " frames after dropping ",
        P.dropped_duplicates, " with duplicate colour; all-invalid depth or no overlap?)"));
  return P;
}

struct LevelProblem {
  std::vector<LevelImages> images;
  std::unique_ptr<ceres::Problem> problem;
  std::vector<ceres::ResidualBlockId> photo_ids, edge_ids;
  std::unique_ptr<ceres::LossFunction> photo_loss, edge_loss;
};

glm::dquat InitialRotation(const CalibrationOptions& o) {
  return o.initial.color_camera.fx > 0 ? o.initial.color_from_depth.rotation
                                       : glm::dquat(1, 0, 0, 0);
}

std::unique_ptr<LevelProblem> BuildProblem(const Prepared& P, const CalibrationOptions& o,
                                           int level, Params* params) {
  auto lp = std::make_unique<LevelProblem>();
  const double scale = std::ldexp(1.0, -level);
  const double trunc_level = std::max(3.0, o.edge_truncation_px * scale);
  lp->images = BuildLevel(P.frames, level, trunc_level);
  ceres::Problem::Options po;
  po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  lp->problem = std::make_unique<ceres::Problem>(po);
  lp->photo_loss = std::make_unique<ceres::HuberLoss>(1.0);
  lp->edge_loss = std::make_unique<ceres::CauchyLoss>(1.0);
  ceres::Problem& pr = *lp->problem;
  pr.AddParameterBlock(params->intr, 4);
  pr.AddParameterBlock(params->q, 4, new ceres::QuaternionManifold);
  pr.AddParameterBlock(params->t, 3);
  if (o.same_focal) pr.SetManifold(params->intr, new ceres::SubsetManifold(4, {1}));
  if (!o.estimate_rotation) pr.SetParameterBlockConstant(params->q);
  const int w = lp->images[0].w, h = lp->images[0].h;
  if (o.photometric_weight > 0) {
    const double factor = std::sqrt(o.photometric_weight) / o.photometric_sigma;
    for (const PhotoSample& s : P.photo) {
      auto* c = new PhotoCost{{s.p_i.x, s.p_i.y, s.p_i.z},
                              {s.p_j.x, s.p_j.y, s.p_j.z},
                              lp->images[s.i].grey_interp.get(),
                              lp->images[s.j].grey_interp.get(),
                              w, h, scale, factor, o.same_focal};
      lp->photo_ids.push_back(pr.AddResidualBlock(
          new ceres::AutoDiffCostFunction<PhotoCost, 1, 4, 4, 3>(c), lp->photo_loss.get(),
          params->intr, params->q, params->t));
    }
  }
  if (o.edge_weight > 0) {
    const double factor = std::sqrt(o.edge_weight) / o.edge_sigma_px / scale;
    for (size_t k = 0; k < P.frames.size(); ++k)
      for (const glm::dvec3& p : P.frames[k].edge_points) {
        auto* c = new EdgeCost{{p.x, p.y, p.z}, lp->images[k].dist_interp.get(), w, h, scale,
                               factor, trunc_level, o.same_focal};
        lp->edge_ids.push_back(pr.AddResidualBlock(
            new ceres::AutoDiffCostFunction<EdgeCost, 1, 4, 4, 3>(c), lp->edge_loss.get(),
            params->intr, params->q, params->t));
      }
  }
  if (o.tz_prior_sigma_m > 0)
    pr.AddResidualBlock(new ceres::AutoDiffCostFunction<TzPrior, 1, 3>(
                            new TzPrior{params->t[2], 1.0 / o.tz_prior_sigma_m}),
                        nullptr, params->t);
  if (o.rotation_prior_sigma_deg > 0 && o.estimate_rotation) {
    const glm::dquat q0 = glm::normalize(InitialRotation(o));
    lp->problem->AddResidualBlock(
        new ceres::AutoDiffCostFunction<RotationPrior, 3, 4>(new RotationPrior{
            {q0.w, -q0.x, -q0.y, -q0.z}, 180.0 / M_PI / o.rotation_prior_sigma_deg}),
        nullptr, params->q);
  }
  return lp;
}

double EvalCost(ceres::Problem& pr, const std::vector<ceres::ResidualBlockId>* ids,
                int threads) {
  ceres::Problem::EvaluateOptions eo;
  eo.num_threads = threads;
  if (ids) {
    if (ids->empty()) return 0.0;
    eo.residual_blocks = *ids;
  }
  double cost = 0;
  pr.Evaluate(eo, &cost, nullptr, nullptr, nullptr);
  return cost;
}

DepthColorCalibration InitialOf(const CalibrationOptions& o, const PinholeCamera& depth_camera,
                                int w, int h) {
  if (o.initial.color_camera.fx > 0) return o.initial;
  DepthColorCalibration c;
  c.color_camera = depth_camera.Scaled(w, h);
  c.color_from_depth = Rigid3d::Identity();
  return c;
}

}  // namespace

absl::Status CalibrationOptions::Validate() const {
  if (initial.color_camera.fx != 0)
    if (auto s = initial.Validate(); !s.ok())
      return absl::InvalidArgumentError(absl::StrCat("initial calibration: ", s.message()));
  if (pyramid_levels < 1 || pyramid_levels > 6)
    return absl::InvalidArgumentError("pyramid_levels must be in [1, 6]");
  if (max_iterations_per_level < 1) return absl::InvalidArgumentError("max_iterations_per_level must be >= 1");
  if (focal_search_step < 0 || (focal_search_step > 0 && !(focal_search_min > 0 &&
                                                           focal_search_max >= focal_search_min)))
    return absl::InvalidArgumentError("focal search: need 0 < min <= max and step >= 0");
  if (!(photometric_weight >= 0) || !(edge_weight >= 0) ||
      (photometric_weight == 0 && edge_weight == 0))
    return absl::InvalidArgumentError("term weights must be >= 0 and not both 0");
  if (!(photometric_sigma > 0) || !(edge_sigma_px > 0) || !(edge_truncation_px > 0))
    return absl::InvalidArgumentError("photometric_sigma, edge_sigma_px, edge_truncation_px must be > 0");
  if (photometric_samples_per_frame < 0 || edge_samples_per_frame < 0 || neighbours_per_frame < 0)
    return absl::InvalidArgumentError("sample and neighbour counts must be >= 0");
  if (!(min_pair_rotation_deg >= 0) || !(max_pair_rotation_deg > 0) ||
      !(min_pair_baseline_m >= 0) || !(max_pair_baseline_m > 0))
    return absl::InvalidArgumentError("pair limits must be >= 0 (max > 0)");
  if (!(depth_jump_relative > 0) || !(depth_jump_min_m >= 0))
    return absl::InvalidArgumentError("depth jump thresholds must be > 0");
  if (!(tz_prior_sigma_m >= 0) || !(rotation_prior_sigma_deg >= 0))
    return absl::InvalidArgumentError("prior sigmas must be >= 0");
  if (num_threads < 1 || num_threads > 256) return absl::InvalidArgumentError("num_threads must be in [1, 256]");
  return absl::OkStatus();
}

std::string CalibrationReport::ToJson() const {
  auto cal = [](const DepthColorCalibration& c) {
    const auto& k = c.color_camera;
    const auto& q = c.color_from_depth.rotation;
    const auto& t = c.color_from_depth.translation;
    return absl::StrFormat(
        "{\"fx\":%.4f,\"fy\":%.4f,\"cx\":%.4f,\"cy\":%.4f,\"width\":%d,\"height\":%d,"
        "\"q_wxyz\":[%.8f,%.8f,%.8f,%.8f],\"t_m\":[%.6f,%.6f,%.6f],\"rotation_deg\":%.4f}",
        k.fx, k.fy, k.cx, k.cy, k.width, k.height, q.w, q.x, q.y, q.z, t.x, t.y, t.z,
        RotationAngleRad(q, glm::dquat(1, 0, 0, 0)) * 180.0 / M_PI);
  };
  auto term = [](const CalibrationTermStats& s) {
    return absl::StrFormat(
        "{\"residuals\":%d,\"cost_before\":%.6g,\"cost_after\":%.6g,"
        "\"median_abs_before\":%.5f,\"median_abs_after\":%.5f}",
        s.residuals, s.cost_before, s.cost_after, s.median_abs_before, s.median_abs_after);
  };
  return absl::StrFormat(
      "{\"calibration\":%s,\"initial\":%s,\"focal_search_best_scale\":%.3f,"
      "\"initial_cost\":%.6g,\"final_cost\":%.6g,\"photometric\":%s,\"edge\":%s,"
      "\"frames_used\":%d,\"frames_dropped_duplicate_color\":%d,\"pairs_used\":%d,"
      "\"iterations\":%d,\"seconds\":%.2f}",
      cal(calibration), cal(initial), focal_search_best_scale, initial_cost, final_cost,
      term(photometric), term(edge), frames_used, frames_dropped_duplicate_color, pairs_used,
      iterations, seconds);
}

absl::StatusOr<CalibrationReport> EstimateDepthColorCalibration(
    const std::vector<Frame>& raw_frames, const PinholeCamera& depth_camera,
    const CalibrationOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  EXO_ASSIGN_OR_RETURN(Prepared P, Prepare(raw_frames, depth_camera, o));
  CalibrationReport rep;
  rep.frames_used = P.frames.size();
  rep.frames_dropped_duplicate_color = P.dropped_duplicates;
  rep.pairs_used = P.pairs;
  const DepthColorCalibration init = InitialOf(o, depth_camera, P.color_w, P.color_h);
  EXO_RETURN_IF_ERROR(init.Validate());
  Params params;
  params.Set(init);

  for (int level = o.pyramid_levels - 1; level >= 0; --level) {
    auto lp = BuildProblem(P, o, level, &params);
    ceres::Problem& pr = *lp->problem;
    if (level == o.pyramid_levels - 1) {
      if (o.focal_search_step > 0) {
        const double fx0 = params.intr[0], fy0 = params.intr[1];
        double best_cost = std::numeric_limits<double>::infinity(), best = 1.0;
        for (double s = o.focal_search_min; s <= o.focal_search_max + 1e-9;
             s += o.focal_search_step) {
          params.intr[0] = s * fx0, params.intr[1] = s * fy0;
          const double c = EvalCost(pr, nullptr, o.num_threads);
          if (c < best_cost) best_cost = c, best = s;
        }
        params.intr[0] = best * fx0, params.intr[1] = best * fy0;
        rep.focal_search_best_scale = best;
      }
      rep.initial = params.Get(P.color_w, P.color_h, o.same_focal);
    }
    ceres::Solver::Options so;
    so.linear_solver_type = ceres::DENSE_QR;
    so.max_num_iterations = o.max_iterations_per_level;
    so.num_threads = o.num_threads;
    so.function_tolerance = 1e-7;
    so.minimizer_progress_to_stdout = false;
    so.logging_type = ceres::SILENT;
    if (level == 0) {
      rep.initial_cost = EvalCost(pr, nullptr, o.num_threads);
      rep.photometric.cost_before = EvalCost(pr, &lp->photo_ids, o.num_threads);
      rep.edge.cost_before = EvalCost(pr, &lp->edge_ids, o.num_threads);
    }
    ceres::Solver::Summary summary;
    ceres::Solve(so, &pr, &summary);
    rep.iterations += static_cast<int>(summary.iterations.size());
    if (summary.termination_type == ceres::FAILURE)
      return absl::InternalError(absl::StrCat("calibration solver failed at level ", level, ": ",
                                              summary.message));
    if (level == 0) {
      rep.final_cost = EvalCost(pr, nullptr, o.num_threads);
      rep.photometric.cost_after = EvalCost(pr, &lp->photo_ids, o.num_threads);
      rep.edge.cost_after = EvalCost(pr, &lp->edge_ids, o.num_threads);
      rep.photometric.residuals = lp->photo_ids.size();
      rep.edge.residuals = lp->edge_ids.size();
    }
  }
  rep.calibration = params.Get(P.color_w, P.color_h, o.same_focal);
  // Raw per-term medians, before (the search's start point) and after, at full resolution.
  EXO_ASSIGN_OR_RETURN(AlignmentMeasures before,
                       MeasureDepthColorAlignment(raw_frames, depth_camera, rep.initial, o));
  EXO_ASSIGN_OR_RETURN(AlignmentMeasures after,
                       MeasureDepthColorAlignment(raw_frames, depth_camera, rep.calibration, o));
  rep.photometric.median_abs_before = before.photometric_median_abs;
  rep.photometric.median_abs_after = after.photometric_median_abs;
  rep.edge.median_abs_before = before.edge_median_px;
  rep.edge.median_abs_after = after.edge_median_px;
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

absl::StatusOr<AlignmentMeasures> MeasureDepthColorAlignment(
    const std::vector<Frame>& raw_frames, const PinholeCamera& depth_camera,
    const DepthColorCalibration& calib, const CalibrationOptions& options) {
  EXO_RETURN_IF_ERROR(calib.Validate());
  EXO_ASSIGN_OR_RETURN(Prepared P, Prepare(raw_frames, depth_camera, options));
  const std::vector<LevelImages> images = BuildLevel(P.frames, 0, /*truncation=*/0.0);
  Params params;
  params.Set(calib);
  const int w = images[0].w, h = images[0].h;
  AlignmentMeasures m;
  std::vector<double> photo, edge;
  for (const PhotoSample& s : P.photo) {
    double ci, ri, cj, rj;
    const double pi[3] = {s.p_i.x, s.p_i.y, s.p_i.z}, pj[3] = {s.p_j.x, s.p_j.y, s.p_j.z};
    if (!ProjectToLevel(params.intr, params.q, params.t, pi, 1.0, false, &ci, &ri) ||
        !ProjectToLevel(params.intr, params.q, params.t, pj, 1.0, false, &cj, &rj) ||
        !InsideLevel(ci, ri, w, h, 2.0) || !InsideLevel(cj, rj, w, h, 2.0))
      continue;
    double gi, gj;
    images[s.i].grey_interp->Evaluate(ri, ci, &gi);
    images[s.j].grey_interp->Evaluate(rj, cj, &gj);
    photo.push_back(std::abs(gi - gj));
  }
  for (size_t k = 0; k < P.frames.size(); ++k)
    for (const glm::dvec3& p : P.frames[k].edge_points) {
      double c, r;
      const double pp[3] = {p.x, p.y, p.z};
      if (!ProjectToLevel(params.intr, params.q, params.t, pp, 1.0, false, &c, &r) ||
          !InsideLevel(c, r, w, h, 1.0))
        continue;
      double d;
      images[k].dist_interp->Evaluate(r, c, &d);
      edge.push_back(std::max(0.0, d));
    }
  auto median = [](std::vector<double>& v) {
    if (v.empty()) return 0.0;
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  m.photometric_samples = photo.size();
  m.edge_samples = edge.size();
  m.photometric_median_abs = median(photo);
  m.edge_median_px = median(edge);
  if (!edge.empty()) {
    const size_t k90 = std::min(edge.size() - 1, edge.size() * 9 / 10);
    std::nth_element(edge.begin(), edge.begin() + k90, edge.end());
    m.edge_p90_px = edge[k90];
  }
  return m;
}

}  // namespace exo
