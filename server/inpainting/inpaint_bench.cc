// inpaint_bench: InpaintFusion keyframe inpainting on real 7-Scenes frames with ground truth.
// Masks (committed, parametric: unions of ellipses, testdata/masks.jsonl) are placed over
// regions whose colour and depth are known; the frame's own pixels under the mask are the truth.
// Methods on the same masks: ours (PatchMatch + geometry term + Poisson on inverse depth), ours
// with the thesis' literal depth domain, colour-only PatchMatch (no rho_g), OpenCV Telea (colour
// and depth), a plane fitted to the ring around the mask (depth). Propagated keyframes: the mask
// region re-projected into frame +5 and inpainted from the previous keyframe's map.
// Prints a run_info line (commit, build, machine, load: common/run_info), one JSON object per
// (method, mask) with an output digest for ours, and per-(method, class) summaries; writes a
// contact sheet (PNG). The time-vs-error chart is drawn from the summary lines by
// tools/charts/inpaint_chart.py (matplotlib).
//
// Depth is registered to colour (the committed 7-Scenes calibration) unless --raw.
//
//   inpaint_bench [--data DIR] [--masks FILE] [--generate_masks [--mask_seed S --mask_frame0 F]]
//                 [--img_dir DIR] [--threads N] [--repeats N] [--max_masks N] [--raw]
//                 [--fusion mean|robust] [--jump_rel R] [--jump_weight W] [--converged F]
//                 [--neumann_prior W] [--prior_local SIGMA_PX] [--seed S]
//                 [--peel_all_normals] [--dump_depth DIR]
//                 [--layered | --no_layered] [--layer_gap R] [--layer_min_share S] [--max_layers K]
//                 [--layer_agree R] [--layer_dist W] [--layer_smooth W]
//                 [--layer_sigma S] [--layer_jump F] [--layer_block PX] [--layer_seed_measured 0|1] [--layer_edge_seeds 0|1]
#include "exoview_source_dir.h"
#include <algorithm>
#include <array>
#include <chrono>
#include <ctime>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Dense>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/photo.hpp>

#include "common/cli/cli.h"
#include "common/datasets/rgbd_registration.h"
#include "common/metrics/metrics.h"
#include "common/run_info/run_info.h"
#include "server/inpainting/depth_maps.h"
#include "server/inpainting/inpaint.h"

namespace exo::inpainting {
namespace {

using Clock = std::chrono::steady_clock;

// Depth registered to colour (common/datasets/rgbd_registration.h, the committed 7-Scenes
// calibration) unless --raw: camera = colour camera, pose = colour-camera pose.
bool g_register = true;

PinholeCamera RawDepthCamera7Scenes();

// Process CPU time (all threads): robust to other processes competing for the 2 cores.
double CpuMs() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

struct Ellipse {
  double cx, cy, rx, ry, angle_deg;
};
struct MaskSpec {
  std::string id, cls;
  int frame = 0;
  double fraction = 0;
  std::vector<Ellipse> ellipses;
};

cv::Mat DrawMask(const MaskSpec& m, int w, int h) {
  cv::Mat mask(h, w, CV_8UC1, cv::Scalar(0));
  for (const Ellipse& e : m.ellipses) {
    cv::ellipse(mask, cv::Point2d(e.cx, e.cy), cv::Size2d(e.rx, e.ry), e.angle_deg, 0, 360,
                cv::Scalar(255), cv::FILLED, cv::LINE_8);
  }
  return mask;
}

std::string FramePath(const std::string& dir, int frame, const char* suffix) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "/frame-%06d.%s", frame, suffix);
  return dir + buf;
}

struct RealFrame {
  cv::Mat color_rgb;  // CV_8UC3 RGB
  cv::Mat depth_m;    // CV_32F
  Rigid3d world_from_cam;
  bool ok = false;
};

RealFrame LoadFrame(const std::string& dir, int frame) {
  RealFrame f;
  cv::Mat bgr = cv::imread(FramePath(dir, frame, "color.jpg"), cv::IMREAD_COLOR);
  cv::Mat d16 = cv::imread(FramePath(dir, frame, "depth.png"), cv::IMREAD_UNCHANGED);
  if (bgr.empty() || d16.empty() || d16.type() != CV_16UC1) {
    std::fprintf(stderr, "frame %d: cannot read colour/depth under %s\n", frame, dir.c_str());
    return f;
  }
  cv::cvtColor(bgr, f.color_rgb, cv::COLOR_BGR2RGB);
  d16.convertTo(f.depth_m, CV_32F, 1e-3);
  std::ifstream pf(FramePath(dir, frame, "pose.txt"));
  std::array<double, 16> m{};
  for (double& v : m) pf >> v;
  if (!pf) {
    std::fprintf(stderr, "frame %d: cannot read the pose\n", frame);
    return f;
  }
  // KinectFusion poses drift off orthonormal (|R^T R - I| up to ~2e-4 in this sequence, above
  // ValidateRotation's 1e-4): project R onto SO(3) with an SVD first.
  {
    Eigen::Matrix3d r;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) r(i, j) = m[i * 4 + j];
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(r, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d q = svd.matrixU() * svd.matrixV().transpose();
    if (q.determinant() < 0) q = -q;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) m[i * 4 + j] = q(i, j);
  }
  auto pose = RigidFromRowMajor4x4(m);
  if (!pose.ok()) {
    std::fprintf(stderr, "frame %d: %s\n", frame, pose.status().ToString().c_str());
    return f;
  }
  f.world_from_cam = *pose;
  if (g_register) {
    const DepthColorCalibration calib = SevenScenesKinectV1Calibration();
    ImageF raw(640, 480, 1);
    std::memcpy(raw.data(), f.depth_m.data, raw.bytes());
    auto reg = RegisterDepthToColor(raw, RawDepthCamera7Scenes(), calib);
    if (!reg.ok()) {
      std::fprintf(stderr, "frame %d: %s\n", frame, reg.status().ToString().c_str());
      return f;
    }
    f.depth_m = cv::Mat(480, 640, CV_32F, reg->data()).clone();
    f.world_from_cam = f.world_from_cam * calib.color_from_depth.Inverse();
  }
  f.ok = true;
  return f;
}

PinholeCamera RawDepthCamera7Scenes() {
  PinholeCamera c;
  c.fx = c.fy = 585.0;
  c.cx = 320.0;
  c.cy = 240.0;
  c.width = 640;
  c.height = 480;
  return c;
}

PinholeCamera Camera7Scenes() {
  return g_register ? SevenScenesKinectV1Calibration().color_camera : RawDepthCamera7Scenes();
}

RgbdKeyframe ToKeyframe(const RealFrame& f, const cv::Mat& mask) {
  RgbdKeyframe k;
  k.camera = Camera7Scenes();
  k.world_from_cam = f.world_from_cam;
  k.color = ImageU8(640, 480, 3);
  k.depth_m = ImageF(640, 480, 1);
  std::memcpy(k.color.data(), f.color_rgb.data, k.color.bytes());
  std::memcpy(k.depth_m.data(), f.depth_m.data, k.depth_m.bytes());
  // Nothing under the mask reaches any method.
  for (int y = 0; y < 480; ++y)
    for (int x = 0; x < 640; ++x)
      if (mask.at<uint8_t>(y, x)) {
        k.depth_m.at(x, y) = 0.f;
        for (int c = 0; c < 3; ++c) k.color.at(x, y, c) = 0;
      }
  return k;
}

// ---------------------------------------------------------------- masks (generation + IO)
// Key order, 6 significant digits and whole numbers without ".0", as the committed masks files
// were written (--generate_masks reproduces them byte for byte).
nlohmann::ordered_json ToJson(const MaskSpec& m) {
  auto g6 = [](double v) {
    char b[32];
    std::snprintf(b, sizeof(b), "%.6g", v);
    const double r = std::strtod(b, nullptr);
    return r == std::round(r) && std::fabs(r) < 1e15 ? nlohmann::ordered_json(static_cast<int64_t>(r))
                                                      : nlohmann::ordered_json(r);
  };
  nlohmann::ordered_json ellipses = nlohmann::ordered_json::array();
  for (const Ellipse& e : m.ellipses)
    ellipses.push_back({g6(e.cx), g6(e.cy), g6(e.rx), g6(e.ry), g6(e.angle_deg)});
  return {{"id", m.id}, {"frame", m.frame}, {"class", m.cls}, {"fraction", g6(m.fraction)},
          {"ellipses", ellipses}};
}

// One line of a masks file; an error names what is missing.
absl::StatusOr<MaskSpec> ParseMask(const std::string& line) {
  const nlohmann::json j = nlohmann::json::parse(line, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) return absl::InvalidArgumentError("not a JSON object");
  MaskSpec m;
  try {
    m.id = j.at("id").get<std::string>();
    m.cls = j.at("class").get<std::string>();
    m.frame = j.at("frame").get<int>();
    m.fraction = j.value("fraction", 0.0);
    for (const auto& e : j.at("ellipses")) {
      if (!e.is_array() || e.size() != 5) return absl::InvalidArgumentError("an ellipse needs 5 numbers");
      m.ellipses.push_back({e[0].get<double>(), e[1].get<double>(), e[2].get<double>(),
                            e[3].get<double>(), e[4].get<double>()});
    }
  } catch (const nlohmann::json::exception& e) {
    return absl::InvalidArgumentError(e.what());
  }
  if (m.id.empty() || m.ellipses.empty()) return absl::InvalidArgumentError("empty id or no ellipse");
  return m;
}

// Blob of 3 ellipses with a random layout, scaled to the target fraction; placed where the
// frame's depth is valid under >= 97 % of the mask (the best of 200 tries).
std::vector<MaskSpec> GenerateMasks(const std::string& data_dir, uint64_t seed, int frame0) {
  std::mt19937_64 rng(seed);
  std::vector<MaskSpec> out;
  const std::vector<std::pair<std::string, std::pair<double, double>>> classes = {
      {"2-5%", {0.02, 0.05}}, {"10-20%", {0.165, 0.175}}, {"30-40%", {0.30, 0.40}}};
  for (int frame = frame0; frame + 5 < 300; frame += 30) {
    RealFrame f = LoadFrame(data_dir, frame);
    if (!f.ok) continue;
    for (const auto& [cls, range] : classes) {
      std::uniform_real_distribution<double> U(0, 1);
      const double target = range.first + (range.second - range.first) * U(rng);
      MaskSpec best;
      double best_valid = -1;
      for (int attempt = 0; attempt < 200; ++attempt) {
        MaskSpec m;
        m.frame = frame;
        m.cls = cls;
        const double cx = 80 + 480 * U(rng), cy = 60 + 360 * U(rng);
        std::vector<Ellipse> base;
        for (int k = 0; k < 3; ++k) {
          base.push_back({cx + (U(rng) - 0.5) * 120, cy + (U(rng) - 0.5) * 90, 0.5 + U(rng),
                          0.5 + U(rng), 180 * U(rng)});
        }
        // Scale the radii until the area hits the target (bisection).
        double lo = 1, hi = 600, frac = 0;
        for (int it = 0; it < 30; ++it) {
          const double mid = 0.5 * (lo + hi);
          m.ellipses = base;
          for (Ellipse& e : m.ellipses) {
            e.rx *= mid;
            e.ry *= mid;
          }
          frac = cv::countNonZero(DrawMask(m, 640, 480)) / (640.0 * 480.0);
          (frac < target ? lo : hi) = mid;
        }
        const cv::Mat mk = DrawMask(m, 640, 480);
        const int area = cv::countNonZero(mk);
        const int valid = cv::countNonZero((f.depth_m > 0) & mk);
        const double vf = area ? static_cast<double>(valid) / area : 0;
        m.fraction = frac;
        if (vf > best_valid) {
          best_valid = vf;
          best = m;
        }
        if (vf >= 0.97) break;
      }
      best.id = "f" + std::to_string(frame) + "_" + (cls == "2-5%" ? "s" : cls == "10-20%" ? "m" : "l");
      for (Ellipse& e : best.ellipses) {
        e.cx = std::round(e.cx * 10) / 10;
        e.cy = std::round(e.cy * 10) / 10;
        e.rx = std::round(e.rx * 10) / 10;
        e.ry = std::round(e.ry * 10) / 10;
        e.angle_deg = std::round(e.angle_deg * 10) / 10;
      }
      best.fraction = cv::countNonZero(DrawMask(best, 640, 480)) / (640.0 * 480.0);
      out.push_back(best);
    }
  }
  return out;
}

// ---------------------------------------------------------------- metrics
struct Metrics {
  double psnr = NAN, ssim = NAN, depth_mae_mm = NAN, depth_rmse_mm = NAN, normal_deg = NAN;
  double seam_color = NAN, seam_color_gt = NAN, seam_depth_mm = NAN, seam_depth_gt_mm = NAN;
  double depth_valid_frac = NAN;
};

exo::ImageU8 U8FromMat(const cv::Mat& m) {
  exo::ImageU8 im(m.cols, m.rows, m.channels());
  for (int y = 0; y < m.rows; ++y) std::memcpy(im.row(y), m.ptr(y), im.stride());
  return im;
}

ImageF FromMat(const cv::Mat& m) {
  ImageF im(m.cols, m.rows, 1);
  std::memcpy(im.data(), m.data, im.bytes());
  return im;
}

Metrics Evaluate(const cv::Mat& mask, const cv::Mat* color_rgb, const cv::Mat* depth_m,
                 const RealFrame& gt) {
  Metrics r;
  const int w = 640, h = 480;
  if (color_rgb) {
    // PSNR and SSIM from common/metrics (SSIM map on BT.601 luma, averaged over the mask).
    const exo::ImageU8 a8 = U8FromMat(*color_rgb), b8 = U8FromMat(gt.color_rgb), m8 = U8FromMat(mask);
    auto psnr = exo::MaskedPsnr(a8, b8, m8);
    auto ssim = exo::MaskedSsim(a8, b8, m8);
    r.psnr = psnr.ok() ? *psnr : NAN;
    r.ssim = ssim.ok() ? *ssim : NAN;
    double seam = 0, seam_gt = 0;
    int ns = 0;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        if (!mask.at<uint8_t>(y, x)) continue;
        const cv::Vec3b a = color_rgb->at<cv::Vec3b>(y, x), b = gt.color_rgb.at<cv::Vec3b>(y, x);
        const int nx[4] = {x - 1, x + 1, x, x}, ny[4] = {y, y, y - 1, y + 1};
        for (int k = 0; k < 4; ++k) {
          if (nx[k] < 0 || ny[k] < 0 || nx[k] >= w || ny[k] >= h || mask.at<uint8_t>(ny[k], nx[k])) continue;
          const cv::Vec3b o = color_rgb->at<cv::Vec3b>(ny[k], nx[k]), og = gt.color_rgb.at<cv::Vec3b>(ny[k], nx[k]);
          for (int c = 0; c < 3; ++c) {
            seam += std::abs(a[c] - o[c]) / 3.0;
            seam_gt += std::abs(b[c] - og[c]) / 3.0;
          }
          ++ns;
        }
      }
    r.seam_color = seam / ns;
    r.seam_color_gt = seam_gt / ns;
  }
  if (depth_m) {
    const PinholeCamera cam = Camera7Scenes();
    const ImageF nd = NormalsFromDepth(FromMat(*depth_m), cam);
    const ImageF ng = NormalsFromDepth(FromMat(gt.depth_m), cam);
    double ae = 0, se = 0, ang = 0, seam = 0, seam_gt = 0;
    int n = 0, nang = 0, ns = 0, total = 0, valid_out = 0;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        if (!mask.at<uint8_t>(y, x)) continue;
        const float g = gt.depth_m.at<float>(y, x), d = depth_m->at<float>(y, x);
        if (!(g > 0.f)) continue;
        ++total;
        if (!(d > 0.f) || !std::isfinite(d)) continue;  // counted by depth_valid_frac
        ++valid_out;
        const double e = (d - g) * 1000.0;
        ae += std::fabs(e);
        se += e * e;
        ++n;
        const float* a = &nd.at(x, y, 0);
        const float* b = &ng.at(x, y, 0);
        const double dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        if ((a[0] != 0 || a[1] != 0 || a[2] != 0) && (b[0] != 0 || b[1] != 0 || b[2] != 0)) {
          ang += std::acos(std::clamp(dot, -1.0, 1.0)) * 180.0 / M_PI;
          ++nang;
        }
        const int nx[4] = {x - 1, x + 1, x, x}, ny[4] = {y, y, y - 1, y + 1};
        for (int k = 0; k < 4; ++k) {
          if (nx[k] < 0 || ny[k] < 0 || nx[k] >= w || ny[k] >= h || mask.at<uint8_t>(ny[k], nx[k])) continue;
          const float o = depth_m->at<float>(ny[k], nx[k]), og = gt.depth_m.at<float>(ny[k], nx[k]);
          if (!(og > 0.f) || !(o > 0.f)) continue;
          seam += std::fabs(d - o) * 1000.0;
          seam_gt += std::fabs(g - og) * 1000.0;
          ++ns;
        }
      }
    r.depth_mae_mm = n ? ae / n : NAN;
    r.depth_rmse_mm = n ? std::sqrt(se / n) : NAN;
    r.normal_deg = nang ? ang / nang : NAN;
    r.seam_depth_mm = ns ? seam / ns : NAN;
    r.seam_depth_gt_mm = ns ? seam_gt / ns : NAN;
    r.depth_valid_frac = total ? static_cast<double>(valid_out) / total : NAN;
  }
  return r;
}

// ---------------------------------------------------------------- baselines
// Telea on colour and on (pre-filled) depth.
void Telea(const RgbdKeyframe& in, const cv::Mat& mask, cv::Mat* color, cv::Mat* depth) {
  cv::Mat rgb(480, 640, CV_8UC3, const_cast<uint8_t*>(in.color.data()));
  cv::inpaint(rgb, mask, *color, 5, cv::INPAINT_TELEA);
  ImageF d = in.depth_m;
  std::vector<uint8_t> outside(640 * 480);
  for (int i = 0; i < 640 * 480; ++i) outside[i] = mask.data[i] == 0;
  PrefillDepth(d, outside, outside);
  // Telea on millimetres as 16-bit (its float path treats values as 8-bit intensities).
  cv::Mat dm(480, 640, CV_32F, d.data()), mm16, out16;
  dm.convertTo(mm16, CV_16U, 1000.0);
  cv::inpaint(mm16, mask, out16, 5, cv::INPAINT_TELEA);
  out16.convertTo(*depth, CV_32F, 1e-3);
}

// Plane through the ring (8 px) around the mask: inverse depth affine in (u, v) (exact for a
// plane), least squares.
void PlaneFit(const RgbdKeyframe& in, const cv::Mat& mask, cv::Mat* depth) {
  cv::Mat dil;
  cv::dilate(mask, dil, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(17, 17)));
  cv::Mat ring = dil & ~mask;
  Eigen::Matrix3d AtA = Eigen::Matrix3d::Zero();
  Eigen::Vector3d Atb = Eigen::Vector3d::Zero();
  for (int y = 0; y < 480; ++y)
    for (int x = 0; x < 640; ++x) {
      const float z = in.depth_m.at(x, y);
      if (!ring.at<uint8_t>(y, x) || !(z > 0.f)) continue;
      const Eigen::Vector3d a(x / 640.0, y / 480.0, 1.0);
      AtA += a * a.transpose();
      Atb += a / z;
    }
  const Eigen::Vector3d p = AtA.ldlt().solve(Atb);
  *depth = cv::Mat(480, 640, CV_32F, const_cast<float*>(in.depth_m.data())).clone();
  for (int y = 0; y < 480; ++y)
    for (int x = 0; x < 640; ++x) {
      if (!mask.at<uint8_t>(y, x)) continue;
      const double q = p[0] * x / 640.0 + p[1] * y / 480.0 + p[2];
      depth->at<float>(y, x) = q > 1e-6 ? static_cast<float>(1.0 / q) : 0.f;
    }
}

// Re-projects the mask's 3D region (frame truth depth) into another frame.
cv::Mat ReprojectMask(const cv::Mat& mask, const RealFrame& from, const RealFrame& to) {
  const PinholeCamera cam = Camera7Scenes();
  const Rigid3d to_from = to.world_from_cam.Inverse() * from.world_from_cam;
  cv::Mat out(480, 640, CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < 480; ++y)
    for (int x = 0; x < 640; ++x) {
      if (!mask.at<uint8_t>(y, x)) continue;
      const float z = from.depth_m.at<float>(y, x);
      if (!(z > 0.f)) continue;
      glm::dvec2 uv;
      if (!cam.Project(to_from * cam.Unproject({x, y}, z), &uv) || !cam.InImage(uv)) continue;
      out.at<uint8_t>(static_cast<int>(std::lround(uv.y)), static_cast<int>(std::lround(uv.x))) = 255;
    }
  cv::morphologyEx(out, out, cv::MORPH_CLOSE, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(9, 9)));
  return out;
}

// ---------------------------------------------------------------- output
// FNV-1a 64 over the result's colour and depth bytes: equal digests = bit-identical outputs
// (compares a change that must not alter results, e.g. a refactoring, run against run).
uint64_t OutputDigest(const InpaintResult& r) {
  uint64_t h = 1469598103934665603ULL;
  auto add = [&h](const void* p, size_t n) {
    const auto* b = static_cast<const uint8_t*>(p);
    for (size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 1099511628211ULL;
  };
  add(r.color.data(), r.color.bytes());
  add(r.depth_m.data(), r.depth_m.bytes());
  return h;
}

// Per-stage times of one run: wall prepare, search, Poisson, total, then the same in process
// CPU time (NaN for the baselines).
using Stages = std::array<double, 8>;
constexpr const char* kStageNames[4] = {"prepare", "search", "poisson", "total"};
Stages StagesOf(const InpaintStats& s) {
  return {s.ms_prepare, s.ms_search, s.ms_poisson, s.ms_total,
          s.cpu_ms_prepare, s.cpu_ms_search, s.cpu_ms_poisson, s.cpu_ms_total};
}
struct Row {
  std::string method, cls;
  double ms;
  Metrics m;
  Stages st{NAN, NAN, NAN, NAN, NAN, NAN, NAN, NAN};
};

void PrintRow(const std::string& method, const MaskSpec& spec, double fraction, double ms,
              const Metrics& m, const nlohmann::json& extra = nlohmann::json::object()) {
  nlohmann::json row = {{"bench", "inpaint"},
                        {"method", method},
                        {"mask", spec.id},
                        {"class", spec.cls},
                        {"frame", spec.frame},
                        {"mask_fraction", fraction},
                        {"ms", ms},
                        {"psnr", m.psnr},
                        {"ssim", m.ssim},
                        {"depth_mae_mm", m.depth_mae_mm},
                        {"depth_rmse_mm", m.depth_rmse_mm},
                        {"normal_err_deg", m.normal_deg},
                        {"seam_color", m.seam_color},
                        {"seam_color_gt", m.seam_color_gt},
                        {"seam_depth_mm", m.seam_depth_mm},
                        {"seam_depth_gt_mm", m.seam_depth_gt_mm},
                        {"depth_valid_frac", m.depth_valid_frac}};
  row.update(extra);  // NaN / inf are written as null
  std::printf("%s\n", row.dump().c_str());
  std::fflush(stdout);
}

std::string DigestHex(uint64_t digest) {
  char b[17];
  std::snprintf(b, sizeof(b), "%016llx", static_cast<unsigned long long>(digest));
  return b;
}

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  const double idx = p * (v.size() - 1);
  const size_t i = static_cast<size_t>(idx);
  return i + 1 < v.size() ? v[i] + (idx - i) * (v[i + 1] - v[i]) : v[i];
}

cv::Mat DepthVis(const cv::Mat& d) {
  cv::Mat u8;
  d.convertTo(u8, CV_8U, 255.0 / 4.0);
  cv::Mat c;
  cv::applyColorMap(u8, c, cv::COLORMAP_TURBO);
  c.setTo(cv::Scalar(0, 0, 0), d <= 0);
  return c;  // BGR
}

}  // namespace
}  // namespace exo::inpainting

int main(int argc, char** argv) {
  using namespace exo::inpainting;
  using exo::ImageU8;
  using exo::Rigid3d;
  std::string data_dir = std::string(EXOVIEW_SOURCE_DIR) + "/../shared/data/7scenes-redkitchen";
  if (const char* env = std::getenv("EXOVIEW_SHARED_DIR")) data_dir = std::string(env) + "/data/7scenes-redkitchen";
  std::string masks_path = std::string(EXOVIEW_SOURCE_DIR) + "/server/inpainting/testdata/masks.jsonl";
  std::string img_dir;
  std::string dump_depth_dir;  // --dump_depth DIR: per-mask depth views (truth | ours)
  bool generate = false;
  uint64_t mask_seed = 20260707;  // the committed TEST set; the training set uses 777
  int mask_frame0 = 0;            // test: frames 0, 30, ...; training: 15, 45, ...
  int threads = 2, repeats = 1, max_masks = 1000, example_frame = 90;
  double poisson_tol = InpaintOptions{}.poisson_tolerance;
  double w_opt = InpaintOptions{}.w, kappa_opt = InpaintOptions{}.kappa;
  bool ours_only = false;
  double neumann_prior = InpaintOptions{}.neumann_prior_weight;
  double prior_local = InpaintOptions{}.prior_local_px;
  uint64_t seed = InpaintOptions{}.seed;
  bool peel_measured = InpaintOptions{}.peel_measured_normals_only;
  double converged = InpaintOptions{}.converged_fraction;
  int fine_iterations = InpaintOptions{}.fine_iterations;
  bool fusion_mean = InpaintOptions{}.gradient_fusion == GradientFusion::kMean;
  double jump_rel = InpaintOptions{}.jump_rel, jump_weight = InpaintOptions{}.jump_weight;
  InpaintOptions layer_opts;  // layered_depth and layer_*
  std::string fusion = fusion_mean ? "mean" : "robust";
  bool raw = false, layered = layer_opts.layered_depth, no_layered = false;
  int seed_measured = layer_opts.layer_seed_measured_only ? 1 : 0;
  int edge_seeds = layer_opts.layer_edge_seeds ? 1 : 0;
  bool peel_all_normals = !peel_measured;
  CLI::App app{"InpaintFusion keyframe inpainting on real 7-Scenes frames with ground truth, "
               "against colour-only PatchMatch, Telea and a ring plane: one JSON line per "
               "(method, mask) and per (method, class), after a run_info line.",
               "inpaint_bench"};
  exo::cli::Setup(app);
  app.add_option("--data", data_dir, "7-Scenes redkitchen folder");
  app.add_option("--masks", masks_path, "masks file (JSON lines)");
  app.add_flag("--generate_masks", generate, "write a new masks file to --masks and exit");
  app.add_option("--mask_seed", mask_seed, "--generate_masks: seed (test set 20260707, training 777)");
  app.add_option("--mask_frame0", mask_frame0, "--generate_masks: first frame (test 0, training 15)");
  app.add_option("--img_dir", img_dir, "write the contact sheet (PNG) here");
  app.add_option("--dump_depth", dump_depth_dir, "write per-mask depth views (truth | ours) here");
  app.add_option("--threads", threads, "InpaintOptions::num_threads")->check(CLI::Range(1, 64));
  app.add_option("--repeats", repeats, "runs per (method, mask)")->check(CLI::PositiveNumber);
  app.add_option("--max_masks", max_masks, "use at most this many masks")->check(CLI::PositiveNumber);
  app.add_option("--example_frame", example_frame, "frame of the contact sheet's examples");
  app.add_flag("--raw", raw, "depth not registered to colour");
  app.add_flag("--ours_only", ours_only, "only InpaintFusion (and its propagated runs)");
  app.add_option("--poisson_tol", poisson_tol, "InpaintOptions::poisson_tolerance");
  app.add_option("--w", w_opt, "InpaintOptions::w");
  app.add_option("--kappa", kappa_opt, "InpaintOptions::kappa");
  app.add_option("--neumann_prior", neumann_prior, "InpaintOptions::neumann_prior_weight");
  app.add_option("--prior_local", prior_local, "InpaintOptions::prior_local_px");
  app.add_option("--seed", seed, "InpaintOptions::seed");
  app.add_flag("--peel_all_normals", peel_all_normals, "peel_measured_normals_only = false");
  app.add_option("--fusion", fusion, "gradient fusion")->check(CLI::IsMember({"mean", "robust"}));
  app.add_option("--jump_rel", jump_rel, "InpaintOptions::jump_rel");
  app.add_option("--jump_weight", jump_weight, "InpaintOptions::jump_weight");
  app.add_option("--converged", converged, "InpaintOptions::converged_fraction");
  app.add_option("--fine_iterations", fine_iterations, "InpaintOptions::fine_iterations");
  app.add_flag("--layered", layered, "layered depth solve (default)");
  app.add_flag("--no_layered", no_layered, "single-surface depth solve");
  app.add_option("--layer_gap", layer_opts.layer_gap_rel, "InpaintOptions::layer_gap_rel");
  app.add_option("--layer_min_share", layer_opts.layer_min_share, "InpaintOptions::layer_min_share");
  app.add_option("--max_layers", layer_opts.max_layers, "InpaintOptions::max_layers");
  app.add_option("--layer_agree", layer_opts.layer_agree_rel, "InpaintOptions::layer_agree_rel");
  app.add_option("--layer_dist", layer_opts.layer_distance_weight, "InpaintOptions::layer_distance_weight");
  app.add_option("--layer_smooth", layer_opts.layer_smooth, "InpaintOptions::layer_smooth");
  app.add_option("--layer_sigma", layer_opts.layer_color_sigma, "InpaintOptions::layer_color_sigma");
  app.add_option("--layer_jump", layer_opts.layer_jump_factor, "InpaintOptions::layer_jump_factor");
  app.add_option("--layer_block", layer_opts.layer_label_block, "InpaintOptions::layer_label_block");
  app.add_option("--layer_seed_measured", seed_measured, "layer_seed_measured_only 0|1")
      ->check(CLI::Range(0, 1));
  app.add_option("--layer_edge_seeds", edge_seeds, "layer_edge_seeds 0|1")->check(CLI::Range(0, 1));
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  if (raw) g_register = false;
  peel_measured = !peel_all_normals;
  fusion_mean = fusion == "mean";
  layer_opts.layered_depth = no_layered ? false : layered;
  layer_opts.layer_seed_measured_only = seed_measured != 0;
  layer_opts.layer_edge_seeds = edge_seeds != 0;
  if (generate) {
    g_register = false;  // masks are placed on the raw depth (reproduces the committed sets)
    std::ofstream out(masks_path);
    for (const MaskSpec& m : GenerateMasks(data_dir, mask_seed, mask_frame0)) out << ToJson(m).dump() << "\n";
    std::fprintf(stderr, "wrote %s\n", masks_path.c_str());
    return 0;
  }
  std::vector<MaskSpec> specs;
  {
    std::ifstream in(masks_path);
    std::string line;
    for (int line_no = 1; std::getline(in, line); ++line_no) {
      if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
      auto m = ParseMask(line);
      if (!m.ok()) {
        std::fprintf(stderr, "%s:%d: %s\n", masks_path.c_str(), line_no, std::string(m.status().message()).c_str());
        return 1;
      }
      specs.push_back(*std::move(m));
    }
  }
  if (specs.empty()) {
    std::fprintf(stderr, "no masks in %s\n", masks_path.c_str());
    return 1;
  }
  if (static_cast<int>(specs.size()) > max_masks) specs.resize(max_masks);
  std::printf("%s\n", nlohmann::json{{"bench", "inpaint"}, {"run_info", exo::RunInfo()}}.dump().c_str());

  std::map<std::pair<std::string, std::string>, std::vector<Row>> rows;  // (method, class)
  struct Example {
    std::string id;
    cv::Mat input, ours_c, cpm_c, telea_c, gt_c, ours_d, plane_d, telea_d, gt_d;
  };
  std::vector<Example> examples;
  InpaintOptions base;
  base.num_threads = threads;
  base.poisson_tolerance = poisson_tol;
  base.w = w_opt;
  base.kappa = kappa_opt;
  base.gradient_fusion = fusion_mean ? GradientFusion::kMean : GradientFusion::kRobust;
  base.jump_rel = jump_rel;
  base.jump_weight = jump_weight;
  base.converged_fraction = converged;
  base.neumann_prior_weight = neumann_prior;
  base.prior_local_px = prior_local;
  base.seed = seed;
  base.peel_measured_normals_only = peel_measured;
  base.fine_iterations = fine_iterations;
  base.layered_depth = layer_opts.layered_depth;
  base.layer_gap_rel = layer_opts.layer_gap_rel;
  base.layer_min_share = layer_opts.layer_min_share;
  base.max_layers = layer_opts.max_layers;
  base.layer_agree_rel = layer_opts.layer_agree_rel;
  base.layer_distance_weight = layer_opts.layer_distance_weight;
  base.layer_smooth = layer_opts.layer_smooth;
  base.layer_color_sigma = layer_opts.layer_color_sigma;
  base.layer_jump_factor = layer_opts.layer_jump_factor;
  base.layer_label_block = layer_opts.layer_label_block;
  base.layer_seed_measured_only = layer_opts.layer_seed_measured_only;
  base.layer_edge_seeds = layer_opts.layer_edge_seeds;
  for (const MaskSpec& spec : specs) {
    const RealFrame gt = LoadFrame(data_dir, spec.frame);
    if (!gt.ok) {
      std::fprintf(stderr, "cannot read frame %d under %s\n", spec.frame, data_dir.c_str());
      return 1;
    }
    const cv::Mat mask = DrawMask(spec, 640, 480);
    const double fraction = cv::countNonZero(mask) / (640.0 * 480.0);
    const RgbdKeyframe in = ToKeyframe(gt, mask);
    ImageU8 mask_img(640, 480, 1);
    std::memcpy(mask_img.data(), mask.data, mask_img.bytes());
    Example ex;
    ex.id = spec.id;
    auto run_ours = [&](const std::string& name, InpaintOptions o, cv::Mat* keep_c, cv::Mat* keep_d,
                        InpaintResult* keep_result) {
      std::vector<double> times, cpu;
      std::vector<Stages> stages;
      absl::StatusOr<InpaintResult> r;
      for (int rep = 0; rep < repeats; ++rep) {
        const double c0 = CpuMs();
        r = InpaintKeyframe(in, mask_img, o);
        cpu.push_back(CpuMs() - c0);
        if (!r.ok()) break;
        times.push_back(r->stats.ms_total);
        stages.push_back(StagesOf(r->stats));
      }
      if (!r.ok()) {
        std::fprintf(stderr, "%s on %s: %s\n", name.c_str(), spec.id.c_str(), r.status().ToString().c_str());
        return;
      }
      cv::Mat c(480, 640, CV_8UC3, r->color.data()), d(480, 640, CV_32F, r->depth_m.data());
      const Metrics m = Evaluate(mask, &c, &d, gt);
      const double ms = Percentile(times, 0.5);
      const nlohmann::json extra = {{"cpu_ms", Percentile(cpu, 0.5)},
                                    {"threads", o.num_threads},
                                    {"levels", r->stats.levels},
                                    {"ms_prepare", r->stats.ms_prepare},
                                    {"ms_search", r->stats.ms_search},
                                    {"ms_poisson", r->stats.ms_poisson},
                                    {"poisson_iters", r->stats.poisson_iterations},
                                    {"sweeps", r->stats.sweeps},
                                    {"layers", r->stats.depth_layers},
                                    {"layer_dist_px", std::round(r->stats.layer_seed_dist_px)},
                                    {"output_digest", DigestHex(OutputDigest(*r))}};
      PrintRow(name, spec, fraction, ms, m, extra);
      for (size_t k = 0; k < times.size(); ++k)
        rows[{name, spec.cls}].push_back({name, spec.cls, times[k], m, stages[k]});
      if (!dump_depth_dir.empty() && name == "inpaintfusion") {
        // --dump_depth: truth depth | ours (with the pre-fill outside T), 0-4 m, T outlined.
        cv::Mat both(480, 1280, CV_8UC3), g8, o8;
        gt.depth_m.convertTo(g8, CV_8U, 255.0 / 4.0);
        d.convertTo(o8, CV_8U, 255.0 / 4.0);
        cv::Mat gc, oc;
        cv::applyColorMap(g8, gc, cv::COLORMAP_JET);
        cv::applyColorMap(o8, oc, cv::COLORMAP_JET);
        gc.setTo(cv::Scalar(0, 0, 0), gt.depth_m <= 0.f);
        std::vector<std::vector<cv::Point>> cs;
        cv::findContours(mask.clone(), cs, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE);
        cv::drawContours(gc, cs, -1, cv::Scalar(255, 255, 255), 1);
        cv::drawContours(oc, cs, -1, cv::Scalar(255, 255, 255), 1);
        if (!r->layers.empty()) {  // layered depth: the cut between layers in magenta
          cv::Mat lab(480, 640, CV_8U, r->layers.data());
          for (int y = 0; y + 1 < 480; ++y)
            for (int x = 0; x + 1 < 640; ++x) {
              const uint8_t a = lab.at<uint8_t>(y, x);
              if (a && !mask.at<uint8_t>(y, x)) {  // a seed of the labelling: white / black / grey
                cv::rectangle(oc, cv::Rect(x - 1, y - 1, 3, 3),
                              a == 1 ? cv::Scalar(255, 255, 255) : a == 2 ? cv::Scalar(0, 0, 0) : cv::Scalar(128, 128, 128), cv::FILLED);
                continue;
              }
              if (!mask.at<uint8_t>(y, x)) continue;
              if (a && ((mask.at<uint8_t>(y, x + 1) && lab.at<uint8_t>(y, x + 1) != a) ||
                        (mask.at<uint8_t>(y + 1, x) && lab.at<uint8_t>(y + 1, x) != a)))
                oc.at<cv::Vec3b>(y, x) = cv::Vec3b(255, 0, 255);
            }
        }
        gc.copyTo(both(cv::Rect(0, 0, 640, 480)));
        oc.copyTo(both(cv::Rect(640, 0, 640, 480)));
        cv::imwrite(dump_depth_dir + "/" + spec.id + ".png", both);
      }
      if (keep_c) *keep_c = c.clone();
      if (keep_d) *keep_d = d.clone();
      if (keep_result) *keep_result = std::move(*r);
    };
    InpaintResult ours_result;
    run_ours("inpaintfusion", base, &ex.ours_c, &ex.ours_d, &ours_result);
    InpaintOptions lit = base;
    lit.depth_domain = DepthDomain::kDepth;
    if (!ours_only) run_ours("inpaintfusion_depth_domain", lit, nullptr, nullptr, nullptr);
    InpaintOptions cpm = base;
    cpm.use_geometry = false;
    if (!ours_only) run_ours("patchmatch_colour_only", cpm, &ex.cpm_c, nullptr, nullptr);
    if (!ours_only) {
      const auto t0 = Clock::now();
      cv::Mat c, d;
      Telea(in, mask, &c, &d);
      const double ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
      const Metrics m = Evaluate(mask, &c, &d, gt);
      PrintRow("telea", spec, fraction, ms, m);
      rows[{"telea", spec.cls}].push_back({"telea", spec.cls, ms, m});
      ex.telea_c = c;
      ex.telea_d = d;
    }
    if (!ours_only) {
      const auto t0 = Clock::now();
      cv::Mat d;
      PlaneFit(in, mask, &d);
      const double ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
      const Metrics m = Evaluate(mask, nullptr, &d, gt);
      PrintRow("plane_ring", spec, fraction, ms, m);
      rows[{"plane_ring", spec.cls}].push_back({"plane_ring", spec.cls, ms, m});
      ex.plane_d = d;
    }
    // Propagated keyframe: the same 3D region seen from frame + 5.
    if (spec.cls == "10-20%" && !ours_result.color.empty() && spec.frame + 5 < 300) {
      const RealFrame gt1 = LoadFrame(data_dir, spec.frame + 5);
      const cv::Mat mask1 = ReprojectMask(mask, gt, gt1);
      if (gt1.ok && cv::countNonZero(mask1) > 0) {
        const RgbdKeyframe in1 = ToKeyframe(gt1, mask1);
        ImageU8 m1(640, 480, 1);
        std::memcpy(m1.data(), mask1.data, m1.bytes());
        MaskSpec s1 = spec;
        s1.id = spec.id + "+5";
        s1.frame = spec.frame + 5;
        for (const bool propagate : {true, false}) {
          std::vector<double> times, cpu;
          std::vector<Stages> stages;
          absl::StatusOr<InpaintResult> r;
          for (int rep = 0; rep < repeats; ++rep) {
            const double c0 = CpuMs();
            r = InpaintKeyframe(in1, m1, base, propagate ? &ours_result : nullptr);
            cpu.push_back(CpuMs() - c0);
            if (!r.ok()) break;
            times.push_back(r->stats.ms_total);
            stages.push_back(StagesOf(r->stats));
          }
          if (!r.ok()) {
            std::fprintf(stderr, "propagated %s: %s\n", s1.id.c_str(), r.status().ToString().c_str());
            continue;
          }
          cv::Mat c(480, 640, CV_8UC3, r->color.data()), d(480, 640, CV_32F, r->depth_m.data());
          const Metrics m = Evaluate(mask1, &c, &d, gt1);
          const std::string name = propagate ? "inpaintfusion_propagated" : "inpaintfusion_scratch_next";
          const nlohmann::json extra = {
              {"propagated_frac", static_cast<double>(r->stats.propagated_pixels) / r->stats.target_pixels},
              {"cpu_ms", Percentile(cpu, 0.5)},
              {"levels", r->stats.levels},
              {"ms_prepare", r->stats.ms_prepare},
              {"ms_search", r->stats.ms_search},
              {"ms_poisson", r->stats.ms_poisson},
              {"poisson_iters", r->stats.poisson_iterations},
              {"layers", r->stats.depth_layers},
              {"output_digest", DigestHex(OutputDigest(*r))}};
          PrintRow(name, s1, cv::countNonZero(mask1) / (640.0 * 480.0), Percentile(times, 0.5), m, extra);
          for (size_t k = 0; k < times.size(); ++k)
            rows[{name, "10-20%"}].push_back({name, "10-20%", times[k], m, stages[k]});
        }
      }
    }
    cv::cvtColor(gt.color_rgb, ex.gt_c, cv::COLOR_RGB2BGR);
    ex.input = ex.gt_c.clone();
    ex.input.setTo(cv::Scalar(255, 0, 255), mask);
    for (cv::Mat* m : {&ex.ours_c, &ex.cpm_c, &ex.telea_c}) {
      if (!m->empty()) cv::cvtColor(*m, *m, cv::COLOR_RGB2BGR);
    }
    ex.gt_d = gt.depth_m.clone();
    if (examples.size() < 3 && spec.frame == example_frame) examples.push_back(ex);
  }

  // Summaries per (method, class).
  struct Summary {
    std::string method, cls;
    double p50, p95, psnr, ssim, mae, rmse, nerr, seam_c, seam_d;
    int n;
  };
  for (const auto& [key, v] : rows) {
    std::vector<double> t;
    Summary s{key.first, key.second, 0, 0, 0, 0, 0, 0, 0, 0, 0, static_cast<int>(v.size())};
    auto mean = [&](auto get) {
      double a = 0;
      int n = 0;
      for (const Row& r : v) {
        const double x = get(r.m);
        if (std::isfinite(x)) {
          a += x;
          ++n;
        }
      }
      return n ? a / n : NAN;
    };
    for (const Row& r : v) t.push_back(r.ms);
    s.p50 = Percentile(t, 0.5);
    s.p95 = Percentile(t, 0.95);
    s.psnr = mean([](const Metrics& m) { return m.psnr; });
    s.ssim = mean([](const Metrics& m) { return m.ssim; });
    s.mae = mean([](const Metrics& m) { return m.depth_mae_mm; });
    s.rmse = mean([](const Metrics& m) { return m.depth_rmse_mm; });
    s.nerr = mean([](const Metrics& m) { return m.normal_deg; });
    s.seam_c = mean([](const Metrics& m) { return m.seam_color - m.seam_color_gt; });
    s.seam_d = mean([](const Metrics& m) { return m.seam_depth_mm - m.seam_depth_gt_mm; });
    nlohmann::json row = {{"bench", "inpaint_summary"},
                          {"method", s.method},
                          {"class", s.cls},
                          {"runs", s.n},
                          {"threads", threads},
                          {"ms_p50", s.p50},
                          {"ms_p95", s.p95},
                          {"psnr", s.psnr},
                          {"ssim", s.ssim},
                          {"depth_mae_mm", s.mae},
                          {"depth_rmse_mm", s.rmse},
                          {"normal_err_deg", s.nerr},
                          {"seam_color_excess", s.seam_c},
                          {"seam_depth_excess_mm", s.seam_d}};
    // Per-stage p50/p95, wall and process CPU (ours only; the baselines have no stages).
    for (int k = 0; k < 8; ++k) {
      std::vector<double> vals;
      for (const Row& r : v)
        if (std::isfinite(r.st[k])) vals.push_back(r.st[k]);
      if (vals.empty()) continue;
      row[std::string(k < 4 ? "ms_" : "cpu_ms_") + kStageNames[k % 4]] = {Percentile(vals, 0.5),
                                                                          Percentile(vals, 0.95)};
    }
    std::printf("%s\n", row.dump().c_str());
  }

  if (!img_dir.empty()) {
    // Contact sheet: per example two rows (colour: input | ours | colour-only PM | Telea | truth;
    // depth: ours | plane | Telea | truth | -), tiles 128x96.
    const int tw = 160, th = 120;
    std::vector<cv::Mat> rows_img;
    auto tile = [&](const cv::Mat& m) {
      cv::Mat t;
      if (m.empty()) return cv::Mat(th, tw, CV_8UC3, cv::Scalar(255, 255, 255));
      cv::resize(m, t, cv::Size(tw, th), 0, 0, cv::INTER_AREA);
      return t;
    };
    for (const Example& e : examples) {
      cv::Mat r1, r2;
      cv::hconcat(std::vector<cv::Mat>{tile(e.input), tile(e.ours_c), tile(e.cpm_c), tile(e.telea_c), tile(e.gt_c)}, r1);
      cv::hconcat(std::vector<cv::Mat>{tile(cv::Mat()), tile(DepthVis(e.ours_d)), tile(DepthVis(e.plane_d)), tile(DepthVis(e.telea_d)), tile(DepthVis(e.gt_d))}, r2);
      cv::putText(r2, e.id, cv::Point(8, 30), cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(0, 0, 0), 1);
      rows_img.push_back(r1);
      rows_img.push_back(r2);
    }
    if (!rows_img.empty()) {
      cv::Mat header(22, tw * 5, CV_8UC3, cv::Scalar(255, 255, 255));
      const char* names[5] = {"input / depth:", "InpaintFusion", "colour-only PM | plane", "Telea", "truth"};
      for (int k = 0; k < 5; ++k) cv::putText(header, names[k], cv::Point(k * tw + 4, 16), cv::FONT_HERSHEY_SIMPLEX, 0.38, cv::Scalar(0, 0, 0));
      rows_img.insert(rows_img.begin(), header);
      cv::Mat sheet;
      cv::vconcat(rows_img, sheet);
      cv::imwrite(img_dir + "/inpaint_examples.png", sheet, {cv::IMWRITE_PNG_COMPRESSION, 9});
    }
  }
  return 0;
}
