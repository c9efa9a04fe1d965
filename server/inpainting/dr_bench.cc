// Diminished-reality benchmark (issue 18, SPEC §7): a synthetic scene (textured back wall and
// floor) with a removable box, rendered with and without it from a camera path that walks 90
// degrees around the box, so the scene without the box is the exact ground truth of every frame.
// On the same frames and masks (the box's pixels, dilated 4 px) it compares
//   telea / ns : OpenCV cv::inpaint per frame (colour and depth),
//   pm         : our PatchMatch + Poisson keyframe inpainting per frame, no propagation,
//   ours       : InpaintFusion keyframes (the 0.7 / 10 % rule, keyframe_policy.h) with
//                propagation of the previous keyframe's offsets; a frame between keyframes is
//                the nearest keyframe's inpainted ROI forward-warped through its inpainted depth,
//                the few pixels the warp does not reach filled by Telea,
// and prints one JSON object: per method PSNR / SSIM inside the ROI and in a 10-px seam band
// across its boundary (5 px inside, 5 px outside), depth MAE (mm) inside the ROI, the flicker ratio (mean absolute frame-to-frame
// change inside the ROI after warping by the ground-truth motion, divided by the ground truth's
// own), and wall / CPU time per frame; for ours the keyframe count and timings.
//
//   dr_bench [--frames N] [--width W] [--height H] [--arc_deg A]   (--help lists them)
#include <time.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>
#include <opencv2/photo.hpp>

#include "common/cli/cli.h"
#include "common/metrics/metrics.h"
#include "server/inpainting/inpaint.h"
#include "server/inpainting/keyframe_policy.h"
#include "server/inpainting/test_scenes.h"

namespace exo::inpainting {
namespace {

using testing::RenderPlanes;
using testing::WorldPlane;

const glm::dvec3 kBoxCentre(0.0, 0.35, 2.0);
constexpr double kBoxHalf = 0.25;

std::vector<WorldPlane> Background() {
  return {{glm::dvec3(0, 0, -1), -3.2, nullptr},   // back wall z = 3.2
          {glm::dvec3(0, -1, 0), -0.6, nullptr}};  // floor y = 0.6 (y down)
}

// The box: six faces, each a plane restricted to its square.
std::vector<WorldPlane> WithBox() {
  std::vector<WorldPlane> p = Background();
  const glm::dvec3 c = kBoxCentre;
  const double h = kBoxHalf;
  for (int axis = 0; axis < 3; ++axis)
    for (int s = -1; s <= 1; s += 2) {
      glm::dvec3 n(0.0);
      n[axis] = s;
      const double off = glm::dot(n, c) + h;
      p.push_back({n, off, [c, h, axis](const glm::dvec3& x) {
                     for (int k = 0; k < 3; ++k)
                       if (k != axis && std::fabs(x[k] - c[k]) > h + 1e-9) return false;
                     return true;
                   }});
    }
  return p;
}

Rigid3d LookAt(const glm::dvec3& eye, const glm::dvec3& target) {
  const glm::dvec3 z = glm::normalize(target - eye);
  const glm::dvec3 x = glm::normalize(glm::cross(glm::dvec3(0, 1, 0), z));
  const glm::dvec3 y = glm::cross(z, x);
  Rigid3d p;
  p.rotation = glm::quat_cast(glm::dmat3(x, y, z));
  p.translation = eye;
  return p;
}

double CpuMs() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}
double WallMs() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

cv::Mat Wrap(ImageU8& im) {
  return cv::Mat(im.height(), im.width(), im.channels() == 3 ? CV_8UC3 : CV_8UC1, im.data());
}
cv::Mat Wrap(ImageF& im) { return cv::Mat(im.height(), im.width(), CV_32FC1, im.data()); }

struct Output {
  ImageU8 color;
  ImageF depth;
};

// Forward warp of keyframe `kf`'s ROI pixels (inpainted colour and depth) into the frame's ROI
// (`roi`; observed pixels outside it are kept); z-buffer, 2x2 splat. Returns the pixels reached.
ImageU8 WarpKeyframe(const InpaintResult& kf, const PinholeCamera& cam, const Rigid3d& pose,
                     const ImageU8& roi, Output* out) {
  const int w = cam.width, h = cam.height;
  ImageU8 hit(w, h, 1, 0);
  ImageF zbuf(w, h, 1, 1e30f);
  const Rigid3d cam_from_kf = pose.Inverse() * kf.world_from_cam;
  for (int y = 0; y < kf.mask.height(); ++y)
    for (int x = 0; x < kf.mask.width(); ++x) {
      if (!kf.mask.at(x, y)) continue;
      const float z = kf.depth_m.at(x, y);
      if (!(z > 0.f)) continue;
      const glm::dvec3 p = cam_from_kf * kf.camera.Unproject({x, y}, z);
      glm::dvec2 uv;
      if (!cam.Project(p, &uv)) continue;
      const int u0 = static_cast<int>(std::floor(uv.x)), v0 = static_cast<int>(std::floor(uv.y));
      for (int dv = 0; dv <= 1; ++dv)
        for (int du = 0; du <= 1; ++du) {
          const int u = u0 + du, v = v0 + dv;
          if (!hit.Contains(u, v) || !roi.at(u, v) || p.z >= zbuf.at(u, v)) continue;
          zbuf.at(u, v) = static_cast<float>(p.z);
          hit.at(u, v) = 255;
          for (int c = 0; c < 3; ++c) out->color.at(u, v, c) = kf.color.at(x, y, c);
          out->depth.at(u, v) = static_cast<float>(p.z);
        }
    }
  return hit;
}

struct Scores {
  double psnr_roi = 0, ssim_roi = 0, psnr_seam = 0, ssim_seam = 0, depth_mae_mm = 0;
  double flicker = 0, gt_flicker = 0;
  double wall_ms = 0, cpu_ms = 0;
  int frames = 0, flicker_frames = 0, depth_frames = 0;
};

// Mean absolute change inside `roi_t` between image t and image t-1 warped by the ground-truth
// motion (ground-truth depth of frame t, poses of both).
double Flicker(const ImageU8& cur, const ImageU8& prev, const ImageU8& roi_t, const ImageF& gt_depth_t,
               const PinholeCamera& cam, const Rigid3d& pose_t, const Rigid3d& pose_p) {
  const Rigid3d p_from_t = pose_p.Inverse() * pose_t;
  double sum = 0;
  long n = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      if (!roi_t.at(x, y) || !(gt_depth_t.at(x, y) > 0.f)) continue;
      glm::dvec2 uv;
      if (!cam.Project(p_from_t * cam.Unproject({x, y}, gt_depth_t.at(x, y)), &uv)) continue;
      const int u = static_cast<int>(std::lround(uv.x)), v = static_cast<int>(std::lround(uv.y));
      if (!prev.Contains(u, v)) continue;
      for (int c = 0; c < 3; ++c) sum += std::abs(int(cur.at(x, y, c)) - int(prev.at(u, v, c)));
      n += 3;
    }
  return n ? sum / n : 0.0;
}

int Main(int argc, char** argv) {
  int frames = 300, width = 320, height = 240;
  double arc_deg = 90.0;
  CLI::App app{"Diminished reality on a synthetic scene with a removable box: Telea, "
               "Navier-Stokes, per-frame PatchMatch and InpaintFusion keyframes against the "
               "ground truth without the box; prints JSON"};
  exo::cli::Setup(app);
  app.add_option("--frames", frames, "frames on the arc")->check(CLI::Range(2, 100000));
  app.add_option("--width", width, "frame width")->check(CLI::Range(64, 4096));
  app.add_option("--height", height, "frame height")->check(CLI::Range(48, 4096));
  app.add_option("--arc_deg", arc_deg, "degrees of the arc around the box")->check(CLI::Range(1.0, 180.0));
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  PinholeCamera cam;
  cam.width = width;
  cam.height = height;
  cam.fx = cam.fy = 0.9 * width;
  cam.cx = (width - 1) / 2.0;
  cam.cy = (height - 1) / 2.0;
  const auto with_box = WithBox(), background = Background();
  InpaintOptions opt;
  opt.num_threads = 1;
  KeyframePolicyOptions policy;
  const std::vector<std::string> methods = {"telea", "ns", "pm", "ours"};
  std::map<std::string, Scores> scores;
  std::map<std::string, ImageU8> prev_out;
  ImageU8 prev_gt;
  Rigid3d prev_pose;
  // Ours: keyframes (results) and timings.
  std::vector<std::shared_ptr<InpaintResult>> keyframes;
  int propagated = 0;
  double first_kf_ms = 0, propagated_ms = 0, warp_ms = 0;
  int warped_frames = 0;
  SsimOptions so;
  const double radius = 1.6;
  for (int t = 0; t < frames; ++t) {
    const double a = (-0.5 + double(t) / (frames - 1)) * arc_deg * M_PI / 180.0;
    const glm::dvec3 eye = kBoxCentre + glm::dvec3(radius * std::sin(a), -0.45, -radius * std::cos(a));
    const Rigid3d pose = LookAt(eye, kBoxCentre + glm::dvec3(0, 0.1, 0));
    RgbdKeyframe f = RenderPlanes(with_box, cam, pose);
    const RgbdKeyframe gt = RenderPlanes(background, cam, pose);
    ImageU8 roi(width, height, 1, 0);
    for (size_t i = 0; i < roi.size(); ++i)
      roi.data()[i] = f.depth_m.data()[i] + 0.01f < gt.depth_m.data()[i] ? 255 : 0;
    {
      cv::Mat m = Wrap(roi);
      cv::dilate(m, m, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(9, 9)));
    }
    // The seam: a 10-px band around the ROI's boundary (5 px inside, 5 px outside).
    ImageU8 seam(width, height, 1, 0);
    {
      cv::Mat r = Wrap(roi), s = Wrap(seam), inner;
      const cv::Mat k = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(11, 11));
      cv::dilate(r, s, k);
      cv::erode(r, inner, k);
      s.setTo(0, inner);
    }
    for (const std::string& method : methods) {
      Output out{f.color, f.depth_m};
      const double w0 = WallMs(), c0 = CpuMs();
      if (method == "telea" || method == "ns") {
        const int flag = method == "telea" ? cv::INPAINT_TELEA : cv::INPAINT_NS;
        cv::Mat rgb = Wrap(f.color), dst;
        cv::inpaint(rgb, Wrap(roi), dst, 5.0, flag);
        std::memcpy(out.color.data(), dst.data, out.color.size());
        // Depth as 16-bit millimetres (OpenCV's float path treats values as 8-bit intensities).
        ImageF d = f.depth_m;
        cv::Mat mm16, out16, dd;
        Wrap(d).convertTo(mm16, CV_16U, 1000.0);
        cv::inpaint(mm16, Wrap(roi), out16, 5.0, flag);
        out16.convertTo(dd, CV_32F, 1e-3);
        std::memcpy(out.depth.data(), dd.data, out.depth.bytes());
      } else if (method == "pm") {
        auto r = InpaintKeyframe(f, roi, opt);
        if (!r.ok()) {
          std::fprintf(stderr, "pm frame %d: %s\n", t, std::string(r.status().message()).c_str());
          return 1;
        }
        out = {r->color, r->depth_m};
      } else {  // ours
        std::vector<KeyframeView> views;
        for (const auto& k : keyframes) views.push_back({&k->mask, &k->depth_m, k->camera, k->world_from_cam});
        const KeyframeDecision d = DecideKeyframe(roi, cam, pose, views, policy);
        if (d.insert) {
          const InpaintResult* previous = d.nearest >= 0 ? keyframes[d.nearest].get() : nullptr;
          const double k0 = WallMs();
          auto r = InpaintKeyframe(f, roi, opt, previous);
          if (!r.ok()) {
            std::fprintf(stderr, "ours frame %d: %s\n", t, std::string(r.status().message()).c_str());
            return 1;
          }
          const double ms = WallMs() - k0;
          if (previous) {
            ++propagated;
            propagated_ms += ms;
          } else {
            first_kf_ms = ms;
          }
          out = {r->color, r->depth_m};
          keyframes.push_back(std::make_shared<InpaintResult>(*std::move(r)));
        } else {
          const double k0 = WallMs();
          const ImageU8 hit = WarpKeyframe(*keyframes[d.nearest], cam, pose, roi, &out);
          ImageU8 holes(width, height, 1, 0);
          int n_holes = 0;
          for (size_t i = 0; i < holes.size(); ++i)
            if (roi.data()[i] && !hit.data()[i]) {
              holes.data()[i] = 255;
              ++n_holes;
            }
          if (n_holes > 0) {
            cv::Mat rgb = Wrap(out.color), dst;
            cv::inpaint(rgb, Wrap(holes), dst, 3.0, cv::INPAINT_TELEA);
            std::memcpy(out.color.data(), dst.data, out.color.size());
            cv::Mat mm16, out16, dd;
            Wrap(out.depth).convertTo(mm16, CV_16U, 1000.0);
            cv::inpaint(mm16, Wrap(holes), out16, 3.0, cv::INPAINT_TELEA);
            out16.convertTo(dd, CV_32F, 1e-3);
            std::memcpy(out.depth.data(), dd.data, out.depth.bytes());
          }
          warp_ms += WallMs() - k0;
          ++warped_frames;
        }
      }
      Scores& s = scores[method];
      s.wall_ms += WallMs() - w0;
      s.cpu_ms += CpuMs() - c0;
      ++s.frames;
      s.psnr_roi += MaskedPsnr(out.color, gt.color, roi).value_or(0.0);
      s.ssim_roi += MaskedSsim(out.color, gt.color, roi, so).value_or(0.0);
      s.psnr_seam += MaskedPsnr(out.color, gt.color, seam).value_or(0.0);
      s.ssim_seam += MaskedSsim(out.color, gt.color, seam, so).value_or(0.0);
      double dsum = 0;
      long dn = 0;
      for (size_t i = 0; i < roi.size(); ++i)
        if (roi.data()[i] && gt.depth_m.data()[i] > 0.f) {
          dsum += std::fabs(out.depth.data()[i] - gt.depth_m.data()[i]);
          ++dn;
        }
      if (dn) {
        s.depth_mae_mm += 1000.0 * dsum / dn;
        ++s.depth_frames;
      }
      if (t > 0) {
        s.flicker += Flicker(out.color, prev_out[method], roi, gt.depth_m, cam, pose, prev_pose);
        s.gt_flicker += Flicker(gt.color, prev_gt, roi, gt.depth_m, cam, pose, prev_pose);
        ++s.flicker_frames;
      }
      prev_out[method] = out.color;
    }
    prev_gt = gt.color;
    prev_pose = pose;
  }
  double load = 0;
  std::ifstream("/proc/loadavg") >> load;
  std::printf("{\"bench\": \"dr_bench\", \"frames\": %d, \"width\": %d, \"height\": %d, "
              "\"arc_deg\": %.1f, \"load1\": %.2f, \"methods\": {",
              frames, width, height, arc_deg, load);
  bool first = true;
  for (const std::string& m : methods) {
    const Scores& s = scores[m];
    const double n = std::max(1, s.frames), nf = std::max(1, s.flicker_frames);
    std::printf("%s\"%s\": {\"psnr_roi\": %.2f, \"ssim_roi\": %.4f, \"psnr_seam\": %.2f, "
                "\"ssim_seam\": %.4f, \"depth_mae_mm\": %.1f, \"flicker\": %.3f, "
                "\"flicker_ratio\": %.3f, \"wall_ms_per_frame\": %.2f, \"cpu_ms_per_frame\": %.2f}",
                first ? "" : ", ", m.c_str(), s.psnr_roi / n, s.ssim_roi / n, s.psnr_seam / n,
                s.ssim_seam / n, s.depth_mae_mm / std::max(1, s.depth_frames), s.flicker / nf,
                s.gt_flicker > 0 ? s.flicker / s.gt_flicker : 0.0, s.wall_ms / n, s.cpu_ms / n);
    first = false;
  }
  std::printf("}, \"ours\": {\"keyframes\": %zu, \"propagated\": %d, \"first_keyframe_ms\": %.1f, "
              "\"propagated_keyframe_ms_mean\": %.1f, \"warped_frames\": %d, "
              "\"warp_ms_mean\": %.2f}}\n",
              keyframes.size(), propagated, first_kf_ms, propagated ? propagated_ms / propagated : 0.0,
              warped_frames, warped_frames ? warp_ms / warped_frames : 0.0);
  return 0;
}

}  // namespace
}  // namespace exo::inpainting

int main(int argc, char** argv) { return exo::inpainting::Main(argc, argv); }
