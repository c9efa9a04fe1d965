// service_bench: the service on loopback with a real exoview_server process (SPEC §10 targets).
// Prints one JSON object per phase:
//   ingest_paced    30 Hz upload of distinct 640x480 RGB-D frames: ack/drop counts, frame-to-delta
//                   latency at a subscribed viewer (p50/p95), views in the store
//   initial_sync    bytes a fresh viewer receives to sync the store (by delta kind)
//   steady_state    long 30 Hz upload (frames repeat with new sequence numbers): bytes/s at the
//                   viewer, server RSS samples (flat after warm-up?)
//   ingest_max      upload as fast as the server acks: admitted fps, processed fps, dropped
//   exoview_bench tests/service_bench [--distinct=N] [--long=M] [--max=K] [--width=W --height=H]
//                 [--server_arg=--key=value ...]
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <algorithm>
#include <atomic>
#include <fstream>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "absl/strings/numbers.h"
#include "client/uploader/synth_source.h"
#include "client/uploader/upload_client.h"
#include "client/viewer/viewer_session.h"
#include "proto/exoview.grpc.pb.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using Clock = std::chrono::steady_clock;
int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch()).count();
}

double Pct(std::vector<double> v, double q) {
  if (v.empty()) return -1;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5))];
}

long RssKb(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
  return -1;
}

const char* KindName(const v1::Delta& d) {
  switch (d.kind_case()) {
    case v1::Delta::kViewAdded: return "view_added";
    case v1::Delta::kMeshChunkUpserted: return "mesh_chunk";
    case v1::Delta::kCellRefsChanged: return "cell_refs";
    default: return "other";
  }
}

int Main(int argc, char** argv) {
  int distinct = 300, long_frames = 1800, max_frames = 300, width = 640, height = 480;
  int rss_frames = 0;  // phase 5 (off by default): unpaced long upload, RSS per 1000 frames
  std::vector<std::string> server_args;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    auto val = [&](const char* k, int* out) {
      const std::string p = std::string("--") + k + "=";
      if (a.rfind(p, 0) == 0) return absl::SimpleAtoi(a.substr(p.size()), out);
      return false;
    };
    if (val("distinct", &distinct) || val("long", &long_frames) || val("max", &max_frames) ||
        val("width", &width) || val("height", &height) || val("rss_frames", &rss_frames))
      continue;
    if (a.rfind("--server_arg=", 0) == 0) {
      server_args.push_back(a.substr(13));
      continue;
    }
    std::fprintf(stderr, "bad argument %s\n", a.c_str());
    return 2;
  }
  // ---- frames: rendered once, encoded once (the uploader's cost is not the server's) ----
  SynthSourceOptions so;
  so.scene = "apartment";
  so.trajectory = "walk";
  so.num_frames = distinct;
  so.width = width;
  so.height = height;
  auto source = SynthFrameSource::Create(so);
  if (!source.ok()) return 1;
  std::vector<v1::Frame> frames(distinct);
  {
    std::vector<std::thread> th;
    std::atomic<int> next{0};
    for (int t = 0; t < 2; ++t)
      th.emplace_back([&] {
        for (int i; (i = next.fetch_add(1)) < distinct;) {
          auto f = (*source)->Load(i);
          EXO_CHECK(f.ok());
          auto m = FrameToProto(*f, {});
          EXO_CHECK(m.ok());
          frames[i] = *std::move(m);
        }
      });
    for (auto& t : th) t.join();
  }
  size_t frame_bytes = 0;
  for (auto& f : frames) frame_bytes += f.ByteSizeLong();

  // ---- server process ----
  char tmpl[] = "/tmp/exoview_bench_XXXXXX";
  if (!mkdtemp(tmpl)) return 1;
  const std::string dir = tmpl;
  std::vector<std::string> args{"--listen=127.0.0.1:0", "--port_file=" + dir + "/port"};
  args.insert(args.end(), server_args.begin(), server_args.end());
  testing::Subprocess server(EXOVIEW_SERVER_BIN, args, dir + "/server.log");
  if (!testing::WaitForFile(dir + "/port", 20)) return 1;
  const std::string target = "127.0.0.1:" + std::to_string(std::stoi(testing::ReadAll(dir + "/port")));
  auto channel = MakeChannel(target);
  auto stats = [&] {
    auto stub = v1::Exoview::NewStub(channel);
    grpc::ClientContext ctx;
    v1::Stats s;
    stub->GetStats(&ctx, v1::StatsRequest{}, &s);
    return s;
  };
  auto wait_drained = [&] {
    for (int i = 0; i < 6000; ++i) {
      const v1::Stats s = stats();
      if (s.frames_processed() == s.frames_accepted() && s.async_pending() == 0) return s;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return stats();
  };

  // ---- a live viewer: latency and steady-state bytes ----
  std::mutex mu;
  std::map<double, int64_t> sent_ns;     // frame timestamp -> send time
  std::map<double, double> latency_ms;   // first delta per source frame
  uint64_t live_bytes = 0;
  auto viewer = ViewerSession::Open(channel, "");
  (*viewer)->SetOnDelta([&](const v1::Delta& d, int64_t recv_ns) {
    std::lock_guard lock(mu);
    live_bytes += d.ByteSizeLong();
    if (d.source_timestamp_s() == 0) return;
    auto it = sent_ns.find(d.source_timestamp_s());
    if (it != sent_ns.end() && !latency_ms.count(d.source_timestamp_s()))
      latency_ms[d.source_timestamp_s()] = (recv_ns - it->second) * 1e-6;
  });
  std::thread viewer_thread([&] {
    SyncOptions o;
    o.until_synced = false;
    o.max_seconds = 1e9;
    (void)(*viewer)->Sync(o);
  });

  uint64_t seq = 0;
  double t_frame = 0;
  auto make = [&](size_t i) -> absl::StatusOr<v1::Frame> {
    v1::Frame f = frames[i % frames.size()];
    f.set_sequence(++seq);
    t_frame += 1.0 / 30.0;
    f.set_timestamp_s(t_frame);
    std::lock_guard lock(mu);
    sent_ns[t_frame] = NowNs();
    return f;
  };
  UploadOptions paced;
  paced.rate_hz = 30;
  paced.max_in_flight = 8;

  // Phase 1: distinct frames at 30 Hz.
  auto up1 = UploadStream(channel, frames.size(), make, paced);
  if (!up1.ok()) return 1;
  const v1::Stats s1 = wait_drained();
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  std::vector<double> lat;
  {
    std::lock_guard lock(mu);
    for (auto& [t, ms] : latency_ms) lat.push_back(ms);
  }
  std::printf(
      "{\"phase\": \"ingest_paced\", \"width\": %d, \"height\": %d, \"frames\": %llu, "
      "\"rate_hz\": 30, \"fps\": %.2f, \"accepted\": %llu, \"dropped\": %llu, \"rejected\": %llu, "
      "\"mean_frame_bytes\": %zu, \"views\": %u, \"chunks\": %u, \"cells\": %u, "
      "\"latency_frames_with_delta\": %zu, \"frame_to_delta_p50_ms\": %.2f, "
      "\"frame_to_delta_p95_ms\": %.2f, \"ack_p50_ms\": %.2f, \"ack_p95_ms\": %.2f, "
      "\"stages\": \"%s\"}\n",
      width, height, (unsigned long long)up1->sent, up1->fps(), (unsigned long long)up1->accepted,
      (unsigned long long)up1->dropped, (unsigned long long)up1->rejected, frame_bytes / frames.size(),
      s1.num_views(), s1.num_chunks(), s1.num_cells(), lat.size(), Pct(lat, 0.5), Pct(lat, 0.95),
      up1->ack_latency_p50_ms, up1->ack_latency_p95_ms,
      [&] { std::string s; for (auto& n : s1.stages()) s += (s.empty() ? "" : "+") + n; return s; }().c_str());
  std::fflush(stdout);
  auto print_counters = [&](const char* phase, const v1::Stats& st) {
    std::string c;
    for (const auto& [k, v] : std::map<std::string, double>(st.counters().begin(), st.counters().end()))
      c += (c.empty() ? "" : ", ") + ("\"" + k + "\": " + std::to_string(v));
    std::printf("{\"phase\": \"%s_counters\", %s}\n", phase, c.c_str());
    std::fflush(stdout);
  };
  print_counters("ingest_paced", s1);

  // Phase 2: initial sync of the store by a fresh viewer.
  {
    std::map<std::string, uint64_t> by_kind;
    auto fresh = ViewerSession::Open(channel, "");
    (*fresh)->SetOnDelta([&](const v1::Delta& d, int64_t) { by_kind[KindName(d)] += d.ByteSizeLong(); });
    const auto t0 = Clock::now();
    (void)(*fresh)->Sync({});
    const double sec = std::chrono::duration<double>(Clock::now() - t0).count();
    const v1::Stats s = stats();
    std::printf(
        "{\"phase\": \"initial_sync\", \"views\": %u, \"chunks\": %u, \"bytes\": %llu, "
        "\"mbytes\": %.3f, \"view_bytes\": %llu, \"mesh_bytes\": %llu, \"cell_ref_bytes\": %llu, "
        "\"bytes_per_view\": %.0f, \"snapshot\": %s, \"seconds\": %.3f, \"digest_equal\": %s}\n",
        s.num_views(), s.num_chunks(), (unsigned long long)(*fresh)->stats().bytes,
        (*fresh)->stats().bytes / 1e6, (unsigned long long)by_kind["view_added"],
        (unsigned long long)by_kind["mesh_chunk"], (unsigned long long)by_kind["cell_refs"],
        s.num_views() ? by_kind["view_added"] / static_cast<double>(s.num_views()) : 0.0,
        (*fresh)->stats().snapshots ? "true" : "false", sec,
        (*fresh)->store().Digest() == s.model_digest() ? "true" : "false");
    std::fflush(stdout);
  }

  // Phase 3: long paced upload: steady-state bytes/s and server RSS.
  {
    uint64_t bytes0;
    {
      std::lock_guard lock(mu);
      bytes0 = live_bytes;
    }
    std::vector<long> rss;
    std::atomic<bool> done{false};
    std::thread sampler([&] {
      while (!done.load()) {
        rss.push_back(RssKb(server.pid()));
        std::this_thread::sleep_for(std::chrono::seconds(2));
      }
    });
    const auto t0 = Clock::now();
    auto up = UploadStream(channel, long_frames, make, paced);
    const v1::Stats s = wait_drained();
    const double sec = std::chrono::duration<double>(Clock::now() - t0).count();
    done.store(true);
    sampler.join();
    uint64_t bytes1;
    {
      std::lock_guard lock(mu);
      bytes1 = live_bytes;
    }
    std::string samples;
    for (long r : rss) samples += (samples.empty() ? "" : ", ") + std::to_string(r / 1024);
    const size_t q = rss.size() / 4;
    std::printf(
        "{\"phase\": \"steady_state\", \"frames\": %d, \"seconds\": %.1f, \"accepted\": %llu, "
        "\"dropped\": %llu, \"views\": %u, \"chunks\": %u, \"viewer_bytes\": %llu, "
        "\"viewer_kbit_per_s\": %.1f, \"rss_mb_after_warmup\": %ld, \"rss_mb_end\": %ld, "
        "\"rss_mb_samples\": [%s]}\n",
        long_frames, sec, up.ok() ? (unsigned long long)up->accepted : 0ull,
        up.ok() ? (unsigned long long)up->dropped : 0ull, s.num_views(), s.num_chunks(),
        (unsigned long long)(bytes1 - bytes0), (bytes1 - bytes0) * 8 / 1000.0 / sec,
        rss.empty() ? -1 : rss[q] / 1024, rss.empty() ? -1 : rss.back() / 1024, samples.c_str());
    std::fflush(stdout);
  }

  // Phase 4: as fast as the server acks.
  {
    UploadOptions fast;
    fast.rate_hz = 0;
    fast.max_in_flight = 8;
    const v1::Stats before = stats();
    const auto t0 = Clock::now();
    auto up = UploadStream(channel, max_frames, make, fast);
    const double ack_sec = std::chrono::duration<double>(Clock::now() - t0).count();
    const v1::Stats after = wait_drained();
    const double sec = std::chrono::duration<double>(Clock::now() - t0).count();
    const uint64_t processed = after.frames_processed() - before.frames_processed();
    std::printf(
        "{\"phase\": \"ingest_max\", \"frames\": %d, \"admitted_fps\": %.2f, "
        "\"processed_fps\": %.2f, \"accepted\": %llu, \"dropped\": %llu, \"drop_fraction\": %.3f}\n",
        max_frames, up.ok() ? up->sent / ack_sec : 0, processed / sec,
        up.ok() ? (unsigned long long)up->accepted : 0ull,
        up.ok() ? (unsigned long long)up->dropped : 0ull,
        up.ok() ? up->dropped / static_cast<double>(up->sent) : 0);
    std::fflush(stdout);
  }
  // Phase 5: long unpaced upload (frames cycle through the trajectory): server RSS every 1000
  // frames sent, the pipeline drained before each sample.
  if (rss_frames > 0) {
    UploadOptions fast;
    fast.rate_hz = 0;
    fast.max_in_flight = 8;
    std::string samples;
    uint64_t accepted = 0, dropped = 0;
    const auto t0 = Clock::now();
    for (int done = 0; done < rss_frames; done += 1000) {
      auto up = UploadStream(channel, std::min(1000, rss_frames - done), make, fast);
      if (up.ok()) {
        accepted += up->accepted;
        dropped += up->dropped;
      }
      (void)wait_drained();
      samples += (samples.empty() ? "" : ", ") + std::to_string(RssKb(server.pid()) / 1024);
    }
    const v1::Stats s = stats();
    std::printf(
        "{\"phase\": \"rss_long\", \"frames\": %d, \"seconds\": %.1f, \"accepted\": %llu, "
        "\"dropped\": %llu, \"views\": %u, \"chunks\": %u, \"version\": %llu, "
        "\"rss_mb_per_1000_frames\": [%s]}\n",
        rss_frames, std::chrono::duration<double>(Clock::now() - t0).count(),
        (unsigned long long)accepted, (unsigned long long)dropped, s.num_views(), s.num_chunks(),
        (unsigned long long)s.model_version(), samples.c_str());
    std::fflush(stdout);
    print_counters("rss_long", s);
  }
  (*viewer)->Stop();
  viewer_thread.join();
  server.Signal(SIGTERM);
  server.Wait(20);
  std::filesystem::remove_all(dir);
  return 0;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) { return exo::Main(argc, argv); }
