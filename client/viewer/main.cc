// exoview_viewer: render client. Subscribes to an Exoview server, keeps the local store (with an
// optional journal to resume after a restart), optionally saves it as a model file, then renders
// novel views with the Vulkan engine (lavapipe) or the CPU reference renderer: along the input
// path of a synthetic scene (--render_frames) and at test poses off that path (--test_views per
// set: "near" = within 10 % of the scene extent of the path, "scene" = anywhere in the scene),
// each compared with the scene's ground truth (SSIM). Writes PNG frames (and ground truth with
// --gt_png), an MJPEG stream of the path, and viewer_report.json (per-view ms and SSIM, MSSIM per
// set, the store's state).
// --follow: keep following the stream until SIGTERM/--max_seconds (default: stop when synced,
// i.e. same version as the server, its pipeline drained, and >= --until_frames frames received).
#include <signal.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_split.h"
#include "client/uploader/upload_client.h"
#include "client/viewer/viewer_session.h"
#include "client/vulkan/vulkan_renderer.h"
#ifdef EXOVIEW_HAS_WINDOW
#include "client/window/window_app.h"
#endif
#include "common/cli/cli.h"
#include "common/io/image_file.h"
#include "common/io/jpeg.h"
#include "common/lumigraph/cpu_renderer.h"
#include "common/lumigraph/model_io.h"
#include "common/metrics/metrics.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace {

exo::ViewerSession* g_session = nullptr;
volatile sig_atomic_t g_signalled = 0;
void OnSignal(int) {
  g_signalled = 1;
  if (g_session) g_session->Stop();
}

double Ms(std::chrono::steady_clock::duration d) {
  return std::chrono::duration<double, std::milli>(d).count();
}

struct Flags {
  std::string server, journal, state_json, delta_log, save_model;
  exo::ChannelSecurity security;
  int save_model_jpeg_quality = 90;
  bool follow = false;
  uint64_t until_frames = 0;
  double max_seconds = 60;
  int settle_ms = 400;
  std::string path = "synthetic:apartment:walk";
  int render_frames = 0;
  int test_views = 0;
  std::vector<std::string> test_sets{"near", "scene"};
  uint64_t test_seed = 7;
  int width = 320, height = 240;
  std::string out = "viewer_out";
  std::string renderer = "auto";
  bool no_png = false;
  bool gt_png = false;
};

// One set of poses to render with its ground truth.
struct PoseSet {
  std::string name;    // "path" | "near" | "scene"
  std::string prefix;  // PNG file prefix
  std::vector<exo::Rigid3d> poses;
};

// The renderer the viewer uses: Vulkan when available (or asked), else the CPU reference.
class Renderer {
 public:
  static absl::StatusOr<Renderer> Create(const std::string& which,
                                         const exo::LumigraphModel& model) {
    Renderer r;
    if (which != "cpu") {
      auto vk = exo::VulkanRenderer::Create({});
      absl::Status st = vk.ok() ? (*vk)->SyncModel(model) : vk.status();
      if (st.ok()) {
        r.name_ = "vulkan:" + (*vk)->DeviceName();
        r.vk_ = *std::move(vk);
        return r;
      }
      if (which == "vulkan")
        return absl::UnavailableError("Vulkan unavailable: " + std::string(st.message()));
    }
    EXO_ASSIGN_OR_RETURN(r.cpu_, exo::CpuLumigraphRenderer::Create(model, {}));
    r.name_ = "cpu";
    return r;
  }
  absl::StatusOr<exo::ImageU8> Render(const exo::PinholeCamera& camera,
                                      const exo::Rigid3d& local_from_cam) {
    if (vk_) {
      EXO_ASSIGN_OR_RETURN(auto r, vk_->Render(camera, local_from_cam, exo::blend::BlendOptions{}));
      return std::move(r.color);
    }
    EXO_ASSIGN_OR_RETURN(auto r, cpu_->Render(camera, local_from_cam));
    return std::move(r.color);
  }
  const std::string& name() const { return name_; }

 private:
  std::string name_;
  std::unique_ptr<exo::VulkanRenderer> vk_;
  std::unique_ptr<exo::CpuLumigraphRenderer> cpu_;
};

int Fail(const absl::Status& s) {
  std::fprintf(stderr, "exoview_viewer: %s\n", std::string(s.message()).c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  Flags f;
  CLI::App app{
      "Render client: follows a server's model, renders novel views, compares them with ground "
      "truth.",
      "exoview_viewer"};
  exo::cli::Setup(app);
  app.add_option("--server", f.server, "server address HOST:PORT (required)");
  app.add_option("--tls_ca", f.security.tls_ca, "CA certificate (PEM) of the server's certificate: TLS");
  app.add_option("--tls_cert", f.security.tls_cert, "client certificate (PEM), for mutual TLS");
  app.add_option("--tls_key", f.security.tls_key, "client private key (PEM)");
  app.add_option("--tls_server_name", f.security.server_name, "name to verify in the server certificate");
  app.add_option("--token_file", f.security.token_file, "file holding this client's bearer token");
  app.add_option("--journal", f.journal, "delta journal file (resume after a restart)");
  app.add_option("--state_json", f.state_json,
                 "write the store's state (version, digest, counts) here");
  app.add_option("--delta_log", f.delta_log,
                 "log 'source_timestamp_s steady_ns bytes views' per delta");
  app.add_option("--save_model", f.save_model,
                 "save the synced store as a model file (model_io.h)");
  app.add_option("--save_model_jpeg_quality", f.save_model_jpeg_quality,
                 "colour of the saved model: 0 = lossless, 1..100 = JPEG quality")
      ->check(CLI::Range(0, 100));
  app.add_flag("--follow", f.follow, "follow the stream until SIGTERM or --max_seconds");
  app.add_option("--until_frames", f.until_frames,
                 "sync until the server received this many frames");
  app.add_option("--max_seconds", f.max_seconds, "give up syncing after this many seconds")
      ->check(CLI::PositiveNumber);
  app.add_option("--settle_ms", f.settle_ms, "synced = nothing changed for this long")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--path", f.path, "synthetic:SCENE:TRAJECTORY of the views to render");
  app.add_option("--render_frames", f.render_frames, "views to render along the path (0 = none)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--test_views", f.test_views, "views to render per off-path test set (0 = none)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--test_sets", f.test_sets,
                 "off-path test sets: near (near the path), scene (anywhere)")
      ->delimiter(',')
      ->check(CLI::IsMember({"near", "scene"}));
  app.add_option("--test_seed", f.test_seed, "seed of the test poses");
  app.add_option("--width", f.width, "render width (px)")->check(CLI::PositiveNumber);
  app.add_option("--height", f.height, "render height (px)")->check(CLI::PositiveNumber);
  app.add_option("--out", f.out, "output folder of frames and viewer_report.json");
  app.add_option("--renderer", f.renderer, "auto, vulkan or cpu")
      ->check(CLI::IsMember({"auto", "vulkan", "cpu"}));
  app.add_flag("--no_png", f.no_png, "do not write rendered PNGs");
  app.add_flag("--gt_png", f.gt_png, "also write each view's ground truth as PNG");
  // --window: the interactive window (client/window, also the binary exoview_window).
  bool window = false;
  std::string window_model;
  app.add_flag("--window", window, "open the interactive window (exoview_window) instead");
  app.add_option("--model", window_model, "with --window: show this model file, no server");
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  if (window) {
#ifdef EXOVIEW_HAS_WINDOW
    exo::WindowAppOptions wo;
    wo.model_file = window_model;
    wo.server = window_model.empty() ? f.server : "";
    wo.journal = f.journal;
    wo.save_model = f.save_model;
    if (app.count("--width")) wo.width = f.width;
    if (app.count("--height")) wo.height = f.height;
    return exo::RunWindowApp(wo);
#else
    std::fprintf(stderr, "exoview_viewer: built without the window (libsdl2-dev libimgui-dev)\n");
    return 2;
#endif
  }
  if (f.server.empty()) {  // checked here so that an unknown flag is the error named first
    std::fprintf(stderr, "exoview_viewer: --server HOST:PORT is required\n");
    return 2;
  }

  auto channel = exo::MakeChannel(f.server, f.security);
  if (!channel.ok()) {
    std::fprintf(stderr, "exoview_viewer: %s\n", std::string(channel.status().message()).c_str());
    return 2;
  }
  auto session = exo::ViewerSession::Open(*channel, f.journal);
  if (!session.ok()) return Fail(session.status());
  g_session = session->get();
  signal(SIGTERM, OnSignal);
  signal(SIGINT, OnSignal);
  std::ofstream delta_log;
  if (!f.delta_log.empty()) {
    // "source_timestamp_s steady_ns bytes views" per delta (steady = CLOCK_MONOTONIC; views in
    // the local store after the delta). Called under the session lock: the store is stable.
    delta_log.open(f.delta_log);
    delta_log.precision(17);
    const exo::ViewerSession* vs = session->get();
    (*session)->SetOnDelta([&delta_log, vs](const exo::v1::Delta& d, int64_t recv_ns) {
      delta_log << d.source_timestamp_s() << " " << recv_ns << " " << d.ByteSizeLong() << " "
                << vs->store().model().views.size() << "\n";
    });
  }
  exo::SyncOptions so;
  so.until_synced = !f.follow;
  so.max_seconds = f.max_seconds;
  so.settle_ms = f.settle_ms;
  so.min_server_frames = f.until_frames;
  const auto t_sync = std::chrono::steady_clock::now();
  if (!f.follow) {
    if (auto s = (*session)->Sync(so); !s.ok()) return Fail(s);
  } else {
    // --follow: a stream that ends (server or relay gone) is resumed from the store's (version,
    // epoch) on a new call; with several addresses (--server=ipv4:A,B) the channel fails over.
    for (;;) {
      const double left = f.max_seconds - Ms(std::chrono::steady_clock::now() - t_sync) * 1e-3;
      if (g_signalled || left <= 0) break;
      so.max_seconds = left;
      const absl::Status s = (*session)->Sync(so);
      if (g_signalled) break;
      std::fprintf(stderr, "exoview_viewer: stream ended at version %llu (%s); resuming\n",
                   static_cast<unsigned long long>((*session)->store().version()),
                   s.ok() ? "closed" : std::string(s.message()).c_str());
      std::this_thread::sleep_for(std::chrono::milliseconds(300));
    }
  }
  const double sync_s = Ms(std::chrono::steady_clock::now() - t_sync) * 1e-3;
  const exo::LocalStore& store = (*session)->store();
  const exo::SessionStats& ss = (*session)->stats();
  auto server = (*session)->ServerStats();
  // Defensive: a view the renderer cannot use is skipped and reported, never fatal (issue 20).
  std::vector<std::string> skipped;
  const std::optional<exo::LumigraphModel> usable =
      exo::WithoutUnusableViews(store.model(), &skipped);
  const exo::LumigraphModel& model = usable ? *usable : store.model();
  for (const std::string& s : skipped)
    std::fprintf(stderr, "exoview_viewer: skipped an unusable view: %s\n", s.c_str());
  nlohmann::json state = {{"version", store.version()},
                          {"digest", store.Digest()},
                          {"views", store.model().views.size()},
                          {"cells", store.model().cell_refs.size()},
                          {"chunks", store.model().chunks.size()},
                          {"deltas", ss.deltas},
                          {"bytes", ss.bytes},
                          {"mesh_bytes", ss.mesh_bytes},
                          {"mesh_chunk_deltas", ss.mesh_chunks},
                          {"view_bytes", ss.view_bytes},
                          {"snapshots", ss.snapshots},
                          {"resumed_from", ss.resumed_from},
                          {"replayed", ss.replayed},
                          {"sync_s", sync_s}};
  state["skipped_views"] = skipped;
  if (server.ok()) {
    state["server_version"] = server->model_version();
    state["server_digest"] = server->model_digest();
    state["server_frames_received"] = server->frames_received();
    state["server_frames_accepted"] = server->frames_accepted();
    // The server's applied-frame ledger per named uploader (frame journal, docs/security.md).
    nlohmann::json uploaders = nlohmann::json::array();
    for (const auto& u : server->uploaders())
      uploaders.push_back({{"uploader", u.uploader()},
                           {"applied_max_sequence", u.applied_max_sequence()},
                           {"applied_frames", u.applied_frames()},
                           {"double_applied", u.double_applied()}});
    state["server_uploaders"] = uploaders;
  }
  std::fprintf(stderr, "exoview_viewer: store %s\n", state.dump().c_str());
  if (!f.state_json.empty()) {
    const std::string tmp = f.state_json + ".tmp";
    std::ofstream(tmp) << state.dump(2) << "\n";
    std::filesystem::rename(tmp, f.state_json);
  }
  if (!f.save_model.empty()) {
    exo::ModelIoOptions mo;
    mo.color_jpeg_quality = f.save_model_jpeg_quality;
    if (auto s = exo::SaveModel(f.save_model, model, mo); !s.ok()) return Fail(s);
    std::fprintf(stderr, "exoview_viewer: saved the store (%zu views) to %s\n", model.views.size(),
                 f.save_model.c_str());
  }
  if (f.render_frames <= 0 && f.test_views <= 0) return 0;

  // ---- the poses to render: along the path, and off it ----
  std::vector<std::string> path = absl::StrSplit(f.path, ':');
  if (path.size() != 3 || path[0] != "synthetic") {
    std::fprintf(stderr, "exoview_viewer: --path must be synthetic:SCENE:TRAJECTORY\n");
    return 2;
  }
  auto kind = exo::synth::ParseSceneKind(path[1]);
  auto tkind = exo::synth::ParseTrajectoryKind(path[2]);
  if (!kind.ok() || !tkind.ok()) {
    std::fprintf(stderr, "exoview_viewer: bad --path '%s'\n", f.path.c_str());
    return 2;
  }
  auto scene = exo::synth::MakeScene(*kind, {});
  if (!scene.ok()) return Fail(scene.status());
  exo::synth::RenderOptions ro;
  ro.width = f.width;
  ro.height = f.height;
  const exo::PinholeCamera camera = ro.Camera();
  std::vector<PoseSet> sets;
  {
    exo::synth::TrajectoryOptions to;
    to.num_frames = std::max(f.render_frames, 200);  // dense samples: the bases of near poses
    auto dense = exo::synth::MakeTrajectory(*scene, *tkind, to);
    if (!dense.ok()) return Fail(dense.status());
    std::vector<exo::Rigid3d> bases;
    for (const auto& p : *dense) bases.push_back(p.local_from_cam);
    if (f.render_frames > 0) {
      to.num_frames = f.render_frames;
      auto on = exo::synth::MakeTrajectory(*scene, *tkind, to);
      if (!on.ok()) return Fail(on.status());
      PoseSet s{"path", "frame", {}};
      for (const auto& p : *on) s.poses.push_back(p.local_from_cam);
      sets.push_back(std::move(s));
    }
    for (const std::string& name : f.test_sets) {
      if (f.test_views <= 0) break;
      absl::StatusOr<std::vector<exo::Rigid3d>> poses;
      if (name == "near") {
        poses = exo::synth::MakeNearTestPoses(*scene, bases, camera, f.test_views, f.test_seed,
                                              *tkind == exo::synth::TrajectoryKind::kFlyover);
      } else {
        exo::synth::TestPoseOptions tpo;
        tpo.count = f.test_views;
        tpo.seed = f.test_seed;
        poses = exo::synth::MakeTestPoses(*scene, camera, tpo);
      }
      if (!poses.ok()) return Fail(poses.status());
      sets.push_back({name, name, *std::move(poses)});
    }
  }

  // ---- render and compare ----
  auto renderer = Renderer::Create(f.renderer, model);
  if (!renderer.ok()) return Fail(renderer.status());
  std::filesystem::create_directories(f.out);
  std::ofstream mjpeg(f.out + "/frames.mjpeg", std::ios::binary);
  nlohmann::json per_frame = nlohmann::json::array();
  nlohmann::json set_summary = nlohmann::json::object();
  double path_ms = 0, path_mssim = -1;
  for (const PoseSet& set : sets) {
    std::vector<exo::ImageU8> rendered, truth;
    double total_ms = 0;
    for (size_t i = 0; i < set.poses.size(); ++i) {
      // Synthetic poses are local to the synthetic scene (= world, origin 0); the model's frame
      // is world - model.origin.
      const exo::Rigid3d local_from_cam = model.origin.ToLocal(set.poses[i]);
      const auto t0 = std::chrono::steady_clock::now();
      auto img = renderer->Render(camera, local_from_cam);
      if (!img.ok()) return Fail(img.status());
      const double ms = Ms(std::chrono::steady_clock::now() - t0);
      total_ms += ms;
      auto gt = exo::synth::RenderFrame(*scene, set.poses[i], ro);
      if (!gt.ok()) return Fail(gt.status());
      auto ssim = exo::Ssim(*img, gt->frame.color);
      if (!ssim.ok()) return Fail(ssim.status());
      char name[64];
      std::snprintf(name, sizeof(name), "%s_%04zu", set.prefix.c_str(), i);
      nlohmann::json rec = {{"set", set.name}, {"index", i}, {"render_ms", ms}, {"ssim", *ssim}};
      if (!f.no_png) {
        if (auto s = exo::WriteColorImage(f.out + "/" + name + ".png", *img); !s.ok())
          return Fail(s);
        rec["png"] = std::string(name) + ".png";
      }
      if (f.gt_png) {
        if (auto s = exo::WriteColorImage(f.out + "/" + name + "_gt.png", gt->frame.color); !s.ok())
          return Fail(s);
        rec["gt_png"] = std::string(name) + "_gt.png";
      }
      if (set.name == "path")
        if (auto j = exo::EncodeJpeg(*img, 85); j.ok())
          mjpeg.write(reinterpret_cast<const char*>(j->data()),
                      static_cast<std::streamsize>(j->size()));
      per_frame.push_back(std::move(rec));
      truth.push_back(std::move(gt->frame.color));
      rendered.push_back(*std::move(img));
    }
    auto mssim = exo::MeanSsim(rendered, truth);
    if (!mssim.ok()) return Fail(mssim.status());
    const double mean_ms = total_ms / static_cast<double>(set.poses.size());
    set_summary[set.name] = {
        {"views", set.poses.size()}, {"mssim", *mssim}, {"mean_render_ms", mean_ms}};
    if (set.name == "path") {
      path_ms = mean_ms;
      path_mssim = *mssim;
    }
    std::fprintf(stderr, "exoview_viewer: %s: %zu views with %s, mean %.1f ms, MSSIM %.4f\n",
                 set.name.c_str(), set.poses.size(), renderer->name().c_str(), mean_ms, *mssim);
  }
  const nlohmann::json report = {
      {"renderer", renderer->name()},
      {"path", f.path},
      {"frames", f.render_frames},
      {"width", ro.width},
      {"height", ro.height},
      {"mean_render_ms", path_ms},  // along the path (kept from the first report format)
      {"mssim", path_mssim},
      {"sets", set_summary},
      {"test_seed", f.test_seed},
      {"store", state},
      {"per_frame", per_frame}};
  std::ofstream(f.out + "/viewer_report.json") << report.dump(1) << "\n";
  std::fprintf(stderr, "exoview_viewer: report -> %s/viewer_report.json\n", f.out.c_str());
  return 0;
}
