// exoview_operator: the operator's command line for the Control service (SPEC §8, issue 19):
// autonomous exploration started, stopped and watched over gRPC with the operator's token.
//
//   exoview_operator --server HOST:PORT [--tls_ca ca.pem --token_file operator.token
//                    --tls_server_name NAME] explore start|stop
//   exoview_operator --server HOST:PORT [...] status [--wait_exploring true|false --wait_s S]
//
// Prints the server's reply (InteractionReply for explore, ControlState for status) as one JSON
// line on stdout. Exit status: 0 on success, 1 when the server refuses or cannot be reached
// (stderr names the call, the gRPC code and the server's reason, e.g. FAILED_PRECONDITION: the
// drone has not reported yet; PERMISSION_DENIED: the token is not an operator's), 2 on a bad flag.
// The operator sequence (last writer wins, must increase per operator) defaults to the wall clock
// in microseconds, so successive invocations always increase it.
#include <google/protobuf/util/json_util.h>
#include <grpcpp/grpcpp.h>

#include <chrono>
#include <cstdio>
#include <string>
#include <thread>

#include "client/uploader/upload_client.h"
#include "common/cli/cli.h"
#include "proto/control.grpc.pb.h"

namespace {

namespace cv1 = exoview::control::v1;

const char* CodeName(grpc::StatusCode c) {
  switch (c) {
    case grpc::StatusCode::OK: return "OK";
    case grpc::StatusCode::CANCELLED: return "CANCELLED";
    case grpc::StatusCode::UNKNOWN: return "UNKNOWN";
    case grpc::StatusCode::INVALID_ARGUMENT: return "INVALID_ARGUMENT";
    case grpc::StatusCode::DEADLINE_EXCEEDED: return "DEADLINE_EXCEEDED";
    case grpc::StatusCode::NOT_FOUND: return "NOT_FOUND";
    case grpc::StatusCode::ALREADY_EXISTS: return "ALREADY_EXISTS";
    case grpc::StatusCode::PERMISSION_DENIED: return "PERMISSION_DENIED";
    case grpc::StatusCode::RESOURCE_EXHAUSTED: return "RESOURCE_EXHAUSTED";
    case grpc::StatusCode::FAILED_PRECONDITION: return "FAILED_PRECONDITION";
    case grpc::StatusCode::ABORTED: return "ABORTED";
    case grpc::StatusCode::OUT_OF_RANGE: return "OUT_OF_RANGE";
    case grpc::StatusCode::UNIMPLEMENTED: return "UNIMPLEMENTED";
    case grpc::StatusCode::INTERNAL: return "INTERNAL";
    case grpc::StatusCode::UNAVAILABLE: return "UNAVAILABLE";
    case grpc::StatusCode::DATA_LOSS: return "DATA_LOSS";
    case grpc::StatusCode::UNAUTHENTICATED: return "UNAUTHENTICATED";
    default: return "UNKNOWN";
  }
}

// One line on stderr: what was asked, the code, the server's reason and, for the codes an
// operator can act on, what to do.
int Fail(const std::string& what, const std::string& server, const grpc::Status& s) {
  std::string hint;
  switch (s.error_code()) {
    case grpc::StatusCode::UNAUTHENTICATED:
      hint = " (the server wants a token: --tls_ca and --token_file with an operator's token)";
      break;
    case grpc::StatusCode::PERMISSION_DENIED:
      hint = " (this token's role may not do that: exploration needs an operator or admin token)";
      break;
    case grpc::StatusCode::UNAVAILABLE:
      hint = " (is exoview_server running at " + server + ", with control_zones set?)";
      break;
    case grpc::StatusCode::UNIMPLEMENTED:
      hint = " (the server has no Control service: start it with control_zones)";
      break;
    case grpc::StatusCode::DEADLINE_EXCEEDED:
      hint = " (no answer from " + server + " within --timeout_s)";
      break;
    default: break;
  }
  std::fprintf(stderr, "exoview_operator: %s: %s: %s%s\n", what.c_str(), CodeName(s.error_code()),
               s.error_message().c_str(), hint.c_str());
  return 1;
}

std::string Json(const google::protobuf::Message& m) {
  std::string out;
  google::protobuf::util::JsonPrintOptions o;
  o.preserve_proto_field_names = true;
  o.always_print_primitive_fields = true;  // exploring: false is printed, not left out
  (void)google::protobuf::util::MessageToJsonString(m, &out, o);
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Operator commands for the drone's Control service: start, stop and watch "
               "autonomous exploration. Prints the server's reply as JSON.",
               "exoview_operator"};
  exo::cli::Setup(app);
  std::string server = "127.0.0.1:50051", drone_id = "drone", operator_id = "operator";
  exo::ChannelSecurity security;
  uint64_t sequence = 0;
  double timeout_s = 10;
  app.add_option("--server", server, "HOST:PORT of exoview_server");
  app.add_option("--tls_ca", security.tls_ca, "CA certificate (PEM) of the server's certificate: TLS");
  app.add_option("--tls_cert", security.tls_cert, "client certificate (PEM), for mutual TLS");
  app.add_option("--tls_key", security.tls_key, "client private key (PEM)");
  app.add_option("--tls_server_name", security.server_name,
                 "name to verify in the server certificate");
  app.add_option("--token_file", security.token_file,
                 "file holding the operator's bearer token (needs --tls_ca)");
  app.add_option("--drone_id", drone_id, "the drone to command");
  app.add_option("--operator_id", operator_id,
                 "operator id without tokens (with tokens the server uses the token's principal)");
  app.add_option("--sequence", sequence,
                 "operator sequence, must increase per operator (0: the wall clock in us)");
  app.add_option("--timeout_s", timeout_s, "deadline of each call")->check(CLI::PositiveNumber);
  std::string action;
  CLI::App* explore = app.add_subcommand("explore", "start or stop autonomous exploration");
  explore->add_option("action", action, "start | stop")
      ->required()
      ->check(CLI::IsMember({"start", "stop"}));
  CLI::App* status = app.add_subcommand("status", "the drone's control state (exploring, "
                                                  "decisions, coverage, pose, route)");
  std::string wait_exploring;
  double wait_s = 0;
  status->add_option("--wait_exploring", wait_exploring,
                     "poll until `exploring` equals this (true | false), at most --wait_s")
      ->check(CLI::IsMember({"true", "false"}));
  status->add_option("--wait_s", wait_s, "how long --wait_exploring may poll")
      ->check(CLI::NonNegativeNumber);
  app.require_subcommand(1);
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;

  auto channel = exo::MakeChannel(server, security);
  if (!channel.ok()) {
    std::fprintf(stderr, "exoview_operator: %s\n", std::string(channel.status().message()).c_str());
    return 2;
  }
  auto stub = cv1::Control::NewStub(*channel);
  auto deadline = [&](grpc::ClientContext* ctx) {
    ctx->set_deadline(std::chrono::system_clock::now() +
                      std::chrono::microseconds(static_cast<int64_t>(timeout_s * 1e6)));
  };

  if (explore->parsed()) {
    cv1::ExploreRequest req;
    req.mutable_header()->set_operator_id(operator_id);
    req.mutable_header()->set_drone_id(drone_id);
    req.mutable_header()->set_operator_sequence(
        sequence ? sequence
                 : static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::microseconds>(
                                             std::chrono::system_clock::now().time_since_epoch())
                                             .count()));
    req.set_start(action == "start");
    cv1::InteractionReply reply;
    grpc::ClientContext ctx;
    deadline(&ctx);
    const grpc::Status s = stub->Explore(&ctx, req, &reply);
    if (!s.ok()) return Fail("explore " + action, server, s);
    std::printf("%s\n", Json(reply).c_str());
    return 0;
  }

  const auto until = std::chrono::steady_clock::now() +
                     std::chrono::microseconds(static_cast<int64_t>(wait_s * 1e6));
  for (;;) {
    cv1::ControlStateRequest req;
    req.set_drone_id(drone_id);
    cv1::ControlState st;
    grpc::ClientContext ctx;
    deadline(&ctx);
    const grpc::Status s = stub->GetControlState(&ctx, req, &st);
    if (!s.ok()) return Fail("status", server, s);
    const bool done = wait_exploring.empty() || st.exploring() == (wait_exploring == "true");
    if (done || std::chrono::steady_clock::now() >= until) {
      std::printf("%s\n", Json(st).c_str());
      if (done) return 0;
      std::fprintf(stderr, "exoview_operator: status: exploring is still %s after %.1f s\n",
                   st.exploring() ? "true" : "false", wait_s);
      return 1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
}
