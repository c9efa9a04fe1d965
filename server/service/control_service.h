// The drone control service exoview.control.v1.Control (proto/control.proto, SPEC §8) in the
// modeling server's process: the drone side's bidirectional stream (state in, setpoints out)
// and the operators' interaction RPCs, over server/control's ControlCore. The core's world
// follows the published model: a thread subscribes to the ModelStore like a client and feeds it
// the scene origin, the proxy mesh chunks (ray casting, occupied cells) and the stored views
// (poses for go-to-view, depth carved into known free space). Only observed geometry: inpainted
// views (DR keyframes, scene completions) and completion chunks are skipped, and where the
// published chunk is InpaintFusion's labelled proxy (a marked object carved out) the observed
// mesh of that chunk is used instead (ObservedChunks): the object is physically there.
// Served when at least one flight zone is configured (control_zones).
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "common/status.h"
#include "server/control/control_core.h"

namespace grpc {
class Service;
class ServerContext;
}

namespace exo {

class ModelStore;
class ObservedChunks;
struct ConfigKey;

struct ControlServiceOptions {
  control::ControlCoreOptions core;
  bool enabled() const { return !core.safe.zones.empty(); }
};

// The config keys of the control service (control_*), appended to the server's ConfigKeys().
void AppendControlConfigKeys(std::vector<ConfigKey>* keys);

// The server's one authorization check (server/service/auth.h, docs/security.md): the call's
// principal ("" without authentication) or UNAUTHENTICATED / PERMISSION_DENIED.
enum class Rpc;
using AuthorizeFn = std::function<absl::StatusOr<std::string>(const grpc::ServerContext&, Rpc)>;

class ControlServiceHost {
 public:
  // Errors: invalid options (zones, up axis, ...). `authorize` (null = every call allowed) runs
  // first in every RPC; with authentication an interaction's operator_id is the caller's
  // principal, whatever the request's header says.
  // `observed` (may be null): the observed mesh of the chunks the store publishes labelled
  // (InpaintFusion's proxy with the marked objects carved): the drone's map takes those instead
  // of the published ones, since a removed object is still physically there.
  static absl::StatusOr<std::unique_ptr<ControlServiceHost>> Start(
      const ControlServiceOptions& options, ModelStore* store, AuthorizeFn authorize = nullptr,
      std::shared_ptr<ObservedChunks> observed = nullptr);
  ~ControlServiceHost();
  grpc::Service* service();
  control::ControlCore& core() { return *core_; }
  // Stops the model feeder (the store must still exist) and the exploration thread.
  void Stop();

 private:
  class Impl;
  ControlServiceHost() = default;
  void Feed();
  std::unique_ptr<control::ControlCore> core_;
  std::unique_ptr<Impl> impl_;
  ModelStore* store_ = nullptr;
  std::shared_ptr<ObservedChunks> observed_;
  std::atomic<bool> stop_{false};
  std::thread feeder_;
  std::thread explorer_;
};

}  // namespace exo
