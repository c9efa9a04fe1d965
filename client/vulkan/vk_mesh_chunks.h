// PRIVATE to client/vulkan: the resident proxy mesh. Each MeshChunk is validated and kept
// (replaced whole when its version changes); the draw uses one vertex + index buffer pair holding
// every chunk in chunk-id order (indices rebased), rebuilt on the first draw after a change: one
// indexed draw per frame instead of one per chunk (a 7-Scenes proxy has ~1100 chunks, and on
// lavapipe each draw has a fixed binning/setup cost).
#pragma once

#include <cstdint>
#include <map>
#include <vector>

#include "client/vulkan/vk_core_internal.h"
#include "client/vulkan/vulkan_renderer.h"
#include "common/cell_surface.h"
#include "common/lumigraph/model.h"

namespace exo::vk {

class MeshChunks {
 public:
  struct Entry {
    uint64_t version = 0;
    std::vector<glm::vec3> positions;
    std::vector<uint32_t> indices;
    // This chunk's surface per cell for the grid of cell size surface_q (0: not computed yet).
    CellSurfaceBounds surface;
    double surface_q = 0.0;
  };

  // `ctx` and `stats` must outlive the chunks.
  MeshChunks(const Context& ctx, UploadStats& stats) : ctx_(ctx), stats_(stats) {}

  // Validates and keeps `chunk`; an empty mesh removes it.
  absl::Status Upsert(const MeshChunk& chunk);
  absl::Status Remove(uint64_t chunk_id);
  // Rebuilds the merged buffers when a chunk changed since the last call (before a Submit).
  absl::Status PrepareDraw();
  // Records the indexed draw of every chunk (the pipeline and descriptors are bound by the
  // caller; PrepareDraw() first).
  void RecordDraws(VkCommandBuffer cmd) const;

  // Per cell, the bound of the whole resident proxy surface in it (common/cell_surface.h) for
  // cells of size q: the per-frame reference ranking's region (CellTable::RankRefs). Computed
  // lazily: chunks changed since the last call (all after a change of q) are clipped again, then
  // the per-chunk bounds are merged.
  const CellSurfaceBounds& SurfaceBounds(double q);
  // Changes (> 0) whenever SurfaceBounds re-merged: consumers cache what they derive from it.
  uint64_t surface_stamp() const { return surface_stamp_; }

  const std::map<uint64_t, Entry>& entries() const { return chunks_; }
  uint64_t ResidentBytes() const;

 private:
  const Context& ctx_;
  UploadStats& stats_;
  std::map<uint64_t, Entry> chunks_;
  bool dirty_ = false;
  CellSurfaceBounds surface_;        // merged SurfaceBounds
  bool surface_dirty_ = true;        // a chunk changed since surface_ was merged
  double surface_q_ = 0.0;
  uint64_t surface_stamp_ = 0;
  Buffer vertices_, indices_;
  uint32_t index_count_ = 0;
};

}  // namespace exo::vk
