#include "common/log/log.h"

#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>

#include <regex>
#include <sstream>

namespace exo::log {
namespace {

// Captures every log line while alive.
class Capture {
 public:
  Capture() : sink_(std::make_shared<spdlog::sinks::ostream_sink_mt>(out_)) { AddSink(sink_); }
  ~Capture() { RemoveSink(sink_); }
  std::string text() const { return out_.str(); }

 private:
  std::ostringstream out_;
  spdlog::sink_ptr sink_;
};

TEST(Log, OneLoggerPerComponentWithTimeLevelAndComponent) {
  auto a = Get("log_test_a");
  EXPECT_EQ(a.get(), Get("log_test_a").get());
  EXPECT_NE(a.get(), Get("log_test_b").get());
  Capture cap;
  a->info("hello {}", 42);
  const std::regex line(
      R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}[+-]\d\d:\d\d info \[log_test_a\] hello 42\n)");
  EXPECT_TRUE(std::regex_match(cap.text(), line)) << cap.text();
}

TEST(Log, LevelAppliesToExistingAndNewLoggers) {
  auto before = Get("log_test_level_before");
  ASSERT_TRUE(SetLevel("warn"));
  auto after = Get("log_test_level_after");
  {
    Capture cap;
    before->info("not shown");
    after->info("not shown");
    before->warn("shown 1");
    after->error("shown 2");
    const std::string t = cap.text();
    EXPECT_EQ(t.find("not shown"), std::string::npos) << t;
    EXPECT_NE(t.find("warning [log_test_level_before] shown 1"), std::string::npos) << t;
    EXPECT_NE(t.find("error [log_test_level_after] shown 2"), std::string::npos) << t;
  }
  EXPECT_FALSE(SetLevel("loud"));
  EXPECT_EQ(before->level(), spdlog::level::warn);  // unchanged by the bad name
  ASSERT_TRUE(SetLevel("info"));
  EXPECT_EQ(after->level(), spdlog::level::info);
  EXPECT_EQ(LevelNames().front(), "trace");
  EXPECT_EQ(LevelNames().back(), "off");
}

TEST(RateLimit, AtMostNPerWindowAndCountsTheRest) {
  RateLimit limit(5, 1.0);
  int allowed = 0;
  uint64_t suppressed = 123;
  for (int i = 0; i < 1000; ++i)
    if (limit.Allow(i * 0.001, &suppressed)) ++allowed;
  EXPECT_EQ(allowed, 5);
  EXPECT_EQ(suppressed, 0u);  // the first five had nothing suppressed before them
  EXPECT_EQ(limit.suppressed_total(), 995u);
  ASSERT_TRUE(limit.Allow(1.0, &suppressed));  // next window
  EXPECT_EQ(suppressed, 995u);
  ASSERT_TRUE(limit.Allow(1.1, &suppressed));
  EXPECT_EQ(suppressed, 0u);
  EXPECT_EQ(limit.suppressed_total(), 995u);
}

}  // namespace
}  // namespace exo::log
