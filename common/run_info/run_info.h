// Where and how a benchmark or an evaluation ran, recorded beside its results so that a number
// can be traced to its commit, build and machine: the commit the build was configured from
// (exoview_version.h), the build type, the machine (logical CPUs, CPU model from /proc/cpuinfo)
// and its load (/proc/loadavg) at the time of the call.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

namespace exo {

// {"commit", "version", "build_type", "nproc", "cpu_model", "loadavg": [1, 5, 15 min],
//  "time_utc"}; fields that cannot be read are null.
nlohmann::json RunInfo();

// The first "model name" of a /proc/cpuinfo text ("" if none). Exposed for tests.
std::string CpuModelFromCpuinfo(const std::string& cpuinfo);

}  // namespace exo
