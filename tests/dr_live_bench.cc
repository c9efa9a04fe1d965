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
//   dr_live_bench [--width=640 --height=480] [--frames=150] [--rate_hz=30] [--mark=true]
//                 [--method=dr|keyframe] [--server_arg=--key=value ...]
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <grpcpp/grpcpp.h>
#include <nlohmann/json.hpp>

#include "client/uploader/upload_client.h"
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
  bool mark = true;
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
  for (int k = 0; k < frames; ++k) {
    auto r = synth::RenderFrame(*scene.with, scene.Pose(double(k) / (frames - 1)), scene.ro);
    EXO_CHECK(r.ok());
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
