// Logging for every Exoview program, on spdlog: one named logger per component
// (exo::log::Get("ingest")), all writing one line per event to stderr as
//   2026-11-25T14:50:01.123+00:00 info [ingest] rejected frame: ...
// (ISO 8601 time with milliseconds, level, component, message). The level comes from the
// EXOVIEW_LOG_LEVEL environment variable (trace, debug, info, warning, error, critical, off;
// default info) and can be set by a flag (exoview_server --log_level). Tests capture the lines by
// adding a sink (AddSink). RateLimit keeps a flood of similar events to a few lines per second.
#pragma once

#include <spdlog/spdlog.h>

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

namespace exo::log {

// The logger of `component`, created on first use with the shared sinks and the current level.
std::shared_ptr<spdlog::logger> Get(const std::string& component);

// The level names SetLevel and EXOVIEW_LOG_LEVEL accept (also "warn" and "err").
const std::vector<std::string>& LevelNames();

// Sets the level of every logger, existing and later ones. False for an unknown name (the level
// is then unchanged).
bool SetLevel(std::string_view level);

// The line format: "%Y-%m-%dT%H:%M:%S.%e%z %l [%n] %v".
const char* Pattern();

// Adds a sink every logger writes to (with the common pattern); RemoveSink takes it out again.
void AddSink(const spdlog::sink_ptr& sink);
void RemoveSink(const spdlog::sink_ptr& sink);

// At most `max_per_window` events per window of `window_s` seconds are let through; the others
// are counted. Not thread-safe (one per stream).
class RateLimit {
 public:
  RateLimit(int max_per_window, double window_s);
  // True when the event at `now_s` (any monotonic clock, seconds) may be logged; then
  // `*suppressed_before` is the number of events refused since the last one let through.
  bool Allow(double now_s, uint64_t* suppressed_before);
  uint64_t suppressed_total() const { return suppressed_total_; }

 private:
  int max_per_window_;
  double window_s_;
  double window_start_s_ = -1e300;
  int in_window_ = 0;
  uint64_t suppressed_since_last_ = 0, suppressed_total_ = 0;
};

}  // namespace exo::log
