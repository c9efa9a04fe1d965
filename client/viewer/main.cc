// exoview_viewer: render client. Subscribes to an Exoview server, keeps the local store (with an
// optional journal to resume after a restart), then optionally renders novel views along a path
// with the Vulkan engine (lavapipe) or the CPU reference renderer and writes PNG frames, an MJPEG
// stream, per-frame timings and (for the synthetic scene) MSSIM against ground truth.
//   exoview_viewer --server=HOST:PORT [--journal=FILE] [--state_json=FILE]
//                  [--delta_log=FILE] [--follow] [--until_frames=N] [--max_seconds=S] [--settle_ms=MS]
//                  [--path=synthetic:SCENE:TRAJECTORY] [--render_frames=N]
//                  [--width=W --height=H] [--out=DIR] [--renderer=auto|vulkan|cpu] [--no_png]
// --follow: keep following the stream until SIGTERM/--max_seconds (default: stop when synced,
// i.e. same version as the server, its pipeline drained, and >= --until_frames frames received).
#include <signal.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_split.h"
#include "client/uploader/upload_client.h"
#include "client/viewer/viewer_session.h"
#include "common/io/image_file.h"
#include "common/io/jpeg.h"
#include "common/lumigraph/cpu_renderer.h"
#include "common/metrics/metrics.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "client/vulkan/vulkan_renderer.h"

namespace {

exo::ViewerSession* g_session = nullptr;
void OnSignal(int) {
  if (g_session) g_session->Stop();
}

double Ms(std::chrono::steady_clock::duration d) {
  return std::chrono::duration<double, std::milli>(d).count();
}

}  // namespace

int main(int argc, char** argv) {
  std::map<std::string, std::string> a;
  for (int i = 1; i < argc; ++i) {
    std::string s = argv[i];
    if (s.rfind("--", 0) != 0) {
      std::fprintf(stderr, "exoview_viewer: bad argument '%s'\n", s.c_str());
      return 2;
    }
    const auto eq = s.find('=');
    if (eq == std::string::npos) a[s.substr(2)] = ""; else a[s.substr(2, eq - 2)] = s.substr(eq + 1);
  }
  auto num = [&](const char* k, double def) {
    double v = def;
    if (a.count(k) && !absl::SimpleAtod(a[k], &v)) {
      std::fprintf(stderr, "exoview_viewer: --%s needs a number\n", k);
      std::exit(2);
    }
    return v;
  };
  if (!a.count("server")) {
    std::fprintf(stderr, "exoview_viewer: --server=HOST:PORT is required\n");
    return 2;
  }
  auto session = exo::ViewerSession::Open(exo::MakeChannel(a["server"]), a.count("journal") ? a["journal"] : "");
  if (!session.ok()) {
    std::fprintf(stderr, "exoview_viewer: %s\n", std::string(session.status().message()).c_str());
    return 1;
  }
  g_session = session->get();
  signal(SIGTERM, OnSignal);
  signal(SIGINT, OnSignal);
  std::ofstream delta_log;
  if (a.count("delta_log")) {  // "source_timestamp_s steady_ns bytes" per delta (CLOCK_MONOTONIC)
    delta_log.open(a["delta_log"]);
    delta_log.precision(17);
    (*session)->SetOnDelta([&](const exo::v1::Delta& d, int64_t recv_ns) {
      delta_log << d.source_timestamp_s() << " " << recv_ns << " " << d.ByteSizeLong() << "\n";
    });
  }
  exo::SyncOptions so;
  so.until_synced = !a.count("follow");
  so.max_seconds = num("max_seconds", 60);
  so.settle_ms = static_cast<int>(num("settle_ms", 400));
  so.min_server_frames = static_cast<uint64_t>(num("until_frames", 0));
  const auto t_sync = std::chrono::steady_clock::now();
  if (auto s = (*session)->Sync(so); !s.ok()) {
    std::fprintf(stderr, "exoview_viewer: %s\n", std::string(s.message()).c_str());
    return 1;
  }
  const double sync_s = Ms(std::chrono::steady_clock::now() - t_sync) * 1e-3;
  const exo::LocalStore& store = (*session)->store();
  const exo::SessionStats& ss = (*session)->stats();
  auto server = (*session)->ServerStats();
  std::string state = absl::StrCat(
      "{\"version\": ", store.version(), ", \"digest\": ", store.Digest(),
      ", \"views\": ", store.model().views.size(), ", \"cells\": ", store.model().cell_refs.size(),
      ", \"chunks\": ", store.model().chunks.size(), ", \"deltas\": ", ss.deltas,
      ", \"bytes\": ", ss.bytes, ", \"snapshots\": ", ss.snapshots,
      ", \"resumed_from\": ", ss.resumed_from, ", \"replayed\": ", ss.replayed,
      ", \"sync_s\": ", sync_s);
  if (server.ok())
    absl::StrAppend(&state, ", \"server_version\": ", server->model_version(),
                    ", \"server_digest\": ", server->model_digest());
  state += "}";
  std::fprintf(stderr, "exoview_viewer: store %s\n", state.c_str());
  if (a.count("state_json")) {
    const std::string tmp = a["state_json"] + ".tmp";
    std::ofstream(tmp) << state << "\n";
    std::filesystem::rename(tmp, a["state_json"]);
  }

  const int frames = static_cast<int>(num("render_frames", 0));
  if (frames <= 0) return 0;
  // ---- render along a path ----
  std::vector<std::string> path = absl::StrSplit(a.count("path") ? a["path"] : "synthetic:apartment:walk", ':');
  if (path.size() != 3 || path[0] != "synthetic") {
    std::fprintf(stderr, "exoview_viewer: --path must be synthetic:SCENE:TRAJECTORY\n");
    return 2;
  }
  auto kind = exo::synth::ParseSceneKind(path[1]);
  auto tkind = exo::synth::ParseTrajectoryKind(path[2]);
  if (!kind.ok() || !tkind.ok()) {
    std::fprintf(stderr, "exoview_viewer: bad --path\n");
    return 2;
  }
  auto scene = exo::synth::MakeScene(*kind, {});
  exo::synth::TrajectoryOptions to;
  to.num_frames = frames;
  auto poses = scene.ok() ? exo::synth::MakeTrajectory(*scene, *tkind, to)
                          : absl::StatusOr<std::vector<exo::synth::TimedPose>>(scene.status());
  if (!poses.ok()) {
    std::fprintf(stderr, "exoview_viewer: %s\n", std::string(poses.status().message()).c_str());
    return 1;
  }
  exo::synth::RenderOptions ro;
  ro.width = static_cast<int>(num("width", 320));
  ro.height = static_cast<int>(num("height", 240));
  const exo::PinholeCamera camera = ro.Camera();
  const std::string out = a.count("out") ? a["out"] : "viewer_out";
  std::filesystem::create_directories(out);
  const bool png = !a.count("no_png");
  const std::string which = a.count("renderer") ? a["renderer"] : "auto";
  const exo::LumigraphModel& model = store.model();
  std::string renderer_name = "cpu";
  std::unique_ptr<exo::CpuLumigraphRenderer> cpu;
  std::unique_ptr<exo::VulkanRenderer> vk;
  if (which != "cpu") {
    auto r = exo::VulkanRenderer::Create({});
    if (r.ok() && (*r)->SyncModel(model).ok()) {
      vk = *std::move(r);
      renderer_name = "vulkan:" + vk->DeviceName();
    } else if (which == "vulkan") {
      std::fprintf(stderr, "exoview_viewer: Vulkan unavailable: %s\n",
                   r.ok() ? "sync failed" : std::string(r.status().message()).c_str());
      return 1;
    }
  }
  if (!vk) {
    auto r = exo::CpuLumigraphRenderer::Create(model, {});
    if (!r.ok()) {
      std::fprintf(stderr, "exoview_viewer: %s\n", std::string(r.status().message()).c_str());
      return 1;
    }
    cpu = *std::move(r);
  }
  std::ofstream mjpeg(out + "/frames.mjpeg", std::ios::binary);
  std::vector<exo::ImageU8> rendered, truth;
  std::string timings = "[";
  double total_ms = 0;
  for (int i = 0; i < static_cast<int>(poses->size()); ++i) {
    // Synthetic poses are local to the synthetic scene (= world, origin 0); the model's frame is
    // world - model.origin.
    const exo::Rigid3d world_from_cam = (*poses)[i].local_from_cam;
    const exo::Rigid3d local_from_cam = model.origin.ToLocal(world_from_cam);
    const auto t0 = std::chrono::steady_clock::now();
    exo::ImageU8 img;
    if (vk) {
      auto r = vk->Render(camera, local_from_cam, exo::blend::BlendOptions{});
      if (!r.ok()) { std::fprintf(stderr, "exoview_viewer: %s\n", std::string(r.status().message()).c_str()); return 1; }
      img = std::move(r->color);
    }
    if (cpu) {
      auto r = cpu->Render(camera, local_from_cam);
      if (!r.ok()) { std::fprintf(stderr, "exoview_viewer: %s\n", std::string(r.status().message()).c_str()); return 1; }
      img = std::move(r->color);
    }
    const double ms = Ms(std::chrono::steady_clock::now() - t0);
    total_ms += ms;
    auto gt = exo::synth::RenderFrame(*scene, (*poses)[i].local_from_cam, ro);
    double ssim = -1;
    if (gt.ok()) {
      if (auto s = exo::Ssim(img, gt->frame.color); s.ok()) ssim = *s;
      truth.push_back(gt->frame.color);
      rendered.push_back(img);
    }
    char name[64];
    std::snprintf(name, sizeof(name), "/frame_%04d.png", i);
    if (png) (void)exo::WriteColorImage(out + name, img);
    if (auto j = exo::EncodeJpeg(img, 85); j.ok())
      mjpeg.write(reinterpret_cast<const char*>(j->data()), static_cast<std::streamsize>(j->size()));
    absl::StrAppend(&timings, i ? ", " : "", "{\"frame\": ", i, ", \"render_ms\": ", ms,
                    ", \"ssim\": ", ssim, "}");
  }
  timings += "]";
  double mssim = -1;
  if (!rendered.empty())
    if (auto m = exo::MeanSsim(rendered, truth); m.ok()) mssim = *m;
  const std::string report = absl::StrCat(
      "{\"renderer\": \"", renderer_name, "\", \"frames\": ", poses->size(), ", \"width\": ", ro.width,
      ", \"height\": ", ro.height, ", \"mean_render_ms\": ", total_ms / poses->size(),
      ", \"mssim\": ", mssim, ", \"store\": ", state, ", \"per_frame\": ", timings, "}");
  std::ofstream(out + "/viewer_report.json") << report << "\n";
  std::fprintf(stderr, "exoview_viewer: rendered %zu frames with %s, mean %.1f ms, MSSIM %.4f -> %s\n",
               poses->size(), renderer_name.c_str(), total_ms / poses->size(), mssim, out.c_str());
  return 0;
}
