// service_bench: the service on loopback with a real exoview_server process (SPEC §10 targets).
// Prints one JSON object per phase:
//   ingest_paced    30 Hz upload of distinct 640x480 RGB-D frames: ack/drop counts, frame-to-delta
//                   latency at a subscribed viewer (p50/p95), views in the store
//   initial_sync    bytes a fresh viewer receives to sync the store (by delta kind)
//   steady_state    long 30 Hz upload (frames repeat with new sequence numbers): bytes/s at the
//                   viewer, server RSS samples (flat after warm-up?)
//   ingest_max      upload as fast as the server acks: admitted fps, processed fps, dropped
//   rss_sample      (--rss_frames) long unpaced upload: RSS, heap live/free, log, store per 1000
//                   frames; --rss_fill_frames processes the first N frames without drops so the
//                   store is full sooner (docs/service.md "Memory over a long session")
//   exoview_bench tests/service_bench [--distinct=N] [--long=M] [--max=K] [--width=W --height=H]
//                 [--rss_frames=F [--rss_fill_frames=N]] [--server_arg=--key=value ...]
#include <chrono>
#include <cmath>
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
#include <nlohmann/json.hpp>

#include "client/uploader/synth_source.h"
#include "client/uploader/upload_client.h"
#include "client/viewer/viewer_session.h"
#include "common/cli/cli.h"
#include "proto/exoview.grpc.pb.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using Clock = std::chrono::steady_clock;
using json = nlohmann::ordered_json;  // fields in the order written

// Rounds to `digits` decimals for the JSON lines.
double Round(double x, int digits) {
  const double f = std::pow(10.0, digits);
  return std::round(x * f) / f;
}

void PrintLine(const json& line) {
  std::printf("%s\n", line.dump().c_str());
  std::fflush(stdout);
}

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
    case v1::Delta::kMeshChunkBatch: return "mesh_chunk";  // a snapshot's chunks, batched
    case v1::Delta::kCellRefsChanged: return "cell_refs";
    case v1::Delta::kViewUpdated: return "view_updated";
    case v1::Delta::kViewRemoved: return "view_removed";
    case v1::Delta::kMeshChunkRemoved: return "mesh_chunk_removed";
    default: return "other";
  }
}

int Main(int argc, char** argv) {
  int distinct = 300, long_frames = 1800, max_frames = 300, width = 640, height = 480;
  int rss_frames = 0;  // phase 5 (off by default): unpaced long upload, RSS per 1000 frames
  std::vector<std::string> server_args;
  CLI::App app{"The service on loopback with a real exoview_server process: ingest, initial sync, "
               "steady state, max ingest; one JSON object per phase.",
               "service_bench"};
  exo::cli::Setup(app);
  app.add_option("--distinct", distinct, "distinct frames (phase 1, 30 Hz)")
      ->check(CLI::PositiveNumber);
  app.add_option("--long", long_frames, "frames of the long 30 Hz upload (phase 3)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--max", max_frames, "frames uploaded as fast as acked (phase 4)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--width", width, "frame width")->check(CLI::PositiveNumber);
  app.add_option("--height", height, "frame height")->check(CLI::PositiveNumber);
  app.add_option("--rss_frames", rss_frames, "unpaced upload with RSS per 1000 frames (phase 5)")
      ->check(CLI::NonNegativeNumber);
  int rss_fill_frames = 0;
  app.add_option("--rss_fill_frames", rss_fill_frames,
                 "phase 5: the first N frames in batches of 8, the pipeline drained after each "
                 "(every frame processed, none dropped): the store fills sooner")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--server_arg", server_args,
                 "a flag passed to exoview_server, repeatable: --server_arg=--key=value")
      ->allow_extra_args(false);
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
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
  std::map<std::string, uint64_t> live_by_kind;  // what the live viewer's bytes are
  auto viewer = ViewerSession::Open(channel, "");
  (*viewer)->SetOnDelta([&](const v1::Delta& d, int64_t recv_ns) {
    std::lock_guard lock(mu);
    live_bytes += d.ByteSizeLong();
    live_by_kind[KindName(d)] += d.ByteSizeLong();
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
  std::string stages;
  for (const auto& n : s1.stages()) stages += (stages.empty() ? "" : "+") + n;
  PrintLine({{"phase", "ingest_paced"},
             {"width", width},
             {"height", height},
             {"frames", up1->sent},
             {"rate_hz", 30},
             {"fps", Round(up1->fps(), 2)},
             {"accepted", up1->accepted},
             {"dropped", up1->dropped},
             {"rejected", up1->rejected},
             {"mean_frame_bytes", frame_bytes / frames.size()},
             {"views", s1.num_views()},
             {"chunks", s1.num_chunks()},
             {"cells", s1.num_cells()},
             {"latency_frames_with_delta", lat.size()},
             {"frame_to_delta_p50_ms", Round(Pct(lat, 0.5), 2)},
             {"frame_to_delta_p95_ms", Round(Pct(lat, 0.95), 2)},
             {"ack_p50_ms", Round(up1->ack_latency_p50_ms, 2)},
             {"ack_p95_ms", Round(up1->ack_latency_p95_ms, 2)},
             {"stages", stages}});
  auto print_counters = [&](const std::string& phase, const v1::Stats& st) {
    json line = {{"phase", phase + "_counters"}};
    for (const auto& [k, v] : std::map<std::string, double>(st.counters().begin(), st.counters().end()))
      line[k] = Round(v, 6);
    PrintLine(line);
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
    PrintLine({{"phase", "initial_sync"},
               {"views", s.num_views()},
               {"chunks", s.num_chunks()},
               {"bytes", (*fresh)->stats().bytes},
               {"mbytes", Round((*fresh)->stats().bytes / 1e6, 3)},
               {"view_bytes", by_kind["view_added"]},
               {"mesh_bytes", by_kind["mesh_chunk"]},
               {"cell_ref_bytes", by_kind["cell_refs"]},
               {"bytes_per_view",
                Round(s.num_views() ? by_kind["view_added"] / static_cast<double>(s.num_views())
                                    : 0.0,
                      0)},
               {"snapshot", (*fresh)->stats().snapshots > 0},
               {"seconds", Round(sec, 3)},
               {"digest_equal", (*fresh)->store().Digest() == s.model_digest()}});
  }

  // Phase 3: long paced upload: steady-state bytes/s and server RSS.
  {
    uint64_t bytes0;
    std::map<std::string, uint64_t> kinds0;
    {
      std::lock_guard lock(mu);
      bytes0 = live_bytes;
      kinds0 = live_by_kind;
    }
    const v1::Stats counters0 = stats();
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
    json by_kind = json::object();  // steady-state bytes per delta kind
    {
      std::lock_guard lock(mu);
      bytes1 = live_bytes;
      for (const auto& [k, v] : live_by_kind) by_kind[k] = v - kinds0[k];
    }
    json samples = json::array();
    for (long r : rss) samples.push_back(r / 1024);
    const size_t q = rss.size() / 4;
    PrintLine({{"phase", "steady_state"},
               {"frames", long_frames},
               {"seconds", Round(sec, 1)},
               {"accepted", up.ok() ? up->accepted : 0},
               {"dropped", up.ok() ? up->dropped : 0},
               {"views", s.num_views()},
               {"chunks", s.num_chunks()},
               {"viewer_bytes", bytes1 - bytes0},
               {"viewer_kbit_per_s", Round((bytes1 - bytes0) * 8 / 1000.0 / sec, 1)},
               {"viewer_bytes_by_kind", by_kind},
               {"server_published_chunk_bytes", [&] {
                  // Why the server published mesh chunks in this phase (geometry stage counters).
                  json out = json::object();
                  for (const char* r : {"new", "structural", "interval", "refresh"}) {
                    const std::string k = std::string("geometry.published_bytes_") + r;
                    const auto a = counters0.counters().find(k), b = s.counters().find(k);
                    if (a != counters0.counters().end() && b != s.counters().end())
                      out[r] = b->second - a->second;
                  }
                  return out;
                }()},
               {"rss_mb_after_warmup", rss.empty() ? -1 : rss[q] / 1024},
               {"rss_mb_end", rss.empty() ? -1 : rss.back() / 1024},
               {"rss_mb_samples", samples}});
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
    PrintLine({{"phase", "ingest_max"},
               {"frames", max_frames},
               {"admitted_fps", Round(up.ok() ? up->sent / ack_sec : 0, 2)},
               {"processed_fps", Round(processed / sec, 2)},
               {"accepted", up.ok() ? up->accepted : 0},
               {"dropped", up.ok() ? up->dropped : 0},
               {"drop_fraction", Round(up.ok() ? up->dropped / static_cast<double>(up->sent) : 0, 3)}});
  }
  // Phase 5: long unpaced upload (frames cycle through the trajectory): server RSS every 1000
  // frames sent, the pipeline drained before each sample.
  if (rss_frames > 0) {
    UploadOptions fast;
    fast.rate_hz = 0;
    fast.max_in_flight = 8;
    json samples = json::array();
    uint64_t accepted = 0, dropped = 0;
    const auto t0 = Clock::now();
    // Fill: frames [0, rss_fill_frames) go in batches of 8 (the admission queue), each drained
    // before the next, so every one reaches the planner instead of ~1 in 7. `sent` keeps the
    // cycle going across calls (UploadStream numbers each call's frames from 0).
    size_t sent = 0;
    auto upload = [&](int n) {
      const size_t first = sent;
      sent += n;
      auto up = UploadStream(channel, n, [&](size_t i) { return make(first + i); }, fast);
      if (up.ok()) {
        accepted += up->accepted;
        dropped += up->dropped;
      }
    };
    for (int done = 0; done < rss_frames; done += 1000) {
      const int n = std::min(1000, rss_frames - done);
      const int fill = std::clamp(rss_fill_frames - done, 0, n);
      for (int b = 0; b < fill; b += 8) {
        upload(std::min(8, fill - b));
        wait_drained();
      }
      if (n > fill) upload(n - fill);
      const v1::Stats d = wait_drained();
      samples.push_back(RssKb(server.pid()) / 1024);
      // One line per sample: what could grow beside RSS (the delta log against its bounds, the
      // glibc heap's live and free bytes, the store).
      auto counter = [&d](const char* k) {
        auto it = d.counters().find(k);
        return it == d.counters().end() ? -1.0 : it->second;
      };
      PrintLine({{"phase", "rss_sample"},
                 {"frames", done + std::min(1000, rss_frames - done)},
                 {"seconds", Round(std::chrono::duration<double>(Clock::now() - t0).count(), 1)},
                 {"rss_mb", samples.back()},
                 {"accepted", accepted},
                 {"heap_in_use_mb", Round(counter("process.heap_in_use_bytes") / 1048576.0, 1)},
                 {"heap_free_mb", Round(counter("process.heap_free_bytes") / 1048576.0, 1)},
                 {"log_deltas", counter("store.log_deltas")},
                 {"log_mb", Round(counter("store.log_bytes") / 1048576.0, 1)},
                 {"snapshot_mb", Round(counter("store.snapshot_bytes") / 1048576.0, 1)},
                 {"views", d.num_views()},
                 {"chunks", d.num_chunks()}});
    }
    const v1::Stats s = stats();
    PrintLine({{"phase", "rss_long"},
               {"frames", rss_frames},
               {"fill_frames", rss_fill_frames},
               {"seconds", Round(std::chrono::duration<double>(Clock::now() - t0).count(), 1)},
               {"accepted", accepted},
               {"dropped", dropped},
               {"views", s.num_views()},
               {"chunks", s.num_chunks()},
               {"version", s.model_version()},
               {"rss_mb_per_1000_frames", samples}});
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
