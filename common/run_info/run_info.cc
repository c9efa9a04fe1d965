#include "common/run_info/run_info.h"

#include <ctime>
#include <fstream>
#include <sstream>
#include <thread>

#include "exoview_version.h"

#ifndef EXOVIEW_BUILD_TYPE
#define EXOVIEW_BUILD_TYPE ""
#endif

namespace exo {

std::string CpuModelFromCpuinfo(const std::string& cpuinfo) {
  std::istringstream in(cpuinfo);
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("model name", 0) != 0) continue;
    const size_t colon = line.find(':');
    if (colon == std::string::npos) continue;
    const size_t begin = line.find_first_not_of(" \t", colon + 1);
    return begin == std::string::npos ? std::string() : line.substr(begin);
  }
  return std::string();
}

nlohmann::json RunInfo() {
  nlohmann::json j;
  j["commit"] = EXOVIEW_GIT;
  j["version"] = EXOVIEW_VERSION;
  j["build_type"] = std::string(EXOVIEW_BUILD_TYPE).empty() ? nlohmann::json() : EXOVIEW_BUILD_TYPE;
  const unsigned nproc = std::thread::hardware_concurrency();
  j["nproc"] = nproc > 0 ? nlohmann::json(nproc) : nlohmann::json();
  std::ifstream cpuinfo("/proc/cpuinfo");
  std::stringstream text;
  text << cpuinfo.rdbuf();
  const std::string model = CpuModelFromCpuinfo(text.str());
  j["cpu_model"] = model.empty() ? nlohmann::json() : nlohmann::json(model);
  std::ifstream loadavg("/proc/loadavg");
  double l1, l5, l15;
  if (loadavg >> l1 >> l5 >> l15) {
    j["loadavg"] = {l1, l5, l15};
  } else {
    j["loadavg"] = nullptr;
  }
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buf[32];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%SZ", &tm);
  j["time_utc"] = buf;
  return j;
}

}  // namespace exo
