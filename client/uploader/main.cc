// exoview_uploader: streams frames to an Exoview server, at a chosen rate, with progress and
// ack statistics.
//   exoview_uploader --server=HOST:PORT (--synthetic[=village|apartment] | --dataset=DIR
//                    --format=7scenes|tum|exo) [--trajectory=flyover|walk] [--frames=N]
//                    [--first=I] [--width=W --height=H] [--rate_hz=R] [--jpeg_quality=Q]
//                    [--max_in_flight=N] [--stats_json=FILE] [--send_log=FILE] [--progress]
// Exit status: 0 when the stream completed (rejections are reported, not fatal), 1 on error.
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <string>

#include "absl/strings/numbers.h"
#include "client/uploader/synth_source.h"
#include "client/uploader/upload_client.h"
#include "common/datasets/exo_layout.h"
#include "common/datasets/seven_scenes.h"
#include "common/datasets/tum.h"

int main(int argc, char** argv) {
  std::map<std::string, std::string> a;
  for (int i = 1; i < argc; ++i) {
    std::string s = argv[i];
    if (s.rfind("--", 0) != 0) {
      std::fprintf(stderr, "exoview_uploader: bad argument '%s'\n", s.c_str());
      return 2;
    }
    const auto eq = s.find('=');
    if (eq == std::string::npos)
      a[s.substr(2)] = "";
    else
      a[s.substr(2, eq - 2)] = s.substr(eq + 1);
  }
  auto num = [&](const char* k, double def) {
    double v = def;
    if (a.count(k) && !absl::SimpleAtod(a[k], &v)) {
      std::fprintf(stderr, "exoview_uploader: --%s needs a number\n", k);
      std::exit(2);
    }
    return v;
  };
  if (!a.count("server")) {
    std::fprintf(stderr, "exoview_uploader: --server=HOST:PORT is required\n");
    return 2;
  }
  std::unique_ptr<exo::FrameSource> source;
  absl::Status st;
  if (a.count("synthetic")) {
    exo::SynthSourceOptions o;
    if (!a["synthetic"].empty()) o.scene = a["synthetic"];
    if (a.count("trajectory")) o.trajectory = a["trajectory"];
    o.num_frames = static_cast<int>(num("frames", 120));
    o.width = static_cast<int>(num("width", 640));
    o.height = static_cast<int>(num("height", 480));
    o.seed = static_cast<uint64_t>(num("seed", 1));
    auto s = exo::SynthFrameSource::Create(o);
    if (s.ok()) source = *std::move(s); else st = s.status();
  } else if (a.count("dataset")) {
    const std::string fmt = a.count("format") ? a["format"] : "7scenes";
    if (fmt == "7scenes") {
      auto s = exo::SevenScenesReader::Open(a["dataset"]);
      if (s.ok()) source = *std::move(s); else st = s.status();
    } else if (fmt == "tum") {
      auto s = exo::TumReader::Open(a["dataset"]);
      if (s.ok()) source = *std::move(s); else st = s.status();
    } else if (fmt == "exo") {
      auto s = exo::ExoLayoutReader::Open(a["dataset"]);
      if (s.ok()) source = *std::move(s); else st = s.status();
    } else {
      st = absl::InvalidArgumentError("--format must be 7scenes, tum or exo");
    }
  } else {
    st = absl::InvalidArgumentError("give --synthetic or --dataset=DIR");
  }
  if (!st.ok()) {
    std::fprintf(stderr, "exoview_uploader: %s\n", std::string(st.message()).c_str());
    return 1;
  }
  exo::UploadOptions opt;
  opt.rate_hz = num("rate_hz", 30);
  opt.max_in_flight = static_cast<int>(num("max_in_flight", 16));
  opt.encode.jpeg_quality = static_cast<int>(num("jpeg_quality", 90));
  opt.progress = a.count("progress") > 0;
  const size_t first = static_cast<size_t>(num("first", 0));
  const size_t count = static_cast<size_t>(num("frames", static_cast<double>(source->size())));
  std::fprintf(stderr, "exoview_uploader: %s, %zu frames from %zu at %.1f Hz -> %s\n",
               source->name().c_str(), std::min(count, source->size()), first, opt.rate_hz,
               a["server"].c_str());
  auto stats = exo::UploadFrames(exo::MakeChannel(a["server"]), *source, first, count, opt);
  if (!stats.ok()) {
    std::fprintf(stderr, "exoview_uploader: %s\n", std::string(stats.status().message()).c_str());
    return 1;
  }
  const std::string json = stats->ToJson();
  std::printf("%s\n", json.c_str());
  if (a.count("stats_json")) std::ofstream(a["stats_json"]) << json << "\n";
  if (a.count("send_log")) {  // "timestamp_s steady_ns" per frame (CLOCK_MONOTONIC)
    std::ofstream log(a["send_log"]);
    log.precision(17);
    for (const auto& [t, ns] : stats->send_times) log << t << " " << ns << "\n";
  }
  return 0;
}
