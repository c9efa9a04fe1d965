// The operator's command line (tools/operator, exoview_operator) against real processes on
// loopback: exoview_server with TLS, role tokens (deploy/make_certs.sh) and the apartment's flight
// zone; exoview_uploader --drone=sim as the drone side; the CLI binary itself. Exploration is
// started, watched and stopped with the operator's token; every refusal exits 1 and names the
// gRPC code and the reason: no token, a viewer's token, no drone yet, no server.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "client/uploader/sim_flight.h"
#include "common/synth/scene.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using testing::ReadAll;
using testing::Subprocess;
using testing::WaitForFile;

struct CliResult {
  int code = -1;
  std::string out;           // stdout and stderr together
  nlohmann::json json;       // the last line that parses as a JSON object (null: none)
};

class OperatorCli : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/exoview_operator_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
    certs_ = dir_ + "/certs";
    const std::string cmd = std::string(EXOVIEW_MAKE_CERTS) + " " + certs_ + " 2>/dev/null";
    ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
    auto scene = synth::MakeScene(synth::SceneKind::kApartment, {});
    ASSERT_TRUE(scene.ok());
    server_ = std::make_unique<Subprocess>(
        EXOVIEW_SERVER_BIN,
        std::vector<std::string>{"--listen=127.0.0.1:0", "--port_file=" + dir_ + "/port",
                                 "--tls_cert=" + certs_ + "/server.pem",
                                 "--tls_key=" + certs_ + "/server.key",
                                 "--auth_tokens_file=" + certs_ + "/tokens.txt",
                                 "--control_zones=" + SceneZoneText(*scene),
                                 "--voxel_size_m=0.08", "--control_cell_m=0.15"},
        dir_ + "/server.log");
    ASSERT_TRUE(WaitForFile(dir_ + "/port", 20)) << server_->Log();
    target_ = "127.0.0.1:" + std::to_string(std::stoi(ReadAll(dir_ + "/port")));
  }
  void TearDown() override {
    if (drone_) drone_->Signal(SIGTERM), drone_->Wait(10);
    if (server_) server_->Signal(SIGTERM), server_->Wait(10);
    std::filesystem::remove_all(dir_);
  }
  std::vector<std::string> Tls(const std::string& role) const {
    std::vector<std::string> a{"--tls_ca=" + certs_ + "/ca.pem", "--tls_server_name=localhost"};
    if (!role.empty()) a.push_back("--token_file=" + certs_ + "/" + role + ".token");
    return a;
  }
  // Runs exoview_operator with `args` (the server and TLS flags first).
  CliResult Cli(std::vector<std::string> args, const std::string& role = "operator",
                const std::string& target = "") {
    std::vector<std::string> a{"--server=" + (target.empty() ? target_ : target),
                               "--timeout_s=5"};
    for (const auto& s : Tls(role)) a.push_back(s);
    a.insert(a.end(), args.begin(), args.end());
    const std::string log = dir_ + "/cli" + std::to_string(++calls_) + ".log";
    Subprocess p(EXOVIEW_OPERATOR_BIN, a, log);
    CliResult r;
    r.code = p.Wait(30).value_or(-1);
    r.out = p.Log();
    std::stringstream ss(r.out);
    for (std::string line; std::getline(ss, line);) {
      auto j = nlohmann::json::parse(line, nullptr, false);
      if (!j.is_discarded() && j.is_object()) r.json = j;
    }
    return r;
  }
  void StartDrone() {
    drone_ = std::make_unique<Subprocess>(
        EXOVIEW_UPLOADER_BIN,
        std::vector<std::string>{"--server=" + target_, "--tls_ca=" + certs_ + "/ca.pem",
                                 "--tls_server_name=localhost",
                                 "--token_file=" + certs_ + "/uploader.token", "--drone=sim",
                                 "--synthetic=apartment", "--width=160", "--height=120",
                                 "--camera_hz=4", "--flight_s=60"},
        dir_ + "/drone.log");
  }

  std::string dir_, certs_, target_;
  std::unique_ptr<Subprocess> server_, drone_;
  int calls_ = 0;
};

TEST_F(OperatorCli, StartsWatchesAndStopsExplorationWithClearRefusals) {
  // No drone has reported yet: a clear FAILED_PRECONDITION, exit 1.
  CliResult r = Cli({"explore", "start"});
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_NE(r.out.find("explore start: FAILED_PRECONDITION"), std::string::npos) << r.out;
  // Without a token and with a viewer's token: refused, with what to do.
  r = Cli({"explore", "start"}, "");
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_NE(r.out.find("UNAUTHENTICATED"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("operator's token"), std::string::npos) << r.out;
  r = Cli({"explore", "start"}, "viewer");
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_NE(r.out.find("PERMISSION_DENIED"), std::string::npos) << r.out;
  // A viewer may read the state: no drone yet.
  r = Cli({"status"}, "viewer");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_FALSE(r.json.value("drone_known", false)) << r.out;
  // A bad action is a flag error (exit 2), naming what is allowed.
  r = Cli({"explore", "go"});
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("start"), std::string::npos) << r.out;

  StartDrone();
  bool known = false;
  for (int i = 0; i < 100 && !known; ++i) {
    r = Cli({"status"});
    known = r.code == 0 && r.json.value("drone_known", false);
    if (!known) std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  ASSERT_TRUE(known) << r.out << "\n" << drone_->Log();

  r = Cli({"explore", "start"});
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_EQ(r.json.value("interaction", ""), "EXPLORE") << r.out;
  r = Cli({"status", "--wait_exploring=true", "--wait_s=5"});
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(r.json.value("exploring", false)) << r.out;
  // The server's planner takes decisions while it explores (the first after the drone's hold).
  uint64_t decisions = 0;
  for (int i = 0; i < 50 && decisions < 2; ++i) {
    r = Cli({"status"}, "viewer");
    ASSERT_EQ(r.code, 0) << r.out;
    decisions = std::stoull(r.json.value("explore_decisions", std::string("0")));
    if (decisions < 2) std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  EXPECT_GE(decisions, 2u) << r.out;
  EXPECT_EQ(r.json.value("interaction", ""), "EXPLORE") << r.out;

  r = Cli({"explore", "stop"});
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_EQ(r.json.value("interaction", ""), "HOLD") << r.out;
  r = Cli({"status", "--wait_exploring=false", "--wait_s=5"});
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_FALSE(r.json.value("exploring", true)) << r.out;
  // Waiting for a state that does not come: exit 1 after --wait_s, the state printed.
  r = Cli({"status", "--wait_exploring=true", "--wait_s=0.3"});
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_NE(r.out.find("exploring is still false"), std::string::npos) << r.out;

  // No server there: UNAVAILABLE with a hint (a port nothing listens on: the server's, closed).
  const std::string gone = target_;
  server_->Signal(SIGTERM);
  server_->Wait(10);
  r = Cli({"status"}, "operator", gone);
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_TRUE(r.out.find("UNAVAILABLE") != std::string::npos ||
              r.out.find("DEADLINE_EXCEEDED") != std::string::npos)
      << r.out;
}

}  // namespace
}  // namespace exo
