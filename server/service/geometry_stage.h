// Pipeline stage "geometry" (SPEC §3): fuses each admitted frame into the sparse TSDF of
// server/geometry and publishes the re-meshed dirty chunks (MeshChunkUpserted/Removed deltas)
// every `mesh_every_n_frames` frames.
#pragma once

#include <memory>

#include "server/service/pipeline.h"

namespace exo {
absl::StatusOr<std::unique_ptr<PipelineStage>> MakeGeometryStage(double voxel_size_m, double max_depth_m,
                                                                 int mesh_every_n_frames);
}  // namespace exo
