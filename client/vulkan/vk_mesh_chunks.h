// PRIVATE to client/vulkan: the resident proxy mesh, one vertex + index buffer pair per
// MeshChunk (replaced whole when its version changes), drawn in chunk-id order.
#pragma once

#include <cstdint>
#include <map>

#include "client/vulkan/vk_core_internal.h"
#include "client/vulkan/vulkan_renderer.h"
#include "common/lumigraph/model.h"

namespace exo::vk {

class MeshChunks {
 public:
  struct Entry {
    uint64_t version = 0;
    Buffer vertices, indices;
    uint32_t index_count = 0;
  };

  // `ctx` and `stats` must outlive the chunks.
  MeshChunks(const Context& ctx, UploadStats& stats) : ctx_(ctx), stats_(stats) {}

  // Validates and uploads `chunk`; an empty mesh removes it.
  absl::Status Upsert(const MeshChunk& chunk);
  absl::Status Remove(uint64_t chunk_id);
  // Records one indexed draw per chunk (the pipeline and descriptors are bound by the caller).
  void RecordDraws(VkCommandBuffer cmd) const;

  const std::map<uint64_t, Entry>& entries() const { return chunks_; }
  uint64_t ResidentBytes() const;

 private:
  const Context& ctx_;
  UploadStats& stats_;
  std::map<uint64_t, Entry> chunks_;
};

}  // namespace exo::vk
