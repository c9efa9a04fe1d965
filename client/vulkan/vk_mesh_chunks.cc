#include "client/vulkan/vk_mesh_chunks.h"

#include <cmath>
#include <cstring>

namespace exo::vk {

absl::Status MeshChunks::Upsert(const MeshChunk& chunk) {
  const TriangleMesh& m = chunk.mesh;
  if (m.indices.size() % 3 != 0)
    return absl::InvalidArgumentError(
        absl::StrCat("chunk ", chunk.id, ": index count not a multiple of 3"));
  for (uint32_t i : m.indices)
    if (i >= m.positions.size())
      return absl::InvalidArgumentError(
          absl::StrCat("chunk ", chunk.id, ": index ", i, " out of range"));
  for (const glm::vec3& p : m.positions)
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      return absl::InvalidArgumentError(
          absl::StrCat("chunk ", chunk.id, ": non-finite vertex position"));
  dirty_ = true;
  surface_dirty_ = true;
  if (m.indices.empty()) {
    chunks_.erase(chunk.id);
    return absl::OkStatus();
  }
  Entry g;
  g.version = chunk.version;
  g.positions = m.positions;
  g.indices = m.indices;
  stats_.bytes += m.positions.size() * sizeof(glm::vec3) + m.indices.size() * 4;
  ++stats_.chunk_uploads;
  chunks_[chunk.id] = std::move(g);
  return absl::OkStatus();
}

absl::Status MeshChunks::Remove(uint64_t chunk_id) {
  if (chunks_.erase(chunk_id) == 0)
    return absl::NotFoundError(absl::StrCat("chunk ", chunk_id, " not resident"));
  dirty_ = true;
  surface_dirty_ = true;
  return absl::OkStatus();
}

const CellSurfaceBounds& MeshChunks::SurfaceBounds(double q) {
  if (!surface_dirty_ && q == surface_q_) return surface_;
  surface_.clear();
  for (auto& [id, c] : chunks_) {
    if (c.surface_q != q) {
      c.surface = SurfaceBoundsPerCell(c.positions, c.indices, CellGrid{q});
      c.surface_q = q;
    }
    for (const auto& [cell, b] : c.surface) {
      auto [it, fresh] = surface_.try_emplace(cell, b);
      if (!fresh) MergeSurfaceBound(b, &it->second);
    }
  }
  surface_q_ = q;
  surface_dirty_ = false;
  ++surface_stamp_;
  return surface_;
}

absl::Status MeshChunks::PrepareDraw() {
  if (!dirty_) return absl::OkStatus();
  size_t nv = 0, ni = 0;
  for (const auto& [id, c] : chunks_) {
    nv += c.positions.size();
    ni += c.indices.size();
  }
  if (nv > UINT32_MAX) return absl::ResourceExhaustedError("proxy mesh above 2^32 vertices");
  index_count_ = 0;
  if (ni > 0) {
    // Grow (power of two) only; the buffers are host-visible and mapped (lavapipe: host memory).
    const VkDeviceSize vb = nv * sizeof(glm::vec3), ib = ni * 4;
    if (vertices_.size < vb) {
      EXO_ASSIGN_OR_RETURN(vertices_, Buffer::Create(ctx_, std::max<VkDeviceSize>(vb, 2 * vertices_.size),
                                                     VK_BUFFER_USAGE_VERTEX_BUFFER_BIT));
    }
    if (indices_.size < ib) {
      EXO_ASSIGN_OR_RETURN(indices_, Buffer::Create(ctx_, std::max<VkDeviceSize>(ib, 2 * indices_.size),
                                                    VK_BUFFER_USAGE_INDEX_BUFFER_BIT));
    }
    auto* pv = static_cast<glm::vec3*>(vertices_.mapped);
    auto* pi = static_cast<uint32_t*>(indices_.mapped);
    uint32_t base = 0;
    for (const auto& [id, c] : chunks_) {
      std::memcpy(pv + base, c.positions.data(), c.positions.size() * sizeof(glm::vec3));
      for (uint32_t i : c.indices) *pi++ = base + i;
      base += uint32_t(c.positions.size());
    }
    index_count_ = uint32_t(ni);
  }
  dirty_ = false;
  return absl::OkStatus();
}

void MeshChunks::RecordDraws(VkCommandBuffer cmd) const {
  if (index_count_ == 0) return;
  VkBuffer vb = vertices_.buffer.get();
  VkDeviceSize off = 0;
  vkCmdBindVertexBuffers(cmd, 0, 1, &vb, &off);
  vkCmdBindIndexBuffer(cmd, indices_.buffer.get(), 0, VK_INDEX_TYPE_UINT32);
  vkCmdDrawIndexed(cmd, index_count_, 1, 0, 0, 0);
}

uint64_t MeshChunks::ResidentBytes() const { return vertices_.size + indices_.size; }

}  // namespace exo::vk
