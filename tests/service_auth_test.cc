// TLS and roles on the real server process (issue 20 item 1, SPEC §14), with certificates and
// tokens from deploy/make_certs.sh: every RPC called with no token, a wrong token and each role's
// token gets the expected code; a plain-text client cannot talk to the TLS server; with mutual
// TLS a client without a certificate is refused; plain text on a non-loopback address is refused
// at start.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>

#include "client/uploader/upload_client.h"
#include "proto/control.grpc.pb.h"
#include "proto/exoview.grpc.pb.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using testing::ReadAll;
using testing::Subprocess;
using testing::WaitForFile;

class Auth : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    char tmpl[] = "/tmp/exoview_auth_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = new std::string(tmpl);
    certs_ = new std::string(*dir_ + "/certs");
    const std::string cmd = std::string(EXOVIEW_MAKE_CERTS) + " " + *certs_ + " 2>/dev/null";
    ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
    std::ofstream(*dir_ + "/wrong.token") << "not-a-token-of-this-server-0123456789\n";
    server_ = StartServer(
        {"--tls_cert=" + *certs_ + "/server.pem", "--tls_key=" + *certs_ + "/server.key",
         "--auth_tokens_file=" + *certs_ + "/tokens.txt",
         // The control service too (served with a flight zone): same tokens, same check.
         "--control_zones=house:0,0,0,8,4,2.6"},
        "tls", &target_);
  }
  static void TearDownTestSuite() {
    server_->Signal(SIGTERM);
    server_->Wait(10);
    delete server_;
    std::filesystem::remove_all(*dir_);
    delete dir_;
    delete certs_;
    delete target_;
  }
  static Subprocess* StartServer(const std::vector<std::string>& extra, const std::string& name,
                                 std::string** target) {
    std::vector<std::string> args{"--listen=127.0.0.1:0",
                                  "--port_file=" + *dir_ + "/" + name + ".port"};
    args.insert(args.end(), extra.begin(), extra.end());
    auto* s = new Subprocess(EXOVIEW_SERVER_BIN, args, *dir_ + "/" + name + ".log");
    EXPECT_TRUE(WaitForFile(*dir_ + "/" + name + ".port", 20)) << s->Log();
    *target = new std::string("127.0.0.1:" +
                              std::to_string(std::stoi(ReadAll(*dir_ + "/" + name + ".port"))));
    return s;
  }

  // A TLS channel that sends the token in `token_file` ("" = no token).
  static std::shared_ptr<grpc::Channel> Channel(const std::string& token_file) {
    ChannelSecurity sec;
    sec.tls_ca = *certs_ + "/ca.pem";
    sec.token_file = token_file;
    auto ch = MakeChannel(*target_, sec);
    EXO_CHECK(ch.ok());
    return *ch;
  }

  static grpc::StatusCode CallGetStats(const std::shared_ptr<grpc::Channel>& ch) {
    auto stub = v1::Exoview::NewStub(ch);
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    v1::Stats s;
    return stub->GetStats(&ctx, v1::StatsRequest{}, &s).error_code();
  }
  // Region marking (InpaintFusion): allowed on this empty server means FAILED_PRECONDITION (no
  // scene yet), i.e. the call got past authorization.
  static grpc::StatusCode CallMarkRegion(const std::shared_ptr<grpc::Channel>& ch) {
    auto stub = v1::Exoview::NewStub(ch);
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    v1::MarkRegionRequest req;
    auto* k = req.mutable_camera();
    k->set_fx(100);
    k->set_fy(100);
    k->set_cx(50);
    k->set_cy(50);
    k->set_width(100);
    k->set_height(100);
    req.mutable_local_from_cam()->mutable_quaternion()->set_w(1);
    auto* p = req.add_stroke();
    p->set_x(50);
    p->set_y(50);
    v1::MarkRegionReply out;
    return stub->MarkRegion(&ctx, req, &out).error_code();
  }
  // Allowed: the stream stays open (nothing to send yet) until the deadline.
  static grpc::StatusCode CallSubscribe(const std::shared_ptr<grpc::Channel>& ch) {
    auto stub = v1::Exoview::NewStub(ch);
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(700));
    v1::SubscribeRequest req;
    req.set_last_version(~uint64_t{0} >> 1);  // from the future: a snapshot of the empty model
    auto reader = stub->Subscribe(&ctx, req);
    v1::Delta d;
    while (reader->Read(&d)) {
    }
    return reader->Finish().error_code();
  }
  // Allowed: one ack for a frame (REJECTED here: no colour; the call itself is OK).
  static grpc::StatusCode CallUpload(const std::shared_ptr<grpc::Channel>& ch, int* acks) {
    auto stub = v1::Exoview::NewStub(ch);
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    auto stream = stub->Upload(&ctx);
    v1::Frame f;
    f.set_sequence(next_seq_++);
    stream->Write(f);
    stream->WritesDone();
    v1::Ack a;
    *acks = 0;
    while (stream->Read(&a)) ++*acks;
    return stream->Finish().error_code();
  }

  static Subprocess* server_;
  static std::string *dir_, *certs_, *target_;
  static uint64_t next_seq_;
};
Subprocess* Auth::server_ = nullptr;
std::string* Auth::dir_ = nullptr;
std::string* Auth::certs_ = nullptr;
std::string* Auth::target_ = nullptr;
uint64_t Auth::next_seq_ = 1;

TEST_F(Auth, EveryRpcTimesNoTokenWrongTokenAndEachRole) {
  using C = grpc::StatusCode;
  struct Row {
    std::string who, token_file;
    C upload, subscribe, stats, mark;
  };
  const std::string t = *certs_ + "/";
  const Row rows[] = {
      {"no token", "", C::UNAUTHENTICATED, C::UNAUTHENTICATED, C::UNAUTHENTICATED,
       C::UNAUTHENTICATED},
      {"wrong token", *dir_ + "/wrong.token", C::UNAUTHENTICATED, C::UNAUTHENTICATED,
       C::UNAUTHENTICATED, C::UNAUTHENTICATED},
      {"uploader", t + "uploader.token", C::OK, C::PERMISSION_DENIED, C::PERMISSION_DENIED,
       C::PERMISSION_DENIED},
      {"viewer", t + "viewer.token", C::PERMISSION_DENIED, C::DEADLINE_EXCEEDED, C::OK,
       C::PERMISSION_DENIED},
      {"operator", t + "operator.token", C::PERMISSION_DENIED, C::DEADLINE_EXCEEDED, C::OK,
       C::FAILED_PRECONDITION},
      {"admin", t + "admin.token", C::OK, C::DEADLINE_EXCEEDED, C::OK, C::FAILED_PRECONDITION},
  };
  for (const Row& r : rows) {
    auto ch = Channel(r.token_file);
    int acks = -1;
    EXPECT_EQ(CallUpload(ch, &acks), r.upload) << r.who << ": Upload";
    EXPECT_EQ(acks, r.upload == C::OK ? 1 : 0) << r.who;
    EXPECT_EQ(CallSubscribe(ch), r.subscribe) << r.who << ": Subscribe";
    EXPECT_EQ(CallGetStats(ch), r.stats) << r.who << ": GetStats";
    EXPECT_EQ(CallMarkRegion(ch), r.mark) << r.who << ": MarkRegion";
  }
  // The refusals are counted (admin reads the counter).
  auto stub = v1::Exoview::NewStub(Channel(t + "admin.token"));
  grpc::ClientContext ctx;
  v1::Stats s;
  ASSERT_TRUE(stub->GetStats(&ctx, v1::StatsRequest{}, &s).ok());
  EXPECT_EQ(s.counters().at("server.denied_calls"), 14.0);
}

namespace cv1 = exoview::control::v1;

// Every Control RPC: the auth codes, or (allowed) whatever the control core answers.
std::map<std::string, grpc::StatusCode> CallControl(const std::shared_ptr<grpc::Channel>& ch) {
  auto stub = cv1::Control::NewStub(ch);
  std::map<std::string, grpc::StatusCode> out;
  auto deadline = [](grpc::ClientContext* c) {
    c->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  };
  {
    grpc::ClientContext ctx;
    deadline(&ctx);
    auto link = stub->DroneLink(&ctx);
    cv1::DroneState st;
    st.set_sequence(1);
    st.set_timestamp_s(1.0);
    st.mutable_position()->set_x(1);
    st.mutable_position()->set_y(1);
    st.mutable_position()->set_z(1);
    link->Write(st);
    link->WritesDone();
    cv1::Setpoint sp;
    while (link->Read(&sp)) {
    }
    out["DroneLink"] = link->Finish().error_code();
  }
  static uint64_t op_seq = 1;
  cv1::OperatorHeader h;
  h.set_operator_id("mallory");  // with tokens the server puts the caller's principal here
  h.set_operator_sequence(op_seq++);
  {
    grpc::ClientContext ctx;
    deadline(&ctx);
    cv1::JoypadRequest r;
    *r.mutable_header() = h;
    r.set_right_y(0.5);
    r.set_dt_s(0.1);
    cv1::InteractionReply rep;
    out["Joypad"] = stub->Joypad(&ctx, r, &rep).error_code();
  }
  h.set_operator_sequence(op_seq++);
  {
    grpc::ClientContext ctx;
    deadline(&ctx);
    cv1::GoToViewRequest r;
    *r.mutable_header() = h;
    r.set_view_id(12345);
    cv1::InteractionReply rep;
    out["GoToView"] = stub->GoToView(&ctx, r, &rep).error_code();
  }
  h.set_operator_sequence(op_seq++);
  {
    grpc::ClientContext ctx;
    deadline(&ctx);
    cv1::GazeToSeeRequest r;
    *r.mutable_header() = h;
    r.mutable_eye()->set_x(1);
    r.mutable_direction()->set_x(1);
    cv1::InteractionReply rep;
    out["GazeToSee"] = stub->GazeToSee(&ctx, r, &rep).error_code();
  }
  h.set_operator_sequence(op_seq++);
  {
    grpc::ClientContext ctx;
    deadline(&ctx);
    cv1::PickAndPlaceRequest r;
    *r.mutable_header() = h;
    r.mutable_eye()->set_x(1);
    r.mutable_hand()->set_x(2);
    cv1::InteractionReply rep;
    out["PickAndPlace"] = stub->PickAndPlace(&ctx, r, &rep).error_code();
  }
  {
    grpc::ClientContext ctx;
    deadline(&ctx);
    cv1::ControlState st;
    out["GetControlState"] = stub->GetControlState(&ctx, cv1::ControlStateRequest{}, &st).error_code();
  }
  return out;
}

// Issue 20: the Control service behind the same tokens and the same one check: the drone's
// stream for uploader and admin, interactions for operator and admin, the control state for
// every role but uploader; an operator cannot act under another operator's id.
TEST_F(Auth, ControlServiceRolesDroneLinkInteractionsAndState) {
  using C = grpc::StatusCode;
  const std::string t = *certs_ + "/";
  auto admin = v1::Exoview::NewStub(Channel(t + "admin.token"));
  auto denied = [&] {
    grpc::ClientContext ctx;
    v1::Stats s;
    EXPECT_TRUE(admin->GetStats(&ctx, v1::StatsRequest{}, &s).ok());
    return s.counters().at("server.denied_calls");
  };
  const double denied_before = denied();
  const std::vector<std::string> interactions{"Joypad", "GoToView", "GazeToSee", "PickAndPlace"};
  struct Row {
    std::string who, token_file;
    std::set<std::string> allowed;
  };
  std::set<std::string> everything{"DroneLink", "GetControlState"};
  everything.insert(interactions.begin(), interactions.end());
  std::set<std::string> operator_calls{"GetControlState"};
  operator_calls.insert(interactions.begin(), interactions.end());
  const Row rows[] = {
      {"no token", "", {}},
      {"wrong token", *dir_ + "/wrong.token", {}},
      {"uploader", t + "uploader.token", {"DroneLink"}},
      {"viewer", t + "viewer.token", {"GetControlState"}},
      {"operator", t + "operator.token", operator_calls},
      {"admin", t + "admin.token", everything},
  };
  int refusals = 0;
  for (const Row& r : rows) {
    const bool known = r.who != "no token" && r.who != "wrong token";
    for (const auto& [rpc, code] : CallControl(Channel(r.token_file))) {
      SCOPED_TRACE(r.who + ": " + rpc);
      if (r.allowed.count(rpc)) {
        EXPECT_NE(code, C::UNAUTHENTICATED);
        EXPECT_NE(code, C::PERMISSION_DENIED);
        if (rpc == "DroneLink" || rpc == "GetControlState") EXPECT_EQ(code, C::OK);
      } else {
        EXPECT_EQ(code, known ? C::PERMISSION_DENIED : C::UNAUTHENTICATED);
        ++refusals;
      }
    }
  }
  EXPECT_EQ(denied() - denied_before, refusals);
  // The operator's Joypad ran under its principal, not the "mallory" it wrote in the header.
  auto stub = cv1::Control::NewStub(Channel(t + "operator.token"));
  grpc::ClientContext ctx;
  cv1::ControlState st;
  ASSERT_TRUE(stub->GetControlState(&ctx, cv1::ControlStateRequest{}, &st).ok());
  EXPECT_TRUE(st.drone_known());
  EXPECT_NE(st.operator_id(), "mallory");
  if (!st.operator_id().empty())
    EXPECT_TRUE(st.operator_id() == "operator:operator-1" || st.operator_id() == "admin:admin-1")
        << st.operator_id();
}

TEST_F(Auth, PlainTextClientCannotTalkToTheTlsServer) {
  EXPECT_EQ(CallGetStats(MakeChannel(*target_)), grpc::StatusCode::UNAVAILABLE);
}

TEST_F(Auth, TokenNeedsTlsOnTheClient) {
  ChannelSecurity sec;
  sec.token_file = *certs_ + "/viewer.token";
  auto ch = MakeChannel(*target_, sec);
  ASSERT_FALSE(ch.ok());
  EXPECT_NE(ch.status().message().find("need TLS"), std::string::npos);
}

TEST_F(Auth, MutualTlsRequiresAClientCertificate) {
  std::string* target = nullptr;
  Subprocess* s =
      StartServer({"--tls_cert=" + *certs_ + "/server.pem", "--tls_key=" + *certs_ + "/server.key",
                   "--tls_client_ca=" + *certs_ + "/ca.pem"},
                  "mtls", &target);
  ChannelSecurity sec;
  sec.tls_ca = *certs_ + "/ca.pem";
  EXPECT_EQ(CallGetStats(*MakeChannel(*target, sec)), grpc::StatusCode::UNAVAILABLE);
  sec.tls_cert = *certs_ + "/client.pem";
  sec.tls_key = *certs_ + "/client.key";
  EXPECT_EQ(CallGetStats(*MakeChannel(*target, sec)), grpc::StatusCode::OK);
  s->Signal(SIGTERM);
  s->Wait(10);
  delete s;
  delete target;
}

TEST_F(Auth, PlainTextOnANonLoopbackAddressIsRefusedAtStart) {
  Subprocess s(EXOVIEW_SERVER_BIN, {"--listen=0.0.0.0:0"}, *dir_ + "/open.log");
  const auto rc = s.Wait(20);
  ASSERT_TRUE(rc.has_value());
  EXPECT_NE(*rc, 0);
  EXPECT_NE(s.Log().find("refusing plain text on 0.0.0.0:0"), std::string::npos) << s.Log();
}

TEST_F(Auth, PlainTextLoopbackStartsWithALoudWarning) {
  std::string* target = nullptr;
  Subprocess* s = StartServer({}, "plain", &target);
  EXPECT_EQ(CallGetStats(MakeChannel(*target)), grpc::StatusCode::OK);
  EXPECT_NE(s->Log().find("PLAIN TEXT on 127.0.0.1:0"), std::string::npos) << s->Log();
  s->Signal(SIGTERM);
  s->Wait(10);
  delete s;
  delete target;
}

}  // namespace
}  // namespace exo
