#include "common/log/log.h"

#include <spdlog/sinks/dist_sink.h>
#include <spdlog/sinks/stdout_sinks.h>

#include <cstdlib>
#include <mutex>

namespace exo::log {
namespace {

// Every logger writes to one distributing sink: stderr plus whatever tests add.
struct State {
  std::mutex mu;
  std::shared_ptr<spdlog::sinks::dist_sink_mt> sinks;
  spdlog::level::level_enum level = spdlog::level::info;
};

// spdlog's names ("warning") and short forms ("warn", "err").
bool ParseLevel(std::string_view name, spdlog::level::level_enum* level) {
  const auto l = spdlog::level::from_str(std::string(name));
  if (l == spdlog::level::off && name != "off") return false;  // from_str's "unknown"
  *level = l;
  return true;
}

State& GetState() {
  static State* const state = [] {
    auto* s = new State;
    s->sinks = std::make_shared<spdlog::sinks::dist_sink_mt>();
    auto err = std::make_shared<spdlog::sinks::stderr_sink_mt>();
    err->set_pattern(Pattern());
    s->sinks->add_sink(err);
    if (const char* env = std::getenv("EXOVIEW_LOG_LEVEL"); env && *env)
      if (!ParseLevel(env, &s->level))
        std::fprintf(stderr, "EXOVIEW_LOG_LEVEL=%s is not a level (trace ... off); using info\n",
                     env);
    return s;
  }();
  return *state;
}

}  // namespace

const char* Pattern() { return "%Y-%m-%dT%H:%M:%S.%e%z %l [%n] %v"; }

std::shared_ptr<spdlog::logger> Get(const std::string& component) {
  State& s = GetState();
  std::lock_guard lock(s.mu);
  if (auto existing = spdlog::get(component)) return existing;
  auto logger = std::make_shared<spdlog::logger>(component, s.sinks);
  logger->set_level(s.level);
  logger->flush_on(spdlog::level::trace);  // stderr: every line as it happens
  spdlog::register_logger(logger);
  return logger;
}

const std::vector<std::string>& LevelNames() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> v;
    for (int l = spdlog::level::trace; l < spdlog::level::n_levels; ++l) {
      const auto n = spdlog::level::to_string_view(static_cast<spdlog::level::level_enum>(l));
      v.emplace_back(n.data(), n.size());
    }
    return v;
  }();
  return names;
}

bool SetLevel(std::string_view level) {
  spdlog::level::level_enum l;
  if (!ParseLevel(level, &l)) return false;
  State& s = GetState();
  std::lock_guard lock(s.mu);
  s.level = l;
  spdlog::apply_all([l](const std::shared_ptr<spdlog::logger>& logger) { logger->set_level(l); });
  return true;
}

void AddSink(const spdlog::sink_ptr& sink) {
  sink->set_pattern(Pattern());
  GetState().sinks->add_sink(sink);
}

void RemoveSink(const spdlog::sink_ptr& sink) { GetState().sinks->remove_sink(sink); }

RateLimit::RateLimit(int max_per_window, double window_s)
    : max_per_window_(max_per_window), window_s_(window_s) {}

bool RateLimit::Allow(double now_s, uint64_t* suppressed_before) {
  if (now_s - window_start_s_ >= window_s_) {
    window_start_s_ = now_s;
    in_window_ = 0;
  }
  if (in_window_ >= max_per_window_) {
    ++suppressed_since_last_;
    ++suppressed_total_;
    return false;
  }
  ++in_window_;
  *suppressed_before = suppressed_since_last_;
  suppressed_since_last_ = 0;
  return true;
}

}  // namespace exo::log
