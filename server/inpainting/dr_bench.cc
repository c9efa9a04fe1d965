// Diminished-reality benchmark (issue 18, SPEC §7): a synthetic scene with a removable object
// (--scene: the apartment's chair or the village's cart, common/synth removable objects, or the
// old planes scene with a box), rendered with and without it from a camera path that walks
// --arc_deg around the object, so the scene without the object is the exact ground truth of
// every frame. On the same frames and masks (the object's pixels, dilated 4 px) it compares
//   telea / ns : OpenCV cv::inpaint per frame (colour and depth),
//   pm         : our PatchMatch + Poisson keyframe inpainting per frame, no propagation,
//   kf_warp    : session-9 "ours": InpaintFusion keyframes (the 0.7 / 10 % rule,
//                keyframe_policy.h) with propagation; a frame between keyframes is the nearest
//                keyframe's inpainted ROI forward-warped, the pixels the warp misses Telea-filled,
//   ours       : the same keyframes, but every ROI pixel of a frame is looked up through 3D:
//                its background depth is the nearest keyframe's (observed + inpainted) depth
//                forward-warped into the frame, and its colour is taken from the nearest view
//                that OBSERVED that point (the keyframes' observed pixels and the last
//                --obs_views frames, one every --obs_stride, outside their own ROI, depth
//                agreeing), else from the nearest keyframe's inpainted colour; a new keyframe
//                is inpainted only where no view observed the background (observations are
//                preferred); the output depth is the warped depth refined through the keyframe
//                and re-anchored on the frame's depth around the ROI (Poisson); the colour is
//                blended with the frame's border in the gradient domain and smoothed in time
//                along the camera motion (0.8 previous, looked up through the depth);
//                docs/inpainting.md "Session 10" has the ablations behind these choices;
//                the per-frame orchestration is the library class DiminishedReality
//                (dr_compositor.h, session 11), the flags below map onto its DrOptions,
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
#include <limits>
#include <map>
#include <span>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/photo.hpp>

#include <algorithm>
#include <deque>
#include <functional>
#include <memory>

#include "common/cli/cli.h"
#include "common/image_fill.h"
#include "common/metrics/metrics.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/inpainting/inpaint.h"
#include "server/inpainting/keyframe_policy.h"
#include "server/inpainting/dr_compositor.h"
#include "server/inpainting/dr_view.h"
#include "server/inpainting/poisson.h"
#include "server/inpainting/test_scenes.h"

namespace exo::inpainting {
namespace {

using exo::inpainting::testing::RenderPlanes;
using exo::inpainting::testing::WorldPlane;

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
  // FNV-1a over every frame's output colour and depth bytes (all frames, scored or not): two
  // builds whose digests agree produced the same pixels (exact-work cuts are checked this way).
  uint64_t digest = 1469598103934665603ULL;
  void Digest(const void* p, size_t n) {
    const auto* b = static_cast<const unsigned char*>(p);
    for (size_t i = 0; i < n; ++i) digest = (digest ^ b[i]) * 1099511628211ULL;
  }
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
  int frames = 300, width = 320, height = 240, obs_stride = 10, obs_views = 24, score_first = 0,
      last = -1;
  double arc_deg = 90.0, kf_pose = 0.7, kf_unlabelled = 0.10;
  std::string scene_name = "apartment", blend = "poisson";
  uint64_t seed = 1;
  CLI::App app{"Diminished reality on a synthetic scene with a removable object: Telea, "
               "Navier-Stokes, per-frame PatchMatch and InpaintFusion keyframes against the "
               "ground truth without the object; prints JSON"};
  exo::cli::Setup(app);
  app.add_option("--scene", scene_name, "apartment (chair), village (cart) or planes (box)")
      ->check(CLI::IsMember({"apartment", "village", "planes"}));
  app.add_option("--seed", seed, "synthetic scene seed (apartment / village)");
  app.add_option("--frames", frames, "frames on the arc")->check(CLI::Range(2, 100000));
  app.add_option("--first", score_first, "score frames from this index on (all are processed)");
  app.add_option("--last", last, "score frames up to this index (-1 = the last)");
  app.add_option("--width", width, "frame width")->check(CLI::Range(64, 4096));
  app.add_option("--height", height, "frame height")->check(CLI::Range(48, 4096));
  app.add_option("--arc_deg", arc_deg, "degrees of the arc around the object")->check(CLI::Range(1.0, 180.0));
  app.add_option("--kf_pose", kf_pose, "keyframe rule: pose distance")->check(CLI::Range(0.01, 10.0));
  app.add_option("--kf_unlabelled", kf_unlabelled, "keyframe rule: unlabelled ROI fraction")
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--obs_stride", obs_stride, "ours: keep every Nth frame as an observation view")
      ->check(CLI::Range(1, 1000));
  app.add_option("--obs_views", obs_views, "ours: observation views kept (0 = keyframes only)")
      ->check(CLI::Range(0, 1000));
  app.add_option("--blend", blend, "ours: paste, poisson (gradient-domain with the border) or poisson_hallucinated (only the "
                 "pixels no view observed are solved; observed ones stay as looked up)")
      ->check(CLI::IsMember({"paste", "poisson", "poisson_hallucinated"}));
  std::string sheet;
  int sheet_every = 50;
  app.add_option("--sheet", sheet, "write a contact sheet (JPEG): rows = frames every "
                 "--sheet_every, columns = input, ground truth, telea, pm, kf_warp, ours");
  app.add_option("--sheet_every", sheet_every, "frames between contact-sheet rows")
      ->check(CLI::Range(1, 100000));
  std::vector<std::string> only_methods;
  app.add_option("--methods", only_methods, "run only these (telea, ns, pm, kf_warp, ours, live)")
      ->delimiter(',')
      ->check(CLI::IsMember({"telea", "ns", "pm", "kf_warp", "ours", "live"}));
  int live_views = 4;
  app.add_option("--live_views", live_views, "live: look-up views per frame (nearest first)")
      ->check(CLI::Range(1, 64));
  bool prefer_observed = true, kf_context = true, bicubic = false;
  app.add_option("--bicubic", bicubic, "ours: bicubic colour look-up (false: bilinear)");
  int kf_crop_margin_px = 0;
  double kf_crop_margin_rel = 0.0;
  app.add_option("--kf_crop_margin_px", kf_crop_margin_px,
                 "ours/live: keyframes inpaint a crop around the ROI, margin px (0 and rel 0: whole frame)");
  app.add_option("--kf_crop_margin_rel", kf_crop_margin_rel,
                 "ours/live: crop margin as a multiple of the ROI's larger side");
  std::string ring = "lookup";
  app.add_option("--ring", ring, "ours: the blend's guide on the one-pixel ring around the ROI: "
                 "observed (looked up where another view observed it, else the frame), lookup "
                 "(looked up, hallucinated too), frame")
      ->check(CLI::IsMember({"observed", "lookup", "frame"}));
  double ring_sigma = 0.0, temporal = 0.8;
  bool depth_poisson = true, temporal_hallucinated_only = false;
  app.add_option("--depth_poisson", depth_poisson, "ours: between keyframes the depth is the warped "
                 "depth's gradients anchored on the frame's depth around the ROI (Poisson)");
  app.add_option("--temporal", temporal, "ours: weight of the previous output (warped by the "
                 "camera motion) in an exponential smoothing, 0 = none")->check(CLI::Range(0.0, 0.99));
  app.add_option("--temporal_hallucinated_only", temporal_hallucinated_only,
                 "ours: smooth only the pixels no view observed");
  app.add_option("--ring_sigma", ring_sigma, "ours: blend only the mismatch on the ring smoothed "
                 "by a Gaussian of this sigma (px, 0 = all of it)")->check(CLI::Range(0.0, 100.0));
  app.add_option("--kf_context", kf_context,
                 "ours: a keyframe takes the observed colour first and inpaints only the rest "
                 "(false: inpaints the whole ROI, then observed colour replaces PatchMatch's)");
  app.add_option("--prefer_observed", prefer_observed,
                 "ours: look colour up in every view that observed the point (false: only the "
                 "nearest keyframe, observed + inpainted)");
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  if (last < 0) last = frames - 1;
  std::vector<cv::Mat> sheet_rows;

  // The scene: a renderer of (with object, ground truth without) and the camera path.
  PinholeCamera cam;
  std::function<absl::Status(const Rigid3d&, RgbdKeyframe*, RgbdKeyframe*)> render;
  std::vector<Rigid3d> poses;
  std::shared_ptr<synth::SynthScene> with_obj, without_obj;
  synth::RenderOptions ro;
  ro.width = width;
  ro.height = height;
  ro.num_threads = 1;
  if (scene_name == "planes") {
    cam.width = width;
    cam.height = height;
    cam.fx = cam.fy = 0.9 * width;
    cam.cx = (width - 1) / 2.0;
    cam.cy = (height - 1) / 2.0;
    auto with_box = std::make_shared<std::vector<WorldPlane>>(WithBox());
    auto background = std::make_shared<std::vector<WorldPlane>>(Background());
    render = [=](const Rigid3d& pose, RgbdKeyframe* f, RgbdKeyframe* gt) {
      *f = RenderPlanes(*with_box, cam, pose);
      *gt = RenderPlanes(*background, cam, pose);
      return absl::OkStatus();
    };
    for (int t = 0; t < frames; ++t) {
      const double a = (-0.5 + double(t) / (frames - 1)) * arc_deg * M_PI / 180.0;
      const glm::dvec3 eye = kBoxCentre + glm::dvec3(1.6 * std::sin(a), -0.45, -1.6 * std::cos(a));
      poses.push_back(LookAt(eye, kBoxCentre + glm::dvec3(0, 0.1, 0)));
    }
  } else {
    synth::SceneOptions so;
    so.seed = seed;
    so.removable_objects = true;
    auto s = synth::MakeScene(scene_name == "village" ? synth::SceneKind::kVillage
                                                      : synth::SceneKind::kApartment, so);
    if (!s.ok()) {
      std::fprintf(stderr, "%s\n", std::string(s.status().message()).c_str());
      return 1;
    }
    auto wo = synth::RemoveObjects(*s);
    if (!wo.ok()) return 1;
    with_obj = std::make_shared<synth::SynthScene>(*std::move(s));
    without_obj = std::make_shared<synth::SynthScene>(*std::move(wo));
    cam = ro.Camera();
    render = [=](const Rigid3d& pose, RgbdKeyframe* f, RgbdKeyframe* gt) -> absl::Status {
      EXO_ASSIGN_OR_RETURN(synth::RenderedFrame a, synth::RenderFrame(*with_obj, pose, ro));
      EXO_ASSIGN_OR_RETURN(synth::RenderedFrame b, synth::RenderFrame(*without_obj, pose, ro));
      *f = {std::move(a.frame.color), std::move(a.frame.depth_m), cam, pose};
      *gt = {std::move(b.frame.color), std::move(b.frame.depth_m), cam, pose};
      return absl::OkStatus();
    };
    // A walk on a circle around the object, eye height, looking at it: the chair from the
    // north side of the living room (the bookshelf wall and the wooden floor behind it), the
    // cart from the street (the pavement and the houses behind it).
    const glm::dvec3 c = with_obj->removable[0].bounds.Centre();
    const bool apt = scene_name == "apartment";
    const double radius = apt ? 1.7 : 3.2, eye_z = apt ? 1.5 : 1.6;
    const double a0 = apt ? 90.0 : 0.0;
    for (int t = 0; t < frames; ++t) {
      const double a = (a0 + (-0.5 + double(t) / (frames - 1)) * arc_deg) * M_PI / 180.0;
      poses.push_back(synth::LookAt({c.x + radius * std::cos(a), c.y + radius * std::sin(a), eye_z},
                                    {c.x, c.y, c.z}));
    }
  }
  InpaintOptions opt;
  opt.num_threads = 1;
  KeyframePolicyOptions policy;
  policy.max_pose_distance = kf_pose;
  policy.max_unlabelled_fraction = kf_unlabelled;
  std::vector<std::string> methods = {"telea", "ns", "pm", "kf_warp", "ours"};
  if (!only_methods.empty()) methods = only_methods;
  std::map<std::string, Scores> scores;
  std::map<std::string, ImageU8> prev_out;
  ImageU8 prev_gt;
  Rigid3d prev_pose;
  // kf_warp: keyframes (results) and timings.
  std::vector<std::shared_ptr<InpaintResult>> keyframes;
  int propagated = 0;
  double first_kf_ms = 0, propagated_ms = 0, warp_ms = 0;
  int warped_frames = 0;
  // ours: the per-frame orchestration of the library (keyframes, observation views, look-up,
  // blend, depth Poisson, temporal smoothing), synchronous here.
  DrOptions dro;
  dro.inpaint = opt;
  dro.policy = policy;
  dro.obs_stride = obs_stride;
  dro.obs_views = obs_views;
  dro.blend = blend == "paste" ? DrBlend::kPaste
              : blend == "poisson" ? DrBlend::kPoisson
                                   : DrBlend::kPoissonHallucinated;
  dro.ring = ring == "observed" ? DrRing::kObserved : ring == "frame" ? DrRing::kFrame : DrRing::kLookUp;
  dro.ring_sigma = ring_sigma;
  dro.temporal = temporal;
  dro.temporal_hallucinated_only = temporal_hallucinated_only;
  dro.depth_poisson = depth_poisson;
  dro.kf_context = kf_context;
  dro.prefer_observed = prefer_observed;
  dro.bicubic = bicubic;
  dro.kf_crop_margin_px = kf_crop_margin_px;
  dro.kf_crop_margin_rel = kf_crop_margin_rel;
  if (auto st = dro.Validate(); !st.ok()) {
    std::fprintf(stderr, "%s\n", std::string(st.message()).c_str());
    return 1;
  }
  DiminishedReality ours(dro);
  // live: the server's live DR view. The same keyframes and observation views as ours, but a
  // keyframe is ready only from the NEXT frame on (the server computes it asynchronously; its
  // latency is not modelled beyond that), and every frame's output is ComposeLiveFrame (no
  // keyframe work, push-pull instead of Poisson). cpu_ms_per_frame of "live" is the compose
  // only; the keyframes' CPU is reported apart ("live" block).
  DiminishedReality live(dro);
  DrLiveOptions live_opt;
  live_opt.max_views = live_views;
  live_opt.temporal = temporal;
  DrLiveState live_state;
  double live_kf_cpu_ms = 0, live_first_kf_ms = 0, live_prop_kf_ms = 0;
  // CPU per keyframe (first / propagated) and the library's phases (CPU, summed).
  double live_first_kf_cpu = 0, live_prop_kf_cpu = 0, live_prep = 0, live_search = 0,
         live_poisson = 0;
  int live_lib_runs = 0;
  int live_keyframes = 0, live_composited = 0;
  long live_unreached = 0;
  double our_frame_ms = 0;
  long our_roi_px = 0, our_observed_px = 0;
  int our_frames = 0;
  SsimOptions so;
  for (int t = 0; t < frames; ++t) {
    const Rigid3d pose = poses[t];
    RgbdKeyframe f, gt;
    if (auto st = render(pose, &f, &gt); !st.ok()) {
      std::fprintf(stderr, "render: %s\n", std::string(st.message()).c_str());
      return 1;
    }
    ImageU8 roi(width, height, 1, 0);
    for (size_t i = 0; i < roi.size(); ++i)
      roi.data()[i] = (f.depth_m.data()[i] + 1e-4f < gt.depth_m.data()[i] ||
                       (f.depth_m.data()[i] > 0.f && !(gt.depth_m.data()[i] > 0.f)))
                          ? 255
                          : 0;
    {
      cv::Mat m = Wrap(roi);
      cv::dilate(m, m, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(9, 9)));
    }
    int roi_px = 0;
    for (size_t i = 0; i < roi.size(); ++i) roi_px += roi.data()[i] != 0;
    // The seam: a 10-px band around the ROI's boundary (5 px inside, 5 px outside).
    ImageU8 seam(width, height, 1, 0);
    {
      cv::Mat r = Wrap(roi), s = Wrap(seam), inner;
      const cv::Mat k = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(11, 11));
      cv::dilate(r, s, k);
      cv::erode(r, inner, k);
      s.setTo(0, inner);
    }
    const bool scored = t >= score_first && t <= last && roi_px > 0;
    for (const std::string& method : methods) {
      Output out{f.color, f.depth_m};
      const double w0 = WallMs(), c0 = CpuMs();
      if (roi_px == 0) {
        // Nothing to remove in this frame.
      } else if (method == "telea" || method == "ns") {
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
      } else if (method == "kf_warp") {
        std::vector<KeyframeView> views;
        for (const auto& k : keyframes) views.push_back({&k->mask, &k->depth_m, k->camera, k->world_from_cam});
        const KeyframeDecision d = DecideKeyframe(roi, cam, pose, views, policy);
        if (d.insert) {
          const InpaintResult* previous = d.nearest >= 0 ? keyframes[d.nearest].get() : nullptr;
          const double k0 = WallMs();
          auto r = InpaintKeyframe(f, roi, opt, previous);
          if (!r.ok()) {
            std::fprintf(stderr, "kf_warp frame %d: %s\n", t, std::string(r.status().message()).c_str());
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
      } else if (method == "live") {
        auto r = ComposeLiveFrame(f, roi, live.LiveSnapshot(pose, live_opt.max_views), live_opt,
                                  &live_state);
        if (!r.ok()) {
          std::fprintf(stderr, "live frame %d: %s\n", t, std::string(r.status().message()).c_str());
          return 1;
        }
        live_composited += r->composited;
        live_unreached += r->unreached_px;
        out = {std::move(r->color), std::move(r->depth)};
      } else {  // ours: the library's DiminishedReality (dr_compositor.h), synchronous keyframes
        const double k0 = WallMs();
        auto r = ours.ProcessFrame(f, roi, t);
        if (!r.ok()) {
          std::fprintf(stderr, "ours frame %d: %s\n", t, std::string(r.status().message()).c_str());
          return 1;
        }
        out = {std::move(r->color), std::move(r->depth)};
        our_frame_ms += WallMs() - k0;
        ++our_frames;
        if (!r->keyframe) {
          our_roi_px += roi_px;
          our_observed_px += r->observed_px;
        }
      }
      Scores& s = scores[method];
      const double wall = WallMs() - w0, cpu = CpuMs() - c0;
      s.Digest(out.color.data(), out.color.size());
      s.Digest(out.depth.data(), out.depth.bytes());
      if (method == "live" && roi_px > 0) {
        // After the frame's output: the keyframe the rule asks for (ready for the next frame)
        // and the observation view, as the server's worker and stage thread do.
        const double k0 = CpuMs(), kw = WallMs();
        const KeyframeDecision d = live.Decide(roi, cam, pose);
        if (d.insert) {
          const double kc = CpuMs();
          auto k = DiminishedReality::ComputeKeyframe(live.MakeJob(f, roi, d), dro);
          if (!k.ok()) {
            std::fprintf(stderr, "live keyframe %d: %s\n", t, std::string(k.status().message()).c_str());
            return 1;
          }
          if (k->inpainted) {
            live_prep += k->stats.cpu_ms_prepare;
            live_search += k->stats.cpu_ms_search;
            live_poisson += k->stats.cpu_ms_poisson;
            ++live_lib_runs;
          }
          live.AddKeyframe(k->view, &*k);
          if (live_keyframes == 0) {
            live_first_kf_ms = WallMs() - kw;
            live_first_kf_cpu = CpuMs() - kc;
          } else {
            live_prop_kf_ms += WallMs() - kw;
            live_prop_kf_cpu += CpuMs() - kc;
          }
          ++live_keyframes;
        }
        live.AddObservation(f, roi, t);
        live_kf_cpu_ms += CpuMs() - k0;
      }
      if (!scored) {
        prev_out[method] = out.color;
        continue;
      }
      s.wall_ms += wall;
      s.cpu_ms += cpu;
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
      if (t > score_first && !prev_out[method].empty()) {
        s.flicker += Flicker(out.color, prev_out[method], roi, gt.depth_m, cam, pose, prev_pose);
        s.gt_flicker += Flicker(gt.color, prev_gt, roi, gt.depth_m, cam, pose, prev_pose);
        ++s.flicker_frames;
      }
      prev_out[method] = out.color;
    }
    if (!sheet.empty() && t % sheet_every == 0) {
      std::vector<cv::Mat> cols = {Wrap(f.color).clone(), Wrap(gt.color).clone()};
      for (const char* m : {"telea", "pm", "kf_warp", "ours", "live"})
        if (!prev_out[m].empty()) cols.push_back(Wrap(prev_out[m]).clone());
      for (const char* m : {"telea", "ours", "live"})
        if (!prev_out[m].empty()) {
          cv::Mat e;
          cv::absdiff(Wrap(prev_out[m]), Wrap(gt.color), e);
          cols.push_back(e * 4);  // |method - ground truth| x 4
        }
      for (cv::Mat& c : cols) {
        cv::Mat r = Wrap(roi), edge;
        cv::morphologyEx(r, edge, cv::MORPH_GRADIENT, cv::Mat());
        c.setTo(cv::Scalar(255, 0, 255), edge);  // the ROI's outline
      }
      cv::Mat row;
      cv::hconcat(cols, row);
      sheet_rows.push_back(row);
    }
    prev_gt = gt.color;
    prev_pose = pose;
  }
  if (!sheet.empty() && !sheet_rows.empty()) {
    cv::Mat all, bgr;
    cv::vconcat(sheet_rows, all);
    cv::cvtColor(all, bgr, cv::COLOR_RGB2BGR);
    if (!cv::imwrite(sheet, bgr, {cv::IMWRITE_JPEG_QUALITY, 85})) {
      std::fprintf(stderr, "cannot write %s\n", sheet.c_str());
      return 1;
    }
  }
  double load = 0;
  std::ifstream("/proc/loadavg") >> load;
  std::printf("{\"bench\": \"dr_bench\", \"scene\": \"%s\", \"seed\": %llu, \"frames\": %d, "
              "\"scored\": [%d, %d], \"width\": %d, \"height\": %d, \"arc_deg\": %.1f, "
              "\"kf_pose\": %.3f, \"kf_unlabelled\": %.3f, \"blend\": \"%s\", "
              "\"obs_stride\": %d, \"obs_views\": %d, \"load1\": %.2f, \"methods\": {",
              scene_name.c_str(), static_cast<unsigned long long>(seed), frames, score_first, last, width,
              height, arc_deg, kf_pose, kf_unlabelled, blend.c_str(), obs_stride, obs_views, load);
  bool first = true;
  for (const std::string& m : methods) {
    const Scores& s = scores[m];
    const double n = std::max(1, s.frames), nf = std::max(1, s.flicker_frames);
    std::printf("%s\"%s\": {\"psnr_roi\": %.2f, \"ssim_roi\": %.4f, \"psnr_seam\": %.2f, "
                "\"ssim_seam\": %.4f, \"depth_mae_mm\": %.1f, \"flicker\": %.3f, "
                "\"flicker_ratio\": %.3f, \"wall_ms_per_frame\": %.2f, \"cpu_ms_per_frame\": %.2f, "
                "\"output_digest\": \"%016llx\"}",
                first ? "" : ", ", m.c_str(), s.psnr_roi / n, s.ssim_roi / n, s.psnr_seam / n,
                s.ssim_seam / n, s.depth_mae_mm / std::max(1, s.depth_frames), s.flicker / nf,
                s.gt_flicker > 0 ? s.flicker / s.gt_flicker : 0.0, s.wall_ms / n, s.cpu_ms / n,
                static_cast<unsigned long long>(s.digest));
    first = false;
  }
  std::printf("}, \"kf_warp\": {\"keyframes\": %zu, \"propagated\": %d, \"first_keyframe_ms\": %.1f, "
              "\"propagated_keyframe_ms_mean\": %.1f, \"warped_frames\": %d, "
              "\"warp_ms_mean\": %.2f}",
              keyframes.size(), propagated, first_kf_ms, propagated ? propagated_ms / propagated : 0.0,
              warped_frames, warped_frames ? warp_ms / warped_frames : 0.0);
  std::printf(", \"ours\": {\"keyframes\": %zu, \"inpainted\": %d, \"propagated\": %d, "
              "\"first_keyframe_ms\": %.1f, "
              "\"propagated_keyframe_ms_mean\": %.1f, \"frame_ms_mean\": %.2f, "
              "\"observed_fraction_between_keyframes\": %.3f}",
              ours.keyframes().size(), ours.stats().keyframes_inpainted,
              ours.stats().keyframes_propagated, ours.stats().first_keyframe_ms,
              ours.stats().keyframes_propagated
                  ? ours.stats().propagated_keyframe_ms / ours.stats().keyframes_propagated
                  : 0.0,
              our_frames ? our_frame_ms / our_frames : 0.0,
              our_roi_px ? double(our_observed_px) / our_roi_px : 0.0);
  if (std::find(methods.begin(), methods.end(), "live") != methods.end()) {
    const Scores& s = scores["live"];
    const double cpu = s.frames ? s.cpu_ms / s.frames : 0.0;
    std::printf(", \"live\": {\"compose_cpu_ms_per_frame\": %.2f, \"compose_fps_one_core\": %.1f, "
                "\"composited_frames\": %d, \"unreached_px_mean\": %.1f, \"keyframes\": %d, "
                "\"first_keyframe_ms\": %.1f, \"propagated_keyframe_ms_mean\": %.1f, "
                "\"keyframe_and_observation_cpu_ms_total\": %.1f, \"views\": %d, "
                "\"first_keyframe_cpu_ms\": %.1f, \"propagated_keyframe_cpu_ms_mean\": %.1f, "
                "\"library_cpu_ms_mean\": {\"prepare\": %.1f, \"search\": %.1f, \"poisson\": %.1f}}",
                cpu, cpu > 0 ? 1000.0 / cpu : 0.0, live_composited,
                live_composited ? double(live_unreached) / live_composited : 0.0, live_keyframes,
                live_first_kf_ms, live_keyframes > 1 ? live_prop_kf_ms / (live_keyframes - 1) : 0.0,
                live_kf_cpu_ms, live_opt.max_views, live_first_kf_cpu,
                live_keyframes > 1 ? live_prop_kf_cpu / (live_keyframes - 1) : 0.0,
                live_lib_runs ? live_prep / live_lib_runs : 0.0,
                live_lib_runs ? live_search / live_lib_runs : 0.0,
                live_lib_runs ? live_poisson / live_lib_runs : 0.0);
  }
  std::printf("}\n");
  return 0;
}

}  // namespace
}  // namespace exo::inpainting

int main(int argc, char** argv) { return exo::inpainting::Main(argc, argv); }
