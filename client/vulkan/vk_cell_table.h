// PRIVATE to client/vulkan: the GPU cell reference table R(b_k). An open-addressing hash table
// (linear probing, tombstones; same hash as shaders/lumigraph_common.glsl) maps a CellId to its
// slab of max_refs_per_cell view slots; a host mirror keeps uploads to the changed entries. Per
// frame, RankRefs writes every visible cell's references sorted by an upper bound of their
// blend weight (the ranked buffer blend.frag walks).
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <span>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "client/vulkan/vk_core_internal.h"
#include "client/vulkan/vk_view_store.h"
#include "client/vulkan/vulkan_renderer.h"
#include "common/cell_surface.h"

namespace exo::vk {

// RGBA32UI texels per reference slot of the per-frame ranked buffer (blend_shade.glsl
// kRankedTexels): (c_i, bound), (M row 0, layer | list position << 16), (M row 1, width |
// height << 16), (M row 2, exposure), with M = K R^T the 3x3 part of the view's P (P's 4th
// column -M c_i is not stored: the shader projects c_i - x). Layer and position fit 16 bits
// (array layers <= 2048, max_refs_per_cell <= 1024).
inline constexpr int kRankedTexels = 4;

class CellTable {
 public:
  struct Entry {
    uint32_t table_index = 0;
    uint32_t slab = 0;
    std::vector<ViewId> refs;
    // RankRefs' region of the cell's surface points, valid for surface stamp region_stamp (0:
    // not computed).
    CellRegion region;
    uint64_t region_stamp = 0;
  };

  // `views` resolves references to slots; all arguments must outlive the table.
  CellTable(const Context& ctx, const VulkanRendererOptions& opt, UploadStats& stats,
            const ViewStore& views)
      : ctx_(ctx), opt_(opt), stats_(stats), views_(views) {}

  // The empty table: 64 entries and one slab, so every descriptor is valid.
  absl::Status Init();
  // Sets R(id) (replaces); an empty list removes the cell.
  absl::Status SetRefs(CellId id, std::span<const ViewId> refs);
  // Rewrites the slabs of the cells that reference `view` (after it arrived or left).
  void RefreshCellsOf(ViewId view);
  // Per-frame reference ranking into the ranked buffer (see the .cc for the bound). `surface`
  // (MeshChunks::SurfaceBounds for this cell size; may be null) narrows each cell's region from
  // the cube to the ball and box of the proxy surface in it; `surface_stamp` (> 0,
  // MeshChunks::surface_stamp) changes whenever `surface` or the cell size does: each cell's
  // region is cached until then. With `by_centre_weight`
  // (RenderApprox::max_candidates > 0) the order is an estimate instead: the weight at the cell
  // centre, views that do not see the centre last (not exact).
  void RankRefs(const glm::vec3& c_o, const PinholeCamera& cam, const Rigid3d& local_from_cam,
                double cell_size_m, const blend::BlendOptions& bo,
                const CellSurfaceBounds* surface, uint64_t surface_stamp,
                bool by_centre_weight = false);

  const std::unordered_map<CellId, Entry>& entries() const { return cells_; }
  uint32_t table_mask() const { return uint32_t(table_.size() - 1); }
  uint32_t max_probe() const { return max_probe_; }
  const Buffer& table_buffer() const { return table_buf_; }
  const Buffer& refs_buffer() const { return refs_buf_; }
  const Buffer& ranked_buffer() const { return ranked_buf_; }
  // True once after a buffer was replaced (descriptors must follow).
  bool TakeStorageChanged() { return std::exchange(storage_changed_, false); }
  uint64_t ResidentBytes() const { return table_buf_.size + refs_buf_.size + ranked_buf_.size; }

 private:
  absl::Status GrowSlabs(uint32_t slabs);
  // Re-hashes every cell into a table of `capacity` entries and uploads it whole.
  absl::Status RebuildTable(uint32_t capacity);
  uint32_t Probe(CellId id, bool for_insert) const;
  uint32_t Displacement(CellId id, uint32_t i) const;
  glm::uvec4 EntryOf(CellId id, const Entry& c) const;
  void UploadTableEntry(uint32_t i);
  void WriteSlab(const Entry& c);
  void Unlink(CellId id, const Entry& c);  // drops `id` from the reverse index
  void Erase(std::unordered_map<CellId, Entry>::iterator it);
  absl::StatusOr<std::unordered_map<CellId, Entry>::iterator> Insert(CellId id);
  // Ranks one cell's references for the camera at c_o into ranked_buf_: the bound over the
  // region of the cell's surface points; the centre-weight estimate at the cell centre `centre`.
  void RankCell(const Entry& c, const glm::dvec3& centre, const glm::dvec3& c_o, bool by_centre,
                const blend::BlendOptions& bo);

  const Context& ctx_;
  const VulkanRendererOptions& opt_;
  UploadStats& stats_;
  const ViewStore& views_;
  std::unordered_map<CellId, Entry> cells_;
  std::unordered_map<ViewId, std::unordered_set<CellId>> cells_of_view_;  // reverse index
  std::vector<glm::uvec4> table_;  // host mirror of the GPU hash table
  uint32_t max_probe_ = 0;         // largest displacement of a resident key (lookup bound)
  uint32_t tombstones_ = 0;
  Buffer table_buf_;
  std::vector<uint32_t> free_slabs_;
  uint32_t slab_capacity_ = 0;
  Buffer refs_buf_;
  // Per-frame ranked copy of every slab (RankRefs): 2 RGBA32UI texels per reference slot, same
  // slot index as refs_buf_, sorted per cell by an upper bound of the blend weight this frame.
  Buffer ranked_buf_;
  std::vector<std::pair<float, uint32_t>> rank_scratch_;
  bool storage_changed_ = false;
};

}  // namespace exo::vk
