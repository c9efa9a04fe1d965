// PRIVATE to client/vulkan: included only by this folder's .cc files, never by a public header.
// Small owning (RAII, move-only) wrappers for every Vulkan object the renderer creates, and the
// device context: instance (+ optional VK_LAYER_KHRONOS_validation with a debug messenger that
// records every error), physical-device selection, logical device, queue, command pool,
// host-visible buffers and 2D-array images with one-shot command submission.
#pragma once

#include <vulkan/vulkan.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "common/status.h"

namespace exo::vk {

// "VK_ERROR_OUT_OF_HOST_MEMORY (-1)".
std::string ResultName(VkResult r);
absl::Status Check(VkResult r, const char* what);
#define EXO_VK_RETURN(expr) EXO_RETURN_IF_ERROR(::exo::vk::Check((expr), #expr))

// A device-owned handle destroyed by `Destroy(device, handle, nullptr)`.
template <typename T, void (*Destroy)(VkDevice, T, const VkAllocationCallbacks*)>
class DeviceHandle {
 public:
  DeviceHandle() = default;
  DeviceHandle(VkDevice device, T handle) : device_(device), handle_(handle) {}
  DeviceHandle(const DeviceHandle&) = delete;
  DeviceHandle& operator=(const DeviceHandle&) = delete;
  DeviceHandle(DeviceHandle&& o) noexcept
      : device_(o.device_), handle_(std::exchange(o.handle_, VK_NULL_HANDLE)) {}
  DeviceHandle& operator=(DeviceHandle&& o) noexcept {
    if (this != &o) {
      Reset();
      device_ = o.device_;
      handle_ = std::exchange(o.handle_, VK_NULL_HANDLE);
    }
    return *this;
  }
  ~DeviceHandle() { Reset(); }
  void Reset() {
    if (handle_ != VK_NULL_HANDLE) Destroy(device_, handle_, nullptr);
    handle_ = VK_NULL_HANDLE;
  }
  T get() const { return handle_; }
  explicit operator bool() const { return handle_ != VK_NULL_HANDLE; }

 private:
  VkDevice device_ = VK_NULL_HANDLE;
  T handle_ = VK_NULL_HANDLE;
};

using UniqueBuffer = DeviceHandle<VkBuffer, vkDestroyBuffer>;
using UniqueMemory = DeviceHandle<VkDeviceMemory, vkFreeMemory>;
using UniqueImage = DeviceHandle<VkImage, vkDestroyImage>;
using UniqueImageView = DeviceHandle<VkImageView, vkDestroyImageView>;
using UniqueBufferView = DeviceHandle<VkBufferView, vkDestroyBufferView>;
using UniqueSampler = DeviceHandle<VkSampler, vkDestroySampler>;
using UniqueShaderModule = DeviceHandle<VkShaderModule, vkDestroyShaderModule>;
using UniquePipeline = DeviceHandle<VkPipeline, vkDestroyPipeline>;
using UniquePipelineLayout = DeviceHandle<VkPipelineLayout, vkDestroyPipelineLayout>;
using UniqueDescriptorSetLayout =
    DeviceHandle<VkDescriptorSetLayout, vkDestroyDescriptorSetLayout>;
using UniqueDescriptorPool = DeviceHandle<VkDescriptorPool, vkDestroyDescriptorPool>;
using UniqueRenderPass = DeviceHandle<VkRenderPass, vkDestroyRenderPass>;
using UniqueFramebuffer = DeviceHandle<VkFramebuffer, vkDestroyFramebuffer>;
using UniqueCommandPool = DeviceHandle<VkCommandPool, vkDestroyCommandPool>;
using UniqueFence = DeviceHandle<VkFence, vkDestroyFence>;

class Context;

// A buffer in host-visible, coherent memory, persistently mapped (on lavapipe all memory is
// host memory, so "upload" is one memcpy; byte counts are what a discrete GPU would transfer).
struct Buffer {
  UniqueBuffer buffer;
  UniqueMemory memory;
  void* mapped = nullptr;
  VkDeviceSize size = 0;
  static absl::StatusOr<Buffer> Create(const Context& ctx, VkDeviceSize size,
                                       VkBufferUsageFlags usage);
};

// A 2D (array) image with one view over all layers.
struct Image {
  UniqueImage image;
  UniqueMemory memory;
  UniqueImageView view;
  VkFormat format = VK_FORMAT_UNDEFINED;
  uint32_t width = 0, height = 0, layers = 0;
  VkImageLayout layout = VK_IMAGE_LAYOUT_UNDEFINED;
  static absl::StatusOr<Image> Create(const Context& ctx, uint32_t width, uint32_t height,
                                      uint32_t layers, VkFormat format, VkImageUsageFlags usage,
                                      VkImageAspectFlags aspect, bool array_view);
};

// Records a layout transition of `layers` layers starting at `base_layer`.
void TransitionImage(VkCommandBuffer cmd, VkImage image, VkImageAspectFlags aspect,
                     VkImageLayout from, VkImageLayout to, uint32_t base_layer = 0,
                     uint32_t layer_count = VK_REMAINING_ARRAY_LAYERS);

struct ContextOptions {
  bool enable_validation = false;
};

class Context {
 public:
  static absl::StatusOr<std::unique_ptr<Context>> Create(const ContextOptions& options);
  ~Context();
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  VkDevice device() const { return device_; }
  VkPhysicalDevice physical_device() const { return physical_; }
  VkQueue queue() const { return queue_; }
  const std::string& device_name() const { return device_name_; }
  absl::StatusOr<uint32_t> FindMemoryType(uint32_t type_bits, VkMemoryPropertyFlags props) const;
  // Records with `record`, submits, waits for completion.
  absl::Status Submit(const std::function<void(VkCommandBuffer)>& record) const;

  // Validation messages of severity ERROR seen so far (empty without validation).
  std::vector<std::string> ValidationErrors() const;
  void RecordValidationMessage(std::string msg);
  bool validation_enabled() const { return messenger_ != VK_NULL_HANDLE; }

 private:
  Context() = default;
  VkInstance instance_ = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
  VkPhysicalDevice physical_ = VK_NULL_HANDLE;
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  uint32_t queue_family_ = 0;
  VkCommandPool pool_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;
  VkPhysicalDeviceMemoryProperties mem_props_{};
  std::string device_name_;
  mutable std::mutex mu_;
  std::vector<std::string> validation_errors_;
};

}  // namespace exo::vk
