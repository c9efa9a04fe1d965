// Roles and bearer tokens (SPEC §14, issue 20 item 1): the one place where a call's credentials
// are mapped to a principal and checked against what its role may call. Tokens come from a file
// ("ROLE TOKEN NAME" lines; deploy/make_certs.sh writes one), never from the command line.
//   uploader  Upload, DroneLink (the drone's state stream of the control service)
//   viewer    Subscribe, GetStats, GetControlState
//   operator  the viewer's calls + drone interactions (PickAndPlace, GazeToSee, Joypad, GoToView)
//   admin     everything
// A call without a token is UNAUTHENTICATED, an unknown token UNAUTHENTICATED, a known token
// whose role does not cover the call PERMISSION_DENIED. No gRPC here: the service passes the
// call's `authorization` header value.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <grpcpp/security/server_credentials.h>

#include "common/status.h"

namespace exo {

enum class Role { kUploader, kViewer, kOperator, kAdmin };
// kMarkRegion covers MarkRegion and ClearRegion (InpaintFusion regions).
enum class Rpc {
  kUpload, kSubscribe, kGetStats, kMarkRegion, kListRegions,
  // exoview.control.v1.Control
  kDroneLink, kPickAndPlace, kGazeToSee, kJoypad, kGoToView, kGetControlState, kExplore,
  // Scene completion at a viewer's camera (viewer, operator, admin).
  kCompleteView,
};

const char* RoleName(Role role);
const char* RpcName(Rpc rpc);
absl::StatusOr<Role> ParseRole(const std::string& name);
bool RoleAllows(Role role, Rpc rpc);

struct Principal {
  std::string name;  // from the token file, e.g. "drone-1"
  Role role = Role::kAdmin;
};

class Authorizer {
 public:
  // Reads "ROLE TOKEN [NAME]" lines ('#' starts a comment). Tokens: at least 16 characters,
  // unique; the file must not be readable by others (mode 0600 or stricter group/other bits).
  static absl::StatusOr<std::unique_ptr<Authorizer>> FromFile(const std::string& path);
  static absl::StatusOr<std::unique_ptr<Authorizer>> FromText(const std::string& text);

  // `authorization`: the header value ("Bearer TOKEN"), nullopt when the call has none.
  absl::StatusOr<Principal> Check(const std::optional<std::string>& authorization, Rpc rpc) const;
  size_t size() const { return entries_.size(); }

 private:
  struct Entry {
    std::string token;
    Principal principal;
  };
  std::vector<Entry> entries_;
};

// TLS material for a listener: the PEM file at `path` (`what` names it in errors: "tls_cert").
absl::StatusOr<std::string> ReadPem(const std::string& path, const char* what);
// TLS server credentials from PEM files (server and relay): certificate + key, and with a
// client CA, client certificates required and verified (mutual TLS).
absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> SslServerCredentialsFromFiles(
    const std::string& cert_path, const std::string& key_path, const std::string& client_ca_path);
// Whether a listen address (host:port, or a gRPC peer "ipv4:127.0.0.1:5") is loopback only.
bool IsLoopback(const std::string& listen);

}  // namespace exo
