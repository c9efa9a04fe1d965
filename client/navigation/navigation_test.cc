#include "client/navigation/navigation.h"

#include <gtest/gtest.h>

#include <atomic>
#include <condition_variable>
#include <cstdio>
#include <mutex>
#include <thread>
#include <filesystem>
#include <fstream>

#include "client/navigation/render_scheduler.h"
#include "client/navigation/scene_overlay.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace exo::nav {
namespace {

// A camera at the origin looking along +z with image-up = -y: the scene's up is -y.
TEST(FlyCamera, MovesAlongViewAndUpAndTurnsTheExpectedWay) {
  FlyOptions o;
  o.speed_mps = 2.0;
  FlyCamera cam(Rigid3d{}, {0, -1, 0}, o);
  FlyInput in;
  in.forward = true;
  EXPECT_TRUE(cam.Step(in, 0.5));
  EXPECT_NEAR(cam.pose().translation.z, 1.0, 1e-12);
  EXPECT_NEAR(glm::length(cam.pose().translation), 1.0, 1e-12);
  in = {};
  in.up = true;  // E: along the scene's up (-y here)
  cam.Step(in, 0.25);
  EXPECT_NEAR(cam.pose().translation.y, -0.5, 1e-12);
  in = {};
  in.right = true;  // D: along the image's +x
  cam.Step(in, 0.5);
  EXPECT_NEAR(cam.pose().translation.x, 1.0, 1e-12);
  EXPECT_FALSE(cam.Step(FlyInput{}, 1.0));  // no input: no change

  // Mouse right: forward turns towards the former right (+x); mouse down: looks down (+y).
  FlyCamera look(Rigid3d{}, {0, -1, 0}, o);
  in = {};
  in.look_dx_px = 100;
  look.Step(in, 0.01);
  const glm::dvec3 f1 = look.pose().rotation * glm::dvec3(0, 0, 1);
  EXPECT_GT(f1.x, 0.2);
  EXPECT_NEAR(f1.y, 0.0, 1e-12);  // yaw keeps the horizon
  in = {};
  in.look_dy_px = 100;
  look.Step(in, 0.01);
  const glm::dvec3 f2 = look.pose().rotation * glm::dvec3(0, 0, 1);
  EXPECT_GT(f2.y, 0.2);  // looking down = towards -up = +y
  // Pitch is clamped short of straight down; the camera's x stays horizontal (no roll).
  in.look_dy_px = 10000;
  look.Step(in, 0.01);
  const glm::dvec3 f3 = look.pose().rotation * glm::dvec3(0, 0, 1);
  EXPECT_NEAR(std::asin(f3.y), o.max_pitch_rad, 1e-9);
  EXPECT_NEAR((look.pose().rotation * glm::dvec3(1, 0, 0)).y, 0.0, 1e-9);
  // Scroll: 1.25x per click.
  in = {};
  in.wheel = 2;
  look.Step(in, 0.0);
  EXPECT_NEAR(look.speed_mps(), 2.0 * 1.25 * 1.25, 1e-12);
}

TEST(AdaptiveResolution, QuarterWhileMovingThenHalfThenFullThenReuse) {
  AdaptiveResolution a({});
  EXPECT_EQ(a.Next(true), 4);
  EXPECT_EQ(a.Next(true), 4);
  EXPECT_EQ(a.Next(false), 2);
  EXPECT_EQ(a.Next(false), 1);
  EXPECT_EQ(a.Next(false), 0);
  EXPECT_EQ(a.Next(false), 0);
  EXPECT_EQ(a.Next(true), 4);
  AdaptiveOptions off;
  off.enabled = false;
  AdaptiveResolution b(off);
  EXPECT_EQ(b.Next(false), 1);  // the first frame is always rendered
  EXPECT_EQ(b.Next(false), 0);
  EXPECT_EQ(b.Next(true), 1);
  AdaptiveOptions bad;
  bad.moving_divisor = 3;
  EXPECT_FALSE(bad.Validate().ok());
  bad.moving_divisor = 1;  // below min_divisor 2
  EXPECT_FALSE(bad.Validate().ok());
  EXPECT_TRUE(AdaptiveOptions{}.Validate().ok());
}

TEST(AdaptiveResolution, MovingDivisorFollowsTheFrameBudget) {
  AdaptiveOptions o;  // 33.3 ms, divisors 2..8, start 4
  AdaptiveResolution a(o);
  EXPECT_EQ(a.Next(true), 4);
  a.ReportMovingFrame(60);  // over budget: coarser
  EXPECT_EQ(a.Next(true), 8);
  a.ReportMovingFrame(60);  // already the coarsest
  EXPECT_EQ(a.Next(true), 8);
  a.ReportMovingFrame(20);  // fits, but 4x the pixels would not: stay
  EXPECT_EQ(a.Next(true), 8);
  a.ReportMovingFrame(5);  // 4x the pixels fits: finer
  EXPECT_EQ(a.Next(true), 4);
  a.ReportMovingFrame(5);
  EXPECT_EQ(a.Next(true), 2);
  a.ReportMovingFrame(1);  // min_divisor 2
  EXPECT_EQ(a.Next(true), 2);
  // A report for a refinement frame (not the moving divisor) changes nothing.
  EXPECT_EQ(a.Next(false), 1);
  a.ReportMovingFrame(1000);
  EXPECT_EQ(a.Next(true), 2);
  // Budget 0: fixed divisor.
  o.target_ms = 0;
  AdaptiveResolution f(o);
  EXPECT_EQ(f.Next(true), 4);
  f.ReportMovingFrame(1000);
  EXPECT_EQ(f.Next(true), 4);
}

// Picking: the ray through a pixel of a synthetic frame hits the scene at the ground-truth depth
// of that pixel (the rasterised z-depth), within one voxel (the model grid's cell size is larger).
TEST(Pick, ReturnsTheGroundTruthPointOfSyntheticPixels) {
  auto scene = synth::MakeScene(synth::SceneKind::kApartment, {});
  ASSERT_TRUE(scene.ok()) << scene.status();
  synth::TrajectoryOptions to;
  to.num_frames = 12;
  auto traj = synth::MakeTrajectory(*scene, synth::TrajectoryKind::kWalk, to);
  ASSERT_TRUE(traj.ok()) << traj.status();
  LumigraphModel model;
  model.grid.cell_size_m = 0.25;
  MeshChunk chunk;
  chunk.id = 7;
  chunk.mesh = scene->mesh;
  model.chunks[7] = chunk;
  synth::RenderOptions ro;
  ro.width = 160;
  ro.height = 120;
  const PinholeCamera cam = ro.Camera();
  const double voxel_m = 0.02;  // the server's default TSDF voxel
  int checked = 0, misses = 0;
  for (size_t f = 0; f < traj->size(); f += 3) {
    const Rigid3d& pose = (*traj)[f].local_from_cam;
    ImageF depth;
    auto lin = synth::RenderLinear(*scene, pose, ro, &depth);
    ASSERT_TRUE(lin.ok()) << lin.status();
    for (int y = 5; y < ro.height; y += 23)
      for (int x = 7; x < ro.width; x += 29) {
        const float z = depth.at(x, y);
        auto hit = Pick(model, cam, pose, {double(x), double(y)});
        if (!(z > 0)) {
          misses += hit.has_value();
          continue;
        }
        ASSERT_TRUE(hit.has_value()) << "pixel " << x << "," << y;
        EXPECT_NEAR(hit->z_depth_m, z, voxel_m) << "pixel " << x << "," << y;
        const glm::dvec3 gt = pose * cam.Unproject({double(x), double(y)}, z);
        EXPECT_LT(glm::length(hit->point_local - gt), voxel_m);
        EXPECT_EQ(hit->cell, model.grid.IdOf(hit->point_local));
        EXPECT_EQ(hit->chunk_id, 7u);
        EXPECT_NEAR(glm::length(hit->normal_local), 1.0, 1e-9);
        const glm::dvec3 to_cam = pose.translation - hit->point_local;
        EXPECT_GT(glm::dot(hit->normal_local, to_cam), 0.0);  // faces the camera
        ++checked;
      }
  }
  EXPECT_GT(checked, 50);
  EXPECT_EQ(misses, 0);
  // A ray away from everything: no hit.
  LumigraphModel tri;
  MeshChunk c;
  c.mesh.positions = {{-1, -1, 5}, {1, -1, 5}, {0, 1, 5}};
  c.mesh.indices = {0, 1, 2};
  tri.chunks[0] = c;
  const PinholeCamera pc = PinholeCamera::FromFov(100, 100, 1.0);
  EXPECT_FALSE(Pick(tri, pc, Rigid3d{}, {0, 0}).has_value());
  auto centre = Pick(tri, pc, Rigid3d{}, {49.5, 49.5});
  ASSERT_TRUE(centre.has_value());
  EXPECT_NEAR(centre->z_depth_m, 5.0, 1e-12);
}

TEST(SceneHelpers, UpBoundsAndNearestView) {
  LumigraphModel m;
  EXPECT_EQ(SceneUp(m), glm::dvec3(0, -1, 0));
  EXPECT_FALSE(NearestView(m, {0, 0, 0}).has_value());
  StoredView a, b;
  a.id = 3;
  a.local_from_cam.translation = {0, 0, 0};
  b.id = 5;
  b.local_from_cam.translation = {4, 0, 0};
  // b looks along +z with image-up = +z? Rotate b by 90 deg about x: its -y axis becomes -z.
  b.local_from_cam.rotation = glm::angleAxis(M_PI / 2, glm::dvec3(1, 0, 0));
  m.views[3] = a;
  m.views[5] = b;
  EXPECT_EQ(*NearestView(m, {3, 0, 0}), 5u);
  EXPECT_EQ(*NearestView(m, {1, 0, 0}), 3u);
  const glm::dvec3 up = SceneUp(m);
  EXPECT_NEAR(glm::length(up), 1.0, 1e-12);
  EXPECT_NEAR(up.y, -std::sqrt(0.5), 1e-9);
  const Bounds bb = ModelBounds(m);  // no mesh: the view centres
  EXPECT_NEAR(bb.Diagonal(), 4.0, 1e-12);
}

TEST(TumPath, RoundTripsAndNamesTheBadLine) {
  const std::string dir = testing::TempDir();
  const std::string file = dir + "/nav_path.txt";
  std::vector<PathPose> poses(2);
  poses[0].timestamp_s = 1.5;
  poses[0].world_from_cam.translation = {1, 2, 3};
  poses[1].timestamp_s = 2.0;
  poses[1].world_from_cam.rotation = glm::normalize(glm::dquat(0.9, 0.1, -0.3, 0.2));
  ASSERT_TRUE(WriteTumPath(file, poses).ok());
  auto back = ReadTumPath(file);
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_EQ(back->size(), 2u);
  EXPECT_NEAR((*back)[0].world_from_cam.translation.z, 3.0, 1e-9);
  EXPECT_NEAR((*back)[1].timestamp_s, 2.0, 1e-9);
  EXPECT_NEAR(
      std::abs(glm::dot((*back)[1].world_from_cam.rotation, poses[1].world_from_cam.rotation)), 1.0,
      1e-8);
  std::ofstream(file) << "# comment\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n";
  auto bad = ReadTumPath(file);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find(":3: expected 8 numbers"), std::string::npos)
      << bad.status();
  std::ofstream(file) << "1 0 0 0 0 0 0 2\n";
  EXPECT_NE(ReadTumPath(file).status().message().find("not unit"), std::string::npos);
  EXPECT_TRUE(absl::IsNotFound(ReadTumPath(dir + "/missing.txt").status()));
}


// ---- the render thread (render_scheduler.h) ----
namespace sched {

struct Log {
  std::mutex mu;
  std::condition_variable cv;
  std::vector<RenderJob> jobs;
  bool gate_open = true, in_render = false;
};

ViewRequest At(double z) {
  ViewRequest r;
  r.pose.translation = {0, 0, z};
  r.width = 64;
  r.height = 48;
  return r;
}

AdaptiveOptions Fixed4() {
  AdaptiveOptions o;
  o.moving_divisor = 4;
  o.target_ms = 0;  // keep the moving divisor
  return o;
}

// Waits (bounded) for pred; false on timeout.
template <typename P>
bool WaitFor(P pred, double seconds = 20) {
  const auto t0 = std::chrono::steady_clock::now();
  while (!pred()) {
    if (std::chrono::steady_clock::now() - t0 > std::chrono::duration<double>(seconds))
      return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return true;
}

}  // namespace sched

TEST(RenderScheduler, RefinesToFullResolutionThenStops) {
  sched::Log log;
  std::atomic<int> wakes{0};
  RenderScheduler<int> s(
      sched::Fixed4(),
      [&](const RenderJob& j, int* f) {
        std::lock_guard lock(log.mu);
        log.jobs.push_back(j);
        *f = j.divisor;
        return absl::OkStatus();
      },
      [] { return absl::StatusOr<bool>(false); }, [&] { wakes.fetch_add(1); }, 20);
  s.Post(sched::At(1));
  ASSERT_TRUE(sched::WaitFor([&] { return s.converged(); }));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));  // several idle polls: no renders
  {
    std::lock_guard lock(log.mu);
    ASSERT_EQ(log.jobs.size(), 3u);
    EXPECT_EQ(log.jobs[0].divisor, 4);
    EXPECT_TRUE(log.jobs[0].changed);
    EXPECT_EQ(log.jobs[1].divisor, 2);
    EXPECT_FALSE(log.jobs[1].changed);
    EXPECT_EQ(log.jobs[2].divisor, 1);
  }
  EXPECT_EQ(wakes.load(), 3);
  auto d = s.TakeFrame();  // only the newest is kept
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->seq, 3u);
  EXPECT_EQ(d->frame, 1);
  EXPECT_FALSE(s.TakeFrame().has_value());
  // The same view again is no work; a new epoch is.
  s.Post(sched::At(1));
  ViewRequest forced = sched::At(1);
  forced.epoch = 1;
  s.Post(forced);
  EXPECT_TRUE(sched::WaitFor([&] { return s.frames_rendered() == 6 && s.converged(); }));
}

// While a full-resolution frame renders, the UI thread posts and takes frames without waiting;
// the views posted meanwhile are coalesced into the newest, rendered next at the moving divisor.
TEST(RenderScheduler, PostAndTakeNeverWaitForARenderAndCoalesce) {
  sched::Log log;
  log.gate_open = false;
  RenderScheduler<int> s(
      sched::Fixed4(),
      [&](const RenderJob& j, int* f) {
        std::unique_lock lock(log.mu);
        log.jobs.push_back(j);
        *f = j.divisor;
        if (j.divisor == 1) {
          log.in_render = true;
          log.cv.wait(lock, [&] { return log.gate_open; });
          log.in_render = false;
        }
        return absl::OkStatus();
      },
      [] { return absl::StatusOr<bool>(false); }, [] {}, 20);
  s.Post(sched::At(1));
  ASSERT_TRUE(sched::WaitFor([&] {
    std::lock_guard lock(log.mu);
    return log.in_render;
  }));
  EXPECT_EQ(s.busy_divisor(), 1);
  s.Post(sched::At(2));  // returns although the render is blocked ...
  s.Post(sched::At(3));
  auto half = s.TakeFrame();  // ... and so does this, with the ½ frame
  {
    std::lock_guard lock(log.mu);
    EXPECT_TRUE(log.in_render);  // still blocked: nothing above waited for it
  }
  ASSERT_TRUE(half.has_value());
  EXPECT_EQ(half->job.divisor, 2);
  EXPECT_FALSE(s.converged());
  {
    std::lock_guard lock(log.mu);
    log.gate_open = true;
  }
  log.cv.notify_all();
  ASSERT_TRUE(sched::WaitFor([&] { return s.converged(); }));
  std::lock_guard lock(log.mu);
  ASSERT_EQ(log.jobs.size(), 6u);  // 4 2 1 at z=1, then 4 2 1 at z=3; z=2 never rendered
  EXPECT_EQ(log.jobs[3].request.pose.translation.z, 3.0);
  EXPECT_TRUE(log.jobs[3].changed);
  EXPECT_EQ(log.jobs[3].divisor, 4);
  EXPECT_EQ(log.jobs[5].divisor, 1);
  EXPECT_TRUE(s.status().ok());
}

TEST(RenderScheduler, ModelChangeRerendersAndErrorsStopTheWorker) {
  std::atomic<bool> model_changed{false};
  std::atomic<int> renders{0};
  std::atomic<bool> fail{false};
  RenderScheduler<int> s(
      sched::Fixed4(),
      [&](const RenderJob& j, int*) {
        renders.fetch_add(1);
        if (fail.load()) return absl::InternalError("device lost");
        return absl::OkStatus();
      },
      [&] { return absl::StatusOr<bool>(model_changed.exchange(false)); }, [] {}, 5);
  s.Post(sched::At(1));
  ASSERT_TRUE(sched::WaitFor([&] { return s.converged(); }));
  EXPECT_EQ(renders.load(), 3);
  model_changed = true;  // e.g. a live delta arrived: picked up by the idle poll
  ASSERT_TRUE(sched::WaitFor([&] { return renders.load() == 6 && s.converged(); }));
  fail = true;
  s.Post(sched::At(2));
  ASSERT_TRUE(sched::WaitFor([&] { return !s.status().ok(); }));
  EXPECT_EQ(s.status().message(), "device lost");
  s.Stop();
}

// A 0 x 0 view pauses the worker (the window shows the live DR view instead): model changes
// render nothing until a real view is posted again, which is rendered (and refined) at once.
TEST(RenderScheduler, ZeroSizedViewPausesRendering) {
  std::atomic<bool> model_changed{false};
  std::atomic<int> renders{0}, polls{0};
  RenderScheduler<int> s(
      sched::Fixed4(),
      [&](const RenderJob&, int*) {
        renders.fetch_add(1);
        return absl::OkStatus();
      },
      [&] {
        polls.fetch_add(1);
        return absl::StatusOr<bool>(model_changed.exchange(false));
      },
      [] {}, 5);
  s.Post(sched::At(1));
  ASSERT_TRUE(sched::WaitFor([&] { return s.converged(); }));
  EXPECT_EQ(renders.load(), 3);
  ViewRequest paused = sched::At(1);
  paused.width = paused.height = 0;
  s.Post(paused);
  std::this_thread::sleep_for(std::chrono::milliseconds(30));
  const int polls_paused = polls.load();
  model_changed = true;  // a live delta while paused: not rendered
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_EQ(renders.load(), 3);
  EXPECT_EQ(polls.load(), polls_paused);  // nor polled (the model syncs when the view resumes)
  s.Post(sched::At(1));  // back: the changed model is picked up and rendered 4 2 1
  ASSERT_TRUE(sched::WaitFor([&] { return renders.load() == 6 && s.converged(); }));
  EXPECT_TRUE(s.status().ok());
}

}  // namespace
}  // namespace exo::nav

namespace exo {
namespace {

// ---- scene overlays (cells by coverage τ, the drone: issues 17 and 19) ----

TEST(SceneOverlay, CoverageColourGoesFromRedThroughYellowToGreen) {
  auto rgb = [](uint32_t c) { return glm::ivec3(c & 255, (c >> 8) & 255, (c >> 16) & 255); };
  EXPECT_EQ(rgb(nav::CoverageColor(0)), glm::ivec3(255, 0, 40));     // uncovered: red
  EXPECT_EQ(rgb(nav::CoverageColor(50)), glm::ivec3(255, 255, 40));  // τ_max / 2: yellow
  EXPECT_EQ(rgb(nav::CoverageColor(100)), glm::ivec3(0, 255, 40));   // τ >= τ_max: green
  EXPECT_EQ(nav::CoverageColor(130), nav::CoverageColor(100));       // clamped
  EXPECT_EQ(nav::CoverageColor(-5), nav::CoverageColor(0));
  EXPECT_EQ(nav::CoverageColor(100, 200) >> 24, 200u);
  for (int p = 0; p < 100; ++p) {  // red never rises, green never falls with τ
    EXPECT_GE(rgb(nav::CoverageColor(p)).x, rgb(nav::CoverageColor(p + 1)).x) << p;
    EXPECT_LE(rgb(nav::CoverageColor(p)).y, rgb(nav::CoverageColor(p + 1)).y) << p;
  }
}

TEST(SceneOverlay, DroneCameraAxesFollowYawPitchAndTheSceneUp) {
  auto near = [](const glm::dvec3& a, const glm::dvec3& b) { return glm::length(a - b) < 1e-9; };
  // z up, yaw 0: forward +x, right -y (x forward / y left), down -z.
  glm::dmat3 a = nav::DroneCameraAxes({0, 0, 1}, 0.0, 0.0);
  EXPECT_TRUE(near(a[2], {1, 0, 0}));
  EXPECT_TRUE(near(a[0], {0, -1, 0}));
  EXPECT_TRUE(near(a[1], {0, 0, -1}));
  // yaw +90°: forward +y; pitch -90°: straight down, the image's right still horizontal.
  a = nav::DroneCameraAxes({0, 0, 1}, M_PI / 2, 0.0);
  EXPECT_TRUE(near(a[2], {0, 1, 0}));
  a = nav::DroneCameraAxes({0, 0, 1}, 0.0, -M_PI / 2);
  EXPECT_TRUE(near(a[2], {0, 0, -1}));
  EXPECT_NEAR(a[0].z, 0.0, 1e-12);
  // 7-Scenes: y down (up = -y): the image's down is +y for a level camera.
  a = nav::DroneCameraAxes({0, -1, 0}, 0.3, 0.0);
  EXPECT_TRUE(near(a[1], {0, 1, 0}));
  EXPECT_NEAR(a[2].y, 0.0, 1e-12);
  EXPECT_NEAR(glm::determinant(a), 1.0, 1e-12);  // right-handed: x right, y down, z forward
}

TEST(SceneOverlay, DroneOverlayLinesAreInTheLocalFrame) {
  nav::ControlView c;
  c.drone_known = true;
  c.drone = {3, 2, 1.5};
  c.yaw = 0.0;
  c.camera_pitch = -0.4;
  LocalOrigin origin;
  origin.origin_in_world = {1, 0, 0};
  nav::DroneOverlayOptions o;
  std::vector<nav::OverlayLine> lines = nav::DroneOverlayLines(c, origin, o);
  const glm::dvec3 p(2, 2, 1.5);  // the drone, scene-local
  size_t body = 0, frustum = 0;
  glm::dvec3 far_centre(0.0);
  for (const auto& l : lines) {
    if (l.kind == nav::OverlayKind::kDrone) {
      ++body;
      // Every body line lies within arm + rotor of the drone, in its horizontal plane.
      EXPECT_LE(glm::length(l.a - p), o.arm_m + o.rotor_m + 1e-9);
      EXPECT_NEAR(l.a.z, 1.5, 1e-12);
    }
    if (l.kind == nav::OverlayKind::kFrustum && glm::length(l.a - p) < 1e-12) {
      ++frustum;
      far_centre += 0.25 * l.b;
    }
    EXPECT_NE(l.kind, nav::OverlayKind::kRoute);  // no command: no route, no target
    EXPECT_NE(l.kind, nav::OverlayKind::kTarget);
  }
  EXPECT_EQ(body, 4u + 4u * 10u + 1u);  // arms, rotor rings, nose
  EXPECT_EQ(frustum, 4u);
  // The frustum looks along the heading, pitched down by 0.4 rad, frustum_m deep.
  const glm::dvec3 dir = glm::normalize(far_centre - p);
  EXPECT_NEAR(dir.x, std::cos(0.4), 1e-9);
  EXPECT_NEAR(dir.z, -std::sin(0.4), 1e-9);
  EXPECT_NEAR(glm::dot(far_centre - p, dir), o.frustum_m, 1e-9);

  // A command with a route of 3 waypoints, flying the second: 1 flown (dim), drone -> wp1,
  // wp1 -> wp2 (bright); the target's cross + heading; a box zone's 12 edges; an L prism's 3 per
  // vertex.
  c.has_command = true;
  c.target = {5, 2, 1.0};
  c.waypoints = {{3, 2, 1.5}, {4, 2, 1.2}, {5, 2, 1.0}};
  c.waypoint_index = 1;
  nav::ZoneView box;
  box.min = {0, 0, 0};
  box.max = {6, 4, 3};
  nav::ZoneView prism;
  prism.prism_axis = 2;
  prism.min = {0, 0, 0.2};
  prism.max = {2, 2, 2.5};
  prism.polygon = {{0, 0}, {2, 0}, {2, 1}, {1, 1}, {1, 2}, {0, 2}};
  c.zones = {box, prism};
  lines = nav::DroneOverlayLines(c, origin, o);
  std::vector<nav::OverlayLine> route, zone;
  size_t target = 0;
  for (const auto& l : lines) {
    if (l.kind == nav::OverlayKind::kRoute) route.push_back(l);
    if (l.kind == nav::OverlayKind::kZone) zone.push_back(l);
    if (l.kind == nav::OverlayKind::kTarget) ++target;
  }
  ASSERT_EQ(route.size(), 3u);
  EXPECT_EQ(route[0].a, glm::dvec3(2, 2, 1.5));  // flown: wp0 -> wp1
  EXPECT_EQ(route[1].a, p);                      // the drone -> the waypoint being flown
  EXPECT_EQ(route[1].b, glm::dvec3(3, 2, 1.2));
  EXPECT_EQ(route[2].b, glm::dvec3(4, 2, 1.0));  // -> the target
  EXPECT_NE(route[0].rgba, route[1].rgba);        // flown part dim
  EXPECT_EQ(target, 4u);
  ASSERT_EQ(zone.size(), 12u + 18u);
  for (size_t i = 0; i < 12; ++i)  // the box's corners, local (x - 1)
    for (const glm::dvec3& q : {zone[i].a, zone[i].b}) {
      EXPECT_TRUE(q.x == -1 || q.x == 5) << q.x;
      EXPECT_TRUE(q.z == 0 || q.z == 3) << q.z;
    }
  for (size_t i = 12; i < zone.size(); ++i)  // the prism: floor 0.2, ceiling 2.5 along z
    for (const glm::dvec3& q : {zone[i].a, zone[i].b}) EXPECT_TRUE(q.z == 0.2 || q.z == 2.5);
  // Not known: only the zones.
  c.drone_known = false;
  EXPECT_EQ(nav::DroneOverlayLines(c, origin, o).size(), 30u);
}

TEST(SceneOverlay, ProjectSegmentClipsAtTheNearPlane) {
  const PinholeCamera cam = PinholeCamera::FromFov(100, 100, M_PI / 2);
  Rigid3d at;  // identity: camera at the origin looking along +z
  auto s = nav::ProjectSegment(cam, at, {0, 0, 2}, {1, 0, 2});
  ASSERT_TRUE(s.has_value());
  EXPECT_NEAR(s->a.x, cam.cx, 1e-9);
  EXPECT_NEAR(s->b.x, cam.cx + cam.fx * 0.5, 1e-9);
  // From behind the camera to in front: clipped at z = near, still drawn.
  s = nav::ProjectSegment(cam, at, {0, 0.1, -1}, {0, 0.1, 1}, 0.05);
  ASSERT_TRUE(s.has_value());
  EXPECT_NEAR(s->a.y, cam.cy + cam.fy * 0.1 / 0.05, 1e-6);
  EXPECT_FALSE(nav::ProjectSegment(cam, at, {0, 0, -1}, {1, 0, -2}).has_value());
}

}  // namespace
}  // namespace exo
