// Construction of the pipeline stages this server was built with (geometry, planning,
// refinement, each only when its library exists in the build and the config enables it).
#pragma once

#include <memory>
#include <vector>

#include "server/service/pipeline.h"

namespace exo {
struct ServerConfig;
absl::StatusOr<std::vector<std::unique_ptr<PipelineStage>>> MakeStages(const ServerConfig& config);
}  // namespace exo
