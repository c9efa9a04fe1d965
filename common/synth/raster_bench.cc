// raster_bench: CPU reference rasterizer speed on the synthetic scene meshes, with error side by
// side (depth vs brute-force ray casting on sampled pixels), plus full frame rendering (shading).
// Prints one JSON object per configuration.
//   raster_bench [--iters N] [--threads T]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/cli/cli.h"
#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace exo::synth {
namespace {

using Clock = std::chrono::steady_clock;
using json = nlohmann::ordered_json;  // fields in the order written

// Rounds to `digits` decimals for the JSON lines.
double Round(double x, int digits) {
  const double f = std::pow(10.0, digits);
  return std::round(x * f) / f;
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Nearest hit z-depth along the pixel ray (camera frame), 0 when none.
double RayCastZ(const TriangleMesh& mesh, const std::vector<glm::dvec3>& p_cam,
                const glm::dvec3& dir, double near_m) {
  double best = 0;
  for (size_t t = 0; t < mesh.num_triangles(); ++t) {
    const glm::dvec3& p0 = p_cam[mesh.indices[3 * t]];
    const glm::dvec3 e1 = p_cam[mesh.indices[3 * t + 1]] - p0,
                     e2 = p_cam[mesh.indices[3 * t + 2]] - p0;
    const glm::dvec3 pv = glm::cross(dir, e2);
    const double det = glm::dot(e1, pv);
    if (std::abs(det) < 1e-14) continue;
    const double u = glm::dot(-p0, pv) / det;
    if (u < 0 || u > 1) continue;
    const glm::dvec3 qv = glm::cross(-p0, e1);
    const double v = glm::dot(dir, qv) / det;
    if (v < 0 || u + v > 1) continue;
    const double z = glm::dot(e2, qv) / det;  // dir has z = 1: t is the z-depth
    if (z >= near_m && (best == 0 || z < best)) best = z;
  }
  return best;
}

void Run(int iters, int threads) {
  struct Config {
    SceneKind scene;
    TrajectoryKind traj;
  };
  for (Config c : {Config{SceneKind::kVillage, TrajectoryKind::kFlyover},
                   Config{SceneKind::kVillage, TrajectoryKind::kWalk},
                   Config{SceneKind::kApartment, TrajectoryKind::kWalk}}) {
    auto scene = MakeScene(c.scene, {});
    TrajectoryOptions to;
    to.num_frames = 9;
    auto traj = MakeTrajectory(*scene, c.traj, to);
    if (!scene.ok() || !traj.ok()) {
      std::fprintf(stderr, "setup failed\n");
      std::exit(1);
    }
    const Rigid3d pose = (*traj)[3].local_from_cam;
    for (auto [w, h] : {std::pair{640, 480}, std::pair{1280, 720}}) {
      RenderOptions render;
      render.width = w;
      render.height = h;
      render.num_threads = threads;
      const PinholeCamera cam = render.Camera();
      for (bool all : {false, true}) {
        RasterOptions ro;
        ro.num_threads = threads;
        ro.near_m = 0.05;
        if (all) {
          ro.range = ro.position = ro.normal = ro.triangle_id = ro.cell_id = true;
          ro.cell_grid.cell_size_m = 0.5;
        }
        std::vector<double> ms;
        RasterOutput out;
        for (int i = 0; i < iters; ++i) {
          const auto t0 = Clock::now();
          auto r = Rasterize(scene->mesh, cam, pose, ro);
          ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
          if (!r.ok()) std::exit(1);
          out = std::move(*r);
        }
        // Error: depth vs ray casting on a pixel grid (hit/miss agreement and max rel error).
        const Rigid3d cam_from_local = pose.Inverse();
        std::vector<glm::dvec3> p_cam;
        for (const glm::vec3& p : scene->mesh.positions) p_cam.push_back(cam_from_local * glm::dvec3(p));
        int samples = 0, agree = 0;
        double max_rel = 0;
        for (int y = 7; y < h; y += h / 12)
          for (int x = 5; x < w; x += w / 16) {
            const double z = RayCastZ(scene->mesh, p_cam, cam.RayZ1({x, y}), ro.near_m);
            const double zr = out.z_depth_m.at(x, y);
            ++samples;
            if ((z > 0) == (zr > 0)) {
              ++agree;
              if (z > 0) max_rel = std::max(max_rel, std::abs(zr - z) / z);
            }
          }
        const json line = {
            {"bench", "raster"},
            {"scene", scene->name},
            {"view", TrajectoryKindName(c.traj)},
            {"width", w},
            {"height", h},
            {"triangles", scene->mesh.num_triangles()},
            {"triangles_setup", out.triangles_setup},
            {"outputs", all ? "z,range,position,normal,triangle,cell" : "z"},
            {"threads", threads},
            {"ms_median", Round(Median(ms), 2)},
            {"ms_min", Round(*std::min_element(ms.begin(), ms.end()), 2)},
            {"covered_fraction", Round(double(out.pixels_covered) / (w * h), 3)},
            {"raycast_samples", samples},
            {"hit_agreement", Round(double(agree) / samples, 4)},
            {"max_rel_depth_err", max_rel}};
        std::printf("%s\n", line.dump().c_str());
        std::fflush(stdout);
      }
      // Full frame: raster + procedural shading + sRGB.
      std::vector<double> ms;
      for (int i = 0; i < std::max(1, iters / 4); ++i) {
        const auto t0 = Clock::now();
        auto f = RenderFrame(*scene, pose, render);
        ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        if (!f.ok()) std::exit(1);
      }
      const json line = {{"bench", "render_frame"},
                         {"scene", scene->name},
                         {"view", TrajectoryKindName(c.traj)},
                         {"width", w},
                         {"height", h},
                         {"triangles", scene->mesh.num_triangles()},
                         {"threads", threads},
                         {"ms_median", Round(Median(ms), 2)}};
      std::printf("%s\n", line.dump().c_str());
      std::fflush(stdout);
    }
  }
}

}  // namespace
}  // namespace exo::synth

int main(int argc, char** argv) {
  int iters = 20, threads = 2;
  CLI::App app{"CPU reference rasterizer speed on the synthetic scenes, with the depth error vs ray "
               "casting side by side; one JSON object per configuration on stdout.",
               "raster_bench"};
  exo::cli::Setup(app);
  app.add_option("--iters", iters, "rasterizations per configuration")->check(CLI::PositiveNumber);
  app.add_option("--threads", threads, "rasterizer threads")->check(CLI::PositiveNumber);
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  exo::synth::Run(iters, threads);
  return 0;
}
