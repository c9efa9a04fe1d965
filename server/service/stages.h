// Construction of the pipeline stages (geometry, planning with refinement), each enabled by the
// config, all driving one online model (server/core).
#pragma once

#include <memory>
#include <vector>

#include "server/service/pipeline.h"

namespace exo {
struct ServerConfig;
absl::StatusOr<std::vector<std::unique_ptr<PipelineStage>>> MakeStages(const ServerConfig& config);
}  // namespace exo
