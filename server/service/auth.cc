#include "server/service/auth.h"

#include <sys/stat.h>

#include <fstream>
#include <sstream>

#include "absl/strings/match.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"

namespace exo {
namespace {

// Compares without an early exit (the time does not tell how much of a guess was right).
bool ConstantTimeEquals(const std::string& a, const std::string& b) {
  unsigned char diff = a.size() == b.size() ? 0 : 1;
  const size_t n = std::min(a.size(), b.size());
  for (size_t i = 0; i < n; ++i) diff |= static_cast<unsigned char>(a[i] ^ b[i]);
  return diff == 0;
}

}  // namespace

const char* RoleName(Role role) {
  switch (role) {
    case Role::kUploader:
      return "uploader";
    case Role::kViewer:
      return "viewer";
    case Role::kOperator:
      return "operator";
    case Role::kAdmin:
      return "admin";
  }
  return "?";
}

const char* RpcName(Rpc rpc) {
  switch (rpc) {
    case Rpc::kUpload:
      return "Upload";
    case Rpc::kSubscribe:
      return "Subscribe";
    case Rpc::kGetStats:
      return "GetStats";
    case Rpc::kMarkRegion:
      return "MarkRegion/ClearRegion";
    case Rpc::kListRegions:
      return "ListRegions";
    case Rpc::kDroneLink:
      return "DroneLink";
    case Rpc::kPickAndPlace:
      return "PickAndPlace";
    case Rpc::kGazeToSee:
      return "GazeToSee";
    case Rpc::kJoypad:
      return "Joypad";
    case Rpc::kGoToView:
      return "GoToView";
    case Rpc::kGetControlState:
      return "GetControlState";
    case Rpc::kExplore:
      return "Explore";
    case Rpc::kCompleteView:
      return "CompleteView";
  }
  return "?";
}

absl::StatusOr<Role> ParseRole(const std::string& name) {
  for (Role r : {Role::kUploader, Role::kViewer, Role::kOperator, Role::kAdmin})
    if (name == RoleName(r)) return r;
  return absl::InvalidArgumentError(
      absl::StrCat("unknown role '", name, "' (uploader | viewer | operator | admin)"));
}

// The role table (docs/security.md).
bool RoleAllows(Role role, Rpc rpc) {
  switch (role) {
    case Role::kAdmin:
      return true;
    case Role::kUploader:
      return rpc == Rpc::kUpload || rpc == Rpc::kDroneLink;
    case Role::kViewer:
      return rpc == Rpc::kSubscribe || rpc == Rpc::kGetStats || rpc == Rpc::kListRegions ||
             rpc == Rpc::kGetControlState || rpc == Rpc::kCompleteView;
    case Role::kOperator:
      return rpc == Rpc::kSubscribe || rpc == Rpc::kGetStats || rpc == Rpc::kListRegions ||
             rpc == Rpc::kMarkRegion || rpc == Rpc::kGetControlState ||
             rpc == Rpc::kPickAndPlace || rpc == Rpc::kGazeToSee || rpc == Rpc::kJoypad ||
             rpc == Rpc::kGoToView || rpc == Rpc::kExplore || rpc == Rpc::kCompleteView;
  }
  return false;
}

absl::StatusOr<std::unique_ptr<Authorizer>> Authorizer::FromText(const std::string& text) {
  auto a = std::make_unique<Authorizer>();
  std::istringstream in(text);
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    if (auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::vector<std::string> f = absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty());
    if (f.empty()) continue;
    if (f.size() < 2 || f.size() > 3)
      return absl::InvalidArgumentError(
          absl::StrCat("token file line ", n, ": expected ROLE TOKEN [NAME]"));
    auto role = ParseRole(f[0]);
    if (!role.ok())
      return absl::InvalidArgumentError(
          absl::StrCat("token file line ", n, ": ", role.status().message()));
    if (f[1].size() < 16)
      return absl::InvalidArgumentError(
          absl::StrCat("token file line ", n, ": a token needs at least 16 characters"));
    for (const Entry& e : a->entries_)
      if (e.token == f[1])
        return absl::InvalidArgumentError(
            absl::StrCat("token file line ", n, ": the same token appears twice"));
    Entry e;
    e.token = f[1];
    e.principal.role = *role;
    e.principal.name = f.size() == 3 ? f[2] : absl::StrCat(f[0], "@line", n);
    a->entries_.push_back(std::move(e));
  }
  if (a->entries_.empty()) return absl::InvalidArgumentError("token file holds no token");
  return a;
}

absl::StatusOr<std::unique_ptr<Authorizer>> Authorizer::FromFile(const std::string& path) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0)
    return absl::NotFoundError(absl::StrCat("cannot open token file ", path));
  if ((st.st_mode & (S_IROTH | S_IWOTH)) != 0)
    return absl::PermissionDeniedError(
        absl::StrCat("token file ", path, " is readable or writable by others (chmod 600 it)"));
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open token file ", path));
  std::stringstream ss;
  ss << in.rdbuf();
  auto a = FromText(ss.str());
  if (!a.ok()) return absl::InvalidArgumentError(absl::StrCat(path, ": ", a.status().message()));
  return a;
}

absl::StatusOr<Principal> Authorizer::Check(const std::optional<std::string>& authorization,
                                            Rpc rpc) const {
  if (!authorization)
    return absl::UnauthenticatedError(
        absl::StrCat(RpcName(rpc), " needs a bearer token (authorization: Bearer TOKEN)"));
  absl::string_view v = absl::StripAsciiWhitespace(*authorization);
  if (!absl::ConsumePrefix(&v, "Bearer ") && !absl::ConsumePrefix(&v, "bearer "))
    return absl::UnauthenticatedError("the authorization header is not 'Bearer TOKEN'");
  const std::string token(absl::StripAsciiWhitespace(v));
  const Entry* found = nullptr;
  for (const Entry& e : entries_)
    if (ConstantTimeEquals(e.token, token)) found = &e;
  if (found == nullptr) return absl::UnauthenticatedError("unknown bearer token");
  if (!RoleAllows(found->principal.role, rpc))
    return absl::PermissionDeniedError(absl::StrCat("role ", RoleName(found->principal.role), " (",
                                                    found->principal.name, ") may not call ",
                                                    RpcName(rpc)));
  return found->principal;
}

absl::StatusOr<std::string> ReadPem(const std::string& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot read ", what, " ", path));
  std::stringstream ss;
  ss << in.rdbuf();
  if (ss.str().find("-----BEGIN") == std::string::npos)
    return absl::InvalidArgumentError(absl::StrCat(what, " ", path, " is not PEM"));
  return ss.str();
}

absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> SslServerCredentialsFromFiles(
    const std::string& cert_path, const std::string& key_path, const std::string& client_ca_path) {
  grpc::SslServerCredentialsOptions o;
  EXO_ASSIGN_OR_RETURN(const std::string cert, ReadPem(cert_path, "tls_cert"));
  EXO_ASSIGN_OR_RETURN(const std::string key, ReadPem(key_path, "tls_key"));
  o.pem_key_cert_pairs.push_back({key, cert});
  if (!client_ca_path.empty()) {
    EXO_ASSIGN_OR_RETURN(o.pem_root_certs, ReadPem(client_ca_path, "tls_client_ca"));
    o.client_certificate_request = GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY;
  }
  return grpc::SslServerCredentials(o);
}

bool IsLoopback(const std::string& listen) {
  for (const char* p : {"127.", "localhost:", "[::1]:", "ipv4:127.", "ipv6:[::1]:"})
    if (absl::StartsWith(listen, p)) return true;
  return false;
}

}  // namespace exo
