#include "client/vulkan/vk_render_target.h"

namespace exo::vk {

absl::StatusOr<bool> RenderTarget::Ensure(const Context& ctx, VkRenderPass pass, VkFormat format,
                                          uint32_t width, uint32_t height,
                                          VkRenderPass gbuffer_pass) {
  if (w == width && h == height && fb) return false;
  RenderTarget& t = *this;
  t = RenderTarget{};
  EXO_ASSIGN_OR_RETURN(
      t.color, Image::Create(ctx, width, height, 1, format,
                             VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_SRC_BIT,
                             VK_IMAGE_ASPECT_COLOR_BIT, false));
  EXO_ASSIGN_OR_RETURN(t.depth, Image::Create(ctx, width, height, 1, VK_FORMAT_D32_SFLOAT,
                                              VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT,
                                              VK_IMAGE_ASPECT_DEPTH_BIT, false));
  VkImageView atts[2] = {t.color.view.get(), t.depth.view.get()};
  VkFramebufferCreateInfo fi{VK_STRUCTURE_TYPE_FRAMEBUFFER_CREATE_INFO};
  fi.renderPass = pass;
  fi.attachmentCount = 2;
  fi.pAttachments = atts;
  fi.width = width;
  fi.height = height;
  fi.layers = 1;
  VkFramebuffer raw;
  EXO_VK_RETURN(vkCreateFramebuffer(ctx.device(), &fi, nullptr, &raw));
  t.fb = UniqueFramebuffer(ctx.device(), raw);
  if (gbuffer_pass != VK_NULL_HANDLE) {
    EXO_ASSIGN_OR_RETURN(
        t.gbuffer, Image::Create(ctx, width, height, 1, VK_FORMAT_R32G32B32A32_SFLOAT,
                                 VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_SAMPLED_BIT,
                                 VK_IMAGE_ASPECT_COLOR_BIT, false));
    VkImageView gatts[2] = {t.gbuffer.view.get(), t.depth.view.get()};
    fi.renderPass = gbuffer_pass;
    fi.pAttachments = gatts;
    EXO_VK_RETURN(vkCreateFramebuffer(ctx.device(), &fi, nullptr, &raw));
    t.gbuffer_fb = UniqueFramebuffer(ctx.device(), raw);
    EXO_ASSIGN_OR_RETURN(t.blend_out, Buffer::Create(ctx, VkDeviceSize(width) * height * 4,
                                                     VK_BUFFER_USAGE_STORAGE_BUFFER_BIT));
  }
  EXO_ASSIGN_OR_RETURN(t.readback, Buffer::Create(ctx, VkDeviceSize(width) * height * 8,
                                                  VK_BUFFER_USAGE_TRANSFER_DST_BIT));
  t.w = width;
  t.h = height;
  return true;
}

void RecordReadback(VkCommandBuffer cmd, const RenderTarget& t, uint32_t texel_bytes) {
  VkBufferImageCopy region{};
  region.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  region.imageExtent = {t.w, t.h, 1};
  vkCmdCopyImageToBuffer(cmd, t.color.image.get(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                         t.readback.buffer.get(), 1, &region);
  VkBufferMemoryBarrier hb{VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER};
  hb.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
  hb.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
  hb.srcQueueFamilyIndex = hb.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  hb.buffer = t.readback.buffer.get();
  hb.size = VkDeviceSize(t.w) * t.h * texel_bytes;
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0, 0,
                       nullptr, 1, &hb, 0, nullptr);
}

}  // namespace exo::vk
