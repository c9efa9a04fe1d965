// service_abuse_bench: issue 20's abuse scenario at full scale (default: 500 never-reading
// subscribers + 16 viewers + an uploader at 30 Hz) against a real exoview_server process; prints
// one JSON line: the server's peak RSS in a baseline run without the never-readers (a fresh
// server), then RSS before / peak / after with them, the model size, the bound (baseline peak +
// 2 x model + 100 MB), threads, timed-out calls and the viewers' digest equality.
//   exoview_bench tests/service_abuse_bench [--never_readers=N] [--viewers=V] [--frames=F]
//                 [--loop_frames=L] [--server_arg=--key=value ...]
// The long steady-state run (issue 20, docs/security.md §3): 16 viewers + an uploader at 30 Hz for
// 10 minutes over a closed loop of an already-modelled walk, RSS + heap live/free every 15 s:
//   service_abuse_bench --never_readers=0 --viewers=16 --frames=18000 --loop_frames=900
//                       --skip_baseline --rss_sample_s=15
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "common/cli/cli.h"
#include "tests/abuse_scenario.h"

int main(int argc, char** argv) {
  CLI::App app{
      "Never-reading subscribers + viewers + an uploader against a real server; prints JSON.",
      "service_abuse_bench"};
  exo::cli::Setup(app);
  exo::abuse::Options o;
  o.never_readers = 500;
  o.viewers = 16;
  o.frames = 300;
  std::vector<std::string> server_args;
  double write_timeout_s = 5.0;
  app.add_option("--never_readers", o.never_readers, "subscribers that never read")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--viewers", o.viewers, "normal viewers")->check(CLI::NonNegativeNumber);
  app.add_option("--frames", o.frames, "frames uploaded while they are connected")
      ->check(CLI::PositiveNumber);
  app.add_option("--warm_frames", o.warm_frames, "frames uploaded first")
      ->check(CLI::PositiveNumber);
  app.add_option("--rate_hz", o.rate_hz, "upload rate")->check(CLI::PositiveNumber);
  app.add_option("--write_timeout_s", write_timeout_s, "server's subscriber_write_timeout_s");
  app.add_option("--server_arg", server_args, "extra exoview_server flag (repeatable)");
  bool skip_baseline = false;
  app.add_flag("--skip_baseline", skip_baseline,
               "no baseline run without the never-readers (a long run: the RSS curve only)");
  app.add_option("--rss_sample_s", o.rss_sample_s, "seconds between RSS samples")
      ->check(CLI::PositiveNumber);
  app.add_option("--loop_frames", o.loop_frames,
                 "> 0: the walk rendered over this many frames is uploaded once (warm-up, instead "
                 "of --warm_frames), then --frames cycle over it with fresh sequences/timestamps")
      ->check(CLI::NonNegativeNumber);
  double flat_after_s = -1;
  app.add_option("--flat_after_s", flat_after_s,
                 "warm-up end for the flatness figures (default: a third of the run)");
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;

  char tmpl[] = "/tmp/exoview_abuse_bench_XXXXXX";
  if (mkdtemp(tmpl) == nullptr) return 1;
  const std::string dir = tmpl;
  // One fresh server per run.
  auto run = [&](const exo::abuse::Options& opt, const std::string& name) {
    std::vector<std::string> args{
        "--listen=127.0.0.1:0", "--port_file=" + dir + "/" + name + ".port",
        "--subscriber_write_timeout_s=" + std::to_string(write_timeout_s),
        "--max_subscribers=" + std::to_string(opt.never_readers + opt.viewers + 64)};
    args.insert(args.end(), server_args.begin(), server_args.end());
    exo::testing::Subprocess server(EXOVIEW_SERVER_BIN, args, dir + "/" + name + ".log");
    exo::abuse::Result r;
    if (!exo::testing::WaitForFile(dir + "/" + name + ".port", 30)) {
      r.error = "the server did not start: " + server.Log();
      return r;
    }
    const std::string target =
        "127.0.0.1:" + std::to_string(std::stoi(exo::testing::ReadAll(dir + "/" + name + ".port")));
    r = exo::abuse::Run(target, server.pid(), opt);
    server.Signal(SIGTERM);
    server.Wait(10);
    return r;
  };
  exo::abuse::Options base_o = o;
  base_o.never_readers = 0;
  const exo::abuse::Result base = skip_baseline ? exo::abuse::Result{} : run(base_o, "baseline");
  const exo::abuse::Result r = run(o, "abuse");
  const double bound =
      (skip_baseline ? r.rss_before_mb : base.rss_peak_mb) + 2 * r.model_mb + 100;
  // Flat after warm-up: the spread of the samples of the last two thirds of the run.
  const auto& rs = r.rss_samples_mb;
  double late_min = 0, late_max = 0;
  if (!rs.empty()) {
    const auto first = rs.begin() + static_cast<std::ptrdiff_t>(rs.size() / 3);
    late_min = *std::min_element(first, rs.end());
    late_max = *std::max_element(first, rs.end());
  }
  // After the warm-up (--flat_after_s): RSS and the heap's live / free bytes, first and range.
  nlohmann::ordered_json after_warmup = nlohmann::ordered_json::object();
  {
    const auto& ms = r.memory_samples;
    const double from_s =
        flat_after_s >= 0 ? flat_after_s : (ms.empty() ? 0.0 : ms.back().t_s / 3.0);
    std::vector<exo::abuse::MemorySample> late;
    for (const auto& m : ms)
      if (m.t_s >= from_s) late.push_back(m);
    auto range = [&](auto field) {
      double lo = 1e300, hi = -1e300;
      for (const auto& m : late) lo = std::min(lo, field(m)), hi = std::max(hi, field(m));
      return nlohmann::ordered_json{{"first", field(late.front())}, {"min", lo}, {"max", hi},
                                    {"last", field(late.back())},
                                    {"spread_of_first", (hi - lo) / field(late.front())}};
    };
    if (!late.empty())
      after_warmup = {{"from_s", from_s},
                      {"samples", late.size()},
                      {"rss_mb", range([](const auto& m) { return m.rss_mb; })},
                      {"heap_in_use_mb", range([](const auto& m) { return m.heap_in_use_mb; })},
                      {"heap_free_mb", range([](const auto& m) { return m.heap_free_mb; })}};
  }
  nlohmann::ordered_json samples = nlohmann::ordered_json::array();
  for (const auto& m : r.memory_samples)
    samples.push_back({{"t_s", std::round(m.t_s)},
                       {"rss_mb", std::round(m.rss_mb * 10) / 10},
                       {"heap_in_use_mb", std::round(m.heap_in_use_mb * 10) / 10},
                       {"heap_free_mb", std::round(m.heap_free_mb * 10) / 10},
                       {"log_mb", std::round(m.log_mb * 10) / 10},
                       {"snapshot_mb", std::round(m.snapshot_mb * 100) / 100},
                       {"views", m.views},
                       {"cells", m.cells},
                       {"chunks", m.chunks},
                       {"frames_accepted", m.frames_accepted}});
  nlohmann::ordered_json j = {{"bench", "service_abuse"},
                              {"never_readers", o.never_readers},
                              {"viewers", o.viewers},
                              {"frames", (o.loop_frames > 0 ? o.loop_frames : o.warm_frames) +
                                             o.frames},
                              {"loop_frames", o.loop_frames},
                              {"rate_hz", o.rate_hz},
                              {"model_mb", r.model_mb},
                              {"baseline_rss_peak_mb", base.rss_peak_mb},
                              {"baseline_threads_peak", base.threads_peak},
                              {"rss_before_mb", r.rss_before_mb},
                              {"rss_peak_mb", r.rss_peak_mb},
                              {"rss_after_mb", r.rss_after_mb},
                              {"rss_bound_mb", bound},
                              {"rss_within_bound", r.rss_peak_mb < bound},
                              {"threads_peak", r.threads_peak},
                              {"timed_out_calls", r.timed_out_calls},
                              {"subscribers_left", r.subscribers_left},
                              {"viewers_digest_equal", r.viewers_equal},
                              {"rss_samples_mb", r.rss_samples_mb},
                              {"rss_sample_s", o.rss_sample_s},
                              {"rss_last_two_thirds_min_mb", late_min},
                              {"rss_last_two_thirds_max_mb", late_max},
                              {"rss_last_two_thirds_spread",
                               late_min > 0 ? (late_max - late_min) / late_min : 0.0},
                              {"after_warmup", after_warmup},
                              {"memory_samples", samples},
                              {"error", r.error.empty() ? base.error : r.error}};
  std::printf("%s\n", j.dump().c_str());
  std::filesystem::remove_all(dir);
  return r.error.empty() && r.viewers_equal == o.viewers && r.rss_peak_mb < bound ? 0 : 1;
}
