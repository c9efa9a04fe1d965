// journal_bench: the ingest cost of the frame journal (issue 20 item 3). A real exoview_server
// process on loopback, the same checkpoint set-up with the journal on and off, runs interleaved
// (off, on, off, on, ...). Each run: S upload streams, each sending F pre-encoded 640x480 RGB-D
// frames of the synthetic apartment as fast as the server acks (16 in flight). Prints one JSON
// line per run (acked frames/s, ack latency, server CPU seconds from /proc, journal counters)
// and one summary line (medians, on vs off).
//   journal_bench [--runs=3] [--frames=300] [--streams=1] [--stages=false] [--width=640]
//                 [--server_arg=--key=value ...]
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include <CLI/CLI.hpp>
#include <grpcpp/grpcpp.h>
#include <nlohmann/json.hpp>

#include "client/uploader/synth_source.h"
#include "common/cli/cli.h"
#include "client/uploader/upload_client.h"
#include "proto/exoview.grpc.pb.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using json = nlohmann::ordered_json;

double CpuSeconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string s((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t close = s.rfind(')');
  if (close == std::string::npos) return -1;
  std::istringstream rest(s.substr(close + 2));
  std::string f;
  double utime = 0, stime = 0;
  for (int i = 3; i <= 15 && rest >> f; ++i) {
    if (i == 14) utime = std::stod(f);
    if (i == 15) stime = std::stod(f);
  }
  return (utime + stime) / static_cast<double>(sysconf(_SC_CLK_TCK));
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

double Loadavg() {
  std::ifstream in("/proc/loadavg");
  double l = -1;
  in >> l;
  return l;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) {
  using namespace exo;
  CLI::App app{"journal_bench: ingest with the frame journal on and off, interleaved",
               "journal_bench"};
  exo::cli::Setup(app);
  int runs = 3, frames = 300, streams = 1, width = 640, height = 480;
  bool stages = false;
  std::vector<std::string> server_args;
  app.add_option("--runs", runs, "runs of each mode (interleaved)");
  app.add_option("--frames", frames, "frames per stream and run");
  app.add_option("--streams", streams, "concurrent upload streams");
  app.add_option("--stages", stages, "run the geometry + planning stages (default: ingest only)");
  app.add_option("--width", width);
  app.add_option("--height", height);
  app.add_option("--server_arg", server_args, "extra server flag (repeatable)");
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;

  SynthSourceOptions so;
  so.scene = "apartment";
  so.trajectory = "walk";
  so.num_frames = frames;
  so.width = width;
  so.height = height;
  auto source = SynthFrameSource::Create(so);
  if (!source.ok()) return 1;
  std::vector<v1::Frame> encoded;
  size_t bytes = 0;
  for (int i = 0; i < frames; ++i) {
    auto f = (*source)->Load(i);
    auto m = FrameToProto(*f, {});
    if (!m.ok()) return 1;
    bytes += m->ByteSizeLong();
    encoded.push_back(*std::move(m));
  }
  std::fprintf(stderr, "journal_bench: %d frames of %.0f KB each (mean), %d stream(s)\n", frames,
               bytes / 1024.0 / frames, streams);

  char tmpl[] = "/tmp/exoview_journal_bench_XXXXXX";
  if (!mkdtemp(tmpl)) return 1;
  const std::string dir = tmpl;
  std::map<bool, std::vector<double>> fps, cpu_per_frame, p50;
  for (int run = 0; run < 2 * runs; ++run) {
    const bool journal = run % 2 == 1;
    std::filesystem::remove_all(dir + "/data");
    std::filesystem::create_directories(dir + "/data");
    std::vector<std::string> args{"--listen=127.0.0.1:0", "--port_file=" + dir + "/port",
                                  "--checkpoint_path=" + dir + "/data/model.ckpt",
                                  "--checkpoint_interval_s=2",
                                  std::string("--journal=") + (journal ? "true" : "false"),
                                  "--admission_block=true", "--max_upload_streams=64"};
    if (!stages) {
      args.push_back("--geometry=false");
      args.push_back("--planning=false");
    }
    args.insert(args.end(), server_args.begin(), server_args.end());
    std::filesystem::remove(dir + "/port");
    testing::Subprocess server(EXOVIEW_SERVER_BIN, args, dir + "/server.log");
    if (!testing::WaitForFile(dir + "/port", 30)) {
      std::fprintf(stderr, "%s\n", server.Log().c_str());
      return 1;
    }
    const std::string target = "127.0.0.1:" + testing::ReadAll(dir + "/port");
    const double cpu0 = CpuSeconds(server.pid());
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<std::thread> threads;
    std::vector<UploadAckStats> results(streams);
    bool ok = true;
    for (int s = 0; s < streams; ++s)
      threads.emplace_back([&, s] {
        UploadOptions o;
        o.rate_hz = 0;
        o.max_in_flight = 16;
        o.uploader_id = "bench-" + std::to_string(s);
        auto r = UploadStream(MakeChannel(target), encoded.size(),
                              [&](size_t i) -> absl::StatusOr<v1::Frame> { return encoded[i]; }, o);
        if (r.ok()) results[s] = *r;
        else ok = false;
      });
    for (auto& t : threads) t.join();
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const double cpu = CpuSeconds(server.pid()) - cpu0;
    auto stub = v1::Exoview::NewStub(MakeChannel(target));
    grpc::ClientContext ctx;
    v1::Stats st;
    stub->GetStats(&ctx, v1::StatsRequest{}, &st);
    server.Signal(SIGTERM);
    server.Wait(30);
    uint64_t acked = 0, durable = 0;
    std::vector<double> lat;
    for (const auto& r : results) {
      acked += r.accepted;
      durable += r.durable;
      lat.push_back(r.ack_latency_p50_ms);
    }
    const double f = acked / wall;
    fps[journal].push_back(f);
    cpu_per_frame[journal].push_back(cpu / std::max<uint64_t>(acked, 1) * 1e3);
    p50[journal].push_back(Median(lat));
    auto c = [&](const char* k) { return st.counters().count(k) ? st.counters().at(k) : 0.0; };
    json line = {{"run", run},
                 {"journal", journal},
                 {"streams", streams},
                 {"stages", stages},
                 {"frames_acked", acked},
                 {"durable", durable},
                 {"ok", ok},
                 {"wall_s", wall},
                 {"acked_fps", f},
                 {"server_cpu_s", cpu},
                 {"server_cpu_ms_per_frame", cpu / std::max<uint64_t>(acked, 1) * 1e3},
                 {"ack_latency_p50_ms", Median(lat)},
                 {"journal_groups", c("journal.groups")},
                 {"journal_appends", c("journal.appends")},
                 {"journal_sync_ms_mean", c("journal.sync_ms_mean")},
                 {"journal_sync_ms_max", c("journal.sync_ms_max")},
                 {"loadavg", Loadavg()}};
    std::printf("%s\n", line.dump().c_str());
    std::fflush(stdout);
  }
  json summary = {{"summary", "journal on vs off (medians)"},
                  {"streams", streams},
                  {"stages", stages},
                  {"frame_kb", bytes / 1024.0 / frames},
                  {"fps_off", Median(fps[false])},
                  {"fps_on", Median(fps[true])},
                  {"cpu_ms_per_frame_off", Median(cpu_per_frame[false])},
                  {"cpu_ms_per_frame_on", Median(cpu_per_frame[true])},
                  {"ack_p50_ms_off", Median(p50[false])},
                  {"ack_p50_ms_on", Median(p50[true])}};
  std::printf("%s\n", summary.dump().c_str());
  std::filesystem::remove_all(dir);
  return 0;
}
