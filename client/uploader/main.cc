// exoview_uploader: streams frames to an Exoview server, at a chosen rate, with progress and
// ack statistics. Frames come from the built-in synthetic scene or a dataset folder (the readers
// of common/datasets, the same code exoview_eval reads with). Prints the ack statistics as JSON.
// Exit status: 0 when the stream completed (rejections are reported, not fatal), 1 on error,
// 2 on a bad flag.
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include "client/uploader/dr_view_recorder.h"
#include "client/uploader/sim_flight.h"
#include "client/uploader/synth_source.h"
#include "client/uploader/upload_client.h"
#include "common/cli/cli.h"
#include "common/datasets/dataset.h"
#include <nlohmann/json.hpp>

int main(int argc, char** argv) {
  CLI::App app{
      "Streams RGB-D frames (synthetic scene or a dataset folder) to an Exoview server "
      "and prints the ack statistics as JSON.",
      "exoview_uploader"};
  exo::cli::Setup(app);
  std::string server, synthetic, dataset, stats_json, send_log, durable_log;
  exo::SynthSourceOptions synth;
  exo::DatasetOptions data;
  exo::UploadOptions opt;
  opt.encode.jpeg_quality = 90;
  int frames = -1, first = 0;
  std::string drone = "none";
  exo::DrViewRecordOptions dr_view;
  double dr_view_linger_s = 1.0;
  exo::SimFlightOptions flight;
  app.add_option("--server", server, "HOST:PORT of the server (required)");
  exo::ChannelSecurity security;
  app.add_option("--tls_ca", security.tls_ca, "CA certificate (PEM) of the server's certificate: TLS");
  app.add_option("--tls_cert", security.tls_cert, "client certificate (PEM), for mutual TLS");
  app.add_option("--tls_key", security.tls_key, "client private key (PEM)");
  app.add_option("--tls_server_name", security.server_name, "name to verify in the server certificate");
  app.add_option("--token_file", security.token_file, "file holding this client's bearer token");
  app.add_option("--synthetic", synthetic,
                 "stream the built-in synthetic scene: village | apartment")
      ->expected(0, 1)
      ->default_str("village");
  app.add_option("--trajectory", synth.trajectory, "synthetic: flyover | walk");
  app.add_option("--width", synth.width, "synthetic frame width")->check(CLI::PositiveNumber);
  app.add_option("--height", synth.height, "synthetic frame height")->check(CLI::PositiveNumber);
  app.add_option("--seed", synth.seed, "synthetic scene seed");
  app.add_option("--dataset", dataset, "dataset folder to stream");
  app.add_option("--format", data.format, "dataset format: 7scenes | tum | redwood | scannet | exo")
      ->check(CLI::IsMember({"7scenes", "tum", "redwood", "scannet", "exo"}));
  app.add_option("--register_depth", data.register_depth,
                 "7-Scenes: register depth to the colour camera (default true; "
                 "docs/registration.md)");
  app.add_option("--intrinsics", data.intrinsics, "TUM: fx,fy,cx,cy of the sensor")
      ->delimiter(',')
      ->expected(4);
  app.add_option("--camera_file", data.camera_file,
                 "TUM: file with one line \"fx fy cx cy [width height]\"");
  app.add_option("--hold_out_every", data.hold_out_every,
                 "leave out frames i % N == N-1 (exoview_eval's held-out test frames); 0 = none");
  app.add_option("--hold_out_offset", data.hold_out_offset,
                 "with --hold_out_every N: leave out frames i % N == this instead (the fold, "
                 "exoview_eval --holdout_offset); -1 = N-1");
  app.add_option("--first", first, "first frame to send")->check(CLI::NonNegativeNumber);
  app.add_option("--frames", frames, "frames to send (default: all; synthetic: 120)");
  app.add_option("--rate_hz", opt.rate_hz, "send rate; 0 = as fast as the server acks")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--max_in_flight", opt.max_in_flight, "frames sent but not yet acked")
      ->check(CLI::PositiveNumber);
  app.add_option("--jpeg_quality", opt.encode.jpeg_quality, "colour JPEG quality")
      ->check(CLI::Range(1, 100));
  app.add_flag("--progress", opt.progress, "one line per second on stderr");
  app.add_option("--uploader_id", opt.uploader_id,
                 "name of this uploader (exoview-uploader-id): a server with a frame journal "
                 "de-duplicates the frames it resends after a reconnect");
  app.add_option("--reconnect_s", opt.reconnect_s,
                 "when the stream breaks, reconnect for up to this long and resend every frame "
                 "not acked (0 = fail)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--stats_json", stats_json, "also write the statistics JSON to this file");
  app.add_option("--drone", drone,
                 "sim: a simulated drone flies the synthetic scene under the server's control "
                 "service (DroneLink) and uploads what its camera sees")
      ->check(CLI::IsMember({"none", "sim"}));
  app.add_option("--drone_id", flight.drone_id, "drone id on the control stream");
  app.add_option("--flight_s", flight.flight_s, "sim drone: seconds of flight")
      ->check(CLI::PositiveNumber);
  app.add_option("--camera_hz", flight.frame_rate_hz, "sim drone: camera frames per second")
      ->check(CLI::PositiveNumber);
  app.add_option("--link_delay_s", flight.link.delay_s, "sim drone: setpoint link delay")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--link_loss", flight.link.loss, "sim drone: setpoint loss probability")
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--send_log", send_log, "write \"timestamp_s steady_ns\" per sent frame");
  app.add_option("--durable_log", durable_log,
                 "append the sequence of every frame the server acked durable, one a line, "
                 "flushed at once (what an operator compares with the server's model: "
                 "deploy/itest.sh)");
  app.add_option("--dr_view_out", dr_view.out_dir,
                 "also watch the server's live DR view of this stream (WatchDrView: the frames "
                 "with the marked regions removed) and write each frame it sends as "
                 "DIR/dr_<sequence>.jpg; counts under \"dr_view\" in the JSON");
  app.add_option("--dr_view_quality", dr_view.jpeg_quality, "JPEG quality of the DR view")
      ->check(CLI::Range(1, 100));
  app.add_option("--dr_view_linger_s", dr_view_linger_s,
                 "seconds to keep watching after the last frame (the last frames' DR output)")
      ->check(CLI::Range(0.0, 60.0));
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  std::FILE* durable_file = nullptr;
  if (!durable_log.empty()) {
    durable_file = std::fopen(durable_log.c_str(), "a");
    if (!durable_file) {
      std::fprintf(stderr, "exoview_uploader: cannot append to %s\n", durable_log.c_str());
      return 2;
    }
    opt.on_ack = [durable_file](const exo::v1::Ack& a) {
      if (a.status() != exo::v1::Ack::ACCEPTED || !a.durable()) return;
      std::fprintf(durable_file, "%llu\n", static_cast<unsigned long long>(a.sequence()));
      std::fflush(durable_file);
    };
  }

  if (server.empty()) {
    std::fprintf(stderr, "exoview_uploader: --server=HOST:PORT is required\n");
    return 2;
  }
  const bool use_synth = app.count("--synthetic") > 0;
  if (use_synth == !dataset.empty()) {
    std::fprintf(stderr, "exoview_uploader: give exactly one of --synthetic or --dataset=DIR\n");
    return 2;
  }
  if (drone == "sim") {
    if (!use_synth) {
      std::fprintf(stderr, "exoview_uploader: --drone=sim flies the synthetic scene: add --synthetic\n");
      return 2;
    }
    synth.scene = synthetic.empty() ? "village" : synthetic;
    synth.num_frames = 2;
    synth.trajectory = "walk";  // only the scene is used; a walk exists in every scene
    auto s = exo::SynthFrameSource::Create(synth);
    if (!s.ok()) {
      std::fprintf(stderr, "exoview_uploader: %s\n", std::string(s.status().message()).c_str());
      return 1;
    }
    std::fprintf(stderr, "exoview_uploader: sim drone '%s' in %s for %.0f s (server needs "
                 "control_zones=%s)\n", flight.drone_id.c_str(), synth.scene.c_str(),
                 flight.flight_s, exo::SceneZoneText((*s)->scene()).c_str());
    // The same TLS and token as the upload path (the drone's DroneLink is an uploader's call).
    auto channel = exo::MakeChannel(server, security);
    if (!channel.ok()) {
      std::fprintf(stderr, "exoview_uploader: %s\n",
                   std::string(channel.status().message()).c_str());
      return 2;
    }
    auto stats = exo::FlySimDrone(*channel, (*s)->scene(), (*s)->render_options(), flight, opt);
    if (!stats.ok()) {
      std::fprintf(stderr, "exoview_uploader: %s\n", std::string(stats.status().message()).c_str());
      return 1;
    }
    const std::string json = stats->ToJson();
    std::printf("%s\n", json.c_str());
    if (!stats_json.empty()) std::ofstream(stats_json) << json << "\n";
    return 0;
  }
  std::unique_ptr<exo::FrameSource> source;
  absl::Status st;
  if (use_synth) {
    synth.scene = synthetic.empty() ? "village" : synthetic;
    synth.num_frames = frames > 0 ? frames : 120;
    auto s = exo::SynthFrameSource::Create(synth);
    if (s.ok())
      source = *std::move(s);
    else
      st = s.status();
  } else {
    std::vector<std::string> warnings;
    auto s = exo::OpenDataset(dataset, data, &warnings);
    for (const std::string& w : warnings)
      std::fprintf(stderr, "exoview_uploader: warning: %s\n", w.c_str());
    if (s.ok())
      source = *std::move(s);
    else
      st = s.status();
  }
  if (!st.ok()) {
    std::fprintf(stderr, "exoview_uploader: %s\n", std::string(st.message()).c_str());
    return 1;
  }
  const size_t count = frames >= 0 ? static_cast<size_t>(frames) : source->size();
  std::fprintf(stderr, "exoview_uploader: %s, %zu frames from %d at %.1f Hz -> %s\n",
               source->name().c_str(), std::min(count, source->size()), first, opt.rate_hz,
               server.c_str());
  auto channel = exo::MakeChannel(server, security);
  if (!channel.ok()) {
    std::fprintf(stderr, "exoview_uploader: %s\n", std::string(channel.status().message()).c_str());
    return 2;
  }
  std::unique_ptr<exo::DrViewRecorder> recorder;
  if (!dr_view.out_dir.empty()) {
    auto r = exo::DrViewRecorder::Start(*channel, dr_view);
    if (!r.ok()) {
      std::fprintf(stderr, "exoview_uploader: %s\n", std::string(r.status().message()).c_str());
      return 2;
    }
    recorder = *std::move(r);
  }
  auto stats = exo::UploadFrames(*channel, *source, static_cast<size_t>(first), count, opt);
  if (!stats.ok()) {
    std::fprintf(stderr, "exoview_uploader: %s\n", std::string(stats.status().message()).c_str());
    return 1;
  }
  std::string json = stats->ToJson();
  if (recorder) {
    const exo::DrViewRecordStats dr = recorder->Stop(dr_view_linger_s);
    if (!dr.error.empty()) std::fprintf(stderr, "exoview_uploader: DR view: %s\n", dr.error.c_str());
    auto j = nlohmann::ordered_json::parse(json);
    j["dr_view"] = nlohmann::ordered_json::parse(dr.ToJson());
    json = j.dump();
  }
  std::printf("%s\n", json.c_str());
  if (!stats_json.empty()) std::ofstream(stats_json) << json << "\n";
  if (!send_log.empty()) {  // "timestamp_s steady_ns" per frame (CLOCK_MONOTONIC)
    std::ofstream log(send_log);
    log.precision(17);
    for (const auto& [t, ns] : stats->send_times) log << t << " " << ns << "\n";
  }
  return 0;
}
