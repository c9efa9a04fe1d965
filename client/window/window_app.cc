#include "client/window/window_app.h"

#include <SDL2/SDL.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <span>
#include <thread>
#include <vector>

#include "client/navigation/drone_ops.h"
#include "client/navigation/navigation.h"
#include "client/navigation/render_scheduler.h"
#include "client/navigation/scene_overlay.h"
#include "client/store/local_store.h"
#include "client/uploader/upload_client.h"
#include "client/viewer/viewer_session.h"
#include "client/vulkan/vulkan_renderer.h"
#include "client/window/drone_operator.h"
#include "client/window/dr_view_watch.h"
#include "client/window/completion_request.h"
#include "client/window/http_view.h"
#include "client/window/presenter.h"
#include "common/io/image_file.h"
#include "common/io/jpeg.h"
#include "common/lumigraph/model_io.h"
#include "common/metrics/metrics.h"
#include "common/run_info/run_info.h"
#include "imgui.h"
#include "proto/control.grpc.pb.h"
#include <grpcpp/grpcpp.h>

namespace exo {
namespace {

// Scene completion's views (server/service/completion_stage.h; the wire's contract, docs/
// inpainting.md "Session 15"): ids from 0x60000000, inpainted. Clients never include server code.
constexpr ViewId kCompletionViewIdFirst = 0x60000000u;
size_t CountCompletionViews(const LumigraphModel& m) {
  size_t n = 0;
  for (auto it = m.views.lower_bound(kCompletionViewIdFirst); it != m.views.end(); ++it)
    n += it->second.inpainted;
  return n;
}

std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop.store(true); }

using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}
// CPU time of the whole process (every thread, lavapipe's rasteriser threads included), ms.
double ProcessCpuMs() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

int Fail(const absl::Status& s) {
  std::fprintf(stderr, "exoview_window: %s\n", s.ToString().c_str());
  return absl::IsInvalidArgument(s) || absl::IsNotFound(s) || absl::IsDataLoss(s) ? 2 : 1;
}

// A server checkpoint (exoview_server --checkpoint_path) as a model: its snapshot deltas applied
// to a LocalStore (the same steps as tools/export's loader).
absl::StatusOr<LumigraphModel> LoadCheckpointModel(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError("cannot open checkpoint " + path);
  v1::Checkpoint c;
  if (!c.ParseFromIstream(&in))
    return absl::DataLossError("not a checkpoint (protobuf parse failed): " + path);
  if (c.format() != 1)
    return absl::InvalidArgumentError("checkpoint format " + std::to_string(c.format()) +
                                      " is not 1: " + path);
  LocalStore store;
  v1::Delta begin, end;
  begin.mutable_snapshot_begin();
  end.mutable_snapshot_end();
  end.set_version(c.version());
  EXO_RETURN_IF_ERROR(store.Apply(begin));
  for (const v1::Delta& d : c.model()) EXO_RETURN_IF_ERROR(store.Apply(d));
  EXO_RETURN_IF_ERROR(store.Apply(end));
  return store.model();
}

// The model the window shows: a file (fixed) or a live subscription (a background thread keeps
// the ViewerSession's store up to date and reconnects when the server goes away).
class ModelSource {
 public:
  static absl::StatusOr<std::unique_ptr<ModelSource>> Open(const WindowAppOptions& o) {
    auto src = std::unique_ptr<ModelSource>(new ModelSource());
    if (!o.model_file.empty()) {
      EXO_ASSIGN_OR_RETURN(src->file_model_, LoadModel(o.model_file));
      src->state_ = "saved model " + std::filesystem::path(o.model_file).filename().string();
      return src;
    }
    if (!o.checkpoint.empty()) {
      EXO_ASSIGN_OR_RETURN(src->file_model_, LoadCheckpointModel(o.checkpoint));
      src->state_ = "checkpoint " + std::filesystem::path(o.checkpoint).filename().string();
      return src;
    }
    src->live_ = true;
    EXO_ASSIGN_OR_RETURN(auto channel, MakeChannel(o.server, o.security));
    EXO_ASSIGN_OR_RETURN(src->session_, ViewerSession::Open(std::move(channel), o.journal));
    ViewerSession* vs = src->session_.get();
    ModelSource* self = src.get();
    vs->SetOnDelta([self](const v1::Delta& d, int64_t) {
      self->last_delta_ = Clock::now();
      self->deltas_.fetch_add(1);
      self->bytes_.fetch_add(d.ByteSizeLong());
      if (d.source_timestamp_s() > 0) {
        const double now_s =
            std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch())
                .count();
        // Meaningful only when the uploader stamps frames with wall-clock time (a live camera);
        // dataset timestamps (e.g. 7-Scenes' frame times) are not, and are not shown.
        const double ms = (now_s - d.source_timestamp_s()) * 1e3;
        if (ms >= 0 && ms < 3600e3) self->latency_ms_.store(ms);
      }
    });
    src->thread_ = std::thread([self] { self->Run(); });
    return src;
  }
  ~ModelSource() {
    stop_.store(true);
    if (session_) session_->Stop();
    if (thread_.joinable()) thread_.join();
  }
  bool live() const { return live_; }
  // Calls f(model, version) with the model stable.
  template <typename F>
  void With(F&& f) {
    if (!live_) {
      f(file_model_, file_model_.version);
      return;
    }
    std::lock_guard lock(session_->lock());
    f(session_->store().model(), session_->store().version());
  }
  uint64_t version() {
    if (!live_) return file_model_.version;
    std::lock_guard lock(session_->lock());
    return session_->store().version();
  }
  std::string state() {
    std::lock_guard lock(mu_);
    return state_;
  }
  uint64_t deltas() const { return deltas_.load(); }
  uint64_t bytes() const { return bytes_.load(); }
  double latency_ms() const { return latency_ms_.load(); }
  double seconds_since_delta() const { return deltas_.load() ? MsSince(last_delta_) * 1e-3 : -1; }

 private:
  ModelSource() = default;
  void Run() {
    while (!stop_.load()) {
      {
        std::lock_guard lock(mu_);
        state_ = "live: subscribed";
      }
      SyncOptions so;
      so.until_synced = false;
      so.max_seconds = 1e9;
      so.client_name = "window";
      absl::Status s = session_->Sync(so);
      if (stop_.load()) break;
      {
        std::lock_guard lock(mu_);
        state_ = "live: reconnecting (" + std::string(s.ok() ? "stream ended" : s.message()) + ")";
      }
      for (int i = 0; i < 10 && !stop_.load(); ++i)
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  }

  bool live_ = false;
  LumigraphModel file_model_;
  std::unique_ptr<ViewerSession> session_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::mutex mu_;
  std::string state_;
  std::atomic<uint64_t> deltas_{0}, bytes_{0};
  std::atomic<double> latency_ms_{-1};
  Clock::time_point last_delta_ = Clock::now();
};

// The drone overlays' source (issue 19, item 5): a thread polls the control service's
// GetControlState (10 Hz) and keeps the newest state as a nav::ControlView. A server without the
// control service (UNIMPLEMENTED) is asked again every 5 s; the HUD says which.
class ControlSource {
 public:
  ControlSource(const std::string& address, const std::shared_ptr<grpc::Channel>& channel,
                std::string drone_id)
      : drone_id_(std::move(drone_id)),
        stub_(exoview::control::v1::Control::NewStub(channel)) {
    state_ = "control: connecting to " + address;
    thread_ = std::thread([this] { Run(); });
  }
  ~ControlSource() {
    {
      std::lock_guard lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }
  std::optional<nav::ControlView> view() {
    std::lock_guard lock(mu_);
    return view_;
  }
  std::string state() {
    std::lock_guard lock(mu_);
    return state_;
  }
  uint64_t polls() const { return polls_.load(); }

 private:
  void Run() {
    namespace cv1 = exoview::control::v1;
    std::unique_lock lock(mu_);
    while (!stop_) {
      lock.unlock();
      cv1::ControlStateRequest req;
      req.set_drone_id(drone_id_);
      cv1::ControlState st;
      grpc::ClientContext ctx;
      ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(2));
      const grpc::Status gs = stub_->GetControlState(&ctx, req, &st);
      polls_.fetch_add(1);
      lock.lock();
      int wait_ms = 100;
      if (gs.ok()) {
        view_ = Convert(st);
        state_ = st.drone_known()
                     ? "control: drone '" + drone_id_ + "' " +
                           cv1::Interaction_Name(st.interaction()) +
                           (st.waypoints_size()
                                ? " waypoint " + std::to_string(st.waypoint_index() + 1) + "/" +
                                      std::to_string(st.waypoints_size())
                                : std::string()) +
                           (st.exploring() ? " EXPLORING" : "")
                     : "control: no drone '" + drone_id_ + "' connected";
      } else if (gs.error_code() == grpc::StatusCode::UNIMPLEMENTED) {
        state_ = "control: not served by this server";
        view_.reset();
        wait_ms = 5000;
      } else {
        state_ = "control: " + gs.error_message();
        wait_ms = 1000;
      }
      cv_.wait_for(lock, std::chrono::milliseconds(wait_ms), [&] { return stop_; });
    }
  }
  static nav::ControlView Convert(const exoview::control::v1::ControlState& s) {
    auto v3 = [](const exoview::control::v1::Vec3& v) { return glm::dvec3(v.x(), v.y(), v.z()); };
    nav::ControlView c;
    c.drone_known = s.drone_known();
    c.drone = v3(s.drone().position());
    c.velocity = v3(s.drone().velocity());
    c.yaw = s.drone().yaw();
    c.camera_pitch = s.drone().camera_pitch();
    c.has_command = s.command_sequence() > 0;
    c.target = v3(s.target());
    c.target_yaw = s.target_yaw();
    c.target_pitch = s.target_camera_pitch();
    for (const auto& w : s.waypoints()) c.waypoints.push_back(v3(w));
    c.waypoint_index = s.waypoint_index();
    for (const auto& z : s.zones()) {
      nav::ZoneView zv;
      zv.name = z.name();
      zv.min = v3(z.min());
      zv.max = v3(z.max());
      zv.prism_axis = int(z.prism_axis()) - 1;
      for (int i = 0; i + 1 < z.polygon_size(); i += 2)
        zv.polygon.push_back({z.polygon(i), z.polygon(i + 1)});
      c.zones.push_back(std::move(zv));
    }
    if (s.has_up() && glm::length(v3(s.up())) > 0) c.up = v3(s.up());
    c.interaction = exoview::control::v1::Interaction_Name(s.interaction());
    c.exploring = s.exploring();
    return c;
  }

  const std::string drone_id_;
  std::unique_ptr<exoview::control::v1::Control::Stub> stub_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::optional<nav::ControlView> view_;
  std::string state_;
  std::atomic<uint64_t> polls_{0};
  std::thread thread_;
};

// What the overlays and picking need from the model, without the pixels (copied on change).
struct SceneInfo {
  LumigraphModel geom;  // origin, grid, chunks, views (poses + cameras only), cell refs
  uint64_t version = 0;
  size_t cells = 0;
  int max_refs = 1;
  std::optional<ViewId> newest;
};

SceneInfo CopySceneInfo(const LumigraphModel& m, uint64_t version) {
  SceneInfo s;
  s.version = version;
  s.geom.origin = m.origin;
  s.geom.grid = m.grid;
  s.geom.chunks = m.chunks;
  s.geom.cell_refs = m.cell_refs;
  s.geom.cell_coverage = m.cell_coverage;
  for (const auto& [id, v] : m.views) {
    StoredView sv;
    sv.id = id;
    sv.camera = v.camera;
    sv.local_from_cam = v.local_from_cam;
    sv.inpainted = v.inpainted;  // (no labels: the overlay marks the view by its frustum)
    s.geom.views.emplace(id, std::move(sv));
    if (!v.inpainted) s.newest = id;  // the live camera is the newest observation
  }
  s.cells = m.cell_refs.size();
  for (const auto& [c, r] : m.cell_refs) s.max_refs = std::max<int>(s.max_refs, int(r.size()));
  return s;
}

// Bilinear resize (the presenter's blit is bilinear too): for the stage SSIMs of the benchmark.
ImageU8 ResizeBilinear(const ImageU8& src, int w, int h) {
  ImageU8 out(w, h, src.channels());
  const int c = src.channels();
  for (int y = 0; y < h; ++y) {
    const double sy = std::clamp((y + 0.5) * src.height() / h - 0.5, 0.0, src.height() - 1.0);
    const int y0 = int(sy), y1 = std::min(y0 + 1, src.height() - 1);
    const double fy = sy - y0;
    for (int x = 0; x < w; ++x) {
      const double sx = std::clamp((x + 0.5) * src.width() / w - 0.5, 0.0, src.width() - 1.0);
      const int x0 = int(sx), x1 = std::min(x0 + 1, src.width() - 1);
      const double fx = sx - x0;
      for (int k = 0; k < c; ++k) {
        const double v = (1 - fy) * ((1 - fx) * src.at(x0, y0, k) + fx * src.at(x1, y0, k)) +
                         fy * ((1 - fx) * src.at(x0, y1, k) + fx * src.at(x1, y1, k));
        out.at(x, y, k) = uint8_t(std::lround(std::clamp(v, 0.0, 255.0)));
      }
    }
  }
  return out;
}

nlohmann::json PoseJson(const Rigid3d& p) {
  return {{"t", {p.translation.x, p.translation.y, p.translation.z}},
          {"q_wxyz", {p.rotation.w, p.rotation.x, p.rotation.y, p.rotation.z}}};
}

// A view of the drone from behind and above it (key G): 1.6 m back along its heading, 0.7 m up,
// looking at a point 0.3 m above it (the drone below the picture's centre, clear of the HUD);
// scene-local.
Rigid3d ChaseView(const nav::ControlView& c, const LocalOrigin& origin) {
  const glm::dvec3 up = glm::length(c.up) > 0 ? glm::normalize(c.up) : glm::dvec3(0, 0, 1);
  const glm::dvec3 heading = nav::DroneCameraAxes(up, c.yaw, 0.0)[2];
  const glm::dvec3 drone = c.drone - origin.origin_in_world;
  const glm::dvec3 eye = drone - 1.6 * heading + 0.7 * up;
  const glm::dvec3 fwd = glm::normalize(drone + 0.3 * up - eye);
  const glm::dvec3 right = glm::normalize(glm::cross(fwd, up));
  const glm::dvec3 down = glm::cross(fwd, right);
  Rigid3d p;
  p.rotation = glm::normalize(glm::quat_cast(glm::dmat3(right, down, fwd)));
  p.translation = eye;
  return p;
}

// What the render thread hands the UI thread with each frame.
struct WindowFrame {
  ImageU8 image;     // RGB8, 1/divisor of the window per side
  ImageF occ_depth;  // proxy z-depth at 1/8 of the window (overlays on): hides hidden overlays
  std::optional<nav::PickResult> centre;  // the proxy under the centre pixel
  bool has_centre = false;  // `centre` was computed for this frame (else keep the last one)
  std::shared_ptr<const SceneInfo> info;  // the model the frame shows
  double gpu_ms = 0;                      // submit-to-fence of the blend
};

// The window's live DR view (key V; issue 18 item 4): the newest DrViewFrame the server's
// WatchDrView stream sent (the live camera's frame with the marked regions removed), decoded on
// the watcher's thread; the UI thread presents it instead of the free-viewpoint render.
struct DrLive {
  std::mutex mu;
  ImageU8 image;           // the newest frame (RGB8)
  bool fresh = false;      // not presented yet
  uint64_t frames = 0;     // received since the mode was switched on
  uint64_t sequence = 0;   // the uploaded frame's sequence
  bool composited = false;
  uint32_t roi_px = 0;
  double latency_ms = 0;   // the server's admission -> output
  std::string error;       // a frame that could not be decoded
  Clock::time_point arrived{};
  std::vector<Clock::time_point> recent;  // arrivals in the last 2 s (fps)

  void Reset() {
    std::lock_guard lock(mu);
    image = ImageU8();
    fresh = false;
    frames = sequence = 0;
    composited = false;
    roi_px = 0;
    latency_ms = 0;
    error.clear();
    arrived = {};
    recent.clear();
  }
  // Runs on the watcher's thread.
  void Take(const v1::DrViewFrame& m) {
    absl::StatusOr<ImageU8> img = absl::InvalidArgumentError("the frame carries no picture");
    if (!m.color_jpeg().empty()) {
      img = DecodeJpeg(std::span<const uint8_t>(
          reinterpret_cast<const uint8_t*>(m.color_jpeg().data()), m.color_jpeg().size()));
    } else if (m.width() > 0 && m.height() > 0 &&
               m.color_rgb().size() == size_t(m.width()) * m.height() * 3) {
      ImageU8 raw(int(m.width()), int(m.height()), 3);
      std::memcpy(raw.data(), m.color_rgb().data(), m.color_rgb().size());
      img = std::move(raw);
    }
    const auto now = Clock::now();
    std::lock_guard lock(mu);
    if (!img.ok()) {
      error = std::string(img.status().message());
      return;
    }
    image = *std::move(img);
    fresh = true;
    ++frames;
    sequence = m.sequence();
    composited = m.composited();
    roi_px = m.roi_px();
    latency_ms = m.latency_ms();
    error.clear();
    arrived = now;
    recent.push_back(now);
    while (!recent.empty() && now - recent.front() > std::chrono::seconds(2))
      recent.erase(recent.begin());
  }
};

// Why the DR stream is not delivering (the watcher's status), or "" while it is fine.
std::string DrWatchProblem(const std::string& watch_status) {
  if (watch_status.rfind("error: 12 ", 0) == 0)
    return "the server has no DR view (inpainting off): " + watch_status.substr(10);
  if (watch_status.rfind("error: 14 ", 0) == 0)
    return "the server is unreachable (" + watch_status.substr(10) + "), retrying every 2 s";
  if (watch_status.rfind("error:", 0) == 0) return watch_status + ", retrying every 2 s";
  return "";
}

// What the HUD says about the live DR view, from the watcher's status and the newest frame;
// *ok: a good picture is on screen (the line may then be hidden with Tab).
std::string DrHudLine(const std::string& watch_status, DrLive& d, bool* ok) {
  std::lock_guard lock(d.mu);
  char b[256];
  *ok = false;
  const std::string problem = DrWatchProblem(watch_status);
  if (d.frames > 0) {
    const double age_ms = MsSince(d.arrived);
    if (!problem.empty()) {
      std::snprintf(b, sizeof(b), " (last frame seq %llu, %.1f s ago)",
                    (unsigned long long)d.sequence, age_ms * 1e-3);
      return "live DR view (V): " + problem + b;
    }
    double fps = 0;
    if (d.recent.size() >= 2)
      fps = (d.recent.size() - 1) /
            std::max(1e-3, std::chrono::duration<double>(d.recent.back() - d.recent.front()).count());
    std::snprintf(b, sizeof(b), "live DR view (V): frame seq %llu  age %.0f ms  %.1f fps  ",
                  (unsigned long long)d.sequence, age_ms, fps);
    std::string line = b;
    if (d.composited) {
      std::snprintf(b, sizeof(b), "regions removed (%u px)  server latency %.0f ms", d.roi_px,
                    d.latency_ms);
      *ok = age_ms <= 2000;
    } else if (d.roi_px == 0) {
      std::snprintf(b, sizeof(b), "no marked region in view: the camera's frame as it is");
    } else {
      std::snprintf(b, sizeof(b), "no inpainted keyframe yet (%u px marked): frame as it is",
                    d.roi_px);
    }
    line += b;
    if (age_ms > 2000) line += "  (no new frame: camera stopped, or the regions cleared)";
    if (!d.error.empty()) line += "  [bad frame: " + d.error + "]";
    return line;
  }
  if (!problem.empty()) return "live DR view (V): " + problem;
  if (!d.error.empty()) return "live DR view (V): bad frame: " + d.error;
  // The server sends DR frames only while a region is marked and the camera uploads.
  return "live DR view (V): " + watch_status +
         ", no frame yet: nothing marked on the server, or the camera is not uploading";
}

class App {
 public:
  explicit App(const WindowAppOptions& o) : o_(o) {}

  absl::Status InitModelAndRenderer(bool need_views) {
    EXO_ASSIGN_OR_RETURN(source_, ModelSource::Open(o_));
    if (source_->live()) {
      // Wait (bounded) for the first views so there is something to look at.
      const auto t0 = Clock::now();
      while (MsSince(t0) < 30000) {
        size_t n = 0;
        source_->With([&](const LumigraphModel& m, uint64_t) { n = m.views.size(); });
        if (n > 0 || !need_views) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
      }
    }
    cells_by_tau_ = o_.cells_by_tau;
    const std::string control = o_.control.empty() ? (source_->live() ? o_.server : "") : o_.control;
    if (!control.empty() && control != "none") {
      EXO_ASSIGN_OR_RETURN(auto channel, MakeChannel(control, o_.security));
      control_ = std::make_unique<ControlSource>(control, channel, o_.drone_id);
      operator_ = std::make_unique<DroneOperator>(
          channel, o_.drone_id,
          o_.operator_id.empty() ? "window-" + std::to_string(getpid()) : o_.operator_id);
    }
    DroneControlsOptions dco;
    dco.hand_m = o_.hand_m;
    dco.xray_margin_m = o_.xray_margin_m;
    dco.xray_default_m = o_.xray_default_m;
    dco.xray_radius = o_.xray_radius;
    controls_ = std::make_unique<DroneControls>(operator_.get(), dco);
    EXO_ASSIGN_OR_RETURN(renderer_, VulkanRenderer::Create({}));
    EXO_RETURN_IF_ERROR(SyncRenderer());
    if (need_views && info_->geom.views.empty())
      return absl::FailedPreconditionError("the model has no stored views (nothing to show)");
    return absl::OkStatus();
  }

  // Uploads what changed in the model; true when something did.
  absl::StatusOr<bool> MaybeSync() {
    if (source_->version() == info_->version && synced_once_) return false;
    EXO_RETURN_IF_ERROR(SyncRenderer());
    return true;
  }

  absl::Status SyncRenderer() {
    absl::Status st;
    source_->With([&](const LumigraphModel& m, uint64_t version) {
      st = renderer_->SyncModel(m);
      if (st.ok()) info_ = std::make_shared<const SceneInfo>(CopySceneInfo(m, version));
    });
    synced_once_ = true;
    return st;
  }

  Rigid3d StartPose() const {
    const auto& views = info_->geom.views;
    if (o_.start_view >= 0) {
      auto it = views.find(ViewId(o_.start_view));
      if (it != views.end()) return it->second.local_from_cam;
    }
    return views.empty() ? Rigid3d{} : views.begin()->second.local_from_cam;
  }

  size_t ProxyTriangles() const {
    size_t n = 0;
    for (const auto& [id, c] : info_->geom.chunks) n += c.mesh.num_triangles();
    return n;
  }

  PinholeCamera Camera(int w, int h) const {
    return PinholeCamera::FromFov(w, h, o_.hfov_deg * M_PI / 180.0);
  }

  absl::StatusOr<ImageU8> Render(const Rigid3d& pose, int w, int h) {
    EXO_ASSIGN_OR_RETURN(auto r, RenderFull(pose, w, h));
    return std::move(r.color);
  }
  absl::StatusOr<RenderResult> RenderFull(const Rigid3d& pose, int w, int h, bool moving = false) {
    blend::BlendOptions bo;
    bo.n_best = o_.n_best;
    RenderApprox approx;
    if (moving) approx.max_candidates = o_.moving_candidates;
    return renderer_->Render(Camera(w, h), pose, bo, approx);
  }

  // ---- steering the drone (issue 19 item 5; client/window/drone_operator.h) ----
  // The render thread's X-ray hole (the cut-away around the cursor; none when off).
  absl::Status ApplyXrayHole() {
    const std::optional<XrayHole> want = XrayNow();
    const std::optional<XrayHole> has = renderer_->xray_hole();
    const auto same = [](const XrayHole& a, const XrayHole& b) {
      return a.clip_m == b.clip_m && a.centre_x == b.centre_x && a.centre_y == b.centre_y &&
             a.radius == b.radius;
    };
    if (want.has_value() == has.has_value() && (!want || same(*want, *has)))
      return absl::OkStatus();
    return renderer_->SetXrayHole(want);
  }
  std::optional<XrayHole> XrayNow() const {
    std::lock_guard lock(xray_mu_);
    return xray_hole_;
  }
  // The clip at pixel `px` of a W x H picture under the hole `h` (0: not cut there).
  static double ClipAt(const std::optional<XrayHole>& h, const glm::dvec2& px, int W, int H) {
    if (!h || !nav::InsideXrayHole(px, W, H, {h->centre_x, h->centre_y}, h->radius)) return 0.0;
    return h->clip_m;
  }
  void SyncXray() {
    std::optional<XrayHole> h;
    if (controls_->xray()) {
      h = XrayHole{};
      h->clip_m = controls_->xray_clip_m();
      h->centre_x = controls_->xray_centre().x;
      h->centre_y = controls_->xray_centre().y;
      h->radius = controls_->xray_radius();
    }
    {
      std::lock_guard lock(xray_mu_);
      xray_hole_ = h;
    }
    rerender_ = true;
  }
  // The drone (world) and where it is on screen for the frame at `pose`.
  std::optional<std::pair<glm::dvec3, glm::dvec2>> DroneOnScreen(const SceneInfo& info,
                                                                 const Rigid3d& pose, int W,
                                                                 int H) const {
    if (!control_) return std::nullopt;
    auto cv = control_->view();
    if (!cv || !cv->drone_known) return std::nullopt;
    const glm::dvec3 pc = pose.Inverse() * (cv->drone - info.geom.origin.origin_in_world);
    glm::dvec2 uv;
    if (pc.z < 0.05 || !Camera(W, H).Project(pc, &uv)) return std::nullopt;
    return std::pair(cv->drone, uv);
  }
  // The window's operator gestures: ctrl (or drone mode, M) + left click = gaze-to-see, + left
  // drag from the drone = pick-and-place (wheel: the hand along the ray), M, X, [ ]. True when
  // the event was consumed (not navigation).
  bool HandleOperatorEvent(const SDL_Event& e, const SceneInfo& info, const Rigid3d& at, int W,
                           int H) {
    if (e.type == SDL_CONTROLLERDEVICEADDED && !gamepad_) {
      gamepad_ = SDL_GameControllerOpen(e.cdevice.which);
      return true;
    }
    if (e.type == SDL_CONTROLLERDEVICEREMOVED && gamepad_ &&
        e.cdevice.which == SDL_JoystickInstanceID(SDL_GameControllerGetJoystick(gamepad_))) {
      SDL_GameControllerClose(gamepad_);
      gamepad_ = nullptr;
      return true;
    }
    const bool op_mod = controls_->drone_mode() || (SDL_GetModState() & KMOD_CTRL);
    const PinholeCamera cam = Camera(W, H);
    if (e.type == SDL_KEYDOWN && !e.key.repeat) {
      switch (e.key.keysym.sym) {
        case SDLK_m:
          controls_->ToggleDroneMode();
          return true;
        case SDLK_x: {  // the hole around the cursor, cut behind the surface under it
          int mx = W / 2, my = H / 2;
          SDL_GetMouseState(&mx, &my);
          const glm::dvec2 m(mx, my);
          auto p = nav::Pick(info.geom, cam, at, m);
          if (!p) p = nav::Pick(info.geom, cam, at, {W / 2.0 - 0.5, H / 2.0 - 0.5});
          controls_->ToggleXray(p ? std::optional(p->z_depth_m) : std::nullopt,
                                nav::XrayHoleCentre(m, W, H));
          SyncXray();
          return true;
        }
        case SDLK_LEFTBRACKET:
        case SDLK_RIGHTBRACKET:
          controls_->MoveXray(e.key.keysym.sym == SDLK_LEFTBRACKET ? -1 : 1);
          SyncXray();
          return true;
        default:
          return false;
      }
    }
    if (e.type == SDL_MOUSEBUTTONDOWN && e.button.button == SDL_BUTTON_LEFT && op_mod) {
      const glm::dvec2 px(e.button.x, e.button.y);
      auto d = DroneOnScreen(info, at, W, H);
      if (!controls_->BeginDrag(px, d ? std::optional(d->second) : std::nullopt,
                                d ? std::optional(d->first) : std::nullopt))
        press_px_ = px;
      return true;
    }
    if (e.type == SDL_MOUSEMOTION && (controls_->dragging() || press_px_)) {
      controls_->Drag({double(e.motion.x), double(e.motion.y)});
      return true;
    }
    if (e.type == SDL_MOUSEMOTION && controls_->xray()) {  // the hole follows the cursor
      controls_->MoveXrayHole(nav::XrayHoleCentre({double(e.motion.x), double(e.motion.y)}, W, H));
      SyncXray();
      return false;  // still navigation (a drag looks around)
    }
    if (e.type == SDL_MOUSEWHEEL && controls_->dragging()) {
      controls_->Wheel(e.wheel.y);
      return true;
    }
    if (e.type == SDL_MOUSEBUTTONUP && e.button.button == SDL_BUTTON_LEFT) {
      const glm::dvec2 px(e.button.x, e.button.y);
      if (controls_->EndDrag(cam, at, info.geom.origin)) return true;
      if (press_px_) {
        const glm::dvec2 p0 = *press_px_;
        press_px_.reset();
        if (glm::length(px - p0) <= 5.0) {
          auto hit = nav::Pick(info.geom, cam, at, px, controls_->ClipAt(cam, px));
          controls_->Click(cam, at, info.geom.origin, px,
                           hit ? std::optional(hit->point_local) : std::nullopt);
        }
        return true;
      }
    }
    return false;
  }
  // Held keys / an open game controller -> joypad commands. True while some stick is deflected.
  bool OperatorSticks(double dt) {
    nav::JoypadKeys k;
    if (!ImGui::GetIO().WantCaptureKeyboard) {
      const Uint8* ks = SDL_GetKeyboardState(nullptr);
      k.forward = ks[SDL_SCANCODE_I];
      k.back = ks[SDL_SCANCODE_K];
      k.left = ks[SDL_SCANCODE_J];
      k.right = ks[SDL_SCANCODE_L];
      k.turn_left = ks[SDL_SCANCODE_U];
      k.turn_right = ks[SDL_SCANCODE_O];
      k.up = ks[SDL_SCANCODE_Y];
      k.down = ks[SDL_SCANCODE_H];
    }
    if (k.any()) {
      controls_->Joypad(k, dt);
      return true;
    }
    if (gamepad_) {
      auto axis = [&](SDL_GameControllerAxis a) {
        return SDL_GameControllerGetAxis(gamepad_, a) / 32767.0;
      };
      const nav::Sticks s = nav::SticksFromGamepad(
          axis(SDL_CONTROLLER_AXIS_LEFTX), axis(SDL_CONTROLLER_AXIS_LEFTY),
          axis(SDL_CONTROLLER_AXIS_RIGHTX), axis(SDL_CONTROLLER_AXIS_RIGHTY));
      controls_->Gamepad(s, dt);
      return !s.zero();
    }
    controls_->Joypad(k, dt);
    return false;
  }
  // The drag's preview (drone -> the target the server will set) and the last gaze's P_gaze.
  void DrawOperatorOverlays(ImDrawList* dl, const SceneInfo& info, const Rigid3d& pose, int W,
                            int H) {
    const PinholeCamera cam = Camera(W, H);
    auto px = [&](const glm::dvec3& world, ImVec2* out) {
      const glm::dvec3 pc = pose.Inverse() * (world - info.geom.origin.origin_in_world);
      glm::dvec2 uv;
      if (pc.z < 0.05 || !cam.Project(pc, &uv)) return false;
      *out = ImVec2(float(uv.x + 0.5), float(uv.y + 0.5));
      return true;
    };
    const ImU32 preview_col = IM_COL32(80, 200, 255, 255);
    if (controls_->xray()) {  // the X-ray hole's rim (the cut-away is inside it)
      const glm::dvec2 c = controls_->xray_centre();
      dl->AddCircle(ImVec2(float(c.x * W), float(c.y * H)), float(controls_->xray_radius() * H),
                    IM_COL32(120, 220, 255, 160), 64, 1.5f);
    }
    if (auto p = controls_->Preview(cam, pose, info.geom.origin)) {
      ImVec2 a, b;
      const bool has_a = px(*controls_->drag_drone_world(), &a), has_b = px(p->target, &b);
      if (has_a && has_b) dl->AddLine(a, b, preview_col, 2.f);
      if (has_b) {
        dl->AddCircle(b, 10.f, preview_col, 24, 2.5f);
        char t[64];
        std::snprintf(t, sizeof(t), "x%.1f%s", p->scale, p->guarded ? " guarded" : "");
        dl->AddText(ImVec2(b.x + 12, b.y - 6), preview_col, t);
        probe_["drag_preview_px"] = {b.x, b.y};
      }
      probe_["drag_preview"] = {p->target.x, p->target.y, p->target.z};
    }
    if (operator_)
      if (auto r = operator_->last(); r && r->ok && r->has_gaze) {
        ImVec2 g;
        if (px(r->gaze_point, &g)) {
          dl->AddCircle(g, 8.f, IM_COL32(255, 255, 255, 230), 16, 2.f);
          dl->AddCircle(g, 3.f, IM_COL32(255, 60, 255, 255), 8, 2.f);
          probe_["gaze_px"] = {g.x, g.y};
        }
      }
  }

  // ---- scripted render along a TUM path (no window) ----
  int RunPath() {
    auto poses = nav::ReadTumPath(o_.path);
    if (!poses.ok()) return Fail(poses.status());
    if (auto s = InitModelAndRenderer(false); !s.ok()) return Fail(s);
    std::error_code ec;
    std::filesystem::create_directories(o_.out_dir, ec);
    if (ec) return Fail(absl::PermissionDeniedError("cannot create " + o_.out_dir));
    std::vector<double> ms;
    nlohmann::json frames = nlohmann::json::array();
    for (size_t i = 0; i < poses->size(); ++i) {
      const Rigid3d pose = info_->geom.origin.ToLocal((*poses)[i].world_from_cam);
      const auto t0 = Clock::now();
      auto img = Render(pose, o_.width, o_.height);
      if (!img.ok()) return Fail(img.status());
      ms.push_back(MsSince(t0));
      char name[64];
      std::snprintf(name, sizeof(name), "frame_%05zu.png", i);
      if (auto s = WriteColorImage(o_.out_dir + "/" + name, *img); !s.ok()) return Fail(s);
      frames.push_back({{"png", name}, {"render_ms", ms.back()}});
    }
    std::vector<double> sorted = ms;
    std::sort(sorted.begin(), sorted.end());
    const nlohmann::json out = {{"path", o_.path},
                                {"frames", poses->size()},
                                {"width", o_.width},
                                {"height", o_.height},
                                {"median_render_ms", sorted[sorted.size() / 2]},
                                {"out_dir", o_.out_dir},
                                {"per_frame", frames}};
    std::printf("%s\n", out.dump().c_str());
    return 0;
  }

  // ---- overlays (ImGui background draw list: projected lines/points over the frame) ----
  // Drawn at the pose of the frame on screen (so they stay on the picture while the next frame
  // renders), hidden behind the proxy by that frame's ⅛-resolution proxy depth (`occ`).
  void DrawOverlays(const SceneInfo& info, const Rigid3d& pose, const ImageF& occ_depth, int W,
                    int H) {
    if (!overlays_) return;
    ImDrawList* dl = ImGui::GetBackgroundDrawList();
    const PinholeCamera cam = Camera(W, H);
    const Rigid3d cam_from_local = pose.Inverse();
    const int dw = occ_depth.width(), dh = occ_depth.height();
    auto visible = [&](const glm::dvec3& pc, const glm::dvec2& uv) {
      if (occ_depth.empty()) return true;
      const int x = int(std::floor((uv.x + 0.5) * dw / W)),
                y = int(std::floor((uv.y + 0.5) * dh / H));
      if (x < 0 || y < 0 || x >= dw || y >= dh) return true;
      const float z = occ_depth.at(x, y);
      return !(z > 0) || pc.z <= z * 1.03 + 0.01;
    };
    auto project = [&](const glm::dvec3& p_local, ImVec2* out) {
      const glm::dvec3 pc = cam_from_local * p_local;
      if (pc.z < 0.05) return false;
      glm::dvec2 uv;
      if (!cam.Project(pc, &uv)) return false;
      *out = ImVec2(float(uv.x + 0.5), float(uv.y + 0.5));
      return std::abs(uv.x) < 4 * W && std::abs(uv.y) < 4 * H;
    };
    auto seen = [&](const glm::dvec3& p_local) {
      const glm::dvec3 pc = cam_from_local * p_local;
      glm::dvec2 uv;
      return pc.z > 0.05 && cam.Project(pc, &uv) && visible(pc, uv);
    };
    auto line = [&](const glm::dvec3& a, const glm::dvec3& b, ImU32 col, float th) {
      ImVec2 pa, pb;
      if (project(a, &pa) && project(b, &pb) && seen(0.5 * (a + b))) dl->AddLine(pa, pb, col, th);
    };
    const double scale = std::max(0.05, nav::ModelBounds(info.geom).Diagonal() * 0.02);
    if (show_wire_) {
      int budget = 30000;  // edges drawn at most (sampled evenly)
      size_t tris = 0;
      for (const auto& [id, c] : info.geom.chunks) tris += c.mesh.num_triangles();
      const size_t stride = std::max<size_t>(1, tris / size_t(budget));
      size_t k = 0;
      for (const auto& [id, c] : info.geom.chunks) {
        const auto& m = c.mesh;
        for (size_t t = 0; t < m.num_triangles(); ++t, ++k) {
          if (k % stride) continue;
          const glm::dvec3 a(m.positions[m.indices[3 * t]]), b(m.positions[m.indices[3 * t + 1]]),
              d(m.positions[m.indices[3 * t + 2]]);
          const ImU32 col = IM_COL32(0, 255, 255, 70);
          line(a, b, col, 1);
          line(b, d, col, 1);
          line(d, a, col, 1);
        }
      }
    }
    probe_ = nlohmann::json::object();
    if (show_cells_ && info.geom.grid.cell_size_m > 0) {
      size_t stride = std::max<size_t>(1, info.cells / 8000);
      size_t k = 0;
      // Coverage τ (the server's, CellCoverage) when the model has it: red (τ = 0) -> yellow ->
      // green (τ >= τ_max); else the reference count relative to the fullest cell.
      const bool by_tau = cells_by_tau_ && !info.geom.cell_coverage.empty();
      nlohmann::json drawn = nlohmann::json::array();
      for (const auto& [cell, refs] : info.geom.cell_refs) {
        if (k++ % stride) continue;
        ImVec2 p;
        const glm::dvec3 centre = info.geom.grid.Centre(cell);
        if (!project(centre, &p) || !seen(centre)) continue;
        int percent = -1;
        uint32_t col;
        if (by_tau) {
          auto it = info.geom.cell_coverage.find(cell);
          percent = it == info.geom.cell_coverage.end() ? 0 : it->second;
          col = nav::CoverageColor(percent, 255);
        } else {
          col = nav::RefCountColor(refs.size(), size_t(info.max_refs), 255);
        }
        dl->AddCircleFilled(p, 3.f, col);
        if (drawn.size() < 2000 && p.x >= 0 && p.y >= 0 && p.x < W && p.y < H)
          drawn.push_back({p.x, p.y, percent, refs.size()});
      }
      probe_["cells_by"] = by_tau ? "tau" : "refs";
      probe_["cells"] = std::move(drawn);  // [x, y, τ percent (-1: by refs), references]
    }
    // The drone, its camera, target, route and the flight zones (issue 19): always on top (not
    // hidden by the proxy: a person must find the drone behind a wall too).
    if (show_drone_ && control_) {
      if (auto cv = control_->view()) {
        nav::DroneOverlayOptions dopt;
        if (info.newest) {  // the drone's camera: that of the newest stored view (its uploads)
          const PinholeCamera& vc = info.geom.views.at(*info.newest).camera;
          dopt.hfov_rad = 2 * std::atan(0.5 * vc.width / vc.fx);
          dopt.aspect = double(vc.width) / vc.height;
        }
        dopt.frustum_m = std::max(0.3, 1.5 * scale);
        size_t n = 0;
        for (const nav::OverlayLine& l : nav::DroneOverlayLines(*cv, info.geom.origin, dopt)) {
          auto s2 = nav::ProjectSegment(cam, pose, l.a, l.b);
          if (!s2) continue;
          dl->AddLine(ImVec2(float(s2->a.x + 0.5), float(s2->a.y + 0.5)),
                      ImVec2(float(s2->b.x + 0.5), float(s2->b.y + 0.5)), l.rgba, l.width);
          ++n;
        }
        auto px = [&](const glm::dvec3& w) -> nlohmann::json {
          ImVec2 p;
          if (!project(w - info.geom.origin.origin_in_world, &p)) return nullptr;
          return {p.x, p.y};
        };
        probe_["drone_lines"] = n;
        probe_["drone_known"] = cv->drone_known;
        if (cv->drone_known) probe_["drone_px"] = px(cv->drone);
        if (cv->has_command) probe_["target_px"] = px(cv->target);
        if (cv->has_command) probe_["target"] = {cv->target.x, cv->target.y, cv->target.z};
        probe_["waypoints"] = cv->waypoints.size();
        probe_["zones"] = cv->zones.size();
      }
    }
    if (controls_) DrawOperatorOverlays(dl, info, pose, W, H);
    if (show_frusta_ && !info.geom.views.empty()) {
      const ViewId first = info.geom.views.begin()->first;
      const ViewId last = info.geom.views.rbegin()->first;
      for (const auto& [id, v] : info.geom.views) {
        const bool live = info.newest && id == *info.newest;
        // Age: oldest blue -> newest yellow; the live (newest) camera green and thicker.
        // Inpainted views (SPEC §7): scene completion's (ids from 0x60000000) magenta, the
        // diminished-reality keyframes orange.
        const ViewId obs_last = info.newest ? *info.newest : last;
        const float a = obs_last > first ? std::min(1.f, float(id - first) / float(obs_last - first)) : 1.f;
        const bool completion = v.inpainted && id >= kCompletionViewIdFirst;
        const ImU32 col =
            live         ? IM_COL32(40, 255, 40, 255)
            : completion ? IM_COL32(255, 40, 255, 255)
            : v.inpainted ? IM_COL32(255, 140, 0, 230)
                         : IM_COL32(int(60 + 195 * a), int(80 + 175 * a), int(255 * (1 - a)), 200);
        const PinholeCamera& vc = v.camera;
        const double z = live ? 2 * scale : scale;
        glm::dvec3 c[4];
        const glm::dvec2 corners[4] = {{-0.5, -0.5},
                                       {vc.width - 0.5, -0.5},
                                       {vc.width - 0.5, vc.height - 0.5},
                                       {-0.5, vc.height - 0.5}};
        for (int i = 0; i < 4; ++i) c[i] = v.local_from_cam * vc.Unproject(corners[i], z);
        const glm::dvec3 o = v.local_from_cam.translation;
        // A frustum at (or around) the eye would cover the screen: skip those within 3 sizes.
        if (glm::length(o - pose.translation) < 3 * z) continue;
        const float th = live ? 2.5f : v.inpainted ? 2.0f : 1.2f;
        for (int i = 0; i < 4; ++i) {
          line(o, c[i], col, th);
          line(c[i], c[(i + 1) % 4], col, th);
        }
      }
    }
    if (cursor_pick_) {
      ImVec2 p;
      if (project(cursor_pick_->point_local, &p)) {
        dl->AddCircle(p, 6.f, IM_COL32(255, 60, 255, 255), 16, 2.f);
        ImVec2 q;
        if (project(cursor_pick_->point_local + cursor_pick_->normal_local * scale, &q))
          dl->AddLine(p, q, IM_COL32(255, 60, 255, 255), 2.f);
      }
    }
    // Crosshair (the picked point below it is in the HUD).
    dl->AddLine(ImVec2(W / 2.f - 8, H / 2.f), ImVec2(W / 2.f + 8, H / 2.f),
                IM_COL32(255, 255, 255, 160));
    dl->AddLine(ImVec2(W / 2.f, H / 2.f - 8), ImVec2(W / 2.f, H / 2.f + 8),
                IM_COL32(255, 255, 255, 160));
  }

  void DrawHud(const SceneInfo& info, const nav::FlyCamera& cam, int W, int H, int busy) {
    if (!overlays_) return;
    ImGui::SetNextWindowPos(ImVec2(8, 8), ImGuiCond_Always);
    ImGui::SetNextWindowBgAlpha(0.6f);
    ImGui::Begin("Exoview", nullptr,
                 ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_AlwaysAutoResize |
                     ImGuiWindowFlags_NoFocusOnAppearing | ImGuiWindowFlags_NoNav);
    if (frame_moving_)
      ImGui::Text("frame %.1f ms (%.0f fps)  render %.1f ms  present %.1f ms", frame_ms_,
                  frame_ms_ > 0 ? 1000.0 / frame_ms_ : 0.0, render_ms_, present_ms_);
    else
      ImGui::Text("still: refined in %.1f ms  present %.1f ms", render_ms_, present_ms_);
    auto stage_name = [](int d) {
      return d == 1 ? "full" : d == 2 ? "1/2" : d == 4 ? "1/4" : d == 8 ? "1/8" : "?";
    };
    ImGui::Text("resolution %s %dx%d%s%s", stage_name(stage_), W / std::max(1, stage_),
                H / std::max(1, stage_), busy ? "  rendering " : "",
                busy ? stage_name(busy) : "");
    ImGui::Text("model v%llu  views %zu  cells %zu  chunks %zu", (unsigned long long)info.version,
                info.geom.views.size(), info.cells, info.geom.chunks.size());
    ImGui::Text("%s", source_->state().c_str());
    if (source_->live()) {
      const double ago = source_->seconds_since_delta();
      const double lat = source_->latency_ms();
      char lat_text[32] = "n/a";
      if (lat >= 0) std::snprintf(lat_text, sizeof(lat_text), "%.0f ms", lat);
      ImGui::Text("deltas %llu (%.1f MB)  last %.1f s ago  capture->view latency %s",
                  (unsigned long long)source_->deltas(), source_->bytes() / 1e6, ago, lat_text);
    }
    ImGui::Text("speed %.2f m/s%s%s", cam.speed_mps(), follow_ ? "  FOLLOW" : "",
                replaying_ ? "  REPLAY" : "");
    if (centre_pick_)
      ImGui::Text("centre: %.2f m  cell %llx  n (%.2f %.2f %.2f)", centre_pick_->z_depth_m,
                  (unsigned long long)centre_pick_->cell, centre_pick_->normal_local.x,
                  centre_pick_->normal_local.y, centre_pick_->normal_local.z);
    else
      ImGui::Text("centre: no proxy surface");
    if (cursor_pick_)
      ImGui::Text("picked: (%.2f %.2f %.2f)  cell %llx", cursor_pick_->point_local.x,
                  cursor_pick_->point_local.y, cursor_pick_->point_local.z,
                  (unsigned long long)cursor_pick_->cell);
    if (controls_) {
      ImGui::TextColored(controls_->drone_mode() || controls_->xray()
                             ? ImVec4(0.4f, 0.85f, 1.f, 1.f)
                             : ImVec4(0.7f, 0.7f, 0.7f, 1.f),
                         "%s", controls_->HudLine().c_str());
      if (operator_)
        if (auto r = operator_->last())
          ImGui::TextColored(r->ok ? ImVec4(0.6f, 1.f, 0.6f, 1.f) : ImVec4(1.f, 0.5f, 0.4f, 1.f),
                             "%s", r->Summary().c_str());
    }
    {
      bool ok = true;
      const std::string line = CompletionLine(&ok);
      if (!line.empty())
        ImGui::TextColored(ok ? ImVec4(1.f, 0.55f, 1.f, 1.f) : ImVec4(1.f, 0.5f, 0.4f, 1.f), "%s",
                           line.c_str());
    }
    if (control_) {
      ImGui::Text("%s", control_->state().c_str());
      if (auto cv = control_->view(); cv && cv->drone_known) {
        const glm::dvec3 p = cv->drone;
        ImGui::Text("drone (%.2f %.2f %.2f) yaw %.0f° pitch %.0f°  %.2f m/s", p.x, p.y, p.z,
                    cv->yaw * 180 / M_PI, cv->camera_pitch * 180 / M_PI,
                    glm::length(cv->velocity));
      }
    }
    if (show_cells_) {
      if (cells_by_tau_ && !info.geom.cell_coverage.empty())
        ImGui::TextColored(ImVec4(0.9f, 0.9f, 0.5f, 1.f),
                           "cells: coverage tau/tau_max  red 0 - yellow 0.5 - green >= 1");
      else
        ImGui::TextColored(ImVec4(0.9f, 0.9f, 0.5f, 1.f), "cells: references  red 1 - green %d%s",
                           info.max_refs,
                           info.geom.cell_coverage.empty() ? "  (no coverage in this model)" : "");
    }
    ImGui::Checkbox("frusta", &show_frusta_);
    ImGui::SameLine();
    ImGui::Checkbox("wireframe", &show_wire_);
    ImGui::SameLine();
    ImGui::Checkbox("cells", &show_cells_);
    ImGui::SameLine();
    ImGui::Checkbox("tau", &cells_by_tau_);
    ImGui::SameLine();
    ImGui::Checkbox("drone", &show_drone_);
    if (tint_inpainted_.load())
      ImGui::TextColored(ImVec4(1.f, 0.35f, 1.f, 1.f),
                         "T: tinted = rendered from inpainted views (DR keyframes, completions)");
    ImGui::TextDisabled(
        "WASD/QE move, drag/arrows look, wheel speed, right-click pick, R F G V C T Tab 1-5 P Esc");
    const ImVec2 hp = ImGui::GetWindowPos(), hs = ImGui::GetWindowSize();
    probe_["hud"] = {hp.x, hp.y, hs.x, hs.y};
    ImGui::End();
  }

  // Key T: the pixels blended from inpainted views (VulkanRenderer coverage 4: DR keyframes and
  // scene completions, InpaintFusion's label rule) mixed 45 % towards magenta. Returns their count.
  static uint64_t TintInpainted(RenderResult* r) {
    uint64_t n = 0;
    uint8_t* c = r->color.data();
    const uint8_t* cov = r->coverage.data();
    const size_t px = r->coverage.size();
    constexpr int kTint[3] = {255, 64, 255};
    for (size_t i = 0; i < px; ++i) {
      if (cov[i] != 4) continue;
      for (int k = 0; k < 3; ++k) c[3 * i + k] = uint8_t((55 * c[3 * i + k] + 45 * kTint[k] + 50) / 100);
      ++n;
    }
    return n;
  }

  // Key C: scene completion at the camera (CompleteView on the model's server, same security).
  void RequestCompletion(const PinholeCamera& camera, const Rigid3d& pose) {
    if (o_.server.empty()) {
      completion_note_ = "completion (C): only with a live server (--server); this is a saved model";
      return;
    }
    if (!completion_) {
      auto channel = MakeChannel(o_.server, o_.security);
      if (!channel.ok()) {
        completion_note_ = "completion (C): " + std::string(channel.status().message());
        return;
      }
      completion_ = std::make_unique<CompletionRequester>(*channel);
    }
    completion_note_.clear();
    completion_->Request(camera, pose);
  }
  // The HUD's completion line ("" before the first C) and whether it reports a success.
  std::string CompletionLine(bool* ok) const {
    *ok = completion_note_.empty();
    if (!completion_note_.empty()) return completion_note_;
    if (!completion_) return std::string();
    const CompletionRequester::State st = completion_->state();
    *ok = st.ok;
    return st.line;
  }
  nlohmann::json CompletionJson() const {
    bool ok = true;
    nlohmann::json j = {{"hud", CompletionLine(&ok)}, {"ok", ok}};
    if (completion_) {
      const CompletionRequester::State st = completion_->state();
      j["busy"] = st.busy;
      j["requests"] = st.requests;
      j["replies"] = st.replies;
      j["view_id"] = st.view_id;
      j["hole_px"] = st.hole_px;
    }
    return j;
  }

  // Key V: the live DR view on (subscribe to the server's WatchDrView, on the same channel
  // security as the model's) or off (the subscription is closed at once: the server composites
  // only while someone looks).
  void SetDrMode(bool on, uint32_t wake_event) {
    dr_mode_ = on;
    dr_watch_.reset();
    dr_.Reset();
    dr_shown_sequence_ = 0;
    dr_note_.clear();
    if (!on) return;
    if (o_.server.empty()) {
      dr_note_ = "live DR view (V): only with a live server (--server); this is a saved model";
      return;
    }
    auto channel = MakeChannel(o_.server, o_.security);
    if (!channel.ok()) {
      dr_note_ = "live DR view (V): " + std::string(channel.status().message());
      return;
    }
    dr_watch_ = std::make_unique<DrViewWatcher>(
        *channel,
        [this, wake_event](const v1::DrViewFrame& m) {
          dr_.Take(m);
          SDL_Event e{};
          e.type = wake_event;
          SDL_PushEvent(&e);
        },
        /*idle_s=*/2.0);
    dr_watch_->Demand();
  }

  // The live DR view's HUD: one line (frame seq, age, fps, what the server did) while the
  // picture is good and the HUD is on (Tab); a message always when there is no good picture.
  void DrawDrHud(int W) {
    bool ok = false;
    const std::string line =
        !dr_note_.empty() ? dr_note_ : DrHudLine(dr_watch_ ? dr_watch_->status() : "off", dr_, &ok);
    probe_.erase("dr_hud");
    if (ok && !overlays_) return;
    ImGui::SetNextWindowPos(ImVec2(8, 8), ImGuiCond_Always);
    ImGui::SetNextWindowBgAlpha(0.6f);
    ImGui::Begin("Live DR view", nullptr,
                 ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_AlwaysAutoResize |
                     ImGuiWindowFlags_NoFocusOnAppearing | ImGuiWindowFlags_NoNav);
    ImGui::PushTextWrapPos(float(std::max(80, W - 24)));
    ImGui::TextColored(ok ? ImVec4(0.6f, 1.f, 0.6f, 1.f) : ImVec4(1.f, 0.75f, 0.4f, 1.f), "%s",
                       line.c_str());
    ImGui::TextDisabled("V: back to the free-viewpoint view");
    ImGui::PopTextWrapPos();
    const ImVec2 hp = ImGui::GetWindowPos(), hs = ImGui::GetWindowSize();
    probe_["dr_hud"] = {hp.x, hp.y, hs.x, hs.y};
    ImGui::End();
  }

  // The state after a presented frame (`pose`: the pose that frame was rendered at).
  void WriteStatus(const SceneInfo& info, const Rigid3d& pose, uint64_t frame) {
    if (o_.status_file.empty()) return;
    nlohmann::json j = {{"frame", frame},
                        {"stage", stage_},
                        {"width", presenter_->width()},
                        {"height", presenter_->height()},
                        {"hfov_deg", o_.hfov_deg},
                        {"pose_local", PoseJson(pose)},
                        {"model_version", info.version},
                        {"views", info.geom.views.size()},
                        {"completion_views", CountCompletionViews(info.geom)},
                        {"tint_inpainted", tint_inpainted_.load()},
                        {"tinted_px", tinted_px_.load()},
                        {"cells", info.cells},
                        {"sync", source_->state()},
                        {"frame_ms", frame_ms_},
                        {"render_ms", render_ms_},
                        {"ui_max_gap_ms", ui_max_gap_ms_},
                        {"overlays", overlays_},
                        {"follow", follow_},
                        {"cells_with_coverage", info.geom.cell_coverage.size()},
                        {"overlay", probe_}};
    {
      std::vector<int> hist(11, 0);  // τ/τ_max in tenths (the last bin: 100 %)
      for (const auto& [c, p] : info.geom.cell_coverage) ++hist[std::min<int>(p / 10, 10)];
      j["coverage_histogram"] = hist;
    }
    if (control_) j["control"] = control_->state();
    if (controls_) j["drone_controls"] = controls_->StatusJson();
    j["completion"] = CompletionJson();
    {
      bool dr_ok = false;
      const std::string watch = dr_watch_ ? dr_watch_->status() : std::string("off");
      const std::string line = dr_mode_ ? DrHudLine(watch, dr_, &dr_ok) : std::string();
      std::lock_guard lock(dr_.mu);
      j["dr_view"] = {{"on", dr_mode_},
                      {"watch", watch},
                      {"frames", dr_.frames},
                      {"shown_sequence", dr_shown_sequence_},
                      {"composited", dr_.composited},
                      {"roi_px", dr_.roi_px},
                      {"hud", line}};
    }
    const Rigid3d world = {pose.rotation, pose.translation + info.geom.origin.origin_in_world};
    j["pose_world"] = PoseJson(world);
    if (auto n = nav::NearestView(info.geom, pose.translation)) {
      j["nearest_view"] = *n;
      j["nearest_view_distance_m"] =
          glm::length(info.geom.views.at(*n).local_from_cam.translation - pose.translation);
    }
    if (centre_pick_) {
      j["centre_depth_m"] = centre_pick_->z_depth_m;
      j["centre_cell"] = centre_pick_->cell;
      j["centre_point_local"] = {centre_pick_->point_local.x, centre_pick_->point_local.y,
                                 centre_pick_->point_local.z};
    } else {
      j["centre_depth_m"] = nullptr;
    }
    const std::string tmp = o_.status_file + ".tmp";
    std::ofstream(tmp) << j.dump(1) << "\n";
    std::filesystem::rename(tmp, o_.status_file);
  }

  absl::Status SaveModel() {
    if (o_.save_model.empty()) return absl::OkStatus();
    absl::Status st;
    ModelIoOptions mo;
    mo.color_jpeg_quality = o_.save_model_jpeg_quality;
    source_->With(
        [&](const LumigraphModel& m, uint64_t) { st = exo::SaveModel(o_.save_model, m, mo); });
    if (st.ok())
      std::fprintf(stderr, "exoview_window: saved the model to %s\n", o_.save_model.c_str());
    return st;
  }

  // ---- the render thread (nav::RenderScheduler) ----
  using Scheduler = nav::RenderScheduler<WindowFrame>;
  // Renders on its own thread from now on: renderer_, source_ syncing and info_ belong to it
  // until Stop(); each finished frame wakes the SDL loop with `wake_event`.
  std::unique_ptr<Scheduler> StartRenderThread(const nav::AdaptiveOptions& ao, uint32_t wake_event) {
    return std::make_unique<Scheduler>(
        ao,
        [this](const nav::RenderJob& j, WindowFrame* f) -> absl::Status {
          const int W = j.request.width, H = j.request.height, d = j.divisor;
          const Rigid3d& pose = j.request.pose;
          EXO_RETURN_IF_ERROR(ApplyXrayHole());  // the X-ray cut-away (key X)
          // Reduced-resolution frames for a moving camera may be approximate; refinements and
          // every full-resolution frame (the one left on screen) are exact.
          EXO_ASSIGN_OR_RETURN(RenderResult r, RenderFull(pose, std::max(1, W / d),
                                                          std::max(1, H / d), j.changed && d > 1));
          if (tint_inpainted_.load()) tinted_px_ = TintInpainted(&r);
          f->image = std::move(r.color);
          f->gpu_ms = r.gpu_ms;
          if (want_occ_.load()) {
            auto z = renderer_->RenderProxyDepth(Camera(std::max(1, W / 8), std::max(1, H / 8)),
                                                 pose);
            if (z.ok()) f->occ_depth = *std::move(z);
          }
          // The HUD's depth under the crosshair: a ray cast over every proxy triangle (~1.5 ms
          // on 7-Scenes' 113 575, 7 % of a moving frame's CPU), so at most 5 times a second
          // while moving; always for a full-resolution frame and once the camera stops.
          if (d > 1 && j.changed && MsSince(t_centre_) < 200) {
            centre_stale_ = true;
          } else if (d == 1 || j.changed || centre_stale_) {
            const glm::dvec2 c(W / 2.0 - 0.5, H / 2.0 - 0.5);
            f->centre = nav::Pick(info_->geom, Camera(W, H), pose, c,
                                  ClipAt(renderer_->xray_hole(), c, W, H));
            f->has_centre = true;
            centre_stale_ = false;
            t_centre_ = Clock::now();
          }
          f->info = info_;
          return absl::OkStatus();
        },
        [this] { return MaybeSync(); },
        [wake_event] {
          SDL_Event e{};
          e.type = wake_event;
          SDL_PushEvent(&e);
        });
  }

  nav::AdaptiveOptions AdaptiveFromFlags(bool enabled, double target_ms) const {
    nav::AdaptiveOptions ao;
    ao.enabled = enabled;
    ao.moving_divisor = o_.moving_divisor;
    ao.target_ms = target_ms;
    ao.min_divisor = std::min(ao.min_divisor, o_.moving_divisor);
    ao.max_divisor = std::max(ao.max_divisor, o_.moving_divisor);
    return ao;
  }

  // ---- interactive window ----
  // The UI thread (this loop) handles input, moves the camera, posts the view to the render
  // thread and presents whatever frame is newest, with the HUD and the overlays drawn at that
  // frame's pose; it never waits for a render, so keys, the mouse and the HUD stay live while a
  // full-resolution frame takes a second.
  int RunWindow() {
    if (auto s = InitModelAndRenderer(true); !s.ok()) return Fail(s);
    std::vector<nav::PathPose> replay;
    if (!o_.replay.empty()) {
      auto r = nav::ReadTumPath(o_.replay);
      if (!r.ok()) return Fail(r.status());
      replay = *std::move(r);
    }
    PresenterOptions po;
    po.width = o_.width;
    po.height = o_.height;
    po.title = "Exoview — " + (o_.model_file.empty() ? o_.server : o_.model_file);
    auto presenter = Presenter::Create(po);
    if (!presenter.ok()) return Fail(presenter.status());
    presenter_ = std::move(*presenter);
    std::shared_ptr<const SceneInfo> info = info_;  // the UI thread's: that of the frame shown
    nav::FlyOptions fo;
    fo.speed_mps = std::max(0.1, nav::ModelBounds(info->geom).Diagonal() * 0.1);
    nav::FlyCamera cam(StartPose(), nav::SceneUp(info->geom), fo);
    const nav::AdaptiveOptions ao = AdaptiveFromFlags(o_.adaptive, o_.target_ms);
    if (auto s = ao.Validate(); !s.ok()) return Fail(s);
    const uint32_t wake_event = SDL_RegisterEvents(1);
    if (wake_event == uint32_t(-1)) return Fail(absl::InternalError("SDL_RegisterEvents failed"));
    overlays_ = o_.overlays;
    want_occ_ = overlays_;
    std::unique_ptr<Scheduler> sched = StartRenderThread(ao, wake_event);
    std::optional<Scheduler::Done> shown;  // the frame on screen
    std::vector<nav::PathPose> recorded;
    const auto t_start = Clock::now();
    auto t_last = Clock::now(), t_presented = Clock::now(), t_new_frame = Clock::now(),
         t_iter = Clock::now();
    bool quit = false;
    uint64_t epoch = 0;
    size_t replay_i = 0;
    replaying_ = !replay.empty();
    int last_busy = 0;
    auto t_status = Clock::now();
    SDL_InitSubSystem(SDL_INIT_GAMECONTROLLER);  // a gamepad steers the drone (Mode 2)
    while (!quit) {
      ui_max_gap_ms_ = std::max(ui_max_gap_ms_, MsSince(t_iter));
      t_iter = Clock::now();
      nav::FlyInput in;
      bool events = false, overlay_changed = false, dr_switched = false;
      SDL_Event e;
      while (SDL_PollEvent(&e)) {
        if (e.type == wake_event) continue;  // a frame is ready: taken below
        events = true;
        const bool imgui = presenter_->ProcessEvent(e);
        if (e.type == SDL_QUIT) quit = true;
        if (!imgui && controls_ &&
            HandleOperatorEvent(e, *info, shown ? shown->job.request.pose : cam.pose(),
                                presenter_->width(), presenter_->height())) {
          overlay_changed = true;
          continue;
        }
        if (e.type == SDL_KEYDOWN && !e.key.repeat && !imgui) {
          switch (e.key.keysym.sym) {
            case SDLK_ESCAPE:
              quit = true;
              break;
            case SDLK_TAB:
              overlays_ = !overlays_;
              want_occ_ = overlays_;
              overlay_changed = true;
              break;
            case SDLK_r:
              if (auto n = nav::NearestView(info->geom, cam.pose().translation))
                cam.Reset(info->geom.views.at(*n).local_from_cam);
              follow_ = false;
              break;
            case SDLK_f:
              follow_ = !follow_;
              break;
            case SDLK_p:
              if (auto s = SaveModel(); !s.ok())
                std::fprintf(stderr, "exoview_window: %s\n", s.ToString().c_str());
              break;
            case SDLK_1:
              show_frusta_ = !show_frusta_;
              overlay_changed = true;
              break;
            case SDLK_2:
              show_wire_ = !show_wire_;
              overlay_changed = true;
              break;
            case SDLK_3:
              show_cells_ = !show_cells_;
              overlay_changed = true;
              break;
            case SDLK_4:
              cells_by_tau_ = !cells_by_tau_;
              overlay_changed = true;
              break;
            case SDLK_5:
              show_drone_ = !show_drone_;
              overlay_changed = true;
              break;
            case SDLK_c:  // scene completion at this camera (the server inpaints the holes)
              RequestCompletion(Camera(presenter_->width(), presenter_->height()),
                                shown ? shown->job.request.pose : cam.pose());
              overlay_changed = true;
              break;
            case SDLK_t:  // tint the pixels rendered from inpainted views (and back)
              tint_inpainted_ = !tint_inpainted_.load();
              tinted_px_ = 0;
              rerender_ = true;
              break;
            case SDLK_v:  // the live DR view instead of the free-viewpoint render, and back
              SetDrMode(!dr_mode_, wake_event);
              dr_switched = true;
              break;
            case SDLK_g:  // look at the drone from behind and above it
              if (control_)
                if (auto cv = control_->view(); cv && cv->drone_known) {
                  cam.Reset(ChaseView(*cv, info->geom.origin));
                  follow_ = false;
                }
              break;
            default:
              break;
          }
        }
        if (e.type == SDL_MOUSEMOTION && !imgui && (e.motion.state & SDL_BUTTON_LMASK)) {
          in.look_dx_px += e.motion.xrel;
          in.look_dy_px += e.motion.yrel;
        }
        if (e.type == SDL_MOUSEWHEEL && !imgui) in.wheel += e.wheel.y;
        // Right click: pick the proxy under the cursor (point, normal, cell) in the picture on
        // screen, the hook for the operator actions (marking a region, steering the drone).
        if (e.type == SDL_MOUSEBUTTONDOWN && e.button.button == SDL_BUTTON_RIGHT && !imgui) {
          const int W = presenter_->width(), H = presenter_->height();
          const Rigid3d& at = shown ? shown->job.request.pose : cam.pose();
          cursor_pick_ =
              nav::Pick(info->geom, Camera(W, H), at, {double(e.button.x), double(e.button.y)});
          if (cursor_pick_) {
            const glm::dvec3 pw = info->geom.origin.origin_in_world + cursor_pick_->point_local;
            std::printf("%s\n", nlohmann::json(
                                    {{"pick", {pw.x, pw.y, pw.z}},
                                     {"normal",
                                      {cursor_pick_->normal_local.x, cursor_pick_->normal_local.y,
                                       cursor_pick_->normal_local.z}},
                                     {"cell", cursor_pick_->cell},
                                     {"pixel", {e.button.x, e.button.y}}})
                                    .dump()
                                    .c_str());
            std::fflush(stdout);
          }
          overlay_changed = true;
        }
      }
      const double dt = std::min(0.25, MsSince(t_last) * 1e-3);
      t_last = Clock::now();
      const Uint8* ks = SDL_GetKeyboardState(nullptr);
      if (!ImGui::GetIO().WantCaptureKeyboard) {
        in.forward = ks[SDL_SCANCODE_W];
        in.back = ks[SDL_SCANCODE_S];
        in.left = ks[SDL_SCANCODE_A];
        in.right = ks[SDL_SCANCODE_D];
        in.up = ks[SDL_SCANCODE_E];
        in.down = ks[SDL_SCANCODE_Q];
        const double turn_px = 400.0 * dt;  // arrow keys: ~70 deg/s at the default sensitivity
        if (ks[SDL_SCANCODE_LEFT]) in.look_dx_px -= turn_px;
        if (ks[SDL_SCANCODE_RIGHT]) in.look_dx_px += turn_px;
        if (ks[SDL_SCANCODE_UP]) in.look_dy_px -= turn_px;
        if (ks[SDL_SCANCODE_DOWN]) in.look_dy_px += turn_px;
      }
      const bool sticks = controls_ && OperatorSticks(dt);  // joypad keys / gamepad
      if (rerender_) {  // the X-ray plane moved: the same view again
        ++epoch;
        rerender_ = false;
      }
      bool moving = cam.Step(in, dt);
      if (follow_ && info->newest) {
        const Rigid3d& live = info->geom.views.at(*info->newest).local_from_cam;
        if (glm::length(live.translation - cam.pose().translation) > 1e-9 ||
            std::abs(glm::dot(live.rotation, cam.pose().rotation)) < 1 - 1e-12) {
          cam.Reset(live);
          moving = true;
        }
      }
      if (replaying_) {
        const double t = MsSince(t_start) * 1e-3 + replay.front().timestamp_s;
        while (replay_i + 1 < replay.size() && replay[replay_i + 1].timestamp_s <= t) ++replay_i;
        cam.Reset(info->geom.origin.ToLocal(replay[replay_i].world_from_cam));
        moving = true;
        if (replay_i + 1 == replay.size()) replaying_ = false;
      }
      const int W = presenter_->width(), H = presenter_->height();
      // The live DR view on screen: the render thread pauses (0 x 0); the subscription is kept
      // demanded while the mode is on.
      if (dr_mode_ && dr_watch_) dr_watch_->Demand();
      sched->Post({cam.pose(), dr_mode_ ? 0 : W, dr_mode_ ? 0 : H, epoch});
      if (auto st = sched->status(); !st.ok()) return Fail(st);
      std::optional<Scheduler::Done> nf = sched->TakeFrame();
      if (nf) {
        // While moving, what the person sees: the time between new pictures (refinement frames
        // after the camera stopped say their render time instead).
        frame_ms_ = nf->job.changed ? MsSince(t_new_frame) : nf->render_ms;
        frame_moving_ = nf->job.changed;
        t_new_frame = Clock::now();
        shown = std::move(nf);
        info = shown->frame.info;
        stage_ = shown->job.divisor;
        render_ms_ = shown->render_ms;
        if (shown->frame.has_centre) centre_pick_ = shown->frame.centre;
      }
      const int busy = sched->busy_divisor();
      // Present a new frame at once; the HUD alone (input, a render in progress) at most 10 Hz
      // so that presenting does not take the CPU from the render thread.
      const bool hud_due = (overlays_ || dr_mode_) &&
                           (events || busy != last_busy || MsSince(t_presented) >= 250) &&
                           MsSince(t_presented) >= 100;
      last_busy = busy;
      // What goes to the screen: the newest DR frame (a dark picture until the first arrives),
      // or the render (again, after the DR view was switched off).
      const ImageU8* upload = nullptr;
      std::optional<ImageU8> dr_image;
      bool dr_presented = false;
      if (dr_mode_) {
        {
          std::lock_guard lock(dr_.mu);
          if (dr_.fresh) {
            dr_image = std::move(dr_.image);
            dr_.image = ImageU8();
            dr_.fresh = false;
            dr_shown_sequence_ = dr_.sequence;
            dr_presented = true;
          }
        }
        if (!dr_image && dr_switched) {
          dr_image = ImageU8(W, H, 3);
          std::fill(dr_image->data(), dr_image->data() + size_t(W) * H * 3, uint8_t(24));
        }
        if (dr_image) upload = &*dr_image;
      } else if (nf || (dr_switched && shown)) {
        upload = &shown->frame.image;
      }
      if (upload || overlay_changed || hud_due) {
        presenter_->NewFrame();
        if (dr_mode_) {
          DrawDrHud(W);
        } else {
          if (shown)
            DrawOverlays(*info, shown->job.request.pose, shown->frame.occ_depth, W, H);
          DrawHud(*info, cam, W, H, busy);
        }
        PresentTimings pt;
        if (auto s = presenter_->Present(upload, &pt); !s.ok()) return Fail(s);
        t_presented = Clock::now();
        if (nf && !dr_mode_) present_ms_ = pt.upload_ms + pt.submit_ms;
      }
      if (nf && !o_.record.empty()) {
        const Rigid3d& p = shown->job.request.pose;
        recorded.push_back(
            {MsSince(t_start) * 1e-3, {p.rotation, p.translation + info->geom.origin.origin_in_world}});
      }
      // Status after each full-resolution frame, and when the sync state changes (e.g. the
      // server went away: the last model stays on screen, the HUD says "reconnecting").
      const std::string sync_state = source_->state();
      if (shown && ((nf && stage_ == 1 && !dr_mode_) || sync_state != last_sync_state_ ||
                    dr_presented || dr_switched ||
                    ((operator_ || dr_mode_) && MsSince(t_status) > 250))) {  // replies too
        WriteStatus(*info, shown->job.request.pose, shown->seq);
        t_status = Clock::now();
      }
      last_sync_state_ = sync_state;
      if (o_.max_seconds > 0 && MsSince(t_start) > o_.max_seconds * 1e3) quit = true;
      // Moving: step the camera at ~100 Hz; a render in progress: wake for its frame (or input);
      // converged: wait for input (HUD refresh 4 Hz).
      const int wait_ms = moving || follow_ || replaying_ || sticks ? 10
                          : controls_->dragging()                  ? 20
                          : busy                                   ? 100
                          : overlays_ || dr_mode_                  ? 250
                                                                   : 1000;
      t_iter = Clock::now();  // the wait below is idle time, not a UI stall
      SDL_WaitEventTimeout(nullptr, wait_ms);
    }
    sched->Stop();
    dr_watch_.reset();
    if (auto st = sched->status(); !st.ok()) return Fail(st);
    if (!o_.record.empty())
      if (auto s = nav::WriteTumPath(o_.record, recorded); !s.ok()) return Fail(s);
    if (source_->live())
      if (auto s = SaveModel(); !s.ok()) return Fail(s);
    presenter_.reset();
    return 0;
  }

  // The browser page's overlays (/overlay.json) for a frame rendered at `pose` (W x H): the
  // drone lines (not depth-tested, as in the window) and, with cells on, the cells' dots hidden
  // behind the proxy by `occ` (proxy z-depth at 1/8).
  nlohmann::json OverlayJson(const SceneInfo& info, const Rigid3d& pose, int W, int H,
                             const ImageF& occ) {
    const PinholeCamera cam = Camera(W, H);
    auto css = [](uint32_t c) {
      char b[48];
      std::snprintf(b, sizeof(b), "rgba(%u,%u,%u,%.3f)", c & 255, (c >> 8) & 255, (c >> 16) & 255,
                    ((c >> 24) & 255) / 255.0);
      return std::string(b);
    };
    nlohmann::json lines = nlohmann::json::array(), dots = nlohmann::json::array();
    nlohmann::json j = {{"width", W}, {"height", H}};
    if (show_drone_ && control_) {
      if (auto cv = control_->view()) {
        nav::DroneOverlayOptions dopt;
        if (info.newest) {
          const PinholeCamera& vc = info.geom.views.at(*info.newest).camera;
          dopt.hfov_rad = 2 * std::atan(0.5 * vc.width / vc.fx);
          dopt.aspect = double(vc.width) / vc.height;
        }
        dopt.frustum_m = std::max(0.3, 1.5 * std::max(0.05, nav::ModelBounds(info.geom).Diagonal() * 0.02));
        for (const nav::OverlayLine& l : nav::DroneOverlayLines(*cv, info.geom.origin, dopt)) {
          auto s2 = nav::ProjectSegment(cam, pose, l.a, l.b);
          if (!s2) continue;
          lines.push_back({s2->a.x + 0.5, s2->a.y + 0.5, s2->b.x + 0.5, s2->b.y + 0.5,
                           css(l.rgba), l.width, nav::OverlayKindName(l.kind)});
        }
        if (cv->drone_known) {
          glm::dvec2 uv;
          const glm::dvec3 pc = pose.Inverse() * (cv->drone - info.geom.origin.origin_in_world);
          if (cam.Project(pc, &uv)) j["drone_px"] = {uv.x + 0.5, uv.y + 0.5};
        }
      }
    }
    if (show_cells_) {
      const bool by_tau = cells_by_tau_ && !info.geom.cell_coverage.empty();
      const Rigid3d cam_from_local = pose.Inverse();
      size_t k = 0, stride = std::max<size_t>(1, info.cells / 4000);
      for (const auto& [cell, refs] : info.geom.cell_refs) {
        if (k++ % stride) continue;
        const glm::dvec3 pc = cam_from_local * info.geom.grid.Centre(cell);
        glm::dvec2 uv;
        if (pc.z < 0.05 || !cam.Project(pc, &uv) || !cam.InImage(uv)) continue;
        if (!occ.empty()) {
          const int x = std::clamp(int((uv.x + 0.5) * occ.width() / W), 0, occ.width() - 1);
          const int y = std::clamp(int((uv.y + 0.5) * occ.height() / H), 0, occ.height() - 1);
          const float z = occ.at(x, y);
          if (z > 0 && pc.z > z * 1.03 + 0.01) continue;
        }
        int percent = -1;
        uint32_t col;
        if (by_tau) {
          auto it = info.geom.cell_coverage.find(cell);
          percent = it == info.geom.cell_coverage.end() ? 0 : it->second;
          col = nav::CoverageColor(percent, 255);
        } else {
          col = nav::RefCountColor(refs.size(), size_t(info.max_refs), 255);
        }
        dots.push_back({uv.x + 0.5, uv.y + 0.5, css(col), percent});
      }
      j["cells_by"] = by_tau ? "tau" : "refs";
    }
    j["lines"] = std::move(lines);
    j["dots"] = std::move(dots);
    return j;
  }

  // The browser page's drone gestures (HttpInput), at the pose of the frame the page shows.
  // True when the view must be rendered again (the X-ray plane changed).
  bool HttpOperator(const HttpInput& hi, const Rigid3d& at, int W, int H, double dt) {
    const SceneInfo& info = *info_;
    const PinholeCamera cam = Camera(W, H);
    nav::JoypadKeys k;
    for (const std::string& h : hi.held) {
      k.forward |= h == "i";
      k.back |= h == "k";
      k.left |= h == "j";
      k.right |= h == "l";
      k.turn_left |= h == "u";
      k.turn_right |= h == "o";
      k.up |= h == "y";
      k.down |= h == "h";
    }
    controls_->Joypad(k, dt);
    for (const auto& g : hi.gazes) {
      const glm::dvec2 px(g[0] - 0.5, g[1] - 0.5);  // page pixels: corners at integers
      auto hit = nav::Pick(info.geom, cam, at, px, controls_->ClipAt(cam, px));
      controls_->Click(cam, at, info.geom.origin, px,
                       hit ? std::optional(hit->point_local) : std::nullopt);
    }
    for (const auto& p : hi.picks) {
      const glm::dvec2 p0(p[0] - 0.5, p[1] - 0.5), p1(p[2] - 0.5, p[3] - 0.5);
      auto d = DroneOnScreen(info, at, W, H);
      if (d && glm::length(d->second - p0) <= 40)  // a drag that starts on the drone
        controls_->Drag(cam, at, info.geom.origin, p0, p1, p[4], p[5], d->first);
    }
    bool again = false;
    // The page's last pointer position over the picture (page pixels: corners at integers).
    const std::optional<glm::dvec2> pointer =
        hi.xray_at ? std::optional(glm::dvec2((*hi.xray_at)[0] - 0.5, (*hi.xray_at)[1] - 0.5))
                   : std::nullopt;
    for (const std::string& key : hi.presses) {
      if (key == "x") {  // the hole around the pointer (else the picture's centre)
        const glm::dvec2 m = pointer.value_or(glm::dvec2(W / 2.0 - 0.5, H / 2.0 - 0.5));
        auto c = nav::Pick(info.geom, cam, at, m);
        controls_->ToggleXray(c ? std::optional(c->z_depth_m) : std::nullopt,
                              nav::XrayHoleCentre(m, W, H));
      } else if (key == "xnear" || key == "xfar") {
        controls_->MoveXray(key == "xnear" ? -1 : 1);
      } else {
        continue;
      }
      SyncXray();
      again = true;
    }
    if (pointer && controls_->xray() && hi.presses.empty()) {  // the hole follows the pointer
      const glm::dvec2 c = nav::XrayHoleCentre(*pointer, W, H);
      if (c != controls_->xray_centre()) {
        controls_->MoveXrayHole(c);
        SyncXray();
        again = true;
      }
    }
    rerender_ = false;
    return again;
  }

  // ---- browser view (no window) ----
  int RunHttp() {
    if (auto s = InitModelAndRenderer(true); !s.ok()) return Fail(s);
    std::mutex status_mu;
    std::string status_text = "{}";
    std::string controls_text;  // DroneControls::StatusJson, refreshed by the loop
    std::string completion_text;  // CompletionJson, refreshed by the loop
    double frame_ms = 0;
    uint64_t frames = 0;
    HttpView* view_ptr = nullptr;
    auto http = HttpView::Start(
        o_.http,
        [&] {
          std::lock_guard lock(status_mu);
          nlohmann::json j = nlohmann::json::parse(status_text, nullptr, false);
          if (j.is_discarded()) return status_text;
          if (!controls_text.empty())
            j["drone_controls"] = nlohmann::json::parse(controls_text, nullptr, false);
          j["completion"] = completion_text.empty()
                                ? nlohmann::json::object()
                                : nlohmann::json::parse(completion_text, nullptr, false);
          return j.dump();
        },
        [&] {
          std::lock_guard lock(status_mu);
          char buf[1024];
          std::snprintf(
              buf, sizeof(buf),
              "# HELP exoview_viewer_frame_ms Wall time of the last rendered frame.\n"
              "# TYPE exoview_viewer_frame_ms gauge\nexoview_viewer_frame_ms %.3f\n"
              "# HELP exoview_viewer_frames_rendered_total Frames rendered.\n"
              "# TYPE exoview_viewer_frames_rendered_total counter\n"
              "exoview_viewer_frames_rendered_total %llu\n"
              "# HELP exoview_viewer_frames_sent_total JPEG frames sent to browsers.\n"
              "# TYPE exoview_viewer_frames_sent_total counter\n"
              "exoview_viewer_frames_sent_total %llu\n"
              "# HELP exoview_viewer_bytes_received_total Delta bytes received.\n"
              "# TYPE exoview_viewer_bytes_received_total counter\n"
              "exoview_viewer_bytes_received_total %llu\n"
              "# HELP exoview_viewer_model_version Version of the local model.\n"
              "# TYPE exoview_viewer_model_version gauge\nexoview_viewer_model_version %llu\n"
              "# HELP exoview_viewer_browsers Connected browser connections.\n"
              "# TYPE exoview_viewer_browsers gauge\nexoview_viewer_browsers %d\n",
              frame_ms, (unsigned long long)frames,
              (unsigned long long)(view_ptr ? view_ptr->frames_sent() : 0),
              (unsigned long long)source_->bytes(), (unsigned long long)info_->version,
              view_ptr ? view_ptr->clients() : 0);
          return std::string(buf);
        });
    if (!http.ok()) return Fail(http.status());
    view_ptr = http->get();
    // The live DR view of a server (GET /dr.jpg, the page's "DR view" toggle): watched on demand.
    std::unique_ptr<DrViewWatcher> dr_watch;
    if (!o_.server.empty()) {
      // The same security as the model's channel (which opened, so this one builds too).
      auto channel = MakeChannel(o_.server, o_.security);
      if (channel.ok()) {
        dr_watch = std::make_unique<DrViewWatcher>(*channel, [view_ptr](const v1::DrViewFrame& m) {
          if (m.color_jpeg().empty()) return;
          view_ptr->PublishDrFrame(
              std::vector<uint8_t>(m.color_jpeg().begin(), m.color_jpeg().end()),
              nlohmann::json({{"sequence", m.sequence()}, {"composited", m.composited()},
                              {"roi_px", m.roi_px()}, {"latency_ms", std::round(m.latency_ms() * 10) / 10},
                              {"width", m.width()}, {"height", m.height()}}).dump());
        });
        (*http)->SetDrSource([w = dr_watch.get()] { w->Demand(); },
                             [w = dr_watch.get()] { return w->status(); });
      }
    }
    const int port = (*http)->port();
    if (!o_.port_file.empty()) std::ofstream(o_.port_file) << port << "\n";
    std::printf("%s\n", nlohmann::json({{"http", "http://127.0.0.1:" + std::to_string(port) + "/"}})
                            .dump()
                            .c_str());
    std::fflush(stdout);
    signal(SIGTERM, OnSignal);
    signal(SIGINT, OnSignal);
    nav::FlyOptions fo;
    fo.speed_mps = std::max(0.1, nav::ModelBounds(info_->geom).Diagonal() * 0.1);
    nav::FlyCamera cam(StartPose(), nav::SceneUp(info_->geom), fo);
    nav::AdaptiveOptions ao;
    ao.enabled = o_.adaptive;
    ao.moving_divisor = o_.moving_divisor;
    ao.target_ms = o_.target_ms;
    ao.min_divisor = std::min(ao.min_divisor, o_.moving_divisor);
    ao.max_divisor = std::max(ao.max_divisor, o_.moving_divisor);
    if (auto s = ao.Validate(); !s.ok()) return Fail(s);
    nav::AdaptiveResolution adaptive(ao);
    const int W = o_.width, H = o_.height;
    const auto t_start = Clock::now();
    auto t_last = Clock::now(), t_overlay = Clock::now(), t_controls = Clock::now();
    bool force = true, overlay_due = true, have_frame = false;
    Rigid3d last_pose;
    while (!g_stop.load()) {
      if (o_.max_seconds > 0 && MsSince(t_start) > o_.max_seconds * 1e3) break;
      const HttpInput hi = (*http)->TakeInput();
      const double dt = std::min(0.25, MsSince(t_last) * 1e-3);
      t_last = Clock::now();
      nav::FlyInput in;
      in.forward = hi.forward;
      in.back = hi.back;
      in.left = hi.left;
      in.right = hi.right;
      in.up = hi.up;
      in.down = hi.down;
      in.look_dx_px = hi.look_dx_px + 400.0 * dt * (hi.turn_right - hi.turn_left);
      in.look_dy_px = hi.look_dy_px + 400.0 * dt * (hi.turn_down - hi.turn_up);
      in.wheel = hi.wheel;
      if (have_frame && HttpOperator(hi, last_pose, W, H, dt)) force = true;
      if (MsSince(t_controls) >= 200) {
        std::lock_guard lock(status_mu);
        controls_text = controls_->StatusJson().dump();
        completion_text = CompletionJson().dump();
        t_controls = Clock::now();
      }
      for (const std::string& k : hi.presses) {
        if (k == "r") {
          if (auto n = nav::NearestView(info_->geom, cam.pose().translation))
            cam.Reset(info_->geom.views.at(*n).local_from_cam);
          follow_ = false;
          force = true;
        } else if (k == "f") {
          follow_ = !follow_;
          force = true;
        } else if (k == "g") {  // look at the drone from behind and above it
          if (control_)
            if (auto cv = control_->view(); cv && cv->drone_known) {
              cam.Reset(ChaseView(*cv, info_->geom.origin));
              follow_ = false;
              force = true;
            }
        } else if (k == "3") {
          show_cells_ = !show_cells_;
          overlay_due = true;
        } else if (k == "4") {
          cells_by_tau_ = !cells_by_tau_;
          overlay_due = true;
        } else if (k == "5") {
          show_drone_ = !show_drone_;
          overlay_due = true;
        } else if (k == "c") {  // scene completion at the page's camera
          RequestCompletion(Camera(W, H), have_frame ? last_pose : cam.pose());
        }
      }
      // The overlays follow the drone at 5 Hz even when no frame is rendered.
      if (have_frame && (overlay_due || MsSince(t_overlay) >= 200)) {
        ImageF occ;
        if (show_cells_) {
          auto z = renderer_->RenderProxyDepth(Camera(std::max(1, W / 8), std::max(1, H / 8)),
                                               last_pose);
          if (z.ok()) occ = *std::move(z);
        }
        (*http)->SetOverlay(OverlayJson(*info_, last_pose, W, H, occ).dump());
        t_overlay = Clock::now();
        overlay_due = false;
      }
      bool changed = cam.Step(in, dt) || force;
      force = false;
      auto synced = MaybeSync();
      if (!synced.ok()) return Fail(synced.status());
      changed |= *synced;
      if (follow_ && info_->newest) {
        const Rigid3d& live = info_->geom.views.at(*info_->newest).local_from_cam;
        if (glm::length(live.translation - cam.pose().translation) > 1e-9) {
          cam.Reset(live);
          changed = true;
        }
      }
      const int d = adaptive.Next(changed);
      if (d == 0) {
        std::this_thread::sleep_for(std::chrono::milliseconds(15));
        continue;
      }
      const auto t0 = Clock::now();
      if (auto s = ApplyXrayHole(); !s.ok()) return Fail(s);  // the X-ray cut-away
      auto img = Render(cam.pose(), std::max(1, W / d), std::max(1, H / d));
      if (!img.ok()) return Fail(img.status());
      auto jpeg = EncodeJpeg(*img, o_.jpeg_quality);
      if (!jpeg.ok()) return Fail(jpeg.status());
      (*http)->PublishFrame(*std::move(jpeg));
      last_pose = cam.pose();
      have_frame = true;
      overlay_due = true;
      const double ms = MsSince(t0);
      if (changed) adaptive.ReportMovingFrame(ms);
      stage_ = d;
      const Rigid3d& p = cam.pose();
      nlohmann::json j = {{"frame_ms", ms},
                          {"stage", d},
                          {"frames", frames + 1},
                          {"width", img->width()},
                          {"height", img->height()},
                          {"model_version", info_->version},
                          {"views", info_->geom.views.size()},
                          {"completion_views", CountCompletionViews(info_->geom)},
                          {"cells", info_->cells},
                          {"sync", source_->state()},
                          {"bytes_received", source_->bytes()},
                          {"clients", (*http)->clients()},
                          {"follow", follow_},
                          {"speed_mps", cam.speed_mps()},
                          {"cells_with_coverage", info_->geom.cell_coverage.size()},
                          {"pose_local", PoseJson(p)}};
      if (control_) j["control"] = control_->state();
      std::lock_guard lock(status_mu);
      frame_ms = ms;
      ++frames;
      status_text = j.dump();
    }
    http->reset();
    if (source_->live())
      if (auto s = SaveModel(); !s.ok()) return Fail(s);
    return 0;
  }

  // ---- benchmark: scripted motion through the real window loop ----
  // Per mode: the camera walks forward with a slow turn at real time (like W held) through the
  // same render thread + UI loop as the window, until bench_frames new frames were presented;
  // then it stops and the loop runs until the full-quality frame is on screen. Frame time = the
  // time between new pictures on screen (what the person sees); CPU = process CPU time (every
  // thread: render, lavapipe's rasteriser threads, presentation) per presented frame.
  int RunBench() {
    if (auto s = InitModelAndRenderer(true); !s.ok()) return Fail(s);
    PresenterOptions po;
    po.width = o_.width;
    po.height = o_.height;
    po.title = "Exoview benchmark";
    auto presenter = Presenter::Create(po);
    if (!presenter.ok()) return Fail(presenter.status());
    presenter_ = std::move(*presenter);
    overlays_ = o_.overlays;
    want_occ_ = overlays_;
    const int W = presenter_->width(), H = presenter_->height();
    nav::FlyOptions fo;
    fo.speed_mps = std::max(0.1, nav::ModelBounds(info_->geom).Diagonal() * 0.05);
    const glm::dvec3 up = nav::SceneUp(info_->geom);
    const uint32_t wake_event = SDL_RegisterEvents(1);
    if (wake_event == uint32_t(-1)) return Fail(absl::InternalError("SDL_RegisterEvents failed"));
    // Warm-up (shader JIT, first upload) at every size.
    for (int d : {1, 2, 4, 8}) {
      presenter_->NewFrame();
      auto r = Render(StartPose(), W / d, H / d);
      if (!r.ok()) return Fail(r.status());
      if (auto s = presenter_->Present(&*r); !s.ok()) return Fail(s);
    }
    auto median = [](std::vector<double> v) {
      if (v.empty()) return 0.0;
      std::sort(v.begin(), v.end());
      return v[v.size() / 2];
    };
    auto p90 = [](std::vector<double> v) {
      if (v.empty()) return 0.0;
      std::sort(v.begin(), v.end());
      return v[std::min(v.size() - 1, size_t(v.size() * 0.9))];
    };
    auto vmax = [](const std::vector<double>& v) {
      return v.empty() ? 0.0 : *std::max_element(v.begin(), v.end());
    };
    nlohmann::json modes = nlohmann::json::object();
    Rigid3d still_pose;
    struct Mode {
      const char* name;
      bool enabled;
      double target_ms;
    };
    for (const Mode& mode : {Mode{"adaptive_budget", true, o_.target_ms > 0 ? o_.target_ms : 33.3},
                             Mode{"adaptive_fixed", true, 0.0}, Mode{"full_always", false, 0.0}}) {
      if (("," + o_.bench_modes + ",").find("," + std::string(mode.name) + ",") == std::string::npos)
        continue;
      const nav::AdaptiveOptions ao = AdaptiveFromFlags(mode.enabled, mode.target_ms);
      if (auto s = ao.Validate(); !s.ok()) return Fail(s);
      nav::FlyCamera cam(StartPose(), up, fo);
      std::unique_ptr<Scheduler> sched = StartRenderThread(ao, wake_event);
      std::vector<double> moving, moving_render, moving_gpu, moving_present, ui_gaps_moving,
          ui_gaps_still, still_stage_ms, reuse;
      std::vector<int> still_divisors;
      std::map<int, int> divisors;
      double still_to_full = -1;
      // One UI iteration: wait for a frame or 5 ms, step the camera (real dt), post, present a
      // new frame. Returns the frame presented, if any.
      auto t_last = Clock::now(), t_walk = Clock::now();
      auto iterate = [&](bool walk, std::vector<double>* gaps)
          -> absl::StatusOr<std::optional<Scheduler::Done>> {
        SDL_WaitEventTimeout(nullptr, 5);
        const auto t_work = Clock::now();
        SDL_Event e;
        while (SDL_PollEvent(&e))
          if (e.type != wake_event) presenter_->ProcessEvent(e);
        const double dt = std::min(0.25, MsSince(t_last) * 1e-3);
        t_last = Clock::now();
        if (walk) {
          // Forward for a second with a slow turn right (3 px per 1/30 s), then back with the
          // turn undone, and again: any number of frames stays near the start of the walk.
          const bool out = int(MsSince(t_walk) / 1000.0) % 2 == 0;
          nav::FlyInput in;
          in.forward = out;
          in.back = !out;
          in.look_dx_px = (out ? 90.0 : -90.0) * dt;
          cam.Step(in, dt);
        }
        sched->Post({cam.pose(), W, H, 0});
        EXO_RETURN_IF_ERROR(sched->status());
        std::optional<Scheduler::Done> nf = sched->TakeFrame();
        if (nf) {
          presenter_->NewFrame();
          DrawOverlays(*nf->frame.info, nf->job.request.pose, nf->frame.occ_depth, W, H);
          PresentTimings pt;
          EXO_RETURN_IF_ERROR(presenter_->Present(&nf->frame.image, &pt));
          moving_present.push_back(pt.upload_ms + pt.submit_ms);
        }
        gaps->push_back(MsSince(t_work));  // input handling to present: what waits for nothing
        return nf;
      };
      // Moving.
      const nlohmann::json load_start = RunInfo().value("loadavg", nlohmann::json());
      const double cpu0 = ProcessCpuMs();
      const auto t_move = Clock::now();
      t_walk = t_last = Clock::now();
      auto t_prev = Clock::now();
      int got = 0;
      moving_present.clear();
      while (got < o_.bench_frames) {
        auto nf = iterate(true, &ui_gaps_moving);
        if (!nf.ok()) return Fail(nf.status());
        if (!*nf) continue;
        if (got > 0) moving.push_back(MsSince(t_prev));  // the first waits for the thread start
        t_prev = Clock::now();
        moving_render.push_back((*nf)->render_ms);
        moving_gpu.push_back((*nf)->frame.gpu_ms);
        ++divisors[(*nf)->job.divisor];
        ++got;
      }
      const double moving_s = MsSince(t_move) * 1e-3;
      const double cpu_per_frame = (ProcessCpuMs() - cpu0) / std::max(1, got);
      std::vector<double> presents = moving_present;
      // Still: the progressive stages until the full-quality frame is on screen.
      if (modes.empty()) still_pose = cam.pose();  // the SSIMs below: the first mode's stop
      const auto t_stop = Clock::now();
      while (MsSince(t_stop) < 120e3) {
        auto nf = iterate(false, &ui_gaps_still);
        if (!nf.ok()) return Fail(nf.status());
        if (*nf) {
          still_divisors.push_back((*nf)->job.divisor);
          still_stage_ms.push_back(MsSince(t_stop));
          if ((*nf)->job.divisor == 1 &&
              (*nf)->job.request.pose.translation == cam.pose().translation) {
            still_to_full = MsSince(t_stop);
            break;
          }
        }
      }
      sched->Stop();
      // Converged: the last frame reused, only the overlay redrawn.
      for (int i = 0; i < 10; ++i) {
        const auto t0 = Clock::now();
        presenter_->NewFrame();
        if (auto s = presenter_->Present(nullptr); !s.ok()) return Fail(s);
        reuse.push_back(MsSince(t0));
      }
      nlohmann::json hist = nlohmann::json::object();
      for (auto [d, n] : divisors) hist[std::to_string(d)] = n;
      modes[mode.name] = {{"target_ms", mode.target_ms},
                          {"moving_divisor_frames", hist},
                          {"moving_median_ms", median(moving)},
                          {"moving_p90_ms", p90(moving)},
                          {"moving_fps", got / std::max(1e-9, moving_s)},
                          {"moving_fps_from_median", 1000.0 / std::max(1e-9, median(moving))},
                          {"moving_cpu_ms_per_frame", cpu_per_frame},
                          // What the CPU time implies without other load: every thread's work
                          // of a frame run one after the other on one core (a lower bound on
                          // two idle cores, where rendering and presentation overlap).
                          {"moving_fps_one_idle_core", 1000.0 / std::max(1e-9, cpu_per_frame)},
                          {"moving_s", moving_s},
                          {"loadavg_start", load_start},
                          {"loadavg_end", RunInfo().value("loadavg", nlohmann::json())},
                          {"moving_render_median_ms", median(moving_render)},
                          {"moving_render_gpu_median_ms", median(moving_gpu)},
                          {"moving_present_median_ms", median(presents)},
                          {"moving_ui_gap_max_ms", vmax(ui_gaps_moving)},
                          {"still_stage_divisors", still_divisors},
                          {"still_stage_at_ms", still_stage_ms},
                          {"still_to_full_ms", still_to_full},
                          {"still_ui_gap_max_ms", vmax(ui_gaps_still)},
                          {"still_ui_iterations", ui_gaps_still.size()},
                          {"still_reuse_median_ms", median(reuse)}};
    }
    // What the person sees at each stage, against the full-quality frame at the still pose:
    // moving frames (with the candidate cap) and the exact refinement stages after stopping.
    auto full = Render(still_pose, W, H);
    if (!full.ok()) return Fail(full.status());
    nlohmann::json ssim = nlohmann::json::object(), ssim_moving = nlohmann::json::object();
    for (int d : {8, 4, 2, 1}) {
      const char* name = d == 1 ? "full" : d == 2 ? "half" : d == 4 ? "quarter" : "eighth";
      for (bool moving : {false, true}) {
        auto r = RenderFull(still_pose, W / d, H / d, moving);
        if (!r.ok()) return Fail(r.status());
        auto s = Ssim(d == 1 ? r->color : ResizeBilinear(r->color, W, H), *full);
        if (!s.ok()) return Fail(s.status());
        (moving ? ssim_moving : ssim)[name] = *s;
      }
    }
    const nlohmann::json out = {{"bench", "exoview_window"},
                                {"run_info", RunInfo()},
                                {"label", o_.bench_label},
                                {"model", o_.model_file},
                                {"views", info_->geom.views.size()},
                                {"cells", info_->cells},
                                {"chunks", info_->geom.chunks.size()},
                                {"proxy_triangles", ProxyTriangles()},
                                {"width", W},
                                {"height", H},
                                {"overlays", overlays_},
                                {"render_device", renderer_->DeviceName()},
                                {"present_device", presenter_->DeviceName()},
                                {"n_best", o_.n_best},
                                {"frames_moving", o_.bench_frames},
                                {"modes", modes},
                                {"moving_candidates", o_.moving_candidates},
                                {"ssim_to_full", ssim},
                                {"ssim_moving_to_full", ssim_moving}};
    std::printf("%s\n", out.dump().c_str());
    if (!o_.bench_json.empty()) std::ofstream(o_.bench_json) << out.dump(1) << "\n";
    presenter_.reset();
    return 0;
  }

 private:
  WindowAppOptions o_;
  std::unique_ptr<ModelSource> source_;
  std::unique_ptr<VulkanRenderer> renderer_;
  std::unique_ptr<Presenter> presenter_;
  std::shared_ptr<const SceneInfo> info_ = std::make_shared<SceneInfo>();
  bool synced_once_ = false;
  bool overlays_ = true, show_frusta_ = true, show_wire_ = false, show_cells_ = false;
  bool cells_by_tau_ = true, show_drone_ = true;
  // Key T: pixels the renderer blended from inpainted views (coverage code 4) tinted magenta;
  // the count of the last frame rendered with the tint.
  std::atomic<bool> tint_inpainted_{false};
  std::atomic<uint64_t> tinted_px_{0};
  std::unique_ptr<ControlSource> control_;  // drone overlays (nullptr: no control service)
  // Steering the drone from the viewer (issue 19 item 5): the commands' sender (nullptr: no
  // control service) and the gestures; the X-ray plane the render thread applies (0 = off).
  std::unique_ptr<DroneOperator> operator_;
  std::unique_ptr<DroneControls> controls_;
  mutable std::mutex xray_mu_;
  std::optional<XrayHole> xray_hole_;  // guarded by xray_mu_ (the UI sets, the renders read)
  std::optional<glm::dvec2> press_px_;  // an operator press that is not (yet) a drag
  bool rerender_ = false;               // the X-ray plane changed: render the view again
  SDL_GameController* gamepad_ = nullptr;
  nlohmann::json probe_ = nlohmann::json::object();  // what the overlays drew (status file)
  bool follow_ = false, replaying_ = false;
  int stage_ = 1;
  double frame_ms_ = 0, render_ms_ = 0, present_ms_ = 0;
  std::optional<nav::PickResult> centre_pick_, cursor_pick_;
  Clock::time_point t_centre_{};  // render thread: the last centre pick; one skipped since
  bool centre_stale_ = false;
  std::string last_sync_state_;
  std::atomic<bool> want_occ_{false};  // the render thread adds the overlays' proxy depth
  double ui_max_gap_ms_ = 0;
  bool frame_moving_ = true;  // the frame on screen was rendered for a moving camera  // longest UI-loop iteration (input to present), waits excluded
  // The live DR view (key V): the subscription (only while the mode is on) and its newest frame.
  bool dr_mode_ = false;
  std::unique_ptr<CompletionRequester> completion_;  // key C (created on the first press)
  std::string completion_note_;
  DrLive dr_;                                // before dr_watch_: its thread writes here
  std::unique_ptr<DrViewWatcher> dr_watch_;  // (destroyed first)
  uint64_t dr_shown_sequence_ = 0;
  std::string dr_note_;  // why the DR view cannot be watched at all (no server)  // the uploaded frame's sequence of the DR picture on screen
};

}  // namespace

int RunWindowApp(const WindowAppOptions& o) {
  if (int(!o.model_file.empty()) + int(!o.server.empty()) + int(!o.checkpoint.empty()) != 1) {
    std::fprintf(stderr,
                 "exoview_window: give exactly one of --model FILE, --checkpoint FILE or --server "
                 "HOST:PORT\n");
    return 2;
  }
  if (!o.path.empty() && o.out_dir.empty()) {
    std::fprintf(stderr, "exoview_window: --path needs --out_dir\n");
    return 2;
  }
  App app(o);
  if (!o.path.empty()) return app.RunPath();
  if (o.bench) return app.RunBench();
  if (!o.http.empty()) return app.RunHttp();
  return app.RunWindow();
}

}  // namespace exo
