// exoview_synth: the main job on the embedded default. Generates the synthetic scenes and writes
// frames (Exoview layout), ground-truth test views, PNG previews and report.json/report.md.
//
//   exoview_synth --out DIR [--scene village|apartment|all] [--trajectory flyover|walk|all]
//                 [--frames N] [--test-poses N] [--seed S] [--width W --height H]
//                 [--exposure-jitter X] [--pose-noise-deg D] [--pose-noise-m M] [--specular]
//                 [--threads T] [--preview-at F]   (--key=value works too; --help lists them)
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "absl/strings/str_format.h"
#include "common/cli/cli.h"
#include "common/datasets/exo_layout.h"
#include "common/io/image_file.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace exo::synth {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using json = nlohmann::ordered_json;  // fields in the order written

// Rounds to `digits` decimals for report.json.
double Round(double x, int digits) {
  const double f = std::pow(10.0, digits);
  return std::round(x * f) / f;
}

struct Args {
  std::string out;
  std::string scene = "all";
  std::string trajectory = "all";
  int frames = 120;
  int test_poses = 200;
  uint64_t seed = 1;
  int width = 640, height = 480;
  double exposure_jitter = 0;  // exposure = 2^U(-X, X) per frame
  double pose_noise_deg = 0, pose_noise_m = 0;
  bool specular = false;
  int threads = 2;
  double preview_at = 0.33;  // fraction along each trajectory of the preview frame
};

// Fills `a` from the flags; an exit code when the program should stop (--help, a bad flag).
std::optional<int> ParseArgs(int argc, char** argv, Args* a) {
  CLI::App app{"Generates the synthetic scenes: frames (Exoview layout), ground-truth test views, "
               "PNG previews and report.json/report.md.",
               "exoview_synth"};
  exo::cli::Setup(app);
  app.add_option("--out", a->out, "output folder")->required();
  app.add_option("--scene", a->scene, "scene")
      ->check(CLI::IsMember({"village", "apartment", "all"}));
  app.add_option("--trajectory", a->trajectory, "trajectory")
      ->check(CLI::IsMember({"flyover", "walk", "all"}));
  app.add_option("--frames", a->frames, "frames per trajectory")->check(CLI::PositiveNumber);
  app.add_option("--test-poses", a->test_poses, "ground-truth test views per scene")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--seed", a->seed, "random seed");
  app.add_option("--width", a->width, "image width")->check(CLI::PositiveNumber);
  app.add_option("--height", a->height, "image height")->check(CLI::PositiveNumber);
  app.add_option("--exposure-jitter", a->exposure_jitter,
                 "per-frame exposure 2^U(-X, X), X in stops")
      ->check(CLI::Range(0.0, 4.0));
  app.add_option("--pose-noise-deg", a->pose_noise_deg, "rotation noise of the written poses, deg")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--pose-noise-m", a->pose_noise_m, "translation noise of the written poses, m")
      ->check(CLI::NonNegativeNumber);
  app.add_flag("--specular", a->specular, "specular highlights");
  app.add_option("--threads", a->threads, "render threads")->check(CLI::PositiveNumber);
  app.add_option("--preview-at", a->preview_at, "fraction along each trajectory of the preview")
      ->check(CLI::Range(0.0, 1.0));
  return exo::cli::Parse(app, argc, argv);
}

std::string PoseLine(uint64_t seq, double t, const Rigid3d& p) {
  const glm::dmat3 R = p.RotationMatrix();  // column-major: R[col][row]
  std::string s = absl::StrCat(seq, " ", t);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) absl::StrAppend(&s, " ", absl::StrFormat("%.9f", R[c][r]));
    absl::StrAppend(&s, " ", absl::StrFormat("%.9f", p.translation[r]));
  }
  return s + "\n";
}

// Box-filtered downscale of an RGB8 image by an integer factor (for previews).
ImageU8 Downscale(const ImageU8& img, int f) {
  ImageU8 out(img.width() / f, img.height() / f, 3);
  for (int y = 0; y < out.height(); ++y)
    for (int x = 0; x < out.width(); ++x)
      for (int c = 0; c < 3; ++c) {
        int sum = 0;
        for (int j = 0; j < f; ++j)
          for (int i = 0; i < f; ++i) sum += img.at(x * f + i, y * f + j, c);
        out.at(x, y, c) = static_cast<uint8_t>((sum + f * f / 2) / (f * f));
      }
  return out;
}

// Depth preview: near = bright, far = dark, background black.
ImageU8 DepthPreview(const ImageF& d, float max_m) {
  ImageU8 out(d.width(), d.height(), 3, 0);
  for (int y = 0; y < d.height(); ++y)
    for (int x = 0; x < d.width(); ++x) {
      const float z = d.at(x, y);
      if (z <= 0) continue;
      const auto v = static_cast<uint8_t>(255.0f * std::clamp(1.0f - z / max_m, 0.05f, 1.0f));
      for (int c = 0; c < 3; ++c) out.at(x, y, c) = v;
    }
  return out;
}

struct SequenceReport {
  std::string scene, trajectory;
  int frames = 0;
  double render_ms_mean = 0, write_ms_mean = 0, seconds = 0;
  double path_length_m = 0;
};

absl::Status Run(const Args& args) {
  const auto t_start = Clock::now();
  std::vector<SceneKind> scenes;
  if (args.scene == "all") {
    scenes = {SceneKind::kVillage, SceneKind::kApartment};
  } else {
    EXO_ASSIGN_OR_RETURN(SceneKind k, ParseSceneKind(args.scene));
    scenes = {k};
  }
  std::vector<TrajectoryKind> trajs;
  if (args.trajectory == "all") {
    trajs = {TrajectoryKind::kFlyover, TrajectoryKind::kWalk};
  } else {
    EXO_ASSIGN_OR_RETURN(TrajectoryKind k, ParseTrajectoryKind(args.trajectory));
    trajs = {k};
  }
  RenderOptions ro;
  ro.width = args.width;
  ro.height = args.height;
  ro.specular = args.specular;
  ro.num_threads = args.threads;
  EXO_RETURN_IF_ERROR(ro.Validate());
  const fs::path out(args.out);
  std::error_code ec;
  fs::create_directories(out / "previews", ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create ", out.string(), ": ", ec.message()));

  json report = {{"tool", "exoview_synth"},
                 {"seed", args.seed},
                 {"width", args.width},
                 {"height", args.height},
                 {"hfov_deg", ro.hfov_deg},
                 {"specular", args.specular},
                 {"exposure_jitter_stops", args.exposure_jitter},
                 {"pose_noise_deg", args.pose_noise_deg},
                 {"pose_noise_m", args.pose_noise_m},
                 {"scenes", json::array()}};
  std::string md = "# exoview_synth report\n\n";
  absl::StrAppend(&md, "seed ", args.seed, ", ", args.width, "x", args.height, ", hfov ",
                  ro.hfov_deg, " deg, specular ", args.specular ? "on" : "off",
                  ", exposure jitter ", args.exposure_jitter, " stops, pose noise ",
                  args.pose_noise_deg, " deg / ", args.pose_noise_m, " m\n\n");
  absl::StrAppend(&md, "| scene | sequence | frames | path m | render ms/frame | write ms/frame | s |\n"
                       "|---|---|---|---|---|---|---|\n");
  std::string md_scenes;
  ExoLayoutOptions lo_jpeg;  // trajectory frames: JPEG colour like a camera stream
  ExoLayoutOptions lo_png;   // ground truth: lossless colour
  lo_png.color_format = ExoColorFormat::kPng;
  // Outdoor depth beyond 65 m would saturate mm units: 2 mm steps cover 131 m.
  for (size_t si = 0; si < scenes.size(); ++si) {
    SceneOptions so;
    so.seed = args.seed;
    const auto t_scene = Clock::now();
    EXO_ASSIGN_OR_RETURN(SynthScene scene, MakeScene(scenes[si], so));
    const double build_ms =
        std::chrono::duration<double, std::milli>(Clock::now() - t_scene).count();
    std::fprintf(stderr, "[synth] scene %s: %zu triangles, %zu vertices, extent %.1f m (%.0f ms)\n",
                 scene.name.c_str(), scene.mesh.num_triangles(), scene.mesh.num_vertices(),
                 scene.ExtentM(), build_ms);
    ExoLayoutOptions seq_opt = lo_jpeg, gt_opt = lo_png;
    if (!scene.indoor) seq_opt.depth_metres_per_unit = gt_opt.depth_metres_per_unit = 0.002;
    const fs::path sdir = out / scene.name;
    std::vector<SequenceReport> seqs;
    std::mt19937_64 rng(args.seed * 1000003 + si);
    for (TrajectoryKind tk : trajs) {
      if (tk == TrajectoryKind::kFlyover && scene.flyover_altitude_m <= 0) {
        std::fprintf(stderr, "[synth] %s: no fly-over indoors, skipped\n", scene.name.c_str());
        continue;
      }
      TrajectoryOptions to;
      to.num_frames = args.frames;
      EXO_ASSIGN_OR_RETURN(std::vector<TimedPose> poses, MakeTrajectory(scene, tk, to));
      const fs::path dir = sdir / TrajectoryKindName(tk);
      fs::remove_all(dir, ec);
      fs::create_directories(dir, ec);
      std::ofstream true_poses(dir / "poses_true.txt");
      SequenceReport rep{scene.name, TrajectoryKindName(tk)};
      const auto t_seq = Clock::now();
      double render_ms = 0, write_ms = 0;
      for (size_t i = 0; i < poses.size(); ++i) {
        FrameNoise noise;
        if (args.exposure_jitter > 0)
          noise.exposure = std::exp2(std::uniform_real_distribution<double>(
              -args.exposure_jitter, args.exposure_jitter)(rng));
        noise.rotation_deg = args.pose_noise_deg;
        noise.translation_m = args.pose_noise_m;
        noise.seed = args.seed * 7919 + i + 1000 * si;
        const auto t0 = Clock::now();
        EXO_ASSIGN_OR_RETURN(RenderedFrame rf, RenderFrame(scene, poses[i].local_from_cam, ro, noise,
                                                           i, poses[i].timestamp_s));
        const auto t1 = Clock::now();
        EXO_RETURN_IF_ERROR(WriteExoFrame(dir.string(), rf.frame, seq_opt));
        true_poses << PoseLine(i, poses[i].timestamp_s, rf.true_world_from_cam);
        const auto t2 = Clock::now();
        render_ms += std::chrono::duration<double, std::milli>(t1 - t0).count();
        write_ms += std::chrono::duration<double, std::milli>(t2 - t1).count();
        if (i == static_cast<size_t>(args.preview_at * (poses.size() - 1) + 0.5)) {
          const std::string base = absl::StrCat("synth_", scene.name, "_", rep.trajectory);
          EXO_RETURN_IF_ERROR(WriteColorImage((out / "previews" / (base + ".png")).string(),
                                              Downscale(rf.frame.color, 2)));
          EXO_RETURN_IF_ERROR(WriteColorImage(
              (out / "previews" / (base + "_depth.png")).string(),
              Downscale(DepthPreview(rf.frame.depth_m, scene.indoor ? 8.0f : 60.0f), 2)));
        }
        if ((i + 1) % 20 == 0 || i + 1 == poses.size())
          std::fprintf(stderr, "[synth] %s/%s: %zu/%zu frames\n", scene.name.c_str(),
                       rep.trajectory.c_str(), i + 1, poses.size());
      }
      rep.frames = static_cast<int>(poses.size());
      rep.render_ms_mean = render_ms / poses.size();
      rep.write_ms_mean = write_ms / poses.size();
      rep.seconds = std::chrono::duration<double>(Clock::now() - t_seq).count();
      for (size_t i = 1; i < poses.size(); ++i)
        rep.path_length_m += glm::length(poses[i].local_from_cam.translation -
                                         poses[i - 1].local_from_cam.translation);
      seqs.push_back(rep);
    }
    // Ground-truth test views (lossless PNG colour, exact poses, no noise).
    if (args.test_poses > 0) {
      TestPoseOptions tpo;
      tpo.count = args.test_poses;
      tpo.seed = args.seed + 100 * si;
      tpo.min_coverage = scene.indoor ? 0.95 : 0.7;
      EXO_ASSIGN_OR_RETURN(std::vector<Rigid3d> tposes, MakeTestPoses(scene, ro.Camera(), tpo));
      const fs::path dir = sdir / "test";
      fs::remove_all(dir, ec);
      fs::create_directories(dir, ec);
      SequenceReport rep{scene.name, "test"};
      const auto t_seq = Clock::now();
      double render_ms = 0, write_ms = 0;
      for (size_t i = 0; i < tposes.size(); ++i) {
        const auto t0 = Clock::now();
        EXO_ASSIGN_OR_RETURN(RenderedFrame rf, RenderFrame(scene, tposes[i], ro, {}, i, 0.0));
        const auto t1 = Clock::now();
        EXO_RETURN_IF_ERROR(WriteExoFrame(dir.string(), rf.frame, gt_opt));
        render_ms += std::chrono::duration<double, std::milli>(t1 - t0).count();
        write_ms += std::chrono::duration<double, std::milli>(Clock::now() - t1).count();
        if (i < 2)
          EXO_RETURN_IF_ERROR(WriteColorImage(
              (out / "previews" / absl::StrCat("synth_", scene.name, "_test", i, ".png")).string(),
              Downscale(rf.frame.color, 2)));
        if ((i + 1) % 50 == 0 || i + 1 == tposes.size())
          std::fprintf(stderr, "[synth] %s/test: %zu/%zu ground-truth views\n", scene.name.c_str(),
                       i + 1, tposes.size());
      }
      rep.frames = static_cast<int>(tposes.size());
      rep.render_ms_mean = render_ms / tposes.size();
      rep.write_ms_mean = write_ms / tposes.size();
      rep.seconds = std::chrono::duration<double>(Clock::now() - t_seq).count();
      seqs.push_back(rep);
    }
    // Scene JSON + markdown.
    json sequences = json::array();
    for (const SequenceReport& r : seqs) {
      sequences.push_back({{"name", r.trajectory},
                           {"dir", scene.name + "/" + r.trajectory},
                           {"frames", r.frames},
                           {"path_length_m", Round(r.path_length_m, 2)},
                           {"render_ms_per_frame", Round(r.render_ms_mean, 2)},
                           {"write_ms_per_frame", Round(r.write_ms_mean, 2)},
                           {"seconds", Round(r.seconds, 2)}});
      absl::StrAppend(&md, "| ", scene.name, " | ", r.trajectory, " | ", r.frames, " | ",
                      absl::StrFormat("%.1f", r.path_length_m), " | ",
                      absl::StrFormat("%.1f", r.render_ms_mean), " | ",
                      absl::StrFormat("%.1f", r.write_ms_mean), " | ",
                      absl::StrFormat("%.1f", r.seconds), " |\n");
    }
    report["scenes"].push_back(
        {{"name", scene.name},
         {"triangles", scene.mesh.num_triangles()},
         {"vertices", scene.mesh.num_vertices()},
         {"extent_m", Round(scene.ExtentM(), 2)},
         {"bounds_min", {Round(scene.bounds.min.x, 4), Round(scene.bounds.min.y, 4),
                         Round(scene.bounds.min.z, 4)}},
         {"bounds_max", {Round(scene.bounds.max.x, 4), Round(scene.bounds.max.y, 4),
                         Round(scene.bounds.max.z, 4)}},
         {"build_ms", Round(build_ms, 1)},
         {"sequences", sequences}});
    absl::StrAppend(&md_scenes, "- **", scene.name, "**: ", scene.mesh.num_triangles(),
                    " triangles, ", scene.mesh.num_vertices(), " vertices, extent ",
                    absl::StrFormat("%.1f", scene.ExtentM()), " m, built in ",
                    absl::StrFormat("%.0f", build_ms), " ms\n");
  }
  const double total_s = std::chrono::duration<double>(Clock::now() - t_start).count();
  report["total_seconds"] = Round(total_s, 2);
  absl::StrAppend(&md, "\n", md_scenes, "\nTotal ", absl::StrFormat("%.1f", total_s),
                  " s. Layout per sequence: intrinsics.txt, poses.txt (the frames' poses, noisy "
                  "when --pose-noise-* is set), poses_true.txt (render poses), "
                  "frames/NNNNNN.color.{jpg,png} + .depth.png (z-depth, 16-bit, units in "
                  "intrinsics.txt). test/ holds the ground-truth views (lossless PNG).\n");
  std::ofstream(out / "report.json") << report.dump(2) << "\n";
  std::ofstream(out / "report.md") << md;
  std::fprintf(stderr, "[synth] done in %.1f s -> %s\n", total_s, out.string().c_str());
  return absl::OkStatus();
}

}  // namespace
}  // namespace exo::synth

int main(int argc, char** argv) {
  exo::synth::Args args;
  if (auto rc = exo::synth::ParseArgs(argc, argv, &args)) return *rc;
  const absl::Status s = exo::synth::Run(args);
  if (!s.ok()) {
    std::fprintf(stderr, "exoview_synth: %s\n", s.ToString().c_str());
    return 1;
  }
  return 0;
}
