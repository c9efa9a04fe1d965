// dr_7scenes (issue 18): diminished reality on real data. A 3-D box around an object on the
// 7-Scenes redkitchen counter (default: the wooden cube of frame 150) becomes L_ROI labels (the
// box's 2 cm voxels, region_labels.h), every frame's ROI is their re-projection through the
// frame's registered depth (ProjectRegions, as the server does), and the frames run through the
// live path of the server: keyframes by the rule (computed after the frame, ready from the next
// one on: the server's worker is asynchronous), every frame composited by ComposeLiveFrame.
// Writes a before / after contact sheet (PNG) over frames spread across the sequence and prints
// one JSON line (frames, keyframes, compose CPU per frame, keyframe timings).
//
// The box: --pick (a pixel on the object's front face in --pick_frame), --base (a pixel of the
// surface it stands on: its normal is "up"), --size (width across the view, depth along it,
// height; metres). The box stands on that surface (1 cm above it) behind the picked point.
//
//   dr_7scenes --dataset ../shared/data/7scenes-redkitchen --out docs/img/dr_redkitchen_live.png
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/cli/cli.h"
#include "common/datasets/seven_scenes.h"
#include "server/core/online_model.h"
#include "server/inpainting/dr_compositor.h"
#include "server/inpainting/region_labels.h"

namespace exo::inpainting {
namespace {

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

cv::Mat Wrap(const ImageU8& im) {
  return cv::Mat(im.height(), im.width(), im.channels() == 3 ? CV_8UC3 : CV_8UC1,
                 const_cast<uint8_t*>(im.data()));
}

bool ParsePair(const std::string& s, double* a, double* b) {
  return std::sscanf(s.c_str(), "%lf,%lf", a, b) == 2;
}

int Main(int argc, char** argv) {
  std::string dataset = "../shared/data/7scenes-redkitchen", out_path, pick = "280,140",
              base = "300,186", size = "0.24,0.24,0.26";
  int pick_frame = 150, first = 0, last = -1, stride = 1, rows = 6, live_views = 4;
  double scale = 0.5;
  CLI::App app{"Diminished reality on 7-Scenes: a 3-D box region, the live DR path, a before / "
               "after contact sheet", "dr_7scenes"};
  exo::cli::Setup(app);
  app.add_option("--dataset", dataset, "7-Scenes directory");
  app.add_option("--out", out_path, "contact sheet (PNG)")->required();
  app.add_option("--pick_frame", pick_frame, "frame the box is placed in");
  app.add_option("--pick", pick, "u,v: a pixel on the object's front face");
  app.add_option("--base", base, "u,v: a pixel of the surface the object stands on");
  app.add_option("--size", size, "box width,depth,height (m)");
  app.add_option("--first", first, "first frame");
  app.add_option("--last", last, "last frame (-1 = the last)");
  app.add_option("--stride", stride, "every Nth frame")->check(CLI::Range(1, 100));
  app.add_option("--rows", rows, "sheet rows (frames spread evenly over those with the ROI)")
      ->check(CLI::Range(1, 20));
  app.add_option("--scale", scale, "sheet scale")->check(CLI::Range(0.1, 1.0));
  std::vector<std::string> probes;
  app.add_option("--probe", probes, "u,v: print the registered depth there in --pick_frame and exit "
                 "(to choose --pick / --base)");
  double temporal = -1;
  app.add_option("--temporal", temporal, "weight of the previous output (default: the library's 0.8)")
      ->check(CLI::Range(-1.0, 0.99));
  app.add_option("--live_views", live_views, "look-up views per frame")->check(CLI::Range(1, 64));
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  double pu, pv, bu, bv, sw, sd, sh;
  if (!ParsePair(pick, &pu, &pv) || !ParsePair(base, &bu, &bv) ||
      std::sscanf(size.c_str(), "%lf,%lf,%lf", &sw, &sd, &sh) != 3 || sw <= 0 || sd <= 0 || sh <= 0) {
    std::fprintf(stderr, "bad --pick / --base / --size\n");
    return 2;
  }
  SevenScenesOptions so;
  so.register_depth = true;
  auto reader = SevenScenesReader::Open(dataset, so);
  if (!reader.ok()) {
    std::fprintf(stderr, "%s\n", std::string(reader.status().message()).c_str());
    return 1;
  }
  const auto& rd = **reader;
  if (last < 0 || last >= static_cast<int>(rd.size())) last = static_cast<int>(rd.size()) - 1;
  if (pick_frame < 0 || pick_frame >= static_cast<int>(rd.size())) {
    std::fprintf(stderr, "--pick_frame out of range\n");
    return 2;
  }

  // ---- the box ----
  auto pf = rd.Load(pick_frame);
  if (!pf.ok()) return 1;
  const PinholeCamera cam = pf->color_camera;
  const ImageF& pd = pf->depth_m;
  auto world_at = [&](double u, double v, glm::dvec3* p) {
    const int x = static_cast<int>(std::lround(u)), y = static_cast<int>(std::lround(v));
    if (!pd.Contains(x, y) || !(pd.at(x, y) > 0.f)) return false;
    *p = pf->world_from_cam * cam.Unproject({u, v}, pd.at(x, y));
    return true;
  };
  // The picked pixels: the nearest with depth within 25 px (registered depth has holes).
  auto nearest_valid = [&](double* u, double* v) {
    for (int r = 0; r <= 25; ++r)
      for (int dy = -r; dy <= r; ++dy)
        for (int dx = -r; dx <= r; ++dx) {
          const int x = static_cast<int>(std::lround(*u)) + dx, y = static_cast<int>(std::lround(*v)) + dy;
          if (pd.Contains(x, y) && pd.at(x, y) > 0.f) {
            *u = x;
            *v = y;
            return;
          }
        }
  };
  if (!probes.empty()) {
    for (const auto& pr : probes) {
      double u = 0, v = 0;
      if (!ParsePair(pr, &u, &v)) continue;
      const int x = static_cast<int>(u), y = static_cast<int>(v);
      std::printf("%s: depth %.3f m\n", pr.c_str(), pd.Contains(x, y) ? pd.at(x, y) : 0.f);
    }
    return 0;
  }
  nearest_valid(&pu, &pv);
  nearest_valid(&bu, &bv);
  glm::dvec3 P, B;
  if (!world_at(pu, pv, &P) || !world_at(bu, bv, &B)) {
    int valid = 0;
    for (size_t i = 0; i < pd.size(); ++i) valid += pd.data()[i] > 0.f;
    std::fprintf(stderr, "no depth at --pick (%g,%g) or --base (%g,%g): %d of %zu pixels have depth (%dx%d)\n",
                 pu, pv, bu, bv, valid, pd.size(), pd.width(), pd.height());
    return 1;
  }
  // "Up": the normal of the base surface, a least-squares plane through the 15x15 window.
  std::vector<glm::dvec3> pts;
  for (int dy = -7; dy <= 7; ++dy)
    for (int dx = -7; dx <= 7; ++dx) {
      glm::dvec3 q;
      if (world_at(bu + dx, bv + dy, &q)) pts.push_back(q);
    }
  if (pts.size() < 20) {
    std::fprintf(stderr, "too little depth around --base\n");
    return 1;
  }
  cv::Mat A(static_cast<int>(pts.size()), 3, CV_64F);
  glm::dvec3 mean(0.0);
  for (const auto& q : pts) mean += q / double(pts.size());
  for (size_t i = 0; i < pts.size(); ++i)
    for (int c = 0; c < 3; ++c) A.at<double>(static_cast<int>(i), c) = pts[i][c] - mean[c];
  cv::Mat w, u, vt;
  cv::SVD::compute(A, w, u, vt);
  glm::dvec3 up(vt.at<double>(2, 0), vt.at<double>(2, 1), vt.at<double>(2, 2));
  const glm::dvec3 eye = pf->world_from_cam.translation;
  if (glm::dot(up, eye - mean) < 0) up = -up;
  glm::dvec3 fwd = P - eye;
  fwd = glm::normalize(fwd - glm::dot(fwd, up) * up);
  const glm::dvec3 side = glm::cross(up, fwd);
  const double base_h = glm::dot(mean, up);
  const glm::dvec3 centre = P - (glm::dot(P, up) - base_h) * up + (0.01 + sh / 2) * up + fwd * (sd / 2 - 0.03);  // front 3 cm before the picked point
  {
    const Rigid3d cam_from_world = pf->world_from_cam.Inverse();
    const glm::dvec3 up_cam = cam_from_world.rotation * up, c_cam = cam_from_world * centre,
                     p_cam = cam_from_world * P;
    std::fprintf(stderr,
                 "box: up in the pick camera (%.2f, %.2f, %.2f), picked point (%.2f, %.2f, %.2f), "
                 "centre (%.2f, %.2f, %.2f), %zu base points\n",
                 up_cam.x, up_cam.y, up_cam.z, p_cam.x, p_cam.y, p_cam.z, c_cam.x, c_cam.y,
                 c_cam.z, pts.size());
  }
  Region3D box;
  box.id = 1;
  box.voxel_m = 0.02;
  const double step = 0.005;
  for (double a = -sw / 2; a <= sw / 2; a += step)
    for (double b = -sd / 2; b <= sd / 2; b += step)
      for (double c = -sh / 2; c <= sh / 2; c += step) {
        const glm::dvec3 q = centre + a * side + b * fwd + c * up;
        box.voxels.push_back(PackVoxel(static_cast<int>(std::floor(q.x / box.voxel_m)),
                                       static_cast<int>(std::floor(q.y / box.voxel_m)),
                                       static_cast<int>(std::floor(q.z / box.voxel_m))));
      }
  std::sort(box.voxels.begin(), box.voxels.end());
  box.voxels.erase(std::unique(box.voxels.begin(), box.voxels.end()), box.voxels.end());
  const Region3D* regions[] = {&box};
  const RegionLabels labels(regions);
  RegionOptions ro;
  // The ROI of a frame: its pixels whose depth falls into the box (the labels, as the server
  // re-projects them), plus the pixels without depth whose ray crosses the box (Kinect v1 gives
  // no depth on the cube's dark face), dilated like ProjectRegions. An occluder in front of the
  // box and the background seen through the box's empty space stay.
  const glm::dvec3 axes[3] = {side, fwd, up};
  const double half[3] = {sw / 2, sd / 2, sh / 2};
  auto frame_roi = [&](const ImageF& depth, const PinholeCamera& c, const Rigid3d& pose) {
    ImageU8 roi = ProjectRegions(labels, depth, c, pose, ro);
    const glm::dvec3 o = pose.translation;
    // The box's rays: slab test in the box's frame.
    glm::dvec3 ob;
    for (int k = 0; k < 3; ++k) ob[k] = glm::dot(o - centre, axes[k]);
    ImageU8 solid(c.width, c.height, 1, 0);
    for (int y = 0; y < c.height; ++y)
      for (int x = 0; x < c.width; ++x) {
        const glm::dvec3 dir = pose.rotation * c.Unproject({x, y}, 1.0);  // z = 1 along the ray
        double t0 = 0, t1 = 1e9;
        bool hit = true;
        for (int k = 0; k < 3 && hit; ++k) {
          const double dk = glm::dot(dir, axes[k]);
          if (std::fabs(dk) < 1e-12) {
            hit = std::fabs(ob[k]) <= half[k];
            continue;
          }
          double a = (-half[k] - ob[k]) / dk, b = (half[k] - ob[k]) / dk;
          if (a > b) std::swap(a, b);
          t0 = std::max(t0, a);
          t1 = std::min(t1, b);
          hit = t0 <= t1;
        }
        if (!hit) continue;
        const float z = depth.at(x, y);  // t is z-depth here (dir has z = 1 in the camera)
        if (!(z > 0.f)) solid.at(x, y) = 255;
      }
    cv::Mat s = Wrap(solid).clone();
    cv::dilate(s, s, cv::getStructuringElement(cv::MORPH_ELLIPSE,
                                               cv::Size(2 * ro.reproject_dilate_px + 1,
                                                        2 * ro.reproject_dilate_px + 1)));
    for (int y = 0; y < c.height; ++y)
      for (int x = 0; x < c.width; ++x)
        if (s.at<uint8_t>(y, x)) roi.at(x, y) = 255;
    return roi;
  };

  // ---- the live path over the sequence ----
  DrOptions dro;
  DiminishedReality dr(dro);
  DrLiveOptions lo;
  lo.max_views = live_views;
  if (temporal >= 0) lo.temporal = temporal;
  DrLiveState state;
  struct Kept {
    int frame;
    ImageU8 input, output, roi;
  };
  std::vector<Kept> kept;
  int frames = 0, with_roi = 0, composited = 0, keyframes = 0;
  long roi_px_total = 0;
  double compose_cpu = 0, compose_wall = 0, kf_first_ms = 0, kf_prop_ms = 0, kf_cpu = 0;
  // Why the fill looks as it does (session 13): ROI pixels without depth, taken from an
  // observation, hallucinated in the keyframes; luma mean / std of the output's ROI against the
  // input's 10-px ring outside it (a smear: lower std; exposure: a mean shift).
  int64_t diag_roi = 0, diag_nodepth = 0, diag_observed = 0, kf_roi = 0, kf_halluc = 0;
  double luma_roi = 0, luma_ring = 0, std_roi = 0, std_ring = 0;
  int diag_frames = 0;
  auto luma_stats = [](const ImageU8& c, const cv::Mat& m, double* mean, double* sd) {
    cv::Mat rgb(c.height(), c.width(), CV_8UC3, const_cast<uint8_t*>(c.data())), g;
    cv::cvtColor(rgb, g, cv::COLOR_RGB2GRAY);
    cv::Scalar mu, sigma;
    cv::meanStdDev(g, mu, sigma, m);
    *mean = mu[0];
    *sd = sigma[0];
  };
  for (int i = first; i <= last; i += stride) {
    auto f = rd.Load(i);
    if (!f.ok()) {
      std::fprintf(stderr, "frame %d: %s\n", i, std::string(f.status().message()).c_str());
      return 1;
    }
    ++frames;
    const ImageF depth = core::RegisterDepthToColor(*f);
    const ImageU8 roi = frame_roi(depth, f->color_camera, f->world_from_cam);
    roi_px_total += CountNonZero(roi);
    if (CountNonZero(roi) == 0) {
      state.Reset();
      continue;
    }
    ++with_roi;
    const RgbdKeyframe frame{f->color, depth, f->color_camera, f->world_from_cam};
    const double c0 = CpuMs(), w0 = WallMs();
    auto r = ComposeLiveFrame(frame, roi, dr.LiveSnapshot(frame.world_from_cam, lo.max_views), lo,
                              &state);
    if (!r.ok()) {
      std::fprintf(stderr, "frame %d: %s\n", i, std::string(r.status().message()).c_str());
      return 1;
    }
    compose_cpu += CpuMs() - c0;
    compose_wall += WallMs() - w0;
    composited += r->composited;
    if (r->composited) {
      for (size_t p = 0; p < roi.size(); ++p)
        if (roi.data()[p]) {
          ++diag_roi;
          diag_nodepth += !(depth.data()[p] > 0.f);
        }
      diag_observed += r->observed_px;
      cv::Mat m(roi.height(), roi.width(), CV_8UC1, const_cast<uint8_t*>(roi.data())), grown, ring;
      cv::dilate(m, grown, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(21, 21)));
      cv::subtract(grown, m, ring);
      double a, b, c2, d2;
      luma_stats(r->color, m, &a, &b);
      luma_stats(f->color, ring, &c2, &d2);
      luma_roi += a;
      std_roi += b;
      luma_ring += c2;
      std_ring += d2;
      ++diag_frames;
    }
    kept.push_back({i, f->color, std::move(r->color), roi});
    const double k0 = CpuMs(), kw = WallMs();
    const KeyframeDecision d = dr.Decide(roi, frame.camera, frame.world_from_cam);
    if (d.insert) {
      auto k = DiminishedReality::ComputeKeyframe(dr.MakeJob(frame, roi, d), dro);
      if (k.ok()) {
        kf_roi += CountNonZero(roi);
        kf_halluc += k->hallucinated_px;
        dr.AddKeyframe(k->view, &*k);
        (keyframes == 0 ? kf_first_ms : kf_prop_ms) += WallMs() - kw;
        ++keyframes;
      } else {
        std::fprintf(stderr, "keyframe at frame %d: %s\n", i, std::string(k.status().message()).c_str());
      }
    }
    dr.AddObservation(frame, roi, i);
    kf_cpu += CpuMs() - k0;
  }
  if (kept.empty()) {
    std::fprintf(stderr, "the box is in no frame\n");
    return 1;
  }
  // ---- the sheet: rows spread over the frames with the ROI (skipping the first few, before a
  // keyframe exists), columns: input with the ROI outlined, the live DR output ----
  std::vector<cv::Mat> sheet_rows;
  // Rows: frames whose ROI is at least half the largest and clear of the image border (the
  // object well in view),
  // after the first keyframe, spread evenly.
  int max_roi = 0;
  for (const Kept& kp : kept) max_roi = std::max(max_roi, CountNonZero(kp.roi));
  std::vector<size_t> shown;
  auto off_border = [](const ImageU8& m) {
    for (int y = 0; y < m.height(); ++y)
      for (int x = 0; x < m.width(); ++x)
        if (m.at(x, y) && (x < 4 || y < 4 || x >= m.width() - 4 || y >= m.height() - 4)) return false;
    return true;
  };
  for (size_t k = 1; k < kept.size(); ++k)
    if (2 * CountNonZero(kept[k].roi) >= max_roi && off_border(kept[k].roi)) shown.push_back(k);
  if (shown.empty()) shown.push_back(0);
  for (int r = 0; r < rows; ++r) {
    const size_t k = shown[(shown.size() - 1) * r / std::max(1, rows - 1)];
    const Kept& kp = kept[k];
    cv::Mat in = Wrap(kp.input).clone(), outm = Wrap(kp.output).clone(), edge;
    cv::morphologyEx(Wrap(kp.roi), edge, cv::MORPH_GRADIENT, cv::Mat());
    in.setTo(cv::Scalar(255, 0, 255), edge);
    cv::Mat row;
    cv::hconcat(std::vector<cv::Mat>{in, outm}, row);
    cv::putText(row, "frame " + std::to_string(kp.frame), {8, 24}, cv::FONT_HERSHEY_SIMPLEX, 0.8,
                cv::Scalar(255, 255, 0), 2);
    cv::resize(row, row, cv::Size(), scale, scale, cv::INTER_AREA);
    sheet_rows.push_back(row);
  }
  cv::Mat all, bgr;
  cv::vconcat(sheet_rows, all);
  cv::cvtColor(all, bgr, cv::COLOR_RGB2BGR);
  if (!cv::imwrite(out_path, bgr)) {
    std::fprintf(stderr, "cannot write %s\n", out_path.c_str());
    return 1;
  }
  double load = 0;
  std::ifstream("/proc/loadavg") >> load;
  std::printf("{\"tool\": \"dr_7scenes\", \"frames\": %d, \"frames_with_roi\": %d, "
              "\"composited\": %d, \"box_voxels\": %zu, \"keyframes\": %d, "
              "\"first_keyframe_ms\": %.1f, \"propagated_keyframe_ms_mean\": %.1f, "
              "\"keyframe_and_observation_cpu_ms_total\": %.0f, \"compose_cpu_ms_per_frame\": %.2f, "
              "\"compose_wall_ms_per_frame\": %.2f, \"roi_px_mean\": %.0f, \"pick\": [%g, %g], "
              "\"base\": [%g, %g], \"load1\": %.2f, \"sheet\": \"%s\", "
              "\"fill\": {\"roi_without_depth\": %.3f, \"roi_from_observations\": %.3f, "
              "\"keyframe_roi_hallucinated\": %.3f, \"luma_roi_mean\": %.1f, \"luma_ring_mean\": %.1f, "
              "\"luma_roi_std\": %.1f, \"luma_ring_std\": %.1f}}\n",
              frames, with_roi, composited, box.voxels.size(), keyframes, kf_first_ms,
              keyframes > 1 ? kf_prop_ms / (keyframes - 1) : 0.0, kf_cpu,
              with_roi ? compose_cpu / with_roi : 0.0, with_roi ? compose_wall / with_roi : 0.0,
              with_roi ? double(roi_px_total) / with_roi : 0.0, pu, pv, bu, bv, load,
              out_path.c_str(), diag_roi ? double(diag_nodepth) / diag_roi : 0.0,
              diag_roi ? double(diag_observed) / diag_roi : 0.0,
              kf_roi ? double(kf_halluc) / kf_roi : 0.0, diag_frames ? luma_roi / diag_frames : 0.0,
              diag_frames ? luma_ring / diag_frames : 0.0, diag_frames ? std_roi / diag_frames : 0.0,
              diag_frames ? std_ring / diag_frames : 0.0);
  return 0;
}

}  // namespace
}  // namespace exo::inpainting

int main(int argc, char** argv) { return exo::inpainting::Main(argc, argv); }
