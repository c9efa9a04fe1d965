// geometry_bench: speed vs error of the sparse TSDF proxy over voxel sizes.
//
//   geometry_bench [--data DIR] [--frames N] [--synth_frames N] [--voxels 0.01,0.02,0.04,0.08]
//
// Datasets:
// - 7-Scenes redkitchen (real Kinect v1): frames 0..N-1 via common/datasets' SevenScenesReader
//   (depth camera's K and pose; colour not registered, used as is); every 10th frame is
//   held out (not integrated) and its valid depth pixels, back-projected with its pose, give the
//   geometric error: |TSDF(p)| at those points (median, mean; only where the field is observed)
//   and the fraction of held-out points on observed field ("coverage").
// - synthetic room (analytic): a 6 x 5 x 3 m box with spheres, depth rendered by exact ray
//   intersection at 640x480 along a circling trajectory; error = distance of every mesh vertex
//   to the true surface (mean, p95).
// Prints one JSON object per (dataset, voxel size, alloc stride, repeat): integrate ms/frame
// (wall median, p95; process CPU median), incremental extraction ms/frame (median, p95), full
// extraction ms, triangles, blocks, bytes, error. --alloc_strides 1,4 --repeats 3 interleaves the
// per-pixel reference and the subsampled allocation in one run (same frames, same process).
// Chart of these lines: tools/charts/geometry_chart.py (matplotlib).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/cli/cli.h"
#include "common/datasets/seven_scenes.h"
#include "server/geometry/test_scenes.h"
#include "server/geometry/tsdf_volume.h"
#include "exoview_source_dir.h"

namespace exo {
namespace {

using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}
double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(q * (v.size() - 1) + 0.5))];
}

// CPU time of the whole process (all threads), ms.
double CpuMs() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

struct Result {
  std::string dataset;
  double voxel_m = 0;
  int frames = 0, alloc_stride = 1, threads = 1, repeat = 0;
  double integrate_med = 0, integrate_p95 = 0, integrate_cpu_med = 0;
  double extract_med = 0, extract_p95 = 0, extract_all = 0;
  size_t triangles = 0, blocks = 0, bytes = 0, mesh_bytes = 0;
  double err_a = 0, err_b = 0, coverage = 0;  // meaning per dataset (see header)
};

// Rounds to `digits` decimals for the JSON lines.
double Round(double x, int digits) {
  const double f = std::pow(10.0, digits);
  return std::round(x * f) / f;
}

void Print(const Result& r, const char* err_a_name, const char* err_b_name) {
  const nlohmann::ordered_json line = {{"bench", "geometry"},
                                       {"dataset", r.dataset},
                                       {"frames", r.frames},
                                       {"voxel_m", Round(r.voxel_m, 3)},
                                       {"alloc_stride", r.alloc_stride},
                                       {"threads", r.threads},
                                       {"repeat", r.repeat},
                                       {"integrate_ms_median", Round(r.integrate_med, 2)},
                                       {"integrate_cpu_ms_median", Round(r.integrate_cpu_med, 2)},
                                       {"integrate_ms_p95", Round(r.integrate_p95, 2)},
                                       {"extract_dirty_ms_median", Round(r.extract_med, 2)},
                                       {"extract_dirty_ms_p95", Round(r.extract_p95, 2)},
                                       {"extract_all_ms", Round(r.extract_all, 1)},
                                       {"triangles", r.triangles},
                                       {"blocks", r.blocks},
                                       {"tsdf_bytes", r.bytes},
                                       {"mesh_bytes", r.mesh_bytes},
                                       {err_a_name, Round(r.err_a, 2)},
                                       {err_b_name, Round(r.err_b, 2)},
                                       {"coverage", Round(r.coverage, 3)}};
  std::printf("%s\n", line.dump().c_str());
  std::fflush(stdout);
}

// Integrates `frames` (a function giving frame i) and times each step.
// Without extract_every_frame only integration runs per frame (the final full extraction still
// runs).
template <typename GetFrame>
Result Run(const std::string& name, double voxel, int n, GetFrame get, std::vector<bool> skip,
           bool extract_every_frame, TsdfVolume* vol) {
  Result r;
  r.dataset = name;
  r.voxel_m = voxel;
  r.alloc_stride = vol->options().alloc_stride;
  r.threads = vol->options().num_threads;
  std::vector<double> integ, integ_cpu, extr;
  for (int i = 0; i < n; ++i) {
    if (!skip.empty() && skip[i]) continue;
    const Frame f = get(i);
    const double c0 = CpuMs();
    auto t0 = Clock::now();
    auto s = vol->Integrate(f, LocalOrigin{});
    integ.push_back(MsSince(t0));
    integ_cpu.push_back(CpuMs() - c0);
    if (!s.ok()) {
      std::fprintf(stderr, "frame %d: %s\n", i, std::string(s.status().message()).c_str());
      std::exit(1);
    }
    if (!extract_every_frame) continue;
    t0 = Clock::now();
    auto chunks = vol->ExtractDirtyChunks();
    extr.push_back(MsSince(t0));
  }
  r.frames = int(integ.size());
  r.integrate_med = Percentile(integ, 0.5);
  r.integrate_cpu_med = Percentile(integ_cpu, 0.5);
  r.integrate_p95 = Percentile(integ, 0.95);
  r.extract_med = Percentile(extr, 0.5);
  r.extract_p95 = Percentile(extr, 0.95);
  const auto t0 = Clock::now();
  const TriangleMesh mesh = vol->ExtractAll();
  r.extract_all = MsSince(t0);
  r.triangles = mesh.num_triangles();
  r.mesh_bytes = mesh.bytes();
  r.blocks = vol->num_blocks();
  r.bytes = vol->bytes();
  return r;
}

// ---- synthetic room ----
struct Primitive {
  bool sphere;
  glm::dvec3 a;  // centre or normal
  double b;      // radius or offset
  double Distance(const glm::dvec3& p) const {
    return sphere ? std::abs(glm::length(p - a) - b) : std::abs(glm::dot(a, p) - b);
  }
};
std::vector<Primitive> RoomPrimitives() {
  return {{false, {1, 0, 0}, -3.0}, {false, {1, 0, 0}, 3.0},  {false, {0, 1, 0}, -2.5},
          {false, {0, 1, 0}, 2.5},  {false, {0, 0, 1}, 0.0},  {false, {0, 0, 1}, 3.0},
          {true, {1.2, 0.8, 0.6}, 0.6}, {true, {-1.5, -1.0, 0.4}, 0.4}, {true, {0.3, -1.6, 1.2}, 0.35},
          {true, {-0.8, 1.4, 0.9}, 0.5}};
}

}  // namespace

}  // namespace exo

int main(int argc, char** argv) {
  using namespace exo;
  std::string data = std::string(EXOVIEW_SOURCE_DIR) + "/../shared/data/7scenes-redkitchen";
  if (const char* e = std::getenv("EXOVIEW_SHARED_DIR")) data = std::string(e) + "/data/7scenes-redkitchen";
  int frames = 300, synth_frames = 120;
  std::vector<double> voxels = {0.01, 0.02, 0.04, 0.08};
  std::vector<int> strides = {TsdfOptions().alloc_stride};
  int threads = TsdfOptions().num_threads, repeats = 1;
  bool extract_every_frame = true;
  CLI::App app{"Speed vs error of the sparse TSDF proxy over voxel sizes (synthetic room and "
               "7-Scenes redkitchen); one JSON object per dataset and voxel size.",
               "geometry_bench"};
  exo::cli::Setup(app);
  app.add_option("--data", data, "7-Scenes redkitchen folder");
  app.add_option("--frames", frames, "7-Scenes frames (0: skip 7-Scenes)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--synth_frames", synth_frames, "synthetic room frames (0: skip it)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--voxels", voxels, "voxel sizes in m, comma-separated")
      ->delimiter(',')
      ->check(CLI::PositiveNumber);
  app.add_option("--alloc_strides", strides,
                 "TsdfOptions.alloc_stride values to run (1 = per-pixel allocation), "
                 "comma-separated; interleaved per repeat")
      ->delimiter(',')
      ->check(CLI::Range(1, 64));
  app.add_option("--threads", threads, "TsdfOptions.num_threads")->check(CLI::Range(1, 64));
  app.add_option("--repeats", repeats, "runs per voxel size and stride (interleaved)")
      ->check(CLI::PositiveNumber);
  app.add_option("--extract_every_frame", extract_every_frame,
                 "incremental extraction after every frame (false: integration only)");
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  std::vector<Result> results;

  // Synthetic room: render once, reuse for every voxel size.
  if (synth_frames > 0) {
    const auto prims = RoomPrimitives();
    std::vector<geometry_test::HitFn> fns;
    for (const auto& p : prims)
      fns.push_back(p.sphere ? geometry_test::Sphere(p.a, p.b) : geometry_test::Plane(p.a, p.b));
    const auto hit = geometry_test::Union(fns);
    const PinholeCamera cam = PinholeCamera::FromFov(640, 480, 65.0 * M_PI / 180);
    std::vector<Frame> fr;
    for (int i = 0; i < synth_frames; ++i) {
      const double t = 2 * M_PI * i / synth_frames;
      const glm::dvec3 eye(1.6 * std::cos(t), 1.3 * std::sin(t), 1.5 + 0.4 * std::sin(3 * t));
      const glm::dvec3 target(-2.5 * std::cos(t + 0.9), -2.0 * std::sin(t + 0.9), 0.8);
      const Rigid3d pose = geometry_test::LookAt(eye, target);
      fr.push_back(geometry_test::MakeFrame(cam, pose, geometry_test::RenderDepth(cam, pose, hit),
                                            [](const glm::dvec3& p) {
                                              const int c = (int(std::floor(p.x * 4)) + int(std::floor(p.y * 4)) + int(std::floor(p.z * 4))) & 1;
                                              return c ? glm::u8vec3(220, 200, 160) : glm::u8vec3(60, 90, 140);
                                            }));
    }
    for (double vs : voxels) for (int rep = 0; rep < repeats; ++rep) for (int stride : strides) {
      TsdfOptions o;
      o.voxel_size_m = float(vs);
      o.max_depth_m = 8.0f;
      o.alloc_stride = stride;
      o.num_threads = threads;
      TsdfVolume vol(o);
      Result r = Run("synthetic-room", vs, synth_frames, [&](int i) { return fr[i]; }, {},
                     extract_every_frame, &vol);
      r.repeat = rep;
      const TriangleMesh m = vol.ExtractAll();
      std::vector<double> err;
      err.reserve(m.positions.size());
      for (const auto& p : m.positions) {
        double d = 1e9;
        for (const auto& pr : prims) d = std::min(d, pr.Distance(glm::dvec3(p)));
        err.push_back(d * 1000);
      }
      double sum = 0;
      for (double e : err) sum += e;
      r.err_a = err.empty() ? 0 : sum / err.size();
      r.err_b = Percentile(err, 0.95);
      r.coverage = 1.0;
      Print(r, "vertex_err_mm_mean", "vertex_err_mm_p95");
      results.push_back(r);
    }
  }

  // 7-Scenes redkitchen.
  if (frames > 0) {
    auto reader_or = SevenScenesReader::Open(data);
    if (!reader_or.ok()) {
      std::fprintf(stderr, "no 7-Scenes data at %s (%s); skipping\n", data.c_str(),
                   std::string(reader_or.status().message()).c_str());
    } else {
      const SevenScenesReader& reader = **reader_or;
      frames = std::min<int>(frames, int(reader.size()));
      auto load = [&](int i) {
        auto f = reader.Load(i);
        if (!f.ok()) {
          std::fprintf(stderr, "%s\n", std::string(f.status().message()).c_str());
          std::exit(1);
        }
        return *std::move(f);
      };
      const PinholeCamera& kcam = reader.camera();
      std::vector<bool> held_out(frames);
      for (int i = 0; i < frames; ++i) held_out[i] = i % 10 == 0;
      for (double vs : voxels) for (int rep = 0; rep < repeats; ++rep) for (int stride : strides) {
        TsdfOptions o;
        o.voxel_size_m = float(vs);
        o.max_depth_m = 4.0f;
        o.alloc_stride = stride;
        o.num_threads = threads;
        TsdfVolume vol(o);
        Result r = Run("7scenes-redkitchen", vs, frames, load, held_out, extract_every_frame, &vol);
        r.repeat = rep;
        std::vector<double> err;
        size_t total = 0;
        for (int i = 0; i < frames; i += 10) {
          const Frame f = load(i);
          const glm::dmat3 rot = f.world_from_cam.RotationMatrix();
          for (int v = 0; v < 480; v += 4)
            for (int u = 0; u < 640; u += 4) {
              const float d = f.depth_m.at(u, v);
              if (!(d > 0.1f && d < 4.0f)) continue;
              ++total;
              const glm::dvec3 p = f.world_from_cam.translation + rot * kcam.Unproject({double(u), double(v)}, d);
              float s;
              if (vol.SdfAt(glm::vec3(p), &s)) err.push_back(std::abs(s) * 1000);
            }
        }
        double sum = 0;
        for (double e : err) sum += e;
        r.err_a = err.empty() ? 0 : sum / err.size();
        r.err_b = Percentile(err, 0.5);
        r.coverage = total ? double(err.size()) / total : 0;
        Print(r, "heldout_abs_sdf_mm_mean", "heldout_abs_sdf_mm_median");
        results.push_back(r);
      }
    }
  }
  return 0;
}
