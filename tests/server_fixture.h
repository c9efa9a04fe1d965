// Test fixture shared by the process-level service tests: a temporary directory, an
// exoview_server process on a free loopback port (stopped with SIGTERM at the end), and
// GetStats on it. The directory is kept when a test fails, for its logs.
#pragma once

#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include "client/uploader/upload_client.h"
#include "proto/exoview.grpc.pb.h"
#include "tests/subprocess.h"

namespace exo::testing {

class ServerProcessTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/exoview_test_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override {
    if (server_) {
      server_->Signal(SIGTERM);
      server_->Wait(10);
    }
    if (!HasFailure() && !getenv("EXO_KEEP")) std::filesystem::remove_all(dir_);
  }
  // Starts (or restarts) the server with `extra` flags; its output goes to dir_/log.
  void StartServer(const std::vector<std::string>& extra, const std::string& log = "server.log") {
    std::filesystem::remove(dir_ + "/port");
    std::vector<std::string> args{"--listen=127.0.0.1:0", "--port_file=" + dir_ + "/port"};
    args.insert(args.end(), extra.begin(), extra.end());
    server_ = std::make_unique<Subprocess>(EXOVIEW_SERVER_BIN, args, dir_ + "/" + log);
    ASSERT_TRUE(WaitForFile(dir_ + "/port", 20)) << server_->Log();
    target_ = "127.0.0.1:" + std::to_string(std::stoi(ReadAll(dir_ + "/port")));
  }
  v1::Stats Stats() {
    auto stub = v1::Exoview::NewStub(MakeChannel(target_));
    grpc::ClientContext ctx;
    v1::Stats s;
    EXPECT_TRUE(stub->GetStats(&ctx, v1::StatsRequest{}, &s).ok());
    return s;
  }

  std::string dir_, target_;
  std::unique_ptr<Subprocess> server_;
};

}  // namespace exo::testing
