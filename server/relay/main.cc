// exoview_relay: serves a scene's model to viewers from NATS JetStream (server/relay/relay.h).
//   exoview_relay --nats_url=nats://127.0.0.1:4222 --scene=default --listen=127.0.0.1:50061
// --listen=127.0.0.1:0 picks a free port; --port_file writes it once listening. Health
// (grpc.health.v1) is SERVING once the replica caught up with the stream. SIGINT/SIGTERM: stop.
#include <pthread.h>
#include <signal.h>

#include <cstdio>
#include <fstream>
#include <string>

#include "common/cli/cli.h"
#include "common/log/log.h"
#include "common/process/malloc_tuning.h"
#include "server/relay/relay.h"

int main(int argc, char** argv) {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  CLI::App app{"Exoview relay: the Subscribe API for viewers, from a scene's NATS JetStream stream "
               "(stateless; any number per scene).",
               "exoview_relay"};
  exo::cli::Setup(app);
  exo::RelayConfig c;
  std::string port_file, log_level = "info";
  int malloc_arena_max = exo::process::kDefaultMallocArenaMax;
  size_t malloc_mmap_threshold = exo::process::kDefaultMallocMmapThreshold;
  app.add_option("--listen", c.listen, "gRPC address host:port (port 0: a free port)")
      ->capture_default_str();
  app.add_option("--nats_url", c.nats.url, "NATS server URL(s), comma-separated")
      ->capture_default_str();
  app.add_option("--scene", c.nats.scene, "scene name (as the server's --scene)")
      ->capture_default_str();
  app.add_option("--max_subscribers", c.max_subscribers, "concurrent Subscribe calls")
      ->capture_default_str();
  app.add_option("--max_log_deltas", c.store.max_log_deltas, "replica's delta log bound (entries)")
      ->capture_default_str();
  app.add_option("--max_log_bytes", c.store.max_log_bytes, "replica's delta log bound (bytes)")
      ->capture_default_str();
  app.add_option("--snapshot_when_cheaper", c.store.snapshot_when_cheaper,
                 "on resume, a snapshot instead of the missed deltas when it is fewer bytes")
      ->capture_default_str();
  app.add_option("--snapshot_chunk_batch_bytes", c.store.snapshot_chunk_batch_bytes,
                 "a snapshot's mesh chunks in zstd batches of up to this many bytes (0: one by one)")
      ->capture_default_str();
  app.add_option("--tls_cert", c.tls_cert, "certificate chain (PEM); with --tls_key: TLS");
  app.add_option("--tls_key", c.tls_key, "private key (PEM)");
  app.add_option("--tls_client_ca", c.tls_client_ca, "CA of required client certificates");
  app.add_option("--auth_tokens_file", c.auth_tokens_file, "bearer tokens (needs TLS)");
  app.add_option("--allow_insecure_remote", c.allow_insecure_remote,
                 "allow plain text on a non-loopback address")
      ->capture_default_str();
  app.add_option("--malloc_arena_max", malloc_arena_max, exo::process::kMallocArenaMaxHelp)
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--malloc_mmap_threshold", malloc_mmap_threshold,
                 exo::process::kMallocMmapThresholdHelp)
      ->check(CLI::Range(size_t{0}, size_t{32} << 20))
      ->capture_default_str();
  app.add_option("--port_file", port_file, "write the port here once listening");
  app.add_option("--log_level", log_level, "log level")->check(CLI::IsMember(exo::log::LevelNames()));
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  exo::log::SetLevel(log_level);
  auto log = exo::log::Get("relay");
  // Before any thread exists (gRPC's and the NATS client's start in relay.Start()).
  if (auto s = exo::process::LimitMallocArenas(malloc_arena_max); !s.ok())
    log->warn("{}", std::string(s.message()));
  if (auto s = exo::process::SetMallocMmapThreshold(malloc_mmap_threshold); !s.ok())
    log->warn("{}", std::string(s.message()));
  exo::Relay relay(c);
  if (auto s = relay.Start(); !s.ok()) {
    log->critical("cannot start: {}", std::string(s.message()));
    return 1;
  }
  log->info("exoview_relay {} listening on port {}; scene {} from {}; malloc_arena_max {}",
            exo::cli::Version(), relay.port(), c.nats.scene, c.nats.url, malloc_arena_max);
  if (!port_file.empty()) {
    const std::string tmp = port_file + ".tmp";
    std::ofstream(tmp) << relay.port() << "\n";
    std::rename(tmp.c_str(), port_file.c_str());
  }
  int sig = 0;
  sigwait(&signals, &sig);
  log->info("{}: shutting down", sig == SIGINT ? "SIGINT" : "SIGTERM");
  relay.Shutdown();
  relay.Wait();
  return 0;
}
