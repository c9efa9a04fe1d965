// exoview_server: the modeling server. Usage:
//   exoview_server [--config FILE] [--port_file FILE] [--log_level LEVEL] [--key=value ...]
// Every config key (server_config.cc; docs/service.md) works in the file (`key = value`) and as a
// flag (--key=value or --key value); flags win over the file. --help lists every key with its
// default. --listen=127.0.0.1:0 picks a free port; --port_file writes the port once listening.
// SIGINT/SIGTERM: graceful shutdown (admitted frames are processed, subscribers end, exit 0).
#include <pthread.h>
#include <signal.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "common/cli/cli.h"
#include "common/log/log.h"
#include "common/process/malloc_tuning.h"
#include "server/service/server.h"

namespace {

constexpr char kConfigGroup[] = "Config keys (also `key = value` lines of the --config file)";

// The keys whose value differs from the default, as "key=value" (the startup log line).
std::string ChangedKeys(const exo::ServerConfig& config) {
  const exo::ServerConfig defaults;
  std::vector<std::string> changed;
  for (const exo::ConfigKey& k : exo::ConfigKeys())
    if (k.get(config) != k.get(defaults)) changed.push_back(k.name + "=" + k.get(config));
  return changed.empty() ? "(all defaults)" : absl::StrJoin(changed, " ");
}

}  // namespace

int main(int argc, char** argv) {
  // Block the shutdown signals in every thread (gRPC's included); the main thread waits for them.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  CLI::App app{
      "The Exoview modeling server: RGB-D frames in (gRPC Upload), the view store and "
      "proxy out (Subscribe, GetStats).",
      "exoview_server"};
  exo::cli::Setup(app);
  std::string config_file, port_file;
  const char* env_level = std::getenv("EXOVIEW_LOG_LEVEL");
  std::string log_level = env_level && *env_level ? env_level : "info";
  app.add_option("--config", config_file, "config file of `key = value` lines (flags override it)")
      ->check(CLI::ExistingFile);
  app.add_option("--port_file", port_file, "write the port here once listening");
  app.add_option("--log_level", log_level, "log level (default: EXOVIEW_LOG_LEVEL, else info)")
      ->check(CLI::IsMember(exo::log::LevelNames()));
  // One flag per config key; its value is checked at parse time (exit 2 naming the flag).
  const exo::ServerConfig defaults;
  std::map<std::string, std::string> flag_values;
  std::vector<std::pair<const exo::ConfigKey*, CLI::Option*>> key_flags;
  for (const exo::ConfigKey& k : exo::ConfigKeys()) {
    const std::string default_text = k.get(defaults);
    CLI::Option* opt = app.add_option("--" + k.name, flag_values[k.name], k.help)
                           ->default_str(default_text.empty() ? "\"\"" : default_text)
                           ->type_name("VALUE")
                           ->group(kConfigGroup)
                           ->check(CLI::Validator(
                               [&k](std::string& v) {
                                 exo::ServerConfig scratch;
                                 const absl::Status s = k.set(v, &scratch);
                                 return s.ok() ? std::string() : std::string(s.message());
                               },
                               ""));
    key_flags.emplace_back(&k, opt);
  }
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  exo::log::SetLevel(log_level);
  auto log = exo::log::Get("server");

  // The config file first, then the flags override it.
  exo::ServerConfig config;
  if (!config_file.empty())
    if (auto s = exo::LoadConfigFile(config_file, &config); !s.ok()) {
      std::fprintf(stderr, "exoview_server: %s\n", std::string(s.message()).c_str());
      return 2;
    }
  for (const auto& [key, opt] : key_flags)
    if (opt->count() > 0)
      if (auto s = key->set(flag_values[key->name], &config); !s.ok()) {  // checked at parse
        std::fprintf(stderr, "exoview_server: --%s: %s\n", key->name.c_str(),
                     std::string(s.message()).c_str());
        return 2;
      }
  if (auto s = config.Validate(); !s.ok()) {
    std::fprintf(stderr, "exoview_server: bad config: %s\n", std::string(s.message()).c_str());
    return 2;
  }

  // Before any thread exists (gRPC's and the pipeline's start in server.Start()).
  if (auto s = exo::process::LimitMallocArenas(config.malloc_arena_max); !s.ok())
    log->warn("{}", std::string(s.message()));
  if (auto s = exo::process::SetMallocMmapThreshold(config.malloc_mmap_threshold); !s.ok())
    log->warn("{}", std::string(s.message()));
  exo::ExoviewServer server(config);
  if (auto s = server.Start(); !s.ok()) {
    log->critical("cannot start: {}", std::string(s.message()));
    return 1;
  }
  const std::vector<std::string> stages = exo::AvailableStages();
  log->info("exoview_server {} listening on port {}; stages: {}; {}; config{}: {}",
            exo::cli::Version(), server.port(),
            stages.empty() ? "(none)" : absl::StrJoin(stages, " "),
            server.udp_pose_port() >= 0 ? absl::StrCat("UDP poses on port ", server.udp_pose_port())
                                        : "no UDP poses",
            config_file.empty() ? "" : " " + config_file, ChangedKeys(config));
  if (!port_file.empty()) {
    const std::string tmp = port_file + ".tmp";
    std::ofstream(tmp) << server.port() << "\n";
    std::rename(tmp.c_str(), port_file.c_str());  // atomic: readers never see a partial file
  }
  int sig = 0;
  sigwait(&signals, &sig);
  log->info("{}: shutting down", sig == SIGINT ? "SIGINT" : "SIGTERM");
  server.Shutdown();
  server.Wait();
  const auto summary = server.store().GetSummary();
  log->info("stopped at model version {} ({} views, {} chunks)", summary.version, summary.num_views,
            summary.num_chunks);
  return 0;
}
