// PRIVATE to client/vulkan: an off-screen render target of one pass (colour + depth
// attachments, framebuffer, host-visible read-back buffer), recreated when the size changes.
// The blend target also holds the deferred pass's G-buffer and the blend.comp output buffer.
#pragma once

#include <cstdint>

#include "client/vulkan/vk_core_internal.h"

namespace exo::vk {

struct RenderTarget {
  uint32_t w = 0, h = 0;
  Image color, depth;
  UniqueFramebuffer fb;
  // Deferred blend only: RGBA32F surface point per pixel + its framebuffer (shares `depth`).
  Image gbuffer;
  UniqueFramebuffer gbuffer_fb;
  Buffer readback;
  Buffer blend_out;  // blend.comp output, W*H RGBA8 (host-visible)

  // (Re)creates the target at w x h for `pass` unless it already has that size. With a
  // non-null `gbuffer_pass` also the G-buffer (for that pass) and blend_out. Returns whether
  // it was recreated.
  absl::StatusOr<bool> Ensure(const Context& ctx, VkRenderPass pass, VkFormat format, uint32_t w,
                              uint32_t h, VkRenderPass gbuffer_pass = VK_NULL_HANDLE);
};

// Records the copy of t.color (TRANSFER_SRC_OPTIMAL) to t.readback and its host visibility.
void RecordReadback(VkCommandBuffer cmd, const RenderTarget& t, uint32_t texel_bytes);

}  // namespace exo::vk
