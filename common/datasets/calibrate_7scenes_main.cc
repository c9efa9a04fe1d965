// exoview_calibrate_7scenes: estimates the depth -> colour calibration of a 7-Scenes sequence
// (Kinect v1) from its own posed RGB-D frames (EstimateDepthColorCalibration) and prints one
// JSON object: the estimate, the solver report, and the alignment measures (median multi-view
// photometric difference, median depth-edge -> colour-edge distance) of identity registration
// (colour camera = depth K), of the estimate and of the committed constant, on the frames used
// and on a disjoint set of held-out frames.
//
//   exoview_calibrate_7scenes --dir /work/shared/data/7scenes-redkitchen [--step 10] [--first 0]
//       [--count 30] [--levels 3] [--iterations 25] [--same_focal] [--threads 2]
#include <sys/resource.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "common/datasets/rgbd_registration.h"
#include "common/datasets/seven_scenes.h"

namespace {

double CpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

std::string MeasuresJson(const exo::AlignmentMeasures& m) {
  return absl::StrFormat(
      "{\"photometric_median_abs\":%.5f,\"photometric_samples\":%d,\"edge_median_px\":%.3f,"
      "\"edge_samples\":%d}",
      m.photometric_median_abs, m.photometric_samples, m.edge_median_px, m.edge_samples);
}

}  // namespace

int main(int argc, char** argv) {
  std::string dir = std::string(EXOVIEW_SOURCE_DIR) + "/../shared/data/7scenes-redkitchen";
  int step = 10, first = 0, count = 30;
  exo::CalibrationOptions o;
  for (int a = 1; a < argc; ++a) {
    auto next = [&](const char* name) -> const char* {
      if (a + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", name);
        std::exit(2);
      }
      return argv[++a];
    };
    if (!std::strcmp(argv[a], "--dir")) dir = next("--dir");
    else if (!std::strcmp(argv[a], "--step")) step = std::atoi(next("--step"));
    else if (!std::strcmp(argv[a], "--first")) first = std::atoi(next("--first"));
    else if (!std::strcmp(argv[a], "--count")) count = std::atoi(next("--count"));
    else if (!std::strcmp(argv[a], "--levels")) o.pyramid_levels = std::atoi(next("--levels"));
    else if (!std::strcmp(argv[a], "--iterations")) o.max_iterations_per_level = std::atoi(next("--iterations"));
    else if (!std::strcmp(argv[a], "--threads")) o.num_threads = std::atoi(next("--threads"));
    else if (!std::strcmp(argv[a], "--photo_weight")) o.photometric_weight = std::atof(next("--photo_weight"));
    else if (!std::strcmp(argv[a], "--edge_weight")) o.edge_weight = std::atof(next("--edge_weight"));
    else if (!std::strcmp(argv[a], "--same_focal")) o.same_focal = true;
    else if (!std::strcmp(argv[a], "--fixed_rotation")) o.estimate_rotation = false;
    else if (!std::strcmp(argv[a], "--rotation_sigma_deg")) o.rotation_prior_sigma_deg = std::atof(next("--rotation_sigma_deg"));
    else {
      std::fprintf(stderr, "unknown argument %s (see the header comment)\n", argv[a]);
      return 2;
    }
  }
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
  absl::PrintF(
      "{\"dir\":\"%s\",\"first\":%d,\"step\":%d,\"frames\":%d,\"levels\":%d,\"same_focal\":%s,\"estimate_rotation\":%s,"
      "\"report\":%s,\"cpu_s\":%.2f,\"measures\":{%s}}\n",
      dir, first, step, frames.size(), o.pyramid_levels, o.same_focal ? "true" : "false", o.estimate_rotation ? "true" : "false",
      rep->ToJson(), cpu_s, measures);
  return 0;
}
