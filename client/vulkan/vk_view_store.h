// PRIVATE to client/vulkan: the GPU residency of the stored views. Each view owns one layer of
// two texture arrays (colour decoded to linear UNORM16, baked depth R32F) and one GpuView record
// of a texel buffer; slots are reused after removal and the arrays grow by doubling (GPU-side
// copy of the resident layers).
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <unordered_map>
#include <utility>
#include <vector>

#include "client/vulkan/vk_core_internal.h"
#include "client/vulkan/vulkan_renderer.h"
#include "common/lumigraph/model.h"

namespace exo::vk {

// No view slot: a reference to a view that is not resident.
inline constexpr uint32_t kNoSlot = 0xFFFFFFFFu;
inline constexpr int kBgBlockPx = 8;  // block size of Entry::bg_block_sat

// A view record: 5 RGBA32F texels of the Views texel buffer (shaders/blend.frag): rows of
// P = K [R^T | -R^T c] (local point -> (z u, z v, z)), centre + exposure, and width, height,
// layer, valid as floats (exact below 2^24).
struct GpuView {
  glm::vec4 p0, p1, p2;
  glm::vec4 centre_exposure;
  glm::vec4 size_layer;
};
static_assert(sizeof(GpuView) == 80);

class ViewStore {
 public:
  struct Entry {
    uint32_t slot = 0;
    uint64_t fingerprint = 0;
    blend::BlendView params;      // as the CPU reference builds it (MakeBlendView)
    bool has_background = false;  // some pixel of the baked background mask is set
    // Bounding box of the baked background mask in pixels, inclusive (x0, y0, x1, y1); empty
    // (x0 > x1) without background. The background pass's per-tile view lists test against it.
    glm::ivec4 bg_box{0, 0, -1, -1};
    // The same mask in kBgBlockPx blocks (a block is set when any of its pixels is) as a
    // summed-area table of (blocks_x + 1) x (blocks_y + 1) counts, row-major; empty when the
    // block count exceeds 65535 (then only bg_box is used). BackgroundMaskAny reads it.
    std::vector<uint16_t> bg_block_sat;
    bool inpainted = false;       // SPEC §7: colour alpha holds its labels (1 = L_IP)
  };

  // `ctx`, `opt` and `stats` must outlive the store.
  ViewStore(const Context& ctx, const VulkanRendererOptions& opt, UploadStats& stats)
      : ctx_(ctx), opt_(opt), stats_(stats) {}

  // Grows the texture arrays to >= (w, h, slots); existing layers are copied GPU-side.
  absl::Status Grow(uint32_t w, uint32_t h, uint32_t slots);
  // Validates and uploads `v` (colour, baked depth, record). Returns whether the id is new.
  absl::StatusOr<bool> Upsert(const StoredView& v, uint64_t fingerprint);
  // Marks the record invalid and frees the slot.
  absl::Status Remove(ViewId id);

  const std::unordered_map<ViewId, Entry>& entries() const { return views_; }
  // Whether the background mask of `e` may hold a pixel of [x0, x1] x [y0, y1] (inclusive,
  // clipped to the view): false only when it holds none (block table, else the box).
  static bool BackgroundMaskAny(const Entry& e, int x0, int y0, int x1, int y1);
  // The slot of a resident view, kNoSlot otherwise.
  uint32_t SlotOf(ViewId id) const {
    auto it = views_.find(id);
    return it == views_.end() ? kNoSlot : it->second.slot;
  }
  const GpuView* records() const { return static_cast<const GpuView*>(records_.mapped); }
  const Buffer& records_buffer() const { return records_; }
  // Layouts of the arrays while resident: both are read as storage images (imageLoad in
  // blend_shade.glsl), the colour layers also through the bilinear sampler (floors).
  static constexpr VkImageLayout kColorLayout = VK_IMAGE_LAYOUT_GENERAL;
  static constexpr VkImageLayout kDepthLayout = VK_IMAGE_LAYOUT_GENERAL;
  const Image& colors() const { return colors_; }
  const Image& depths() const { return depths_; }
  // True once after the arrays or the record buffer were replaced (descriptors must follow).
  bool TakeStorageChanged() { return std::exchange(storage_changed_, false); }
  uint64_t ResidentBytes() const;

 private:
  // Clears the new arrays nc, nd and, when `had`, copies the resident layers into them; they end
  // in kColorLayout / kDepthLayout.
  void RecordRegrowth(VkCommandBuffer cmd, Image* nc, Image* nd, bool had) const;
  absl::Status Validate(const StoredView& v) const;
  // The slot of `id` (a free one when new), after growing the arrays to hold it.
  absl::StatusOr<uint32_t> AcquireSlot(ViewId id, int w, int h, bool is_new);
  // Writes linear UNORM16 colour then baked depth into staging_; returns has_background.
  // Also returns the mask's bounding box and block table (Entry::bg_box, bg_block_sat).
  absl::StatusOr<bool> Stage(const StoredView& v, glm::ivec4* bg_box,
                             std::vector<uint16_t>* bg_block_sat);
  absl::Status CopyStagingToLayer(uint32_t slot, uint32_t w, uint32_t h);
  void WriteRecord(const StoredView& v, uint32_t slot);

  const Context& ctx_;
  const VulkanRendererOptions& opt_;
  UploadStats& stats_;
  std::unordered_map<ViewId, Entry> views_;
  std::vector<uint32_t> free_slots_;
  uint32_t slot_capacity_ = 0;
  uint32_t layer_w_ = 1, layer_h_ = 1;
  Image colors_, depths_;
  Buffer records_;
  Buffer staging_;
  bool storage_changed_ = false;
};

}  // namespace exo::vk
