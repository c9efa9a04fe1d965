#include "common/cli/cli.h"

#include <gtest/gtest.h>

#include <vector>

namespace exo::cli {
namespace {

struct Args {
  std::vector<std::string> s;
  std::vector<const char*> p;
  explicit Args(std::vector<std::string> v) : s(std::move(v)) {
    for (auto& x : s) p.push_back(x.c_str());
  }
  int argc() const { return static_cast<int>(p.size()); }
  const char* const* argv() const { return p.data(); }
};

std::optional<int> ParseArgs(const std::vector<std::string>& argv, int* frames, std::string* out) {
  CLI::App app{"test app", "exo_test"};
  exo::cli::Setup(app);
  app.add_option("--frames", *frames, "frames")->check(CLI::PositiveNumber);
  app.add_option("--out", *out, "output");
  Args a(argv);
  return Parse(app, a.argc(), a.argv());
}

TEST(Cli, BothValueSyntaxes) {
  int frames = 0;
  std::string out;
  EXPECT_FALSE(ParseArgs({"exo_test", "--frames=3", "--out", "dir"}, &frames, &out).has_value());
  EXPECT_EQ(frames, 3);
  EXPECT_EQ(out, "dir");
  EXPECT_FALSE(ParseArgs({"exo_test", "--frames", "7", "--out=d2"}, &frames, &out).has_value());
  EXPECT_EQ(frames, 7);
  EXPECT_EQ(out, "d2");
}

TEST(Cli, HelpAndVersionExitZero) {
  int frames = 0;
  std::string out;
  testing::internal::CaptureStdout();
  EXPECT_EQ(ParseArgs({"exo_test", "--help"}, &frames, &out), 0);
  const std::string help = testing::internal::GetCapturedStdout();
  EXPECT_NE(help.find("--frames"), std::string::npos) << help;
  testing::internal::CaptureStdout();
  EXPECT_EQ(ParseArgs({"exo_test", "--version"}, &frames, &out), 0);
  EXPECT_NE(testing::internal::GetCapturedStdout().find(Version()), std::string::npos);
}

TEST(Cli, UnknownFlagAndBadValueExitTwoNamingIt) {
  int frames = 0;
  std::string out;
  testing::internal::CaptureStderr();
  EXPECT_EQ(ParseArgs({"exo_test", "--bogus", "3"}, &frames, &out), 2);
  EXPECT_NE(testing::internal::GetCapturedStderr().find("--bogus"), std::string::npos);
  testing::internal::CaptureStderr();
  EXPECT_EQ(ParseArgs({"exo_test", "--frames=-4"}, &frames, &out), 2);
  EXPECT_NE(testing::internal::GetCapturedStderr().find("frames"), std::string::npos);
  testing::internal::CaptureStderr();
  EXPECT_EQ(ParseArgs({"exo_test", "--frames=abc"}, &frames, &out), 2);
  (void)testing::internal::GetCapturedStderr();
}

TEST(Cli, UnknownFlagNamedBeforeAMissingRequiredOne) {
  std::string out;
  CLI::App app{"test app", "exo_test"};
  exo::cli::Setup(app);
  app.add_option("--out", out, "output")->required();
  Args a({"exo_test", "--bogus_flag", "3"});
  testing::internal::CaptureStderr();
  EXPECT_EQ(Parse(app, a.argc(), a.argv()), 2);
  const std::string err = testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find("--bogus_flag"), std::string::npos) << err;
  Args b({"exo_test"});
  testing::internal::CaptureStderr();
  EXPECT_EQ(Parse(app, b.argc(), b.argv()), 2);
  EXPECT_NE(testing::internal::GetCapturedStderr().find("--out is required"), std::string::npos);
}

}  // namespace
}  // namespace exo::cli
