// exoview_calibrate_7scenes: estimates the depth -> colour calibration of a 7-Scenes sequence
// (Kinect v1) from its own posed RGB-D frames (EstimateDepthColorCalibration) and prints one
// JSON object: the estimate, the solver report, and the alignment measures (median multi-view
// photometric difference, median depth-edge -> colour-edge distance) of identity registration
// (colour camera = depth K), of the estimate and of the committed constant, on the frames used
// and on a disjoint set of held-out frames.
//
//   exoview_calibrate_7scenes --dir /work/shared/data/7scenes-redkitchen [--step 10] [--first 0]
//       [--count 30] [--levels 3] [--iterations 25] [--same_focal] [--fixed_rotation]
//       [--rotation_sigma_deg 0.5] [--threads 2] [--png out.png --png_frame 150]
// --png writes depth discontinuities over the (grey) colour image of one frame, cropped to
// x 120-520, y 40-340: left = identity registration (raw depth pixels taken as colour pixels),
// right = the committed calibration.
// It also times RegisterDepthToColor (CPU and wall ms per 640x480 frame) on the loaded frames.
#include "exoview_source_dir.h"
#include <sys/resource.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <chrono>
#include <ctime>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "common/cli/cli.h"
#include "common/datasets/rgbd_registration.h"
#include "common/datasets/seven_scenes.h"
#include "common/io/image_file.h"

namespace {

double CpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

std::string MeasuresJson(const exo::AlignmentMeasures& m) {
  return absl::StrFormat(
      "{\"photometric_median_abs\":%.5f,\"photometric_samples\":%d,\"edge_median_px\":%.3f,"
      "\"edge_p90_px\":%.3f,\"edge_samples\":%d}",
      m.photometric_median_abs, m.photometric_samples, m.edge_median_px, m.edge_p90_px,
      m.edge_samples);
}

// Marks pixels of `depth` on the near side of a discontinuity (neighbour farther by > 6 % and
// 8 cm, the estimator's thresholds) in `rgb`, dimmed to make them visible.
void DrawDepthEdges(const exo::ImageF& depth, const uint8_t color[3], exo::ImageU8* rgb) {
  for (int v = 1; v + 1 < depth.height(); ++v)
    for (int u = 1; u + 1 < depth.width(); ++u) {
      const float z = depth.at(u, v);
      if (z <= 0) continue;
      bool edge = false;
      const int du[4] = {1, -1, 0, 0}, dv[4] = {0, 0, 1, -1};
      for (int k = 0; k < 4; ++k) {
        const float n = depth.at(u + du[k], v + dv[k]);
        if (n > 0 && n - z > std::max(0.08f, 0.06f * z)) edge = true;
      }
      if (!edge) continue;
      for (int c = 0; c < 3; ++c) rgb->at(u, v, c) = color[c];
    }
}

}  // namespace

int main(int argc, char** argv) {
  std::string dir = std::string(EXOVIEW_SOURCE_DIR) + "/../shared/data/7scenes-redkitchen";
  int step = 10, first = 0, count = 30, png_frame = 150;
  std::string png;
  exo::CalibrationOptions o;
  CLI::App app{"Estimates the 7-Scenes (Kinect v1) depth -> colour calibration from the data "
               "(Ceres); prints JSON.",
               "exoview_calibrate_7scenes"};
  exo::cli::Setup(app);
  app.add_option("--dir", dir, "7-Scenes sequence directory");
  app.add_option("--step", step, "use every step-th frame");
  app.add_option("--first", first, "first frame");
  app.add_option("--count", count, "frames used");
  app.add_option("--levels", o.pyramid_levels, "pyramid levels");
  app.add_option("--iterations", o.max_iterations_per_level, "iterations per level");
  app.add_option("--threads", o.num_threads, "Ceres threads");
  app.add_option("--photo_weight", o.photometric_weight, "photometric term weight");
  app.add_option("--edge_weight", o.edge_weight, "edge term weight");
  app.add_flag("--same_focal", o.same_focal, "one focal length for x and y");
  bool fixed_rotation = false;
  app.add_flag("--fixed_rotation", fixed_rotation, "do not estimate the rotation");
  app.add_option("--rotation_sigma_deg", o.rotation_prior_sigma_deg, "rotation prior sigma (deg)");
  app.add_option("--png", png, "write depth edges over colour of one frame to this PNG");
  app.add_option("--png_frame", png_frame, "frame of --png");
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  if (fixed_rotation) o.estimate_rotation = false;
  if (step < 1 || count < 1 || first < 0) {
    std::fprintf(stderr, "--step and --count must be >= 1, --first >= 0\n");
    return 2;
  }
  auto reader = exo::SevenScenesReader::Open(dir);
  if (!reader.ok()) {
    std::fprintf(stderr, "%s\n", std::string(reader.status().message()).c_str());
    return 1;
  }
  const exo::PinholeCamera depth_camera = (*reader)->camera();
  std::vector<exo::Frame> frames, held_out;
  for (size_t i = first; i < (*reader)->size() && static_cast<int>(frames.size()) < count;
       i += step) {
    auto f = (*reader)->Load(i);
    if (!f.ok()) {
      std::fprintf(stderr, "%s\n", std::string(f.status().message()).c_str());
      return 1;
    }
    frames.push_back(*std::move(f));
    // Held-out: the frame half a step later (not used for the estimate).
    if (step >= 2 && i + step / 2 < (*reader)->size()) {
      auto h = (*reader)->Load(i + step / 2);
      if (h.ok()) held_out.push_back(*std::move(h));
    }
  }
  const double cpu0 = CpuSeconds();
  auto rep = exo::EstimateDepthColorCalibration(frames, depth_camera, o);
  const double cpu_s = CpuSeconds() - cpu0;
  if (!rep.ok()) {
    std::fprintf(stderr, "%s\n", std::string(rep.status().message()).c_str());
    return 1;
  }
  exo::DepthColorCalibration identity;
  identity.color_camera = depth_camera;
  const exo::DepthColorCalibration committed = exo::SevenScenesKinectV1Calibration();
  std::string measures;
  for (const auto& [set_name, set] :
       {std::pair<const char*, const std::vector<exo::Frame>*>{"used", &frames},
        {"held_out", &held_out}}) {
    if (set->empty()) continue;
    std::string part;
    for (const auto& [name, calib] :
         {std::pair<const char*, const exo::DepthColorCalibration*>{"identity", &identity},
          {"estimate", &rep->calibration},
          {"committed", &committed}}) {
      auto m = exo::MeasureDepthColorAlignment(*set, depth_camera, *calib, o);
      if (!m.ok()) {
        std::fprintf(stderr, "%s\n", std::string(m.status().message()).c_str());
        return 1;
      }
      part += absl::StrFormat("%s\"%s\":%s", part.empty() ? "" : ",", name, MeasuresJson(*m));
    }
    measures += absl::StrFormat("%s\"%s\":{\"frames\":%d,%s}", measures.empty() ? "" : ",",
                                set_name, set->size(), part);
  }
  // RegisterDepthToColor timing with the committed calibration.
  double reg_cpu_ms = 0, reg_wall_ms = 0, raw_valid_fraction = 0, reg_valid_fraction = 0;
  for (const auto& f : frames) {
    const double c0 = CpuSeconds();
    const auto w0 = std::chrono::steady_clock::now();
    auto d = exo::RegisterDepthToColor(f.depth_m, depth_camera, committed);
    reg_wall_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - w0).count();
    reg_cpu_ms += 1e3 * (CpuSeconds() - c0);
    if (!d.ok()) return 1;
    size_t raw_valid = 0, reg_valid = 0;
    for (float z : f.depth_m.span()) raw_valid += z > 0;
    for (float z : d->span()) reg_valid += z > 0;
    raw_valid_fraction += double(raw_valid) / f.depth_m.size();
    reg_valid_fraction += double(reg_valid) / d->size();
  }
  raw_valid_fraction /= frames.size();
  reg_valid_fraction /= frames.size();
  reg_cpu_ms /= frames.size();
  reg_wall_ms /= frames.size();
  if (!png.empty()) {
    auto f = (*reader)->Load(png_frame);
    if (!f.ok()) {
      std::fprintf(stderr, "%s\n", std::string(f.status().message()).c_str());
      return 1;
    }
    auto reg = exo::RegisterDepthToColor(f->depth_m, depth_camera, committed);
    if (!reg.ok()) return 1;
    // Crop x in [120, 520), y in [40, 340) of each side (keeps the PNG small), grey background.
    const int x0 = 120, y0 = 40, CW = 400, CH = 300;
    exo::ImageU8 out(2 * CW, CH, 3);
    const uint8_t red[3] = {255, 40, 40}, green[3] = {40, 255, 40};
    for (int side = 0; side < 2; ++side) {
      exo::ImageU8 half = f->color;
      for (int y = 0; y < half.height(); ++y)
        for (int x = 0; x < half.width(); ++x) {
          const int g = (half.at(x, y, 0) * 3 + half.at(x, y, 1) * 6 + half.at(x, y, 2)) / 14;
          for (int c = 0; c < 3; ++c) half.at(x, y, c) = static_cast<uint8_t>(g);
        }
      DrawDepthEdges(side == 0 ? f->depth_m : *reg, side == 0 ? red : green, &half);
      for (int y = 0; y < CH; ++y)
        for (int x = 0; x < CW; ++x)
          for (int c = 0; c < 3; ++c)
            out.at(side * CW + x, y, c) = x == 0 && side == 1 ? 255 : half.at(x0 + x, y0 + y, c);
    }
    if (auto s = exo::WriteColorImage(png, out); !s.ok()) {
      std::fprintf(stderr, "%s\n", std::string(s.message()).c_str());
      return 1;
    }
  }
  absl::PrintF(
      "{\"dir\":\"%s\",\"first\":%d,\"step\":%d,\"frames\":%d,\"levels\":%d,\"same_focal\":%s,\"estimate_rotation\":%s,"
      "\"report\":%s,\"cpu_s\":%.2f,\"register_depth_cpu_ms\":%.3f,"
      "\"register_depth_wall_ms\":%.3f,\"raw_depth_valid_fraction\":%.4f,"
      "\"registered_depth_valid_fraction\":%.4f,\"measures\":{%s}}\n",
      dir, first, step, frames.size(), o.pyramid_levels, o.same_focal ? "true" : "false", o.estimate_rotation ? "true" : "false",
      rep->ToJson(), cpu_s, reg_cpu_ms, reg_wall_ms, raw_valid_fraction, reg_valid_fraction,
      measures);
  return 0;
}
