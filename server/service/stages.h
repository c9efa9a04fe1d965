// Construction of the pipeline stages (geometry, planning with refinement), each enabled by the
// config, all driving one online model (server/core).
#pragma once

#include <memory>
#include <vector>

#include "server/service/pipeline.h"

namespace exo {
struct ServerConfig;
class RegionRegistry;
class InpaintingStage;
class ObservedChunks;
// With `regions` (inpainting enabled) the inpainting stage is appended and returned in
// `*inpainting`. With the labelled proxy (geometry inpaint_fuse) the geometry stage keeps the
// observed mesh of the chunks it publishes labelled in `observed` (for the drone's map).
absl::StatusOr<std::vector<std::unique_ptr<PipelineStage>>> MakeStages(
    const ServerConfig& config, std::shared_ptr<RegionRegistry> regions = nullptr,
    ModelStore* store = nullptr, InpaintingStage** inpainting = nullptr,
    std::shared_ptr<ObservedChunks> observed = nullptr,
    std::shared_ptr<ObservedChunks> coloured = nullptr);  // completion's colour guide
}  // namespace exo
