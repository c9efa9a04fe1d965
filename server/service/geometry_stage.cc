#include "server/service/geometry_stage.h"

#include "server/geometry/tsdf_volume.h"

namespace exo {
namespace {

class GeometryStage final : public PipelineStage {
 public:
  GeometryStage(const TsdfOptions& options, int mesh_every)
      : volume_(options), mesh_every_(mesh_every) {}
  std::string name() const override { return "geometry"; }

  absl::Status Process(const PipelineFrame& f, const SceneContext& ctx) override {
    if (f.frame.depth_m.empty()) return absl::OkStatus();  // colour-only frame: nothing to fuse
    EXO_RETURN_IF_ERROR(volume_.Integrate(f.frame, ctx.origin).status());
    if (++fused_ % mesh_every_ != 0) return absl::OkStatus();
    for (const MeshChunk& c : volume_.ExtractDirtyChunks())
      ctx.store->UpsertChunk(c.id, c.version, c.mesh);
    for (uint64_t id : volume_.TakeRemovedChunkIds()) (void)ctx.store->RemoveChunk(id);
    return absl::OkStatus();
  }

 private:
  TsdfVolume volume_;
  const int mesh_every_;
  uint64_t fused_ = 0;
};

}  // namespace

absl::StatusOr<std::unique_ptr<PipelineStage>> MakeGeometryStage(double voxel_size_m, double max_depth_m,
                                                                 int mesh_every_n_frames) {
  TsdfOptions o;
  o.voxel_size_m = static_cast<float>(voxel_size_m);
  o.max_depth_m = static_cast<float>(max_depth_m);
  o.num_threads = 1;  // the stage is one pipeline thread; other stages use the other core
  EXO_RETURN_IF_ERROR(o.Validate());
  if (mesh_every_n_frames < 1) return absl::InvalidArgumentError("mesh_every_n_frames must be >= 1");
  return std::unique_ptr<PipelineStage>(new GeometryStage(o, mesh_every_n_frames));
}

}  // namespace exo
