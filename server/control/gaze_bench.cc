// Gaze-to-see benchmark (issue 19 metrics): the model is built the way the server builds it
// (TSDF proxy fused from frames rendered along the scene's eye-height walk, the occupancy view
// from the TSDF + the frames' depth carved + the proxy's cells), then N random gaze rays from
// eye positions on the walk. Each ray: gaze-to-see on the proxy, safe-flight route, a closed-loop
// flight of the simulated drone to the target (waypoints streamed by the control core), and a
// render of the drone camera's view at arrival. Reports, as one JSON line, the fraction of rays
// whose target is reachable, whose drone arrives, and whose frame sees P_gaze (unoccluded, by
// the ground-truth depth) within the central third of the image; collisions against the ground
// truth mesh; and the interaction cost (ray cast + plan) p50/p95.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <random>

#include "common/cli/cli.h"
#include "common/drone/sim_drone.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/control/control_core.h"
#include "server/geometry/tsdf_volume.h"

namespace {

using namespace exo;
using namespace exo::control;

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(p * (v.size() - 1) + 0.5))];
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Gaze-to-see benchmark: reachable fraction and P_gaze in the central third.",
               "exoview_gaze_bench"};
  exo::cli::Setup(app);
  std::string scene_name = "apartment";
  int rays = 100, frames = 80, width = 320, height = 240;
  uint64_t seed = 1;
  double cell_m = 0.1, voxel_m = 0.05, max_flight_s = 40;
  app.add_option("--scene", scene_name, "apartment | village");
  app.add_option("--rays", rays, "gaze rays")->check(CLI::PositiveNumber);
  app.add_option("--frames", frames, "walk frames fused into the model")
      ->check(CLI::PositiveNumber);
  app.add_option("--width", width, "frame width")->check(CLI::PositiveNumber);
  app.add_option("--height", height, "frame height")->check(CLI::PositiveNumber);
  app.add_option("--seed", seed, "ray seed");
  app.add_option("--cell_m", cell_m, "occupancy cell")->check(CLI::PositiveNumber);
  app.add_option("--voxel_m", voxel_m, "TSDF voxel")->check(CLI::PositiveNumber);
  app.add_option("--max_flight_s", max_flight_s, "flight time limit per ray")
      ->check(CLI::PositiveNumber);
  bool gimbal = true;
  app.add_option("--gimbal", gimbal,
                 "the camera pitches to face P_gaze from the reached target (false: level camera)");
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;

  auto fail = [](const absl::Status& s) {
    std::fprintf(stderr, "exoview_gaze_bench: %s\n", std::string(s.message()).c_str());
    return 1;
  };
  auto kind = synth::ParseSceneKind(scene_name);
  if (!kind.ok()) return fail(kind.status());
  auto scene = synth::MakeScene(*kind, synth::SceneOptions{});
  if (!scene.ok()) return fail(scene.status());
  synth::TrajectoryOptions to;
  to.num_frames = frames;
  auto walk = synth::MakeTrajectory(*scene, synth::TrajectoryKind::kWalk, to);
  if (!walk.ok()) return fail(walk.status());
  synth::RenderOptions ro;
  ro.width = width;
  ro.height = height;

  // ---- the model, as the server builds it ----
  const auto t_model = std::chrono::steady_clock::now();
  TsdfOptions tso;
  tso.voxel_size_m = static_cast<float>(voxel_m);
  tso.integrate_color = false;
  TsdfVolume tsdf(tso);
  std::vector<synth::RenderedFrame> rendered;
  for (const auto& p : *walk) {
    auto r = synth::RenderFrame(*scene, p.local_from_cam, ro);
    if (!r.ok()) return fail(r.status());
    if (auto s = tsdf.IntegrateDepth(r->frame.depth_m, r->frame.depth_camera, p.local_from_cam);
        !s.ok())
      return fail(s.status());
    rendered.push_back(*std::move(r));
  }
  const TriangleMesh proxy = tsdf.ExtractAll();
  ControlCoreOptions co;
  co.safe.zones = {{"navigable", scene->navigable.min, scene->navigable.max}};
  co.safe.cell_m = cell_m;
  co.safe.drone_radius_m = 0.2;
  auto core_or = ControlCore::Create(co);
  if (!core_or.ok()) return fail(core_or.status());
  ControlCore& core = **core_or;
  core.UpsertChunk(1, proxy);
  core.WithSafeFlight([&](SafeFlight& s) {
    s.grid().MarkFromTsdf(tsdf, glm::dvec3(0.0));
    for (size_t i = 0; i < rendered.size(); ++i)
      s.grid().CarveDepth(rendered[i].frame.depth_m, rendered[i].frame.depth_camera,
                          (*walk)[i].local_from_cam, 2, 6.0);
  });
  const double model_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_model).count();

  // ---- the rays ----
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u01(0, 1);
  const SceneFrame frame = SceneFrame::ZUp();
  const PinholeCamera cam = ro.Camera();
  int hits = 0, horizontal = 0, reachable = 0, clamped = 0, arrived = 0, central = 0,
      central_of_arrived = 0, no_path = 0;
  uint64_t collisions_total = 0;
  double min_clearance = 1e9;
  std::vector<double> interaction_ms, flight_s;
  for (int i = 0; i < rays; ++i) {
    const auto& pose = (*walk)[static_cast<size_t>(u01(rng) * walk->size()) % walk->size()];
    const glm::dvec3 eye = pose.local_from_cam.translation;
    const double yaw = u01(rng) * 2 * kPi, elev = (-40 + 50 * u01(rng)) * kPi / 180;
    const glm::dvec3 dir = std::cos(elev) * frame.Heading(yaw) + std::sin(elev) * frame.up;
    // The drone starts next to the user (where the walk went: known free space).
    SimDrone drone{SimDroneOptions{}};
    drone.Reset(eye, yaw);
    core.OnDroneState("drone", drone.state(), 0);
    const auto t0 = std::chrono::steady_clock::now();
    auto r = core.GazeToSee({"bench", static_cast<uint64_t>(i + 1), "drone"}, eye, dir, 0);
    interaction_ms.push_back(
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    if (!r.ok()) {
      if (r.status().code() == absl::StatusCode::kNotFound &&
          r.status().message().find("no path") != std::string_view::npos) {
        ++hits;
        ++no_path;
      }
      continue;  // sky (no hit) or no path
    }
    ++hits;
    ++reachable;
    horizontal += r->gaze->horizontal_surface;
    clamped += r->route.clamped;
    CollisionMonitor collisions(scene->mesh, drone.options().radius_m);
    double t_arrive = -1;
    for (int k = 0; k < static_cast<int>(max_flight_s * 120); ++k) {
      const double now = drone.state().timestamp_s;
      core.OnDroneState("drone", drone.state(), now);
      if (auto sp = core.NextSetpoint("drone", now)) drone.Receive(sp->setpoint, now);
      const DroneState& s = drone.Step();
      collisions.Update(s.position);
      if (glm::length(s.position - r->target.position) < 0.1 && glm::length(s.velocity) < 0.1 &&
          std::abs(WrapAngle(s.yaw - r->target.yaw)) < 0.05) {
        t_arrive = s.timestamp_s;
        break;
      }
    }
    collisions_total += collisions.collisions();
    min_clearance = std::min(min_clearance, collisions.min_clearance_m());
    if (t_arrive < 0) continue;
    ++arrived;
    flight_s.push_back(t_arrive);
    // The drone camera's view (facing its yaw; level, or pitched by the gimbal towards P_gaze
    // from the target the route reached, which safe flight may have clamped) and the
    // ground-truth depth.
    const glm::dvec3 p = drone.state().position;
    const double pitch = gimbal ? CameraPitchToward(r->target.position, r->gaze->hit.point, frame)
                                : 0.0;
    const Rigid3d local_from_cam = synth::LookAt(
        p, p + std::cos(pitch) * frame.Heading(drone.state().yaw) + std::sin(pitch) * frame.up);
    ImageF z;
    if (!synth::RenderLinear(*scene, local_from_cam, ro, &z).ok()) continue;
    const glm::dvec3 pc = local_from_cam.Inverse() * r->gaze->hit.point;
    glm::dvec2 uv;
    if (!cam.Project(pc, &uv)) continue;
    const bool in_third = uv.x >= cam.width / 3.0 && uv.x < 2 * cam.width / 3.0 &&
                          uv.y >= cam.height / 3.0 && uv.y < 2 * cam.height / 3.0;
    const int px = static_cast<int>(std::lround(uv.x)), py = static_cast<int>(std::lround(uv.y));
    const bool visible =
        z.Contains(px, py) && std::abs(z.at(px, py) - pc.z) < std::max(0.05, 0.03 * pc.z);
    if (in_third && visible) {
      ++central;
      ++central_of_arrived;
    }
  }
  nlohmann::json j;
  j["bench"] = "gaze_to_see";
  j["scene"] = scene_name;
  j["rays"] = rays;
  j["gimbal"] = gimbal;
  j["model"] = {{"frames", frames},
                {"proxy_triangles", proxy.num_triangles()},
                {"free_cells", core.CountCells(Occupancy::kFree)},
                {"occupied_cells", core.CountCells(Occupancy::kOccupied)},
                {"build_s", model_s}};
  j["hit_fraction"] = static_cast<double>(hits) / rays;
  j["horizontal_surface_fraction_of_reachable"] = reachable ? double(horizontal) / reachable : 0.0;
  j["reachable_fraction"] = static_cast<double>(reachable) / rays;
  j["no_path"] = no_path;
  j["clamped_fraction_of_reachable"] = reachable ? double(clamped) / reachable : 0.0;
  j["arrived_fraction"] = static_cast<double>(arrived) / rays;
  j["central_third_fraction"] = static_cast<double>(central) / rays;
  j["central_third_fraction_of_arrived"] = arrived ? double(central_of_arrived) / arrived : 0.0;
  j["collisions"] = collisions_total;
  j["min_clearance_m"] = min_clearance;
  j["flight_s_p50"] = Percentile(flight_s, 0.5);
  j["flight_s_p95"] = Percentile(flight_s, 0.95);
  j["interaction_ms_p50"] = Percentile(interaction_ms, 0.5);
  j["interaction_ms_p95"] = Percentile(interaction_ms, 0.95);
  std::printf("%s\n", j.dump().c_str());
  return 0;
}
