// exoview_render: renders a stored lumigraph model along a camera path with the Vulkan client
// engine (lavapipe) and writes PNG frames or an MJPEG stream, with a progress bar on stderr and
// one JSON summary line on stdout.
//
//   exoview_render --model=FILE.exomodel | --synthetic=village|apartment [options]
// Model:
//   --model=FILE           a model file (common/lumigraph/model_io.h)
//   --synthetic=SCENE      build one from common/synth: the scene's own trajectory rendered as
//                          RGB-D frames, the online view planner (server/planning) choosing the
//                          stored views and per-cell references, the scene mesh as proxy
//   --synth_frames=N       trajectory frames offered to the planner (default 120)
//   --store=N --r_max=N    planner store capacity (default 60) and refs per cell (default 16)
//   --save_model=FILE      write the model that is rendered (e.g. the synthetic one)
// Camera path (scene-local frame, camera looks along +z, image y down):
//   --path=FILE            one pose per line "tx ty tz qw qx qy qz" (local_from_cam), # comments
//   --path_format=tum      the path is a TUM trajectory "t tx ty tz qx qy qz qw" (world_from_cam)
//   --intrinsics=fx,fy,cx,cy  the rendered camera (e.g. 7-Scenes 585,585,320,240 at 640x480)
//   --orbit=N              N poses on a circle around the proxy's bounding box, looking at its
//                          centre (default when no path is given: 60 poses)
//   --synthetic paths default to the scene trajectory between the stored frames (novel views)
//   --write_path=FILE      write the path used in the --path format
// Output:
//   --out_dir=DIR          frame_00000.png ...       --mjpeg=FILE  concatenated JPEG frames
//   --width=640 --height=480 --hfov_deg=65 --jpeg_quality=90 --n_best=3
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>

#include "client/vulkan/vulkan_renderer.h"
#include "common/cli/cli.h"
#include "common/io/image_file.h"
#include "common/io/jpeg.h"
#include "common/lumigraph/model_io.h"
#include "common/raster/rasterizer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "server/geometry/cell_areas.h"
#include "server/geometry/scene_scale.h"
#include "server/planning/view_planner.h"

namespace exo {
namespace {

using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}

struct Args {
  std::string model, synthetic, save_model, path, write_path, out_dir, mjpeg;
  std::string path_format = "local";  // local | tum
  std::vector<double> intrinsics;     // fx, fy, cx, cy at --width x --height (empty: --hfov_deg)
  int synth_frames = 120, store = 60, r_max = 16, orbit = 0;
  int width = 640, height = 480, jpeg_quality = 90, n_best = 3;
  double hfov_deg = 65.0;
};

// Flags (common/cli): --key=value or --key value; --help lists them with their defaults.
absl::StatusOr<Args> ValidateArgs(Args a) {
  if (a.model.empty() == a.synthetic.empty())
    return absl::InvalidArgumentError("give exactly one of --model=FILE or --synthetic=SCENE");
  if (a.width < 16 || a.height < 16 || a.width > 8192 || a.height > 8192)
    return absl::InvalidArgumentError("--width/--height must be in [16, 8192]");
  if (!(a.hfov_deg > 1 && a.hfov_deg < 170)) return absl::InvalidArgumentError("bad --hfov_deg");
  if (a.synth_frames < 2 || a.store < 1 || a.r_max < 2 || a.r_max > 256)
    return absl::InvalidArgumentError("bad --synth_frames / --store / --r_max");
  if (a.jpeg_quality < 1 || a.jpeg_quality > 100)
    return absl::InvalidArgumentError("--jpeg_quality must be in [1, 100]");
  if (a.orbit < 0 || a.orbit > 100000) return absl::InvalidArgumentError("bad --orbit");
  if (!a.intrinsics.empty()) {
    if (a.intrinsics.size() != 4 || !(a.intrinsics[0] > 0) || !(a.intrinsics[1] > 0))
      return absl::InvalidArgumentError("--intrinsics needs fx,fy,cx,cy with fx, fy > 0");
    for (double v : a.intrinsics)
      if (!std::isfinite(v)) return absl::InvalidArgumentError("--intrinsics: not finite");
  }
  return a;
}

// ---- camera path file: "tx ty tz qw qx qy qz" per line ----
// format "local": "tx ty tz qw qx qy qz" (local_from_cam). format "tum": the TUM RGB-D trajectory
// format "timestamp tx ty tz qx qy qz qw" (world_from_cam, e.g. exoview_export's trajectory or a
// dataset's ground truth), made scene-local with the model's origin.
absl::StatusOr<std::vector<Rigid3d>> ReadPath(const std::string& file, const std::string& format,
                                              const LocalOrigin& origin) {
  std::ifstream f(file);
  if (!f) return absl::NotFoundError(absl::StrCat("cannot open camera path ", file));
  std::vector<Rigid3d> out;
  std::string line;
  for (int n = 1; std::getline(f, line); ++n) {
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    std::istringstream in(line);
    const bool tum = format == "tum";
    const int want = tum ? 8 : 7;
    double v[8];
    int k = 0;
    while (k < want && (in >> v[k])) ++k;
    if (k == 0 && in.eof()) continue;  // blank / comment
    std::string rest;
    if (k != want || (in >> rest))
      return absl::InvalidArgumentError(
          absl::StrCat(file, ":", n,
                       tum ? ": expected 8 numbers timestamp tx ty tz qx qy qz qw (TUM)"
                           : ": expected 7 numbers tx ty tz qw qx qy qz"));
    Rigid3d p;
    if (tum) {
      p.translation = {v[1], v[2], v[3]};
      p.rotation = glm::dquat(v[7], v[4], v[5], v[6]);
    } else {
      p.translation = {v[0], v[1], v[2]};
      p.rotation = glm::dquat(v[3], v[4], v[5], v[6]);
    }
    for (int i = 0; i < want; ++i)
      if (!std::isfinite(v[i]))
        return absl::InvalidArgumentError(absl::StrCat(file, ":", n, ": not finite"));
    const double qn = glm::length(p.rotation);
    if (std::abs(qn - 1.0) > 1e-3)
      return absl::InvalidArgumentError(absl::StrCat(file, ":", n, ": quaternion norm ", qn, " is not 1"));
    p.rotation = glm::normalize(p.rotation);
    out.push_back(tum ? origin.ToLocal(p) : p);
  }
  if (out.empty()) return absl::InvalidArgumentError(absl::StrCat(file, ": no poses"));
  return out;
}

absl::Status WritePath(const std::string& file, const std::vector<Rigid3d>& poses) {
  std::ofstream f(file);
  if (!f) return absl::UnavailableError(absl::StrCat("cannot write ", file));
  f << "# exoview camera path: local_from_cam per line, tx ty tz qw qx qy qz (scene-local frame)\n";
  char buf[256];
  for (const auto& p : poses) {
    std::snprintf(buf, sizeof(buf), "%.9g %.9g %.9g %.12g %.12g %.12g %.12g\n", p.translation.x,
                  p.translation.y, p.translation.z, p.rotation.w, p.rotation.x, p.rotation.y,
                  p.rotation.z);
    f << buf;
  }
  return f ? absl::OkStatus() : absl::UnavailableError(absl::StrCat("write failed: ", file));
}

// Orbit around the proxy's bounding box: radius 0.7 of the larger horizontal half-extent plus a
// margin, height a third of the diameter above the centre, looking at the centre.
absl::StatusOr<std::vector<Rigid3d>> OrbitPath(const LumigraphModel& m, int n) {
  glm::dvec3 lo(1e300), hi(-1e300);
  for (const auto& [id, c] : m.chunks)
    for (const auto& p : c.mesh.positions) {
      lo = glm::min(lo, glm::dvec3(p));
      hi = glm::max(hi, glm::dvec3(p));
    }
  if (!(lo.x <= hi.x)) return absl::FailedPreconditionError("the model has no proxy geometry to orbit");
  const glm::dvec3 centre = 0.5 * (lo + hi);
  const double diameter = glm::length(hi - lo);
  const double radius = 0.7 * std::max(hi.x - lo.x, hi.y - lo.y) + 0.05 * diameter;
  std::vector<Rigid3d> out;
  for (int i = 0; i < n; ++i) {
    const double a = 2.0 * M_PI * i / n;
    const glm::dvec3 eye = centre + glm::dvec3(radius * std::cos(a), radius * std::sin(a),
                                               diameter / 3.0);
    out.push_back(synth::LookAt(eye, centre));
  }
  return out;
}

// ---- synthetic model: scene trajectory -> planner -> stored views + refs ----
struct SyntheticModel {
  LumigraphModel model;
  std::vector<Rigid3d> novel_path;  // trajectory poses halfway between offered frames
};

absl::StatusOr<SyntheticModel> BuildSynthetic(const Args& args) {
  EXO_ASSIGN_OR_RETURN(const auto kind, synth::ParseSceneKind(args.synthetic));
  EXO_ASSIGN_OR_RETURN(synth::SynthScene scene, synth::MakeScene(kind, {}));
  const auto tkind = scene.indoor ? synth::TrajectoryKind::kWalk : synth::TrajectoryKind::kFlyover;
  const SceneScale scale = DeriveSceneScale(scene.bounds.min, scene.bounds.max);
  synth::RenderOptions ro;  // stored views 640x480
  const PinholeCamera cam = ro.Camera();
  const size_t frame_bytes = size_t(cam.width) * cam.height * (3 + 4) + sizeof(StoredView);
  planning::PlannerOptions po;
  po.r_max = args.r_max;
  po.max_views = size_t(args.store);
  po.max_bytes = size_t(args.store) * frame_bytes;
  po.cell_size_m = scale.cell_size_m;
  po.d_max_m = scale.d_max_m;
  po.sigma_m = scale.sigma_m;
  po.lambda = scene.indoor ? 0.4 : 0.5;
  EXO_ASSIGN_OR_RETURN(planning::ViewPlanner planner, planning::ViewPlanner::Create(po));
  MeshChunk chunk;
  chunk.id = 0;
  chunk.version = 1;
  chunk.mesh = scene.mesh;
  CellAreas areas(planner.grid());
  areas.UpdateChunk(chunk);
  for (const auto& [cell, a] : areas.areas()) EXO_RETURN_IF_ERROR(planner.SetCellArea(cell, a));
  synth::TrajectoryOptions to;
  to.num_frames = 2 * args.synth_frames;  // odd frames become the novel (test) path
  EXO_ASSIGN_OR_RETURN(auto traj, synth::MakeTrajectory(scene, tkind, to));
  RasterOptions rop;
  rop.cell_id = true;
  rop.cell_grid = planner.grid();
  rop.width = 160;
  rop.height = 120;
  SyntheticModel out;
  std::map<ViewId, StoredView> stored;
  for (size_t i = 0; i < traj.size(); ++i) {
    const Rigid3d& pose = traj[i].local_from_cam;
    if (i % 2 == 1) {
      out.novel_path.push_back(pose);
      continue;
    }
    if (isatty(2) || (i / 2) % 20 == 0)
      std::fprintf(stderr, "%sbuilding synthetic model: frame %zu/%zu, %zu views stored%s",
                   isatty(2) ? "\r" : "", i / 2 + 1, traj.size() / 2, planner.num_views(),
                   isatty(2) ? "" : "\n");
    EXO_ASSIGN_OR_RETURN(auto ids, Rasterize(scene.mesh, cam, pose, rop));
    planning::Candidate c;
    c.id = ViewId(i + 1);
    c.local_from_cam = pose;
    c.id_camera = ids.camera;
    c.cells = planning::CountCellPixels(ids.cell_id.data(), ids.cell_id.size());
    c.bytes = frame_bytes;
    EXO_ASSIGN_OR_RETURN(auto d, planner.Consider(c));
    if (!d.accepted) continue;
    for (ViewId v : d.removed) stored.erase(v);
    EXO_ASSIGN_OR_RETURN(auto f, synth::RenderFrame(scene, pose, ro));
    StoredView sv;
    sv.id = c.id;
    sv.camera = cam;
    sv.local_from_cam = pose;
    sv.color = std::move(f.frame.color);
    sv.depth_m = std::move(f.frame.depth_m);
    stored[c.id] = std::move(sv);
  }
  std::fprintf(stderr, "\n");
  out.model.origin = scene.origin;
  out.model.grid = planner.grid();
  out.model.views = std::move(stored);
  out.model.cell_refs = planner.CellPublishedRefs();
  // Proxy in chunks of <= 4096 triangles (one draw each).
  const TriangleMesh& mesh = scene.mesh;
  const size_t per = 4096;
  for (size_t t0 = 0, k = 0; t0 < mesh.num_triangles(); t0 += per, ++k) {
    MeshChunk c;
    c.id = k;
    c.version = 1;
    const size_t t1 = std::min(mesh.num_triangles(), t0 + per);
    std::vector<int64_t> remap(mesh.positions.size(), -1);
    for (size_t t = t0; t < t1; ++t)
      for (int j = 0; j < 3; ++j) {
        const uint32_t vi = mesh.indices[3 * t + j];
        if (remap[vi] < 0) {
          remap[vi] = int64_t(c.mesh.positions.size());
          c.mesh.positions.push_back(mesh.positions[vi]);
        }
        c.mesh.indices.push_back(uint32_t(remap[vi]));
      }
    out.model.chunks[k] = std::move(c);
  }
  return out;
}

// On a terminal: one bar redrawn in place; otherwise (logs) a line per 10 %.
void Progress(int done, int total, double elapsed_ms) {
  static const bool tty = isatty(2);
  if (!tty && done != total && (done * 10 / total) == ((done - 1) * 10 / total)) return;
  const int width = 40;
  const int filled = total > 0 ? done * width / total : width;
  std::string bar(size_t(filled), '#');
  bar.resize(width, '.');
  const double per = done > 0 ? elapsed_ms / done : 0.0;
  std::fprintf(stderr, "%s[%s] %d/%d frames  %.1f ms/frame  ETA %.0f s ", tty ? "\r" : "",
               bar.c_str(), done, total, per, per * (total - done) / 1000.0);
  if (done == total || !tty) std::fprintf(stderr, "\n");
  std::fflush(stderr);
}

int Main(int argc, char** argv) {
  Args parsed;
  CLI::App app{"Renders a stored lumigraph model (or a synthetic one) along a camera path with the "
               "Vulkan client engine; writes PNG frames or an MJPEG stream and one JSON summary "
               "line on stdout.",
               "exoview_render"};
  cli::Setup(app);
  app.add_option("--model", parsed.model, "a model file (common/lumigraph/model_io.h)");
  app.add_option("--synthetic", parsed.synthetic,
                 "build a model from common/synth (village|apartment): the scene trajectory as "
                 "RGB-D frames, the online view planner choosing views and cell references");
  app.add_option("--synth_frames", parsed.synth_frames, "trajectory frames offered to the planner")
      ->capture_default_str();
  app.add_option("--store", parsed.store, "planner store capacity (views)")->capture_default_str();
  app.add_option("--r_max", parsed.r_max, "planner references per cell")->capture_default_str();
  app.add_option("--save_model", parsed.save_model, "write the model that is rendered");
  app.add_option("--path", parsed.path,
                 "camera path: one pose per line 'tx ty tz qw qx qy qz' (local_from_cam), # comments");
  app.add_option("--path_format", parsed.path_format,
                 "local: 'tx ty tz qw qx qy qz' local_from_cam; tum: 'timestamp tx ty tz qx qy qz "
                 "qw' world_from_cam (made local with the model's origin)")
      ->check(CLI::IsMember({"local", "tum"}))
      ->capture_default_str();
  app.add_option("--intrinsics", parsed.intrinsics,
                 "fx,fy,cx,cy of the rendered camera at --width x --height (default: --hfov_deg)")
      ->delimiter(',');
  app.add_option("--orbit", parsed.orbit,
                 "N poses on a circle around the proxy's bounding box (default without a path: 60; "
                 "synthetic models default to the scene trajectory between the stored frames)");
  app.add_option("--write_path", parsed.write_path, "write the path used, in the --path format");
  app.add_option("--out_dir", parsed.out_dir, "write frame_00000.png ... here");
  app.add_option("--mjpeg", parsed.mjpeg, "write concatenated JPEG frames to this file");
  app.add_option("--width", parsed.width, "image width (px)")->capture_default_str();
  app.add_option("--height", parsed.height, "image height (px)")->capture_default_str();
  app.add_option("--hfov_deg", parsed.hfov_deg, "horizontal field of view (degrees)")
      ->capture_default_str();
  app.add_option("--jpeg_quality", parsed.jpeg_quality, "MJPEG quality [1, 100]")
      ->capture_default_str();
  app.add_option("--n_best", parsed.n_best, "views blended per pixel")->capture_default_str();
  if (auto rc = cli::Parse(app, argc, argv)) return *rc;
  auto args_or = ValidateArgs(parsed);
  if (!args_or.ok()) {
    std::fprintf(stderr, "exoview_render: %s\n", std::string(args_or.status().message()).c_str());
    return 2;
  }
  const Args& args = *args_or;
  LumigraphModel model;
  std::vector<Rigid3d> path;
  if (!args.model.empty()) {
    auto m = LoadModel(args.model);
    if (!m.ok()) {
      std::fprintf(stderr, "exoview_render: %s\n", m.status().ToString().c_str());
      return 1;
    }
    model = std::move(*m);
  } else {
    auto s = BuildSynthetic(args);
    if (!s.ok()) {
      std::fprintf(stderr, "exoview_render: %s\n", s.status().ToString().c_str());
      return 1;
    }
    model = std::move(s->model);
    if (args.path.empty() && args.orbit == 0) path = std::move(s->novel_path);
  }
  if (!args.save_model.empty()) {
    if (auto st = SaveModel(args.save_model, model); !st.ok()) {
      std::fprintf(stderr, "exoview_render: %s\n", st.ToString().c_str());
      return 1;
    }
  }
  if (!args.path.empty()) {
    auto p = ReadPath(args.path, args.path_format, model.origin);
    if (!p.ok()) {
      std::fprintf(stderr, "exoview_render: %s\n", p.status().ToString().c_str());
      return 1;
    }
    path = std::move(*p);
  } else if (path.empty()) {
    auto p = OrbitPath(model, args.orbit > 0 ? args.orbit : 60);
    if (!p.ok()) {
      std::fprintf(stderr, "exoview_render: %s\n", p.status().ToString().c_str());
      return 1;
    }
    path = std::move(*p);
  }
  if (!args.write_path.empty()) {
    if (auto st = WritePath(args.write_path, path); !st.ok()) {
      std::fprintf(stderr, "exoview_render: %s\n", st.ToString().c_str());
      return 1;
    }
  }
  // Renderer: reference slots sized to the model's longest list.
  VulkanRendererOptions vo;
  for (const auto& [c, refs] : model.cell_refs)
    vo.max_refs_per_cell = std::max<int>(vo.max_refs_per_cell, int(refs.size()));
  auto r = VulkanRenderer::Create(vo);
  if (!r.ok()) {
    std::fprintf(stderr, "exoview_render: %s\n", r.status().ToString().c_str());
    return 1;
  }
  const auto t_up = Clock::now();
  if (auto st = (*r)->SyncModel(model); !st.ok()) {
    std::fprintf(stderr, "exoview_render: %s\n", st.ToString().c_str());
    return 1;
  }
  const double upload_ms = MsSince(t_up);
  std::FILE* mjpeg = nullptr;
  if (!args.mjpeg.empty()) {
    mjpeg = std::fopen(args.mjpeg.c_str(), "wb");
    if (!mjpeg) {
      std::fprintf(stderr, "exoview_render: cannot write %s\n", args.mjpeg.c_str());
      return 1;
    }
  }
  if (!args.out_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(args.out_dir, ec);
    if (ec) {
      std::fprintf(stderr, "exoview_render: cannot create %s: %s\n", args.out_dir.c_str(),
                   ec.message().c_str());
      return 1;
    }
  }
  PinholeCamera cam = PinholeCamera::FromFov(args.width, args.height, args.hfov_deg * M_PI / 180.0);
  if (!args.intrinsics.empty()) {
    cam.fx = args.intrinsics[0];
    cam.fy = args.intrinsics[1];
    cam.cx = args.intrinsics[2];
    cam.cy = args.intrinsics[3];
  }
  blend::BlendOptions bo;
  bo.n_best = args.n_best;
  std::vector<double> render_ms;
  double first_ms = 0, write_ms = 0;
  size_t out_bytes = 0;
  const auto t_all = Clock::now();
  int status = 0;
  for (size_t i = 0; i < path.size(); ++i) {
    const auto t0 = Clock::now();
    auto out = (*r)->Render(cam, path[i], bo);
    const double ms = MsSince(t0);
    if (!out.ok()) {
      std::fprintf(stderr, "\nexoview_render: frame %zu: %s\n", i, out.status().ToString().c_str());
      status = 1;
      break;
    }
    (i == 0 ? first_ms : render_ms.emplace_back()) = ms;
    const auto t1 = Clock::now();
    if (!args.out_dir.empty()) {
      char name[64];
      std::snprintf(name, sizeof(name), "/frame_%05zu.png", i);
      if (auto st = WriteColorImage(args.out_dir + name, out->color); !st.ok()) {
        std::fprintf(stderr, "\nexoview_render: %s\n", st.ToString().c_str());
        status = 1;
        break;
      }
    }
    if (mjpeg) {
      auto jpeg = EncodeJpeg(out->color, args.jpeg_quality);
      if (!jpeg.ok() || std::fwrite(jpeg->data(), 1, jpeg->size(), mjpeg) != jpeg->size()) {
        std::fprintf(stderr, "\nexoview_render: writing %s failed\n", args.mjpeg.c_str());
        status = 1;
        break;
      }
      out_bytes += jpeg->size();
    }
    write_ms += MsSince(t1);
    Progress(int(i + 1), int(path.size()), MsSince(t_all));
  }
  if (mjpeg && std::fclose(mjpeg) != 0) status = 1;
  std::sort(render_ms.begin(), render_ms.end());
  const double median = render_ms.empty() ? first_ms : render_ms[render_ms.size() / 2];
  std::printf("{\"tool\":\"exoview_render\",\"device\":\"%s\",\"views\":%zu,\"cells\":%zu,"
              "\"chunks\":%zu,\"frames\":%zu,\"width\":%d,\"height\":%d,\"upload_ms\":%.1f,"
              "\"first_frame_ms\":%.1f,\"median_render_ms\":%.2f,\"write_ms_per_frame\":%.2f,"
              "\"mjpeg_bytes\":%zu,\"status\":%d}\n",
              (*r)->DeviceName().c_str(), model.views.size(), model.cell_refs.size(),
              model.chunks.size(), path.size(), args.width, args.height, upload_ms, first_ms, median,
              path.empty() ? 0.0 : write_ms / path.size(), out_bytes, status);
  return status;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) { return exo::Main(argc, argv); }
