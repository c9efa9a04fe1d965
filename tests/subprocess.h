// Test helper: real child processes (fork/exec of the built binaries) for end-to-end tests on
// loopback, with output captured to a file, timeouts and explicit kills by pid.
#pragma once

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

namespace exo::testing {

class Subprocess {
 public:
  Subprocess(const std::string& binary, const std::vector<std::string>& args,
             const std::string& log_path) : log_path_(log_path) {
    std::vector<std::string> argv_s{binary};
    argv_s.insert(argv_s.end(), args.begin(), args.end());
    // Everything the child needs is built before fork(): in a multi-threaded parent (gRPC
    // threads, an uploader thread) the child may only make async-signal-safe calls; a malloc
    // there can deadlock on a lock another thread held at the fork.
    std::vector<char*> argv;
    for (auto& s : argv_s) argv.push_back(s.data());
    argv.push_back(nullptr);
    const std::string log_copy = log_path;
    pid_ = fork();
    if (pid_ == 0) {
      const int fd = open(log_copy.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      if (fd >= 0) {
        dup2(fd, 1);
        dup2(fd, 2);
      }
      execv(argv[0], argv.data());
      _exit(127);
    }
  }
  ~Subprocess() {
    if (running()) {
      kill(pid_, SIGKILL);
      Wait(5);
    }
  }
  pid_t pid() const { return pid_; }
  bool running() { return pid_ > 0 && !status_ && !Poll(); }
  void Signal(int sig) {
    if (pid_ > 0 && !status_) kill(pid_, sig);
  }
  // Exit code (or 128 + signal); nullopt on timeout.
  std::optional<int> Wait(double timeout_s) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    while (!status_ && !Poll()) {
      if (std::chrono::steady_clock::now() > end) return std::nullopt;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return status_;
  }
  std::string Log() const {
    std::ifstream in(log_path_);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }

 private:
  bool Poll() {
    int st = 0;
    if (waitpid(pid_, &st, WNOHANG) == pid_) {
      status_ = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
      return true;
    }
    return false;
  }
  pid_t pid_ = -1;
  std::optional<int> status_;
  std::string log_path_;
};

// Reads a whole file ("" if missing).
inline std::string ReadAll(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Waits for a file to exist with content; false on timeout.
inline bool WaitForFile(const std::string& path, double timeout_s) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (ReadAll(path).empty()) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return true;
}

// A top-level number of a JSON object written by our binaries, parsed with nlohmann::json
// (-1 / 0 when the text is not JSON, the key is absent or not a number).
inline double JsonNumber(const std::string& json, const std::string& key) {
  const auto j = nlohmann::json::parse(json, nullptr, /*allow_exceptions=*/false);
  if (!j.is_object() || !j.contains(key) || !j[key].is_number()) return -1;
  return j[key].get<double>();
}
inline uint64_t JsonU64(const std::string& json, const std::string& key) {
  const auto j = nlohmann::json::parse(json, nullptr, /*allow_exceptions=*/false);
  if (!j.is_object() || !j.contains(key) || !j[key].is_number_unsigned()) return 0;
  return j[key].get<uint64_t>();
}

// A loopback TCP port that was free a moment ago (for processes that must listen on a fixed port,
// e.g. a server restarted on the same address).
inline int FreeLoopbackPort() {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = 0;
  bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  close(fd);
  return ntohs(a.sin_port);
}

}  // namespace exo::testing
