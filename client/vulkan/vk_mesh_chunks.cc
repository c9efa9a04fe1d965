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
  if (m.indices.empty()) {
    chunks_.erase(chunk.id);
    return absl::OkStatus();
  }
  Entry g;
  g.version = chunk.version;
  g.index_count = uint32_t(m.indices.size());
  const size_t vb = m.positions.size() * sizeof(glm::vec3), ib = m.indices.size() * 4;
  EXO_ASSIGN_OR_RETURN(g.vertices, Buffer::Create(ctx_, vb, VK_BUFFER_USAGE_VERTEX_BUFFER_BIT));
  EXO_ASSIGN_OR_RETURN(g.indices, Buffer::Create(ctx_, ib, VK_BUFFER_USAGE_INDEX_BUFFER_BIT));
  std::memcpy(g.vertices.mapped, m.positions.data(), vb);
  std::memcpy(g.indices.mapped, m.indices.data(), ib);
  stats_.bytes += vb + ib;
  ++stats_.chunk_uploads;
  chunks_[chunk.id] = std::move(g);
  return absl::OkStatus();
}

absl::Status MeshChunks::Remove(uint64_t chunk_id) {
  if (chunks_.erase(chunk_id) == 0)
    return absl::NotFoundError(absl::StrCat("chunk ", chunk_id, " not resident"));
  return absl::OkStatus();
}

void MeshChunks::RecordDraws(VkCommandBuffer cmd) const {
  for (const auto& [id, c] : chunks_) {
    VkBuffer vb = c.vertices.buffer.get();
    VkDeviceSize off = 0;
    vkCmdBindVertexBuffers(cmd, 0, 1, &vb, &off);
    vkCmdBindIndexBuffer(cmd, c.indices.buffer.get(), 0, VK_INDEX_TYPE_UINT32);
    vkCmdDrawIndexed(cmd, c.index_count, 1, 0, 0, 0);
  }
}

uint64_t MeshChunks::ResidentBytes() const {
  uint64_t b = 0;
  for (const auto& [id, c] : chunks_) b += c.vertices.size + c.indices.size;
  return b;
}

}  // namespace exo::vk
