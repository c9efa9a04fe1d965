// exoview_relay's --malloc_arena_max and --malloc_mmap_threshold (the same glibc settings and
// defaults as exoview_server's config keys, common/process/malloc_tuning.h): --help shows it with its default, a bad value is an error
// naming the flag (exit 2, nothing runs), a good value parses and the relay goes on to start
// (here it then fails on a scene name NATS cannot carry: exit 1 "cannot start", not a parse error).
#include <gtest/gtest.h>

#include <filesystem>
#include <regex>

#include "common/process/malloc_tuning.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using testing::Subprocess;

class RelayFlags : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/exoview_relayflags_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::pair<int, std::string> RunToExit(const std::vector<std::string>& args) {
    Subprocess p(EXOVIEW_RELAY_BIN, args, dir_ + "/out.log");
    const auto rc = p.Wait(20);
    EXPECT_TRUE(rc.has_value()) << "exoview_relay did not exit";
    return {rc.value_or(-1), p.Log()};
  }
  std::string dir_;
};

TEST_F(RelayFlags, HelpShowsMallocArenaMaxWithTheServersDefault) {
  const auto [rc, out] = RunToExit({"--help"});
  ASSERT_EQ(rc, 0) << out;
  EXPECT_EQ(process::kDefaultMallocArenaMax, 2);
  EXPECT_TRUE(std::regex_search(out, std::regex("--malloc_arena_max [A-Z:]*=2\\s"))) << out;
  EXPECT_EQ(process::kDefaultMallocMmapThreshold, 131072u);
  EXPECT_TRUE(std::regex_search(out, std::regex("--malloc_mmap_threshold [A-Z:]*[^\n]*=131072\\s")))
      << out;
}

TEST_F(RelayFlags, BadMallocArenaMaxNamesTheFlag) {
  for (const char* bad : {"--malloc_arena_max=-1", "--malloc_arena_max=many"}) {
    const auto [rc, out] = RunToExit({bad});
    EXPECT_EQ(rc, 2) << bad << "\n" << out;
    EXPECT_NE(out.find("--malloc_arena_max"), std::string::npos) << out;
  }
  for (const char* bad : {"--malloc_mmap_threshold=-5", "--malloc_mmap_threshold=40000000"}) {
    const auto [rc, out] = RunToExit({bad});
    EXPECT_EQ(rc, 2) << bad << "\n" << out;
    EXPECT_NE(out.find("--malloc_mmap_threshold"), std::string::npos) << out;
  }
}

TEST_F(RelayFlags, GoodMallocArenaMaxParsesInBothSyntaxes) {
  for (const std::vector<std::string>& args :
       {std::vector<std::string>{"--malloc_arena_max=4", "--malloc_mmap_threshold=262144",
                                 "--scene=not/a/scene"},
        std::vector<std::string>{"--malloc_arena_max", "0", "--malloc_mmap_threshold", "0",
                                 "--scene=not/a/scene"}}) {
    const auto [rc, out] = RunToExit(args);
    EXPECT_EQ(rc, 1) << out;  // past parsing: Start() refuses the scene name
    EXPECT_NE(out.find("cannot start"), std::string::npos) << out;
    EXPECT_NE(out.find("scene name 'not/a/scene'"), std::string::npos) << out;
    EXPECT_EQ(out.find("malloc"), std::string::npos) << out;  // no parse error, no mallopt warning
  }
}

}  // namespace
}  // namespace exo
