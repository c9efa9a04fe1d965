#include "common/run_info/run_info.h"

#include <gtest/gtest.h>

#include "exoview_version.h"

namespace exo {
namespace {

TEST(RunInfoTest, CpuModelIsTheFirstModelName) {
  EXPECT_EQ(
      CpuModelFromCpuinfo("processor\t: 0\nvendor_id\t: X\nmodel name\t: Example CPU @ 2.0GHz\n"
                          "processor\t: 1\nmodel name\t: Other\n"),
      "Example CPU @ 2.0GHz");
  EXPECT_EQ(CpuModelFromCpuinfo("processor\t: 0\n"), "");
}

TEST(RunInfoTest, RecordsCommitBuildMachineAndLoad) {
  const nlohmann::json j = RunInfo();
  EXPECT_EQ(j.at("commit"), EXOVIEW_GIT);
  ASSERT_TRUE(j.at("build_type").is_string());
  EXPECT_FALSE(j.at("build_type").get<std::string>().empty());
  ASSERT_TRUE(j.at("nproc").is_number_integer());
  EXPECT_GE(j.at("nproc").get<int>(), 1);
  ASSERT_TRUE(j.at("loadavg").is_array());  // Linux: /proc/loadavg
  EXPECT_EQ(j.at("loadavg").size(), 3u);
  EXPECT_GE(j.at("loadavg")[0].get<double>(), 0.0);
  ASSERT_TRUE(j.at("time_utc").is_string());
  EXPECT_EQ(j.at("time_utc").get<std::string>().size(), 20u);  // 2026-11-25T15:00:00Z
}

}  // namespace
}  // namespace exo
