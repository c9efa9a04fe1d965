// exoview_server: the modeling server. Usage:
//   exoview_server [--config=FILE] [--port_file=FILE] [--key=value ...]
// Every config key (docs/service.md) works in the file (`key = value`) and as a flag; flags win.
// --listen=127.0.0.1:0 picks a free port; --port_file writes the port once listening.
// SIGINT/SIGTERM: graceful shutdown (admitted frames are processed, subscribers end, exit 0).
#include <pthread.h>
#include <signal.h>

#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>

#include "server/service/server.h"

namespace {

void Usage() {
  std::fprintf(stderr,
               "usage: exoview_server [--config=FILE] [--port_file=FILE] [--key=value ...]\n"
               "keys: listen max_frame_bytes transport_max_bytes admission_queue stage_queue\n"
               "      cell_size_m max_log_deltas max_log_bytes max_subscriber_lag snapshot_when_cheaper\n"
               "      publish_jpeg_quality publish_depth_downscale geometry voxel_size_m max_depth_m\n"
               "      mesh_every_n_frames fuse_depth_downscale chunk_republish_change chunk_republish_interval_s planning max_views max_store_bytes r_max d_max_m\n"
               "      sigma_m delta_tau_sum max_candidates_per_s_when_full id_buffer_stride udp_pose_port udp_pose_address\n"
               "      udp_pose_tolerance_s refinement refine_queue refine_downscale refine_remove_outliers\n"
               "      planning_cell_areas planning_id_from_proxy checkpoint_path checkpoint_interval_s checkpoint_max_log_bytes\n");
}

}  // namespace

int main(int argc, char** argv) {
  // Block the shutdown signals in every thread (gRPC's included); the main thread waits for them.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  exo::ServerConfig config;
  std::string port_file;
  // The config file first, then flags override it.
  for (int i = 1; i < argc; ++i)
    if (std::strncmp(argv[i], "--config=", 9) == 0)
      if (auto s = exo::LoadConfigFile(argv[i] + 9, &config); !s.ok()) {
        std::fprintf(stderr, "exoview_server: %s\n", std::string(s.message()).c_str());
        return 2;
      }
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      Usage();
      return 0;
    }
    if (a.rfind("--config=", 0) == 0) continue;
    const auto eq = a.find('=');
    if (a.rfind("--", 0) != 0 || eq == std::string::npos) {
      std::fprintf(stderr, "exoview_server: bad argument '%s'\n", a.c_str());
      Usage();
      return 2;
    }
    const std::string key = a.substr(2, eq - 2), value = a.substr(eq + 1);
    if (key == "port_file") {
      port_file = value;
      continue;
    }
    if (auto s = exo::ApplyConfigValue(key, value, &config); !s.ok()) {
      std::fprintf(stderr, "exoview_server: %s\n", std::string(s.message()).c_str());
      return 2;
    }
  }

  exo::ExoviewServer server(config);
  if (auto s = server.Start(); !s.ok()) {
    std::fprintf(stderr, "exoview_server: %s\n", std::string(s.message()).c_str());
    return 1;
  }
  std::string stages;
  for (const auto& n : exo::AvailableStages()) stages += " " + n;
  std::fprintf(stderr, "exoview_server: listening on port %d, stages built:%s\n", server.port(),
               stages.empty() ? " (none)" : stages.c_str());
  if (server.udp_pose_port() >= 0)
    std::fprintf(stderr, "exoview_server: UDP poses on port %d\n", server.udp_pose_port());
  if (!port_file.empty()) {
    const std::string tmp = port_file + ".tmp";
    std::ofstream(tmp) << server.port() << "\n";
    std::rename(tmp.c_str(), port_file.c_str());  // atomic: readers never see a partial file
  }
  int sig = 0;
  sigwait(&signals, &sig);
  std::fprintf(stderr, "exoview_server: %s, shutting down\n", sig == SIGINT ? "SIGINT" : "SIGTERM");
  server.Shutdown();
  server.Wait();
  const auto summary = server.store().GetSummary();
  std::fprintf(stderr, "exoview_server: stopped at model version %llu (%u views, %u chunks)\n",
               static_cast<unsigned long long>(summary.version), summary.num_views,
               summary.num_chunks);
  return 0;
}
