// The "bounded under abuse" scenario of issue 20 (item 4), shared by tests/service_abuse_test.cc
// (a scale two CPU cores run in seconds) and the benchmark tests/service_abuse_bench.cc (500
// never-reading subscribers, printing JSON): a real exoview_server process, an uploader at a
// fixed rate, normal viewers that sync the whole model, and subscribers that open Subscribe and
// never read. Measures the server's RSS over time and the viewers' digests.
#pragma once

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <fstream>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "client/uploader/synth_source.h"
#include "client/uploader/upload_client.h"
#include "client/viewer/viewer_session.h"
#include "common/status.h"
#include "proto/frame_proto.h"
#include "proto/exoview.grpc.pb.h"
#include "tests/subprocess.h"

namespace exo::abuse {

inline int64_t ProcKb(pid_t pid, const std::string& key) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind(key + ":", 0) == 0) return std::atoll(line.c_str() + key.size() + 1);
  return -1;
}

inline v1::Stats ServerStats(const std::string& target) {
  auto stub = v1::Exoview::NewStub(MakeChannel(target));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  v1::Stats s;
  stub->GetStats(&ctx, v1::StatsRequest{}, &s);
  return s;
}

// A subscriber that never reads: its own connection, the call open, Read() never called.
struct NeverReader {
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<grpc::ClientContext> ctx;
  std::unique_ptr<grpc::ClientReader<v1::Delta>> reader;
};

inline NeverReader OpenNeverReader(const std::string& target, int i) {
  grpc::ChannelArguments args;
  args.SetInt("exoview.abuse_connection", i);  // distinct args: a connection of its own
  args.SetMaxReceiveMessageSize(64 << 20);
  NeverReader n;
  n.channel = grpc::CreateCustomChannel(target, grpc::InsecureChannelCredentials(), args);
  n.ctx = std::make_unique<grpc::ClientContext>();
  auto stub = v1::Exoview::NewStub(n.channel);
  v1::SubscribeRequest req;
  req.set_client_name("never-reads-" + std::to_string(i));
  n.reader = stub->Subscribe(n.ctx.get(), req);
  return n;
}

struct Options {
  int never_readers = 48;
  int viewers = 4;
  int frames = 90;       // uploaded while the subscribers are connected
  int warm_frames = 40;  // uploaded first (the model the never-readers are sent)
  double rate_hz = 30.0;
  int width = 320, height = 240;
  double rss_sample_s = 10.0;
  // > 0: a closed-loop stream for a steady state. The walk is rendered over `loop_frames` frames;
  // the warm-up uploads all of them once (instead of `warm_frames`), then the `frames` uploaded
  // while the subscribers are connected cycle over the same encoded loop with fresh sequence
  // numbers and timestamps: the model (TSDF, store) covers the path after the first pass, so what
  // still grows is the process, not the scene.
  int loop_frames = 0;
};

// One sample of the server's memory while the subscribers are connected.
struct MemorySample {
  double t_s = 0;
  double rss_mb = 0;
  double heap_in_use_mb = 0, heap_free_mb = 0;  // glibc mallinfo2 (live vs kept free)
  double log_mb = 0, snapshot_mb = 0;           // delta log, model snapshot
  uint64_t views = 0, cells = 0, chunks = 0, frames_accepted = 0;
};

struct Result {
  double rss_before_mb = 0;  // after the warm-up upload, before any subscriber
  double rss_peak_mb = 0;    // largest VmRSS sample while the subscribers were connected
  double rss_after_mb = 0;   // after the never-readers were timed out and the viewers left
  double model_mb = 0;       // server's snapshot size (store.snapshot_bytes)
  int viewers_equal = 0;     // viewers whose digest equals the server's
  uint64_t server_digest = 0;
  double timed_out_calls = 0;
  double subscribers_left = 0;
  int threads_peak = 0;
  // VmRSS every `rss_sample_s` seconds while the subscribers were connected (a long run's curve).
  std::vector<double> rss_samples_mb;
  std::vector<MemorySample> memory_samples;  // the same moments, with the heap and the model
  std::string error;
};

// Runs the scenario against a server at `target` (process `pid`, for RSS).
inline Result Run(const std::string& target, pid_t pid, const Options& o) {
  Result r;
  SynthSourceOptions so;
  so.scene = "apartment";
  so.trajectory = "walk";
  so.width = o.width;
  so.height = o.height;
  const bool loop = o.loop_frames > 0;
  const int warm_frames = loop ? o.loop_frames : o.warm_frames;
  so.num_frames = loop ? o.loop_frames : o.warm_frames + o.frames;
  auto source = SynthFrameSource::Create(so);
  if (!source.ok()) {
    r.error = std::string(source.status().message());
    return r;
  }
  UploadOptions uo;
  uo.rate_hz = 0;
  std::vector<v1::Frame> loop_protos;  // the encoded loop, kept for the cycles
  auto warm = UploadStream(MakeChannel(target), warm_frames,
                           [&](size_t i) -> absl::StatusOr<v1::Frame> {
                             EXO_ASSIGN_OR_RETURN(Frame f, (*source)->Load(i));
                             EXO_ASSIGN_OR_RETURN(v1::Frame m, FrameToProto(f, uo.encode));
                             if (loop) loop_protos.push_back(m);
                             return m;
                           },
                           uo);
  if (!warm.ok()) {
    r.error = std::string(warm.status().message());
    return r;
  }
  auto wait_processed = [&] {
    for (int i = 0; i < 600; ++i) {
      const v1::Stats s = ServerStats(target);
      if (s.frames_processed() == s.frames_accepted() && s.async_pending() == 0) return;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  };
  wait_processed();
  r.model_mb = ServerStats(target).counters().at("store.snapshot_bytes") / 1e6;
  r.rss_before_mb = ProcKb(pid, "VmRSS") / 1024.0;

  std::atomic<bool> sampling{true};
  std::atomic<int64_t> peak_kb{0};
  std::atomic<int> peak_threads{0};
  std::mutex samples_mu;
  std::thread sampler([&] {
    const auto t0 = std::chrono::steady_clock::now();
    double next_sample_s = 0.0;
    while (sampling.load()) {
      const int64_t kb = ProcKb(pid, "VmRSS");
      peak_kb.store(std::max<int64_t>(peak_kb.load(), kb));
      const double t =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (t >= next_sample_s) {
        const v1::Stats st = ServerStats(target);
        auto counter = [&](const char* k) {
          const auto it = st.counters().find(k);
          return it == st.counters().end() ? 0.0 : it->second / 1048576.0;
        };
        MemorySample m;
        m.t_s = t;
        m.rss_mb = kb / 1024.0;
        m.heap_in_use_mb = counter("process.heap_in_use_bytes");
        m.heap_free_mb = counter("process.heap_free_bytes");
        m.log_mb = counter("store.log_bytes");
        m.snapshot_mb = counter("store.snapshot_bytes");
        m.views = st.num_views();
        m.cells = st.num_cells();
        m.chunks = st.num_chunks();
        m.frames_accepted = st.frames_accepted();
        std::lock_guard lock(samples_mu);
        r.rss_samples_mb.push_back(m.rss_mb);
        r.memory_samples.push_back(m);
        next_sample_s += o.rss_sample_s;
      }
      peak_threads.store(
          std::max<int>(peak_threads.load(), static_cast<int>(ProcKb(pid, "Threads"))));
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  });
  std::vector<NeverReader> never;
  for (int i = 0; i < o.never_readers; ++i) never.push_back(OpenNeverReader(target, i));
  // Viewers follow the model while the uploader goes on.
  std::vector<std::unique_ptr<ViewerSession>> sessions;
  for (int i = 0; i < o.viewers; ++i) {
    auto s = ViewerSession::Open(MakeChannel(target), "");
    if (s.ok()) sessions.push_back(*std::move(s));
  }
  std::vector<std::thread> viewer_threads;
  std::vector<absl::Status> viewer_status(sessions.size());
  for (size_t i = 0; i < sessions.size(); ++i)
    viewer_threads.emplace_back([&, i] {
      SyncOptions sync;
      sync.max_seconds = std::max(120.0, 2.0 * o.frames / o.rate_hz + 60.0);  // long runs
      sync.min_server_frames = static_cast<uint64_t>(warm_frames + o.frames);
      sync.client_name = "viewer-" + std::to_string(i);
      viewer_status[i] = sessions[i]->Sync(sync);
    });
  uo.rate_hz = o.rate_hz;
  absl::StatusOr<UploadAckStats> up;
  if (loop && !loop_protos.empty()) {
    const uint64_t seq0 = loop_protos.back().sequence();
    const double t0 = loop_protos.back().timestamp_s();
    up = UploadStream(MakeChannel(target), o.frames,
                      [&](size_t i) -> absl::StatusOr<v1::Frame> {
                        v1::Frame f = loop_protos[i % loop_protos.size()];
                        f.set_sequence(seq0 + i + 1);
                        f.set_timestamp_s(t0 + (i + 1) / so.frame_rate_hz);
                        return f;
                      },
                      uo);
  } else {
    up = UploadFrames(MakeChannel(target), **source, o.warm_frames, o.frames, uo);
  }
  if (!up.ok()) r.error = std::string(up.status().message());
  wait_processed();
  for (auto& t : viewer_threads) t.join();
  r.server_digest = ServerStats(target).model_digest();
  for (size_t i = 0; i < sessions.size(); ++i) {
    if (!viewer_status[i].ok() && r.error.empty())
      r.error = std::string(viewer_status[i].message());
    if (sessions[i]->store().Digest() == r.server_digest) ++r.viewers_equal;
  }
  sessions.clear();
  // The never-readers are still connected: the server times them out on its own.
  for (int i = 0; i < 200; ++i) {
    const v1::Stats s = ServerStats(target);
    if (s.counters().at("server.subscriber_calls") == 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  const v1::Stats s = ServerStats(target);
  r.timed_out_calls = s.counters().at("server.timed_out_calls");
  r.subscribers_left = s.counters().at("server.subscriber_calls");
  sampling.store(false);
  sampler.join();
  r.rss_peak_mb = peak_kb.load() / 1024.0;
  r.threads_peak = peak_threads.load();
  for (auto& n : never) n.ctx->TryCancel();
  never.clear();
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  r.rss_after_mb = ProcKb(pid, "VmRSS") / 1024.0;
  return r;
}

}  // namespace exo::abuse
