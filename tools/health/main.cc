// exoview_health: the grpc.health.v1 check of an Exoview process (server or relay), for container
// health checks and Kubernetes exec probes (images carry no shell and no grpcurl).
//   exoview_health [HOST:PORT] [--timeout_s S] [--tls_ca PEM]   (default 127.0.0.1:50051)
// Exit 0 when the process answers SERVING, 1 when it answers anything else or not at all.
// The request and answer are tiny fixed protobufs (HealthCheckRequest{service=""} is empty,
// HealthCheckResponse{status=SERVING} is 08 01), sent through grpc::GenericStub, so no generated
// code of health.proto is needed.
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <vector>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>

#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>

#include "common/cli/cli.h"

int main(int argc, char** argv) {
  CLI::App app{"gRPC health check (grpc.health.v1) of an Exoview server or relay: exit 0 when "
               "SERVING.",
               "exoview_health"};
  exo::cli::Setup(app);
  std::string target = "127.0.0.1:50051", ca_file;
  double timeout_s = 2.0;
  app.add_option("target", target, "HOST:PORT")->capture_default_str();
  app.add_option("--timeout_s", timeout_s, "deadline of the check")->capture_default_str();
  app.add_option("--tls_ca", ca_file, "CA (PEM) of the server's certificate: check over TLS");
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  std::string ca;
  if (!ca_file.empty()) {
    std::ifstream in(ca_file);
    std::stringstream ss;
    ss << in.rdbuf();
    ca = ss.str();
  }
  auto creds = ca.empty() ? grpc::InsecureChannelCredentials()
                          : grpc::SslCredentials(grpc::SslCredentialsOptions{ca, "", ""});
  auto channel = grpc::CreateChannel(target, creds);
  grpc::GenericStub stub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() +
                   std::chrono::milliseconds(static_cast<int>(timeout_s * 1000)));
  grpc::ByteBuffer request, response;  // empty request = HealthCheckRequest{service: ""}
  grpc::Slice empty;
  request = grpc::ByteBuffer(&empty, 1);
  std::mutex mu;
  std::condition_variable cv;
  bool done = false;
  grpc::Status status;
  stub.UnaryCall(&ctx, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                 [&](grpc::Status s) {
                   std::lock_guard lock(mu);
                   status = s;
                   done = true;
                   cv.notify_all();
                 });
  std::unique_lock lock(mu);
  cv.wait(lock, [&] { return done; });
  if (!status.ok()) {
    std::fprintf(stderr, "exoview_health: %s: %s\n", target.c_str(), status.error_message().c_str());
    return 1;
  }
  std::vector<grpc::Slice> slices;
  response.Dump(&slices);
  std::string bytes;
  for (const auto& s : slices) bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
  const bool serving = bytes.size() == 2 && bytes[0] == 0x08 && bytes[1] == 0x01;
  std::printf("%s %s\n", target.c_str(), serving ? "SERVING" : "NOT_SERVING");
  return serving ? 0 : 1;
}
