// exoview_server's flags and config file (a real server process): --help lists every config key
// with its default; a config file's bad line is an error naming file and line (exit 2); flags
// override the file; both --key=value and --key value work; a bad value names the flag (exit 2).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "server/service/server.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using testing::ReadAll;
using testing::Subprocess;
using testing::WaitForFile;

class ServerFlags : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/exoview_srvflags_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  // Runs the server to completion (for --help and errors); returns exit code and output.
  std::pair<int, std::string> RunToExit(const std::vector<std::string>& args) {
    Subprocess p(EXOVIEW_SERVER_BIN, args, dir_ + "/out.log");
    const auto rc = p.Wait(20);
    EXPECT_TRUE(rc.has_value()) << "exoview_server did not exit";
    return {rc.value_or(-1), p.Log()};
  }

  std::string dir_;
};

TEST_F(ServerFlags, HelpListsEveryConfigKeyWithItsDefault) {
  const auto [rc, out] = RunToExit({"--help"});
  ASSERT_EQ(rc, 0) << out;
  const ServerConfig defaults;
  ASSERT_GT(ConfigKeys().size(), 30u);
  for (const ConfigKey& k : ConfigKeys()) {
    const std::string d = k.get(defaults);
    EXPECT_NE(out.find("--" + k.name + " VALUE=" + (d.empty() ? "\"\"" : d)), std::string::npos)
        << k.name << "\n"
        << out;
  }
  EXPECT_NE(out.find("--max_views VALUE=200"), std::string::npos) << out;
  EXPECT_NE(out.find("--config"), std::string::npos);
  EXPECT_NE(out.find("--log_level"), std::string::npos);
}

TEST_F(ServerFlags, ConfigFileErrorNamesFileAndLine) {
  const std::string conf = dir_ + "/bad.conf";
  std::ofstream(conf) << "# a comment\nmax_views = 12\nr_max = lots\n";
  const auto [rc, out] = RunToExit({"--config", conf});
  EXPECT_EQ(rc, 2) << out;
  EXPECT_NE(out.find(conf + ":3: config r_max: cannot parse 'lots'"), std::string::npos) << out;
  std::ofstream(conf) << "max_views = 12\nno_such_key = 1\n";
  const auto [rc2, out2] = RunToExit({"--config=" + conf});
  EXPECT_EQ(rc2, 2) << out2;
  EXPECT_NE(out2.find(conf + ":2: unknown config key 'no_such_key'"), std::string::npos) << out2;
}

TEST_F(ServerFlags, BadFlagValueNamesTheFlag) {
  const auto [rc, out] = RunToExit({"--max_views", "many"});
  EXPECT_EQ(rc, 2) << out;
  EXPECT_NE(out.find("--max_views"), std::string::npos) << out;
  const auto [rc2, out2] = RunToExit({"--udp_pose_port=70000"});
  EXPECT_EQ(rc2, 2) << out2;
  EXPECT_NE(out2.find("--udp_pose_port"), std::string::npos) << out2;
  const auto [rc3, out3] = RunToExit({"--malloc_arena_max=-1"});
  EXPECT_EQ(rc3, 2) << out3;
  EXPECT_NE(out3.find("--malloc_arena_max"), std::string::npos) << out3;
  const auto [rc4, out4] = RunToExit({"--malloc_mmap_threshold=40000000"});  // > 32 MiB
  EXPECT_EQ(rc4, 2) << out4;
  EXPECT_NE(out4.find("malloc_mmap_threshold must be <= 32 MiB"), std::string::npos) << out4;
}

TEST_F(ServerFlags, FlagsOverrideTheConfigFileInBothSyntaxes) {
  const std::string conf = dir_ + "/server.conf";
  std::ofstream(conf) << "max_views = 12   # file only... overridden below\nr_max = 8\n"
                         "listen = 127.0.0.1:0\n";
  Subprocess server(
      EXOVIEW_SERVER_BIN,
      {"--config=" + conf, "--max_views", "9", "--port_file=" + dir_ + "/port", "--sigma_m=1.5"},
      dir_ + "/server.log");
  ASSERT_TRUE(WaitForFile(dir_ + "/port", 20)) << server.Log();
  EXPECT_GT(std::stoi(ReadAll(dir_ + "/port")), 0);
  server.Signal(SIGTERM);
  ASSERT_EQ(server.Wait(20), 0) << server.Log();
  const std::string log = server.Log();
  // The startup line lists the keys that differ from the defaults: the flag's value wins.
  EXPECT_NE(log.find("config " + conf + ": listen=127.0.0.1:0 max_views=9 r_max=8 sigma_m=1.5"),
            std::string::npos)
      << log;
}

}  // namespace
}  // namespace exo
