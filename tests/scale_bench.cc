// scale_bench (issue 21 item 5): fan-out cost with real processes on loopback. For each
// configuration (R relays, M simulated viewers) a fresh exoview_server (R = 0: the embedded
// in-memory log, every viewer on the server; R > 0: delta_log=jetstream on a nats-server started
// here, viewers spread over R exoview_relay processes) is given a model (phase 1 upload), then M
// viewers join at once (raw Subscribe readers: they count bytes and arrival times, they do not
// decode), then phase 2 frames arrive while they follow. Prints one JSON line per configuration:
//   server_egress_MBps   model bytes the server sent in the measured window (join + phase 2),
//                        per second: deltas and snapshots to its own gRPC subscribers (Stats
//                        bytes_published, minus the bench's reference subscriber) + deltas and
//                        snapshots published to JetStream (delta_log.bytes_published)
//   server_cpu_s         server CPU (user + system) in the window
//   relay_cpu_ms_per_viewer  relays' CPU in the window / M
//   join_s_p50/p95       Subscribe from version 0 to holding the model (SnapshotEnd, or the
//                        version current at the join) for the M simultaneous joins
//   delta_latency_ms_p50/p95  arrival of each phase-2 version at a viewer minus its arrival at a
//                        reference subscriber on the server itself (what the fan-out path adds)
//   viewer_bytes_total   bytes received by all viewers
//   exoview_bench tests/scale_bench [--relays=0,1,2] [--viewers=10,100] [--frames1=30]
//                 [--frames2=30] [--width=320 --height=240]
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>
#include <unistd.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <grpcpp/grpcpp.h>
#include <nlohmann/json.hpp>

#include "absl/strings/str_split.h"
#include "client/uploader/upload_client.h"
#include "common/cli/cli.h"
#include "proto/exoview.grpc.pb.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using Clock = std::chrono::steady_clock;
using testing::ReadAll;
using testing::Subprocess;
using testing::WaitForFile;

using testing::FreeLoopbackPort;

double CpuS(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string s((std::istreambuf_iterator<char>(in)), {});
  const auto close = s.rfind(')');
  std::istringstream rest(s.substr(close + 2));
  std::string f;
  double ut = 0, st = 0;
  for (int i = 3; i <= 15 && rest >> f; ++i) {
    if (i == 14) ut = std::stod(f);
    if (i == 15) st = std::stod(f);
  }
  return (ut + st) / sysconf(_SC_CLK_TCK);
}

double Pct(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(p * (v.size() - 1) + 0.5))];
}

// A raw subscriber: arrival time of every version, bytes, time to hold the model.
struct Reader {
  std::unique_ptr<grpc::ClientContext> ctx = std::make_unique<grpc::ClientContext>();
  std::thread thread;
  std::mutex mu;
  std::map<uint64_t, int64_t> arrival_ns;  // version -> steady ns (log deltas only)
  std::atomic<uint64_t> bytes{0}, version{0};
  std::atomic<int64_t> synced_ns{0};
  void Start(const std::string& target, uint64_t sync_version) {
    thread = std::thread([this, target, sync_version] {
      auto stub = v1::Exoview::NewStub(MakeChannel(target));
      v1::SubscribeRequest req;
      auto r = stub->Subscribe(ctx.get(), req);
      v1::Delta d;
      while (r->Read(&d)) {
        const int64_t t = Clock::now().time_since_epoch().count();
        bytes += d.ByteSizeLong();
        version = d.version();
        if (!d.has_snapshot_begin() && !d.has_snapshot_end() && d.model_epoch() != 0 &&
            d.source_timestamp_s() != 0) {
          std::lock_guard l(mu);
          arrival_ns.emplace(d.version(), t);
        }
        if (synced_ns.load() == 0 &&
            (d.has_snapshot_end() || (d.version() >= sync_version && sync_version > 0)))
          synced_ns = t;
      }
    });
  }
  void Stop() {
    ctx->TryCancel();
    if (thread.joinable()) thread.join();
  }
};

struct Options {
  std::vector<int> relays{0, 1, 2}, viewers{10, 100};
  int frames1 = 30, frames2 = 30, width = 320, height = 240;
  double rate_hz = 10;
};

v1::Stats Stats(const std::string& target) {
  auto stub = v1::Exoview::NewStub(MakeChannel(target));
  grpc::ClientContext ctx;
  v1::Stats s;
  stub->GetStats(&ctx, v1::StatsRequest{}, &s);
  return s;
}

void WaitVersion(const std::string& target, uint64_t v) {
  const auto end = Clock::now() + std::chrono::seconds(60);
  while (Stats(target).model_version() < v && Clock::now() < end)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
}

uint64_t Settle(const std::string& server) {
  uint64_t prev = ~uint64_t{0};
  for (;;) {
    const v1::Stats s = Stats(server);
    if (s.model_version() == prev && s.frames_processed() == s.frames_accepted() &&
        s.async_pending() == 0)
      return prev;
    prev = s.model_version();
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
  }
}

int Upload(const std::string& target, int first, int n, const Options& o, const std::string& log) {
  Subprocess up(EXOVIEW_UPLOADER_BIN,
                {"--server=" + target, "--synthetic=apartment", "--trajectory=walk",
                 "--frames=" + std::to_string(first + n), "--first=" + std::to_string(first),
                 "--width=" + std::to_string(o.width), "--height=" + std::to_string(o.height),
                 "--rate_hz=" + std::to_string(o.rate_hz)},
                log);
  return up.Wait(300).value_or(-1);
}

nlohmann::ordered_json RunConfig(const Options& o, int R, int M, const std::string& dir,
                                 const std::string& nats_url, int run) {
  const std::string scene = "bench" + std::to_string(run);
  std::vector<std::string> args{"--listen=127.0.0.1:0", "--port_file=" + dir + "/sport" + scene,
                                "--voxel_size_m=0.08", "--mesh_every_n_frames=5",
                                "--fuse_depth_downscale=2", "--admission_block=true",
                                "--snapshot_when_cheaper=false"};
  if (R > 0) {
    args.push_back("--delta_log=jetstream");
    args.push_back("--nats_url=" + nats_url);
    args.push_back("--scene=" + scene);
  }
  Subprocess server(EXOVIEW_SERVER_BIN, args, dir + "/server_" + scene + ".log");
  WaitForFile(dir + "/sport" + scene, 30);
  const std::string st = "127.0.0.1:" + ReadAll(dir + "/sport" + scene).substr(0, 5);
  std::string server_target = "127.0.0.1:" + std::to_string(std::stoi(ReadAll(dir + "/sport" + scene)));
  std::vector<std::unique_ptr<Subprocess>> relays;
  std::vector<std::string> relay_targets;
  for (int i = 0; i < R; ++i) {
    const std::string pf = dir + "/rport" + scene + "_" + std::to_string(i);
    relays.push_back(std::make_unique<Subprocess>(
        EXOVIEW_RELAY_BIN,
        std::vector<std::string>{"--listen=127.0.0.1:0", "--port_file=" + pf,
                                 "--nats_url=" + nats_url, "--scene=" + scene,
                                 "--snapshot_when_cheaper=false"},
        dir + "/relay_" + scene + "_" + std::to_string(i) + ".log"));
    WaitForFile(pf, 30);
    relay_targets.push_back("127.0.0.1:" + std::to_string(std::stoi(ReadAll(pf))));
  }
  // Phase 1: the model.
  Upload(server_target, 0, o.frames1, o, dir + "/up1_" + scene + ".log");
  const uint64_t v1 = Settle(server_target);
  for (const auto& t : relay_targets) WaitVersion(t, v1);
  Reader reference;
  reference.Start(server_target, v1);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  // Window: M joins, then phase 2.
  const double cpu0 = CpuS(server.pid());
  auto egress = [&] {
    const v1::Stats s = Stats(server_target);
    const auto it = s.counters().find("delta_log.bytes_published");
    return static_cast<double>(s.bytes_published()) +
           (it == s.counters().end() ? 0.0 : it->second) - static_cast<double>(reference.bytes);
  };
  const double w0 = egress();
  std::vector<double> relay_cpu0;
  for (auto& r : relays) relay_cpu0.push_back(CpuS(r->pid()));
  const auto t0 = Clock::now();
  const int64_t t0_ns = t0.time_since_epoch().count();
  std::vector<std::unique_ptr<Reader>> viewers;
  for (int i = 0; i < M; ++i) {
    viewers.push_back(std::make_unique<Reader>());
    viewers.back()->Start(R == 0 ? server_target : relay_targets[i % R], v1);
  }
  const auto join_end = Clock::now() + std::chrono::seconds(120);
  while (Clock::now() < join_end &&
         std::any_of(viewers.begin(), viewers.end(), [](auto& v) { return v->synced_ns == 0; }))
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  Upload(server_target, o.frames1, o.frames2, o, dir + "/up2_" + scene + ".log");
  const uint64_t v2 = Settle(server_target);
  const auto end = Clock::now() + std::chrono::seconds(60);
  while (Clock::now() < end &&
         std::any_of(viewers.begin(), viewers.end(), [&](auto& v) { return v->version < v2; }))
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  const double window_s = std::chrono::duration<double>(Clock::now() - t0).count();
  const double cpu = CpuS(server.pid()) - cpu0;
  const double wbytes = egress() - w0;
  double relay_cpu = 0;
  for (size_t i = 0; i < relays.size(); ++i) relay_cpu += CpuS(relays[i]->pid()) - relay_cpu0[i];
  for (auto& v : viewers) v->Stop();
  reference.Stop();
  std::vector<double> joins, lat;
  uint64_t bytes = 0;
  int complete = 0;
  for (auto& v : viewers) {
    if (v->synced_ns) joins.push_back((v->synced_ns - t0_ns) * 1e-9);
    bytes += v->bytes;
    complete += v->version >= v2;
    std::lock_guard l(v->mu);
    for (const auto& [ver, t] : v->arrival_ns) {
      if (ver <= v1) continue;
      auto it = reference.arrival_ns.find(ver);
      if (it != reference.arrival_ns.end()) lat.push_back((t - it->second) * 1e-6);
    }
  }
  for (auto& r : relays) r->Signal(SIGTERM);
  server.Signal(SIGTERM);
  for (auto& r : relays) r->Wait(10);
  server.Wait(20);
  nlohmann::ordered_json j;
  j["relays"] = R;
  j["viewers"] = M;
  j["model_version_at_join"] = v1;
  j["model_version_end"] = v2;
  j["viewers_complete"] = complete;
  j["window_s"] = std::round(window_s * 100) / 100;
  j["server_egress_MBps"] = std::round(wbytes / window_s / 1e4) / 100;
  j["server_sent_MB"] = std::round(wbytes / 1e4) / 100;
  j["server_cpu_s"] = std::round(cpu * 100) / 100;
  j["relay_cpu_ms_per_viewer"] = R ? std::round(relay_cpu * 1000 / M * 10) / 10 : 0.0;
  j["join_s_p50"] = std::round(Pct(joins, 0.5) * 1000) / 1000;
  j["join_s_p95"] = std::round(Pct(joins, 0.95) * 1000) / 1000;
  j["delta_latency_ms_p50"] = std::round(Pct(lat, 0.5) * 10) / 10;
  j["delta_latency_ms_p95"] = std::round(Pct(lat, 0.95) * 10) / 10;
  j["viewer_bytes_total_MB"] = std::round(bytes / 1e4) / 100;
  (void)st;
  return j;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) {
  CLI::App app{"Fan-out cost: 1 server, R relays over NATS JetStream, M viewers (issue 21).",
               "scale_bench"};
  exo::cli::Setup(app);
  exo::Options o;
  std::string relays = "0,1,2", viewers = "10,100";
  app.add_option("--relays", relays, "relay counts")->capture_default_str();
  app.add_option("--viewers", viewers, "viewer counts")->capture_default_str();
  app.add_option("--frames1", o.frames1, "frames before the joins")->capture_default_str();
  app.add_option("--frames2", o.frames2, "frames while the viewers follow")->capture_default_str();
  app.add_option("--width", o.width)->capture_default_str();
  app.add_option("--height", o.height)->capture_default_str();
  app.add_option("--rate_hz", o.rate_hz)->capture_default_str();
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  o.relays.clear();
  o.viewers.clear();
  for (auto s : absl::StrSplit(relays, ',')) o.relays.push_back(std::stoi(std::string(s)));
  for (auto s : absl::StrSplit(viewers, ',')) o.viewers.push_back(std::stoi(std::string(s)));
  char tmpl[] = "/tmp/exoview_scale_XXXXXX";
  const std::string dir = mkdtemp(tmpl);
  std::ofstream(dir + "/nats.conf") << "max_payload: 8MB\n";
  const int port = exo::testing::FreeLoopbackPort();
  exo::testing::Subprocess nats("/usr/sbin/nats-server",
                                {"-c", dir + "/nats.conf", "-js", "-a", "127.0.0.1", "-p",
                                 std::to_string(port), "-sd", dir + "/js"},
                                dir + "/nats.log");
  std::this_thread::sleep_for(std::chrono::seconds(1));
  const std::string url = "nats://127.0.0.1:" + std::to_string(port);
  int run = 0;
  for (int R : o.relays)
    for (int M : o.viewers) {
      auto j = exo::RunConfig(o, R, M, dir, url, run++);
      std::printf("%s\n", j.dump().c_str());
      std::fflush(stdout);
    }
  nats.Signal(SIGTERM);
  nats.Wait(10);
  std::filesystem::remove_all(dir);
  return 0;
}
