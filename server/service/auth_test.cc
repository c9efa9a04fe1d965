// Roles and tokens without gRPC: the role table, UNAUTHENTICATED for no / malformed / unknown
// tokens, PERMISSION_DENIED for a role that does not cover the call, and token-file errors. The
// same checks through a real TLS server: tests/service_auth_test.cc.
#include "server/service/auth.h"

#include <gtest/gtest.h>

namespace exo {
namespace {

constexpr char kFile[] =
    "# role token name\n"
    "uploader up-0123456789abcdef drone-1\n"
    "viewer   vw-0123456789abcdef\n"
    "operator op-0123456789abcdef ops\n"
    "admin    ad-0123456789abcdef root\n";

TEST(Auth, EachRoleMayCallExactlyItsRpcs) {
  auto a = Authorizer::FromText(kFile);
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ((*a)->size(), 4u);
  struct Case {
    const char* token;
    Rpc rpc;
    absl::StatusCode code;
  };
  const Case cases[] = {
      {"up-0123456789abcdef", Rpc::kUpload, absl::StatusCode::kOk},
      {"up-0123456789abcdef", Rpc::kSubscribe, absl::StatusCode::kPermissionDenied},
      {"up-0123456789abcdef", Rpc::kGetStats, absl::StatusCode::kPermissionDenied},
      {"vw-0123456789abcdef", Rpc::kUpload, absl::StatusCode::kPermissionDenied},
      {"vw-0123456789abcdef", Rpc::kSubscribe, absl::StatusCode::kOk},
      {"vw-0123456789abcdef", Rpc::kGetStats, absl::StatusCode::kOk},
      {"op-0123456789abcdef", Rpc::kUpload, absl::StatusCode::kPermissionDenied},
      {"op-0123456789abcdef", Rpc::kSubscribe, absl::StatusCode::kOk},
      {"ad-0123456789abcdef", Rpc::kUpload, absl::StatusCode::kOk},
      {"ad-0123456789abcdef", Rpc::kSubscribe, absl::StatusCode::kOk},
      {"ad-0123456789abcdef", Rpc::kGetStats, absl::StatusCode::kOk},
      // Region marking (InpaintFusion): operator and admin; listing also for viewers.
      {"op-0123456789abcdef", Rpc::kMarkRegion, absl::StatusCode::kOk},
      {"ad-0123456789abcdef", Rpc::kMarkRegion, absl::StatusCode::kOk},
      {"vw-0123456789abcdef", Rpc::kMarkRegion, absl::StatusCode::kPermissionDenied},
      {"up-0123456789abcdef", Rpc::kMarkRegion, absl::StatusCode::kPermissionDenied},
      {"vw-0123456789abcdef", Rpc::kListRegions, absl::StatusCode::kOk},
      {"vw-0123456789abcdef", Rpc::kCompleteView, absl::StatusCode::kOk},
      {"op-0123456789abcdef", Rpc::kCompleteView, absl::StatusCode::kOk},
      {"up-0123456789abcdef", Rpc::kCompleteView, absl::StatusCode::kPermissionDenied},
      {"op-0123456789abcdef", Rpc::kListRegions, absl::StatusCode::kOk},
      {"up-0123456789abcdef", Rpc::kListRegions, absl::StatusCode::kPermissionDenied},
      {"xx-0123456789abcdef", Rpc::kGetStats, absl::StatusCode::kUnauthenticated},
      {"up-0123456789abcde", Rpc::kUpload, absl::StatusCode::kUnauthenticated},  // a prefix
  };
  for (const Case& c : cases) {
    auto p = (*a)->Check(std::string("Bearer ") + c.token, c.rpc);
    EXPECT_EQ(p.status().code(), c.code) << c.token << " " << RpcName(c.rpc) << ": " << p.status();
  }
  // The control service (exoview.control.v1.Control): the drone's stream for uploaders, the
  // interactions for operators, the state for everyone who may read the model.
  const Rpc interactions[] = {Rpc::kPickAndPlace, Rpc::kGazeToSee, Rpc::kJoypad, Rpc::kGoToView,
                              Rpc::kExplore};
  const std::pair<const char*, Role> roles[] = {{"up-0123456789abcdef", Role::kUploader},
                                                {"vw-0123456789abcdef", Role::kViewer},
                                                {"op-0123456789abcdef", Role::kOperator},
                                                {"ad-0123456789abcdef", Role::kAdmin}};
  for (const auto& entry : roles) {
    const char* token = entry.first;  // (clang 14 cannot capture a structured binding)
    const Role role = entry.second;
    const bool up = role == Role::kUploader, op = role == Role::kOperator,
               ad = role == Role::kAdmin;
    auto code = [&](Rpc rpc) { return (*a)->Check(std::string("Bearer ") + token, rpc).status().code(); };
    const auto ok = absl::StatusCode::kOk, no = absl::StatusCode::kPermissionDenied;
    EXPECT_EQ(code(Rpc::kDroneLink), up || ad ? ok : no) << token;
    EXPECT_EQ(code(Rpc::kGetControlState), up ? no : ok) << token;
    for (Rpc r : interactions) EXPECT_EQ(code(r), op || ad ? ok : no) << token << " " << RpcName(r);
  }
  auto p = (*a)->Check(std::string("Bearer up-0123456789abcdef"), Rpc::kUpload);
  ASSERT_TRUE(p.ok());
  EXPECT_EQ(p->name, "drone-1");
  EXPECT_EQ(p->role, Role::kUploader);
  auto denied = (*a)->Check(std::string("Bearer up-0123456789abcdef"), Rpc::kSubscribe);
  EXPECT_EQ(denied.status().message(), "role uploader (drone-1) may not call Subscribe");
}

TEST(Auth, MissingOrMalformedHeaderIsUnauthenticated) {
  auto a = Authorizer::FromText(kFile);
  ASSERT_TRUE(a.ok());
  auto none = (*a)->Check(std::nullopt, Rpc::kGetStats);
  EXPECT_EQ(none.status().code(), absl::StatusCode::kUnauthenticated);
  EXPECT_NE(none.status().message().find("needs a bearer token"), std::string::npos);
  auto basic = (*a)->Check(std::string("Basic dXNlcjpwYXNz"), Rpc::kGetStats);
  EXPECT_EQ(basic.status().code(), absl::StatusCode::kUnauthenticated);
}

TEST(Auth, BadTokenFilesAreRefusedWithTheLine) {
  EXPECT_NE(Authorizer::FromText("pilot abcdefghijklmnopqrst\n")
                .status()
                .message()
                .find("line 1: unknown role 'pilot'"),
            std::string::npos);
  EXPECT_NE(Authorizer::FromText("viewer short\n").status().message().find("at least 16"),
            std::string::npos);
  EXPECT_NE(Authorizer::FromText("viewer abcdefghijklmnopqrst\nadmin abcdefghijklmnopqrst\n")
                .status()
                .message()
                .find("line 2: the same token appears twice"),
            std::string::npos);
  EXPECT_FALSE(Authorizer::FromText("# only a comment\n").ok());
  EXPECT_EQ(Authorizer::FromFile("/nonexistent/tokens").status().code(),
            absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace exo
