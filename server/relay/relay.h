// exoview_relay (SPEC §15): a stateless gRPC relay that serves the unchanged exoview.v1.Exoview
// Subscribe API (and GetStats, health) to viewers from a scene's NATS JetStream delta stream,
// written by an exoview_server with delta_log=jetstream (server/service/jetstream.h). It holds a
// replica ModelStore in memory: the newest snapshot from the KV bucket/snapshot stream, then
// every delta of the stream in version order (ModelStore::ReplayDelta keeps the server's versions
// and epochs), so a viewer resumes on any relay (or the server) with the same rules: (version,
// epoch) on the history -> only the missed deltas, else a snapshot. Nothing is kept on disk; a
// relay that finds a gap in the stream rebuilds its replica (its viewers reconnect and resume).
// Upload is refused (UNIMPLEMENTED): frames go to the modeling server.
#pragma once

#include <atomic>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "common/status.h"
#include "server/service/jetstream.h"
#include "server/service/model_store.h"

namespace grpc {
class Server;
}

namespace exo {

struct RelayConfig {
  std::string listen = "127.0.0.1:50061";
  JetStreamSceneOptions nats;
  ModelStoreOptions store;        // the replica's in-memory log bounds (replica is forced on)
  int max_subscribers = 4096;
  // Transport security as the server (docs/security.md): TLS with tls_cert/tls_key, mutual TLS
  // with tls_client_ca, bearer tokens (viewer role) from auth_tokens_file.
  std::string tls_cert, tls_key, tls_client_ca, auth_tokens_file;
  bool allow_insecure_remote = false;
  size_t transport_max_bytes = size_t{64} << 20;
};

class Relay {
 public:
  explicit Relay(RelayConfig config);
  ~Relay();
  absl::Status Start();  // listens at once; health is SERVING once the replica caught up
  int port() const { return port_; }
  void Shutdown();
  void Wait();

 private:
  class Service;
  void FollowLoop();
  std::shared_ptr<ModelStore> CurrentStore();

  RelayConfig config_;
  std::unique_ptr<Service> service_;
  std::unique_ptr<grpc::Server> server_;
  int port_ = 0;
  std::mutex mu_;
  std::shared_ptr<ModelStore> store_;  // replaced on a rebuild
  std::atomic<bool> ready_{false}, stop_{false};
  std::atomic<uint64_t> rebuilds_{0}, stream_last_seq_{0};
  std::thread follower_;
};

}  // namespace exo
