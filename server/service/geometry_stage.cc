#include "server/service/geometry_stage.h"

#include <cmath>
#include <unordered_map>

#include "server/geometry/cell_areas.h"
#include "server/geometry/tsdf_volume.h"

namespace exo {

SharedCellAreas::SharedCellAreas(double cell_size_m, bool keep_chunk_changes)
    : areas_(std::make_unique<CellAreas>(CellGrid{cell_size_m})),
      keep_chunk_changes_(keep_chunk_changes) {}
SharedCellAreas::~SharedCellAreas() = default;
void SharedCellAreas::Update(const MeshChunk& chunk) {
  std::lock_guard lock(mu_);
  areas_->UpdateChunk(chunk);
  versions_[chunk.id] = chunk.version;
  if (keep_chunk_changes_) pending_[chunk.id] = chunk;
}
void SharedCellAreas::Remove(uint64_t chunk_id) {
  std::lock_guard lock(mu_);
  areas_->RemoveChunk(chunk_id);
  auto it = versions_.find(chunk_id);
  if (it == versions_.end()) return;
  if (keep_chunk_changes_) {
    MeshChunk gone;  // an empty mesh with a newer version removes the chunk downstream
    gone.id = chunk_id;
    gone.version = it->second + 1;
    pending_[chunk_id] = std::move(gone);
  }
  versions_.erase(it);
}
std::vector<MeshChunk> SharedCellAreas::TakeChunkChanges() {
  std::lock_guard lock(mu_);
  std::vector<MeshChunk> out;
  out.reserve(pending_.size());
  for (auto& [id, c] : pending_) out.push_back(std::move(c));
  pending_.clear();
  return out;
}
std::vector<std::pair<CellId, double>> SharedCellAreas::TakeChanges() {
  std::lock_guard lock(mu_);
  std::vector<std::pair<CellId, double>> out;
  for (CellId c : areas_->TakeChangedCells()) out.emplace_back(c, areas_->Area(c));
  return out;
}
double SharedCellAreas::TotalArea() const {
  std::lock_guard lock(mu_);
  return areas_->TotalArea();
}

namespace {

class GeometryStage final : public PipelineStage {
 public:
  GeometryStage(const TsdfOptions& tsdf, const GeometryStageOptions& options,
                std::shared_ptr<SharedCellAreas> areas)
      : volume_(tsdf), options_(options), areas_(std::move(areas)) {}
  std::string name() const override { return "geometry"; }

  absl::Status Process(const PipelineFrame& f, const SceneContext& ctx) override {
    if (f.frame.depth_m.empty()) return absl::OkStatus();  // colour-only frame: nothing to fuse
    const int k = options_.fuse_depth_downscale;
    if (k == 1) {
      EXO_RETURN_IF_ERROR(volume_.Integrate(f.frame, ctx.origin).status());
    } else {
      // Every k-th depth sample with the depth camera scaled to match (pixel centres kept).
      const ImageF& d = f.frame.depth_m;
      const int w = d.width() / k, h = d.height() / k;
      ImageF small(w, h);
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) small.at(x, y) = d.at(x * k + k / 2, y * k + k / 2);
      PinholeCamera cam = f.frame.depth_camera;
      cam.fx /= k;
      cam.fy /= k;
      cam.cx = (cam.cx - k / 2) / k;
      cam.cy = (cam.cy - k / 2) / k;
      cam.width = w;
      cam.height = h;
      const Rigid3d local_from_depth =
          ctx.origin.ToLocal(f.frame.world_from_cam) * f.frame.color_from_depth;
      EXO_RETURN_IF_ERROR(volume_
                              .IntegrateDepth(small, cam, local_from_depth, &f.frame.color,
                                              &f.frame.color_camera, &f.frame.color_from_depth)
                              .status());
    }
    if (++fused_ % options_.mesh_every_n_frames != 0) return absl::OkStatus();
    const int64_t now = SteadyNowNs();
    for (MeshChunk& c : volume_.ExtractDirtyChunks()) {
      if (areas_) areas_->Update(c);  // the planner sees the newest proxy, published or not
      auto it = published_.find(c.id);
      if (it != published_.end()) {
        const double old_n = static_cast<double>(it->second.triangles);
        const double change = std::abs(static_cast<double>(c.mesh.num_triangles()) - old_n) /
                              std::max(1.0, old_n);
        const double age_s = (now - it->second.time_ns) * 1e-9;
        if (change <= options_.republish_change_fraction && age_s < options_.republish_interval_s) {
          pending_[c.id] = std::move(c);  // newest mesh, published when due
          continue;
        }
      }
      Publish(std::move(c), now, ctx);
    }
    // Held-back chunks whose interval has passed.
    for (auto it = pending_.begin(); it != pending_.end();) {
      auto pub = published_.find(it->first);
      if (pub == published_.end() ||
          (now - pub->second.time_ns) * 1e-9 >= options_.republish_interval_s) {
        MeshChunk c = std::move(it->second);
        it = pending_.erase(it);
        Publish(std::move(c), now, ctx);
      } else {
        ++it;
      }
    }
    for (uint64_t id : volume_.TakeRemovedChunkIds()) {
      pending_.erase(id);
      if (areas_) areas_->Remove(id);
      if (published_.erase(id)) (void)ctx.store->RemoveChunk(id);
    }
    return absl::OkStatus();
  }

 private:
  struct Published {
    size_t triangles = 0;
    int64_t time_ns = 0;
  };
  void Publish(MeshChunk c, int64_t now, const SceneContext& ctx) {
    published_[c.id] = {c.mesh.num_triangles(), now};
    ctx.store->UpsertChunk(c.id, c.version, c.mesh);
  }

  TsdfVolume volume_;
  const GeometryStageOptions options_;
  std::shared_ptr<SharedCellAreas> areas_;
  uint64_t fused_ = 0;
  std::unordered_map<uint64_t, Published> published_;
  std::unordered_map<uint64_t, MeshChunk> pending_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<PipelineStage>> MakeGeometryStage(
    const GeometryStageOptions& options, std::shared_ptr<SharedCellAreas> areas) {
  EXO_RETURN_IF_ERROR(options.Validate());
  TsdfOptions o;
  o.voxel_size_m = static_cast<float>(options.voxel_size_m);
  o.max_depth_m = static_cast<float>(options.max_depth_m);
  o.num_threads = 1;  // the stage is one pipeline thread; other stages use the other core
  EXO_RETURN_IF_ERROR(o.Validate());
  return std::unique_ptr<PipelineStage>(new GeometryStage(o, options, std::move(areas)));
}

}  // namespace exo
