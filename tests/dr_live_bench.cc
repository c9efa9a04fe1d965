// dr_live_bench (issue 18, session 11): diminished reality in the live server. A real
// exoview_server process on loopback takes the synthetic apartment's arc around its removable
// chair (frames rendered and encoded before the upload: the uploader's cost is not the
// server's), paced at --rate_hz; after --before frames the chair is marked through MarkRegion
// (unless --mark=false). Prints one JSON object: the upload after the mark (sent / accepted /
// dropped, admitted fps, ack latency p50/p95), the server's CPU time over it, and the inpainting
// stage's counters (keyframes, first / propagated / mean wall ms and mean CPU ms per keyframe,
// per-frame decision ms, frames skipped while busy, share of keyframe ROI pixels taken from
// observations), with the load average.
//
// With --watch (default on) a client watches the live DR view (WatchDrView, raw RGB) during the
// upload: frames received and their rate, composited frames, the server's compose wall / CPU and
// the latency from admission, and per composited frame the PSNR inside the chair's pixels
// (dilated 4 px) against the apartment rendered WITHOUT the chair from the same pose (and the
// input frame's PSNR there, the chair itself, for contrast).
//
//   dr_live_bench [--width=640 --height=480] [--frames=150] [--rate_hz=30] [--mark=true]
//                 [--method=dr|keyframe] [--watch=true] [--server_arg=--key=value ...]
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstring>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <grpcpp/grpcpp.h>
#include <nlohmann/json.hpp>

#include "client/uploader/upload_client.h"
#include "common/metrics/metrics.h"
#include "common/cli/cli.h"
#include "proto/exoview.grpc.pb.h"
#include "tests/dr_chair_scene.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using json = nlohmann::ordered_json;

double Load1() {
  double l = 0;
  std::ifstream("/proc/loadavg") >> l;
  return l;
}

// utime + stime of a process, ms.
double ProcessCpuMs(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string s((std::istreambuf_iterator<char>(in)), {});
  const size_t close = s.rfind(')');
  if (close == std::string::npos) return -1;
  std::istringstream rest(s.substr(close + 2));
  std::string field;
  double utime = 0, stime = 0;
  for (int i = 3; i <= 15 && rest >> field; ++i) {
    if (i == 14) utime = std::stod(field);
    if (i == 15) stime = std::stod(field);
  }
  return (utime + stime) * 1000.0 / sysconf(_SC_CLK_TCK);
}

double Round(double x, int digits) {
  const double f = std::pow(10.0, digits);
  return std::round(x * f) / f;
}

int Main(int argc, char** argv) {
  int width = 640, height = 480, frames = 150, before = 8;
  double rate_hz = 30.0;
  bool mark = true, watch = true;
  std::string method = "dr";
  std::vector<std::string> server_args;
  CLI::App app{"Diminished reality in the live server: ingest rate with and without a marked "
               "region, per-keyframe inpainting time; prints JSON",
               "dr_live_bench"};
  exo::cli::Setup(app);
  app.add_option("--width", width, "frame width")->check(CLI::Range(64, 4096));
  app.add_option("--height", height, "frame height")->check(CLI::Range(48, 4096));
  app.add_option("--frames", frames, "frames on the 90-degree arc")->check(CLI::Range(16, 100000));
  app.add_option("--before", before, "frames before the mark")->check(CLI::Range(2, 1000));
  app.add_option("--rate_hz", rate_hz, "upload rate (0 = as fast as acked)")
      ->check(CLI::Range(0.0, 1000.0));
  app.add_option("--mark", mark, "mark the chair after --before frames");
  app.add_option("--watch", watch, "watch the live DR view during the upload (WatchDrView)");
  app.add_option("--method", method, "the server's inpaint_method")
      ->check(CLI::IsMember({"dr", "keyframe"}));
  app.add_option("--server_arg", server_args,
                 "a flag passed to exoview_server, repeatable: --server_arg=--key=value")
      ->allow_extra_args(false);
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  if (before >= frames) {
    std::fprintf(stderr, "--before must be < --frames\n");
    return 2;
  }

  // ---- frames: rendered and encoded once ----
  const testing::ChairScene scene = testing::MakeChairScene(width, height);
  std::vector<v1::Frame> msgs(frames);
  // Ground truth of the live DR view: the frame without the chair, and the chair's pixels.
  std::vector<ImageU8> truth(frames), input(frames), chair(frames);
  for (int k = 0; k < frames; ++k) {
    auto r = synth::RenderFrame(*scene.with, scene.Pose(double(k) / (frames - 1)), scene.ro);
    EXO_CHECK(r.ok());
    if (watch && mark) {
      auto g = synth::RenderFrame(*scene.without, scene.Pose(double(k) / (frames - 1)), scene.ro);
      EXO_CHECK(g.ok());
      chair[k] = testing::ChairPixels(*r, *g, 4);
      truth[k] = std::move(g->frame.color);
      input[k] = r->frame.color;
    }
    r->frame.sequence = k + 1;
    r->frame.timestamp_s = (k + 1) / 30.0;
    auto m = FrameToProto(r->frame, {});
    EXO_CHECK(m.ok());
    msgs[k] = *std::move(m);
  }

  // ---- server ----
  char tmpl[] = "/tmp/exoview_drbench_XXXXXX";
  if (!mkdtemp(tmpl)) return 1;
  const std::string dir = tmpl;
  std::vector<std::string> args{"--listen=127.0.0.1:0", "--port_file=" + dir + "/port",
                                "--inpaint_method=" + method};
  args.insert(args.end(), server_args.begin(), server_args.end());
  testing::Subprocess server(EXOVIEW_SERVER_BIN, args, dir + "/server.log");
  if (!testing::WaitForFile(dir + "/port", 20)) return 1;
  const std::string target =
      "127.0.0.1:" + std::to_string(std::stoi(testing::ReadAll(dir + "/port")));
  auto channel = MakeChannel(target);
  auto stats = [&] {
    auto stub = v1::Exoview::NewStub(channel);
    grpc::ClientContext ctx;
    v1::Stats s;
    stub->GetStats(&ctx, v1::StatsRequest{}, &s);
    return s;
  };
  auto wait_drained = [&] {
    for (int i = 0; i < 12000; ++i) {
      const v1::Stats s = stats();
      if (s.frames_processed() == s.frames_accepted() && s.async_pending() == 0) return s;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return stats();
  };
  auto upload = [&](int first, int n) {
    UploadOptions o;
    o.rate_hz = rate_hz;
    auto st = UploadStream(channel, n, [&](size_t i) -> absl::StatusOr<v1::Frame> {
      return msgs[first + i];
    }, o);
    EXO_CHECK(st.ok());
    return *st;
  };
  upload(0, before);
  wait_drained();
  json out;
  out["bench"] = "dr_live_bench";
  out["width"] = width;
  out["height"] = height;
  out["frames"] = frames;
  out["before"] = before;
  out["rate_hz"] = rate_hz;
  out["method"] = method;
  out["marked"] = mark;
  if (mark) {
    auto stub = v1::Exoview::NewStub(channel);
    grpc::ClientContext ctx;
    v1::MarkRegionReply reply;
    const auto req = testing::ChairMarkRequest(scene, scene.Pose(double(before - 1) / (frames - 1)));
    const grpc::Status st = stub->MarkRegion(&ctx, req, &reply);
    if (!st.ok()) {
      std::fprintf(stderr, "MarkRegion: %s\n%s\n", st.error_message().c_str(),
                   testing::ReadAll(dir + "/server.log").c_str());
      return 1;
    }
    out["region_voxels"] = reply.region().num_voxels();
  }
  // The live DR view's watcher: from before the upload until it is drained.
  struct Watched {
    int frames = 0, composited = 0, scored = 0;
    double first_s = 0, last_s = 0, compose_ms = 0, latency_ms = 0, psnr = 0, psnr_input = 0;
    std::vector<double> latencies;
  } watched;
  std::atomic<bool> watching{true};
  grpc::ClientContext watch_ctx;
  std::thread watcher;
  if (watch) {
    watcher = std::thread([&] {
      auto stub = v1::Exoview::NewStub(channel);
      v1::WatchDrViewRequest req;
      req.set_raw(true);
      auto reader = stub->WatchDrView(&watch_ctx, req);
      v1::DrViewFrame m;
      const auto t0 = std::chrono::steady_clock::now();
      while (reader->Read(&m)) {
        const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        if (watched.frames == 0) watched.first_s = t;
        watched.last_s = t;
        ++watched.frames;
        watched.compose_ms += m.compose_ms();
        watched.latency_ms += m.latency_ms();
        watched.latencies.push_back(m.latency_ms());
        if (!m.composited()) continue;
        ++watched.composited;
        const int k = static_cast<int>(m.sequence()) - 1;
        if (k < 0 || k >= frames || truth[k].empty() ||
            m.color_rgb().size() != truth[k].size())
          continue;
        ImageU8 out(width, height, 3);
        std::memcpy(out.data(), m.color_rgb().data(), out.size());
        auto p = MaskedPsnr(out, truth[k], chair[k]);
        auto p0 = MaskedPsnr(input[k], truth[k], chair[k]);
        if (!p.ok() || !p0.ok()) continue;
        watched.psnr += *p;
        watched.psnr_input += *p0;
        ++watched.scored;
      }
      reader->Finish();
    });
  }
  const double load0 = Load1(), cpu0 = ProcessCpuMs(server.pid());
  const UploadAckStats up = upload(before, frames - before);
  const double upload_cpu_ms = ProcessCpuMs(server.pid()) - cpu0;
  const v1::Stats s = wait_drained();
  const double drain_cpu_ms = ProcessCpuMs(server.pid()) - cpu0;
  out["load1_before"] = load0;
  out["load1_after"] = Load1();
  out["upload"] = {{"sent", up.sent},
                   {"accepted", up.accepted},
                   {"dropped", up.dropped},
                   {"rejected", up.rejected},
                   {"fps", Round(up.fps(), 2)},
                   {"ack_latency_p50_ms", Round(up.ack_latency_p50_ms, 1)},
                   {"ack_latency_p95_ms", Round(up.ack_latency_p95_ms, 1)},
                   {"server_cpu_ms_per_frame", Round(upload_cpu_ms / std::max<uint64_t>(1, up.sent), 1)},
                   {"server_cpu_ms_to_drained", Round(drain_cpu_ms, 0)}};
  if (watch) {
    std::this_thread::sleep_for(std::chrono::milliseconds(300));  // the last frame's output
    watch_ctx.TryCancel();
    watcher.join();
    const int n = std::max(1, watched.frames);
    std::sort(watched.latencies.begin(), watched.latencies.end());
    const double span = watched.last_s - watched.first_s;
    out["live_view"] = {
        {"frames", watched.frames},
        {"composited", watched.composited},
        {"fps", span > 0 ? Round((watched.frames - 1) / span, 2) : 0.0},
        {"compose_ms_mean", Round(watched.compose_ms / n, 2)},
        {"latency_ms_mean", Round(watched.latency_ms / n, 1)},
        {"latency_ms_p95", watched.latencies.empty() ? 0.0
             : Round(watched.latencies[std::min(watched.latencies.size() - 1,
                                                watched.latencies.size() * 95 / 100)], 1)},
        {"scored", watched.scored},
        {"psnr_roi", watched.scored ? Round(watched.psnr / watched.scored, 2) : 0.0},
        {"psnr_roi_input", watched.scored ? Round(watched.psnr_input / watched.scored, 2) : 0.0}};
  }
  (void)watching;
  json ip;
  for (const auto& [k, v] : s.counters())
    if (k.rfind("inpainting.", 0) == 0) ip[k.substr(11)] = Round(v, 3);
  out["inpainting"] = ip;
  std::printf("%s\n", out.dump().c_str());
  server.Signal(SIGTERM);
  server.Wait(20);
  std::filesystem::remove_all(dir);
  return 0;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) { return exo::Main(argc, argv); }
