#include "client/window/presenter.h"

#include <SDL2/SDL.h>
#include <SDL2/SDL_vulkan.h>
#include <vulkan/vulkan.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <vector>

#include "backends/imgui_impl_sdl.h"
#include "backends/imgui_impl_vulkan.h"
#include "imgui.h"

namespace exo {
namespace {

double MsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
}

absl::Status VkCheck(VkResult r, const char* what) {
  if (r == VK_SUCCESS) return absl::OkStatus();
  return absl::InternalError(std::string(what) + " failed: VkResult " + std::to_string(int(r)));
}
#define EXO_PVK(expr) EXO_RETURN_IF_ERROR(VkCheck((expr), #expr))

void ImGuiVkCheck(VkResult r) {
  if (r != VK_SUCCESS)
    std::fprintf(stderr, "exoview_window: ImGui Vulkan backend: VkResult %d\n", int(r));
}

void Barrier(VkCommandBuffer cmd, VkImage image, VkImageLayout from, VkImageLayout to,
             VkAccessFlags src_access, VkAccessFlags dst_access, VkPipelineStageFlags src_stage,
             VkPipelineStageFlags dst_stage) {
  VkImageMemoryBarrier b{VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER};
  b.oldLayout = from;
  b.newLayout = to;
  b.srcAccessMask = src_access;
  b.dstAccessMask = dst_access;
  b.srcQueueFamilyIndex = b.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.image = image;
  b.subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
  vkCmdPipelineBarrier(cmd, src_stage, dst_stage, 0, 0, nullptr, 0, nullptr, 1, &b);
}

}  // namespace

absl::Status PresenterOptions::Validate() const {
  if (width < 16 || height < 16 || width > 8192 || height > 8192)
    return absl::InvalidArgumentError("window size must be 16..8192 pixels per side");
  return absl::OkStatus();
}

class Presenter::Impl {
 public:
  ~Impl() { Destroy(); }

  absl::Status Init(const PresenterOptions& o) {
    options_ = o;
    if (SDL_Init(SDL_INIT_VIDEO) != 0)
      return absl::UnavailableError(std::string("no display for the window (SDL_Init: ") +
                                    SDL_GetError() +
                                    "); set DISPLAY or WAYLAND_DISPLAY, or run "
                                    "under xvfb-run");
    sdl_ = true;
    window_ = SDL_CreateWindow(o.title.c_str(), SDL_WINDOWPOS_UNDEFINED, SDL_WINDOWPOS_UNDEFINED,
                               o.width, o.height,
                               SDL_WINDOW_VULKAN | SDL_WINDOW_RESIZABLE | SDL_WINDOW_ALLOW_HIGHDPI);
    if (!window_) return absl::UnavailableError(std::string("SDL_CreateWindow: ") + SDL_GetError());
    unsigned n_ext = 0;
    if (!SDL_Vulkan_GetInstanceExtensions(window_, &n_ext, nullptr))
      return absl::UnavailableError(std::string("SDL_Vulkan_GetInstanceExtensions: ") +
                                    SDL_GetError());
    std::vector<const char*> exts(n_ext);
    SDL_Vulkan_GetInstanceExtensions(window_, &n_ext, exts.data());
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.pApplicationName = "exoview_window";
    app.apiVersion = VK_API_VERSION_1_1;
    VkInstanceCreateInfo ii{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    ii.pApplicationInfo = &app;
    ii.enabledExtensionCount = n_ext;
    ii.ppEnabledExtensionNames = exts.data();
    if (VkResult r = vkCreateInstance(&ii, nullptr, &instance_); r != VK_SUCCESS)
      return absl::UnavailableError("no Vulkan driver for the window (vkCreateInstance: " +
                                    std::to_string(int(r)) + "); install mesa-vulkan-drivers");
    if (!SDL_Vulkan_CreateSurface(window_, instance_, &surface_))
      return absl::UnavailableError(std::string("SDL_Vulkan_CreateSurface: ") + SDL_GetError());
    uint32_t n = 0;
    EXO_PVK(vkEnumeratePhysicalDevices(instance_, &n, nullptr));
    std::vector<VkPhysicalDevice> devs(n);
    EXO_PVK(vkEnumeratePhysicalDevices(instance_, &n, devs.data()));
    for (VkPhysicalDevice d : devs) {
      uint32_t nq = 0;
      vkGetPhysicalDeviceQueueFamilyProperties(d, &nq, nullptr);
      std::vector<VkQueueFamilyProperties> qs(nq);
      vkGetPhysicalDeviceQueueFamilyProperties(d, &nq, qs.data());
      for (uint32_t q = 0; q < nq; ++q) {
        VkBool32 present = VK_FALSE;
        vkGetPhysicalDeviceSurfaceSupportKHR(d, q, surface_, &present);
        if ((qs[q].queueFlags & VK_QUEUE_GRAPHICS_BIT) && present) {
          physical_ = d;
          family_ = q;
          break;
        }
      }
      if (physical_) break;
    }
    if (!physical_) return absl::UnavailableError("no Vulkan device can present to this window");
    VkPhysicalDeviceProperties props;
    vkGetPhysicalDeviceProperties(physical_, &props);
    device_name_ = props.deviceName;
    const float prio = 1.0f;
    VkDeviceQueueCreateInfo qi{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    qi.queueFamilyIndex = family_;
    qi.queueCount = 1;
    qi.pQueuePriorities = &prio;
    const char* dev_ext = VK_KHR_SWAPCHAIN_EXTENSION_NAME;
    VkDeviceCreateInfo di{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
    di.queueCreateInfoCount = 1;
    di.pQueueCreateInfos = &qi;
    di.enabledExtensionCount = 1;
    di.ppEnabledExtensionNames = &dev_ext;
    EXO_PVK(vkCreateDevice(physical_, &di, nullptr, &device_));
    vkGetDeviceQueue(device_, family_, 0, &queue_);
    VkCommandPoolCreateInfo pi{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    pi.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
    pi.queueFamilyIndex = family_;
    EXO_PVK(vkCreateCommandPool(device_, &pi, nullptr, &pool_));
    VkCommandBufferAllocateInfo ai{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    ai.commandPool = pool_;
    ai.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    ai.commandBufferCount = 1;
    EXO_PVK(vkAllocateCommandBuffers(device_, &ai, &cmd_));
    VkFenceCreateInfo fi{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    EXO_PVK(vkCreateFence(device_, &fi, nullptr, &fence_));
    VkSemaphoreCreateInfo si{VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO};
    EXO_PVK(vkCreateSemaphore(device_, &si, nullptr, &acquired_));
    EXO_PVK(vkCreateSemaphore(device_, &si, nullptr, &rendered_));

    // Surface format: 8-bit BGRA/RGBA UNORM (the frames are already sRGB-encoded bytes).
    uint32_t nf = 0;
    EXO_PVK(vkGetPhysicalDeviceSurfaceFormatsKHR(physical_, surface_, &nf, nullptr));
    std::vector<VkSurfaceFormatKHR> formats(nf);
    EXO_PVK(vkGetPhysicalDeviceSurfaceFormatsKHR(physical_, surface_, &nf, formats.data()));
    if (formats.empty()) return absl::UnavailableError("the window surface has no formats");
    surface_format_ = formats[0];
    for (const auto& f : formats)
      if (f.format == VK_FORMAT_B8G8R8A8_UNORM || f.format == VK_FORMAT_R8G8B8A8_UNORM) {
        surface_format_ = f;
        break;
      }
    VkFormatProperties fp;
    vkGetPhysicalDeviceFormatProperties(physical_, surface_format_.format, &fp);
    if (!(fp.optimalTilingFeatures & VK_FORMAT_FEATURE_BLIT_DST_BIT))
      return absl::UnavailableError("the swapchain format cannot be a blit destination");

    // Render pass of the overlay: loads the blitted frame, ends in PRESENT_SRC.
    VkAttachmentDescription att{};
    att.format = surface_format_.format;
    att.samples = VK_SAMPLE_COUNT_1_BIT;
    att.loadOp = VK_ATTACHMENT_LOAD_OP_LOAD;
    att.storeOp = VK_ATTACHMENT_STORE_OP_STORE;
    att.stencilLoadOp = VK_ATTACHMENT_LOAD_OP_DONT_CARE;
    att.stencilStoreOp = VK_ATTACHMENT_STORE_OP_DONT_CARE;
    att.initialLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
    att.finalLayout = VK_IMAGE_LAYOUT_PRESENT_SRC_KHR;
    VkAttachmentReference ref{0, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL};
    VkSubpassDescription sub{};
    sub.pipelineBindPoint = VK_PIPELINE_BIND_POINT_GRAPHICS;
    sub.colorAttachmentCount = 1;
    sub.pColorAttachments = &ref;
    VkSubpassDependency dep{};
    dep.srcSubpass = VK_SUBPASS_EXTERNAL;
    dep.dstSubpass = 0;
    dep.srcStageMask = VK_PIPELINE_STAGE_TRANSFER_BIT;
    dep.dstStageMask = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT;
    dep.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
    dep.dstAccessMask = VK_ACCESS_COLOR_ATTACHMENT_READ_BIT | VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
    VkRenderPassCreateInfo rpi{VK_STRUCTURE_TYPE_RENDER_PASS_CREATE_INFO};
    rpi.attachmentCount = 1;
    rpi.pAttachments = &att;
    rpi.subpassCount = 1;
    rpi.pSubpasses = &sub;
    rpi.dependencyCount = 1;
    rpi.pDependencies = &dep;
    EXO_PVK(vkCreateRenderPass(device_, &rpi, nullptr, &render_pass_));

    EXO_RETURN_IF_ERROR(CreateSwapchain());

    // ImGui: context, SDL2 + Vulkan backends, font atlas upload.
    VkDescriptorPoolSize ps{VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, 16};
    VkDescriptorPoolCreateInfo dpi{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    dpi.flags = VK_DESCRIPTOR_POOL_CREATE_FREE_DESCRIPTOR_SET_BIT;
    dpi.maxSets = 16;
    dpi.poolSizeCount = 1;
    dpi.pPoolSizes = &ps;
    EXO_PVK(vkCreateDescriptorPool(device_, &dpi, nullptr, &descriptor_pool_));
    IMGUI_CHECKVERSION();
    ImGui::CreateContext();
    imgui_ = true;
    ImGui::GetIO().IniFilename = nullptr;  // no imgui.ini beside the binary
    ImGui::StyleColorsDark();
    ImGui_ImplSDL2_InitForVulkan(window_);
    ImGui_ImplVulkan_InitInfo info{};
    info.Instance = instance_;
    info.PhysicalDevice = physical_;
    info.Device = device_;
    info.QueueFamily = family_;
    info.Queue = queue_;
    info.DescriptorPool = descriptor_pool_;
    info.MinImageCount = std::max<uint32_t>(2, min_images_);
    info.ImageCount = std::max<uint32_t>(info.MinImageCount, uint32_t(images_.size()));
    info.MSAASamples = VK_SAMPLE_COUNT_1_BIT;
    info.CheckVkResultFn = ImGuiVkCheck;
    if (!ImGui_ImplVulkan_Init(&info, render_pass_))
      return absl::InternalError("ImGui_ImplVulkan_Init failed");
    imgui_vk_ = true;
    EXO_RETURN_IF_ERROR(OneShot([](VkCommandBuffer c) { ImGui_ImplVulkan_CreateFontsTexture(c); }));
    ImGui_ImplVulkan_DestroyFontUploadObjects();
    return absl::OkStatus();
  }

  absl::Status OneShot(const std::function<void(VkCommandBuffer)>& rec) {
    EXO_PVK(vkResetCommandBuffer(cmd_, 0));
    VkCommandBufferBeginInfo bi{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    bi.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    EXO_PVK(vkBeginCommandBuffer(cmd_, &bi));
    rec(cmd_);
    EXO_PVK(vkEndCommandBuffer(cmd_));
    VkSubmitInfo si{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    si.commandBufferCount = 1;
    si.pCommandBuffers = &cmd_;
    EXO_PVK(vkQueueSubmit(queue_, 1, &si, fence_));
    EXO_PVK(vkWaitForFences(device_, 1, &fence_, VK_TRUE, UINT64_MAX));
    EXO_PVK(vkResetFences(device_, 1, &fence_));
    return absl::OkStatus();
  }

  void DestroySwapchain() {
    for (VkFramebuffer fb : framebuffers_) vkDestroyFramebuffer(device_, fb, nullptr);
    for (VkImageView v : views_) vkDestroyImageView(device_, v, nullptr);
    framebuffers_.clear();
    views_.clear();
    images_.clear();
    if (swapchain_) vkDestroySwapchainKHR(device_, swapchain_, nullptr);
    swapchain_ = VK_NULL_HANDLE;
  }

  absl::Status CreateSwapchain() {
    if (device_) vkDeviceWaitIdle(device_);
    DestroySwapchain();
    VkSurfaceCapabilitiesKHR caps;
    EXO_PVK(vkGetPhysicalDeviceSurfaceCapabilitiesKHR(physical_, surface_, &caps));
    int w = 0, h = 0;
    SDL_Vulkan_GetDrawableSize(window_, &w, &h);
    extent_ = caps.currentExtent;
    if (extent_.width == 0xFFFFFFFFu) {
      extent_.width = std::clamp<uint32_t>(w, caps.minImageExtent.width, caps.maxImageExtent.width);
      extent_.height =
          std::clamp<uint32_t>(h, caps.minImageExtent.height, caps.maxImageExtent.height);
    }
    if (extent_.width == 0 || extent_.height == 0) return absl::OkStatus();  // minimised
    if (!(caps.supportedUsageFlags & VK_IMAGE_USAGE_TRANSFER_DST_BIT))
      return absl::UnavailableError("swapchain images cannot be transfer destinations");
    uint32_t nm = 0;
    vkGetPhysicalDeviceSurfacePresentModesKHR(physical_, surface_, &nm, nullptr);
    std::vector<VkPresentModeKHR> modes(nm);
    vkGetPhysicalDeviceSurfacePresentModesKHR(physical_, surface_, &nm, modes.data());
    VkPresentModeKHR mode = VK_PRESENT_MODE_FIFO_KHR;
    if (!options_.vsync)
      for (VkPresentModeKHR want : {VK_PRESENT_MODE_MAILBOX_KHR, VK_PRESENT_MODE_IMMEDIATE_KHR})
        if (std::find(modes.begin(), modes.end(), want) != modes.end()) {
          mode = want;
          break;
        }
    min_images_ = std::max(2u, caps.minImageCount);
    uint32_t count = min_images_ + 1;
    if (caps.maxImageCount) count = std::min(count, caps.maxImageCount);
    VkSwapchainCreateInfoKHR ci{VK_STRUCTURE_TYPE_SWAPCHAIN_CREATE_INFO_KHR};
    ci.surface = surface_;
    ci.minImageCount = count;
    ci.imageFormat = surface_format_.format;
    ci.imageColorSpace = surface_format_.colorSpace;
    ci.imageExtent = extent_;
    ci.imageArrayLayers = 1;
    ci.imageUsage = VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT;
    ci.imageSharingMode = VK_SHARING_MODE_EXCLUSIVE;
    ci.preTransform = caps.currentTransform;
    ci.compositeAlpha = VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR;
    if (!(caps.supportedCompositeAlpha & VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR))
      ci.compositeAlpha = VK_COMPOSITE_ALPHA_INHERIT_BIT_KHR;
    ci.presentMode = mode;
    ci.clipped = VK_TRUE;
    EXO_PVK(vkCreateSwapchainKHR(device_, &ci, nullptr, &swapchain_));
    uint32_t ni = 0;
    EXO_PVK(vkGetSwapchainImagesKHR(device_, swapchain_, &ni, nullptr));
    images_.resize(ni);
    EXO_PVK(vkGetSwapchainImagesKHR(device_, swapchain_, &ni, images_.data()));
    for (VkImage img : images_) {
      VkImageViewCreateInfo vi{VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO};
      vi.image = img;
      vi.viewType = VK_IMAGE_VIEW_TYPE_2D;
      vi.format = surface_format_.format;
      vi.subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
      VkImageView v;
      EXO_PVK(vkCreateImageView(device_, &vi, nullptr, &v));
      views_.push_back(v);
      VkFramebufferCreateInfo fi{VK_STRUCTURE_TYPE_FRAMEBUFFER_CREATE_INFO};
      fi.renderPass = render_pass_;
      fi.attachmentCount = 1;
      fi.pAttachments = &v;
      fi.width = extent_.width;
      fi.height = extent_.height;
      fi.layers = 1;
      VkFramebuffer fb;
      EXO_PVK(vkCreateFramebuffer(device_, &fi, nullptr, &fb));
      framebuffers_.push_back(fb);
    }
    if (imgui_vk_) ImGui_ImplVulkan_SetMinImageCount(min_images_);
    return absl::OkStatus();
  }

  // Staging image (RGBA8, linear tiling, host-visible) of the frame's size.
  absl::Status EnsureStaging(uint32_t w, uint32_t h) {
    if (staging_ && staging_w_ == w && staging_h_ == h) return absl::OkStatus();
    DestroyStaging();
    VkImageCreateInfo ii{VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO};
    ii.imageType = VK_IMAGE_TYPE_2D;
    ii.format = VK_FORMAT_R8G8B8A8_UNORM;
    ii.extent = {w, h, 1};
    ii.mipLevels = 1;
    ii.arrayLayers = 1;
    ii.samples = VK_SAMPLE_COUNT_1_BIT;
    ii.tiling = VK_IMAGE_TILING_LINEAR;
    ii.usage = VK_IMAGE_USAGE_TRANSFER_SRC_BIT;
    ii.initialLayout = VK_IMAGE_LAYOUT_PREINITIALIZED;
    EXO_PVK(vkCreateImage(device_, &ii, nullptr, &staging_));
    VkMemoryRequirements req;
    vkGetImageMemoryRequirements(device_, staging_, &req);
    VkPhysicalDeviceMemoryProperties mp;
    vkGetPhysicalDeviceMemoryProperties(physical_, &mp);
    const VkMemoryPropertyFlags want =
        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    uint32_t type = UINT32_MAX;
    for (uint32_t i = 0; i < mp.memoryTypeCount; ++i)
      if ((req.memoryTypeBits & (1u << i)) && (mp.memoryTypes[i].propertyFlags & want) == want) {
        type = i;
        break;
      }
    if (type == UINT32_MAX) return absl::UnavailableError("no host-visible memory for staging");
    VkMemoryAllocateInfo ai{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
    ai.allocationSize = req.size;
    ai.memoryTypeIndex = type;
    EXO_PVK(vkAllocateMemory(device_, &ai, nullptr, &staging_mem_));
    EXO_PVK(vkBindImageMemory(device_, staging_, staging_mem_, 0));
    EXO_PVK(vkMapMemory(device_, staging_mem_, 0, VK_WHOLE_SIZE, 0, &staging_map_));
    VkImageSubresource sr{VK_IMAGE_ASPECT_COLOR_BIT, 0, 0};
    vkGetImageSubresourceLayout(device_, staging_, &sr, &staging_layout_);
    staging_w_ = w;
    staging_h_ = h;
    staging_initialised_ = false;
    return absl::OkStatus();
  }

  void DestroyStaging() {
    if (staging_map_) vkUnmapMemory(device_, staging_mem_);
    staging_map_ = nullptr;
    if (staging_) vkDestroyImage(device_, staging_, nullptr);
    if (staging_mem_) vkFreeMemory(device_, staging_mem_, nullptr);
    staging_ = VK_NULL_HANDLE;
    staging_mem_ = VK_NULL_HANDLE;
  }

  absl::Status Present(const ImageU8* frame, PresentTimings* t) {
    ImGui::Render();
    ImDrawData* draw = ImGui::GetDrawData();
    const auto t0 = std::chrono::steady_clock::now();
    if (frame) {
      if (frame->empty() || (frame->channels() != 3 && frame->channels() != 4))
        return absl::InvalidArgumentError("Present: frame must be RGB8 or RGBA8");
      EXO_RETURN_IF_ERROR(EnsureStaging(frame->width(), frame->height()));
      const int c = frame->channels();
      const uint8_t* src = frame->data();
      for (int y = 0; y < frame->height(); ++y) {
        uint8_t* dst = static_cast<uint8_t*>(staging_map_) + staging_layout_.offset +
                       size_t(y) * staging_layout_.rowPitch;
        const uint8_t* s = src + size_t(y) * frame->width() * c;
        for (int x = 0; x < frame->width(); ++x, s += c, dst += 4) {
          dst[0] = s[0];
          dst[1] = s[1];
          dst[2] = s[2];
          dst[3] = 255;
        }
      }
      has_frame_ = true;
    }
    if (t) t->upload_ms = MsSince(t0);
    const auto t1 = std::chrono::steady_clock::now();
    if (need_recreate_) {
      EXO_RETURN_IF_ERROR(CreateSwapchain());
      need_recreate_ = false;
    }
    if (!swapchain_ || extent_.width == 0) return absl::OkStatus();  // minimised
    uint32_t index = 0;
    VkResult r =
        vkAcquireNextImageKHR(device_, swapchain_, UINT64_MAX, acquired_, VK_NULL_HANDLE, &index);
    if (r == VK_ERROR_OUT_OF_DATE_KHR) {
      need_recreate_ = true;
      return absl::OkStatus();
    }
    if (r != VK_SUCCESS && r != VK_SUBOPTIMAL_KHR) return VkCheck(r, "vkAcquireNextImageKHR");
    EXO_PVK(vkResetCommandBuffer(cmd_, 0));
    VkCommandBufferBeginInfo bi{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    bi.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    EXO_PVK(vkBeginCommandBuffer(cmd_, &bi));
    VkImage dst = images_[index];
    Barrier(cmd_, dst, VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 0,
            VK_ACCESS_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT,
            VK_PIPELINE_STAGE_TRANSFER_BIT);
    if (has_frame_) {
      Barrier(cmd_, staging_,
              staging_initialised_ ? VK_IMAGE_LAYOUT_GENERAL : VK_IMAGE_LAYOUT_PREINITIALIZED,
              VK_IMAGE_LAYOUT_GENERAL, VK_ACCESS_HOST_WRITE_BIT, VK_ACCESS_TRANSFER_READ_BIT,
              VK_PIPELINE_STAGE_HOST_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT);
      staging_initialised_ = true;
      // Letterbox: keep the frame's aspect ratio inside the window.
      const double sx = double(extent_.width) / staging_w_,
                   sy = double(extent_.height) / staging_h_;
      const double s = std::min(sx, sy);
      const int32_t w = int32_t(staging_w_ * s + 0.5), h = int32_t(staging_h_ * s + 0.5);
      const int32_t x0 = (int32_t(extent_.width) - w) / 2, y0 = (int32_t(extent_.height) - h) / 2;
      if (w < int32_t(extent_.width) || h < int32_t(extent_.height)) {
        VkClearColorValue black{};
        VkImageSubresourceRange range{VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
        vkCmdClearColorImage(cmd_, dst, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, &black, 1, &range);
        Barrier(cmd_, dst, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, VK_ACCESS_TRANSFER_WRITE_BIT,
                VK_ACCESS_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT,
                VK_PIPELINE_STAGE_TRANSFER_BIT);
      }
      VkImageBlit blit{};
      blit.srcSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
      blit.srcOffsets[1] = {int32_t(staging_w_), int32_t(staging_h_), 1};
      blit.dstSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
      blit.dstOffsets[0] = {x0, y0, 0};
      blit.dstOffsets[1] = {x0 + w, y0 + h, 1};
      // Same size: exact copy (nearest); scaled (adaptive resolution): bilinear.
      const bool same = w == int32_t(staging_w_) && h == int32_t(staging_h_);
      vkCmdBlitImage(cmd_, staging_, VK_IMAGE_LAYOUT_GENERAL, dst,
                     VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &blit,
                     same ? VK_FILTER_NEAREST : VK_FILTER_LINEAR);
    } else {
      VkClearColorValue black{};
      VkImageSubresourceRange range{VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
      vkCmdClearColorImage(cmd_, dst, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, &black, 1, &range);
    }
    VkRenderPassBeginInfo rp{VK_STRUCTURE_TYPE_RENDER_PASS_BEGIN_INFO};
    rp.renderPass = render_pass_;
    rp.framebuffer = framebuffers_[index];
    rp.renderArea.extent = extent_;
    vkCmdBeginRenderPass(cmd_, &rp, VK_SUBPASS_CONTENTS_INLINE);
    ImGui_ImplVulkan_RenderDrawData(draw, cmd_);
    vkCmdEndRenderPass(cmd_);
    EXO_PVK(vkEndCommandBuffer(cmd_));
    const VkPipelineStageFlags wait_stage = VK_PIPELINE_STAGE_TRANSFER_BIT;
    VkSubmitInfo si{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    si.waitSemaphoreCount = 1;
    si.pWaitSemaphores = &acquired_;
    si.pWaitDstStageMask = &wait_stage;
    si.commandBufferCount = 1;
    si.pCommandBuffers = &cmd_;
    si.signalSemaphoreCount = 1;
    si.pSignalSemaphores = &rendered_;
    EXO_PVK(vkQueueSubmit(queue_, 1, &si, fence_));
    VkPresentInfoKHR pi{VK_STRUCTURE_TYPE_PRESENT_INFO_KHR};
    pi.waitSemaphoreCount = 1;
    pi.pWaitSemaphores = &rendered_;
    pi.swapchainCount = 1;
    pi.pSwapchains = &swapchain_;
    pi.pImageIndices = &index;
    r = vkQueuePresentKHR(queue_, &pi);
    // One frame in flight: the staging image is rewritten by the next Present.
    EXO_PVK(vkWaitForFences(device_, 1, &fence_, VK_TRUE, UINT64_MAX));
    EXO_PVK(vkResetFences(device_, 1, &fence_));
    if (r == VK_ERROR_OUT_OF_DATE_KHR || r == VK_SUBOPTIMAL_KHR) {
      need_recreate_ = true;
    } else if (r != VK_SUCCESS) {
      return VkCheck(r, "vkQueuePresentKHR");
    }
    if (t) t->submit_ms = MsSince(t1);
    return absl::OkStatus();
  }

  void Destroy() {
    if (device_) vkDeviceWaitIdle(device_);
    if (imgui_vk_) ImGui_ImplVulkan_Shutdown();
    if (imgui_) {
      ImGui_ImplSDL2_Shutdown();
      ImGui::DestroyContext();
    }
    imgui_vk_ = imgui_ = false;
    if (device_) {
      DestroyStaging();
      DestroySwapchain();
      if (descriptor_pool_) vkDestroyDescriptorPool(device_, descriptor_pool_, nullptr);
      if (render_pass_) vkDestroyRenderPass(device_, render_pass_, nullptr);
      if (acquired_) vkDestroySemaphore(device_, acquired_, nullptr);
      if (rendered_) vkDestroySemaphore(device_, rendered_, nullptr);
      if (fence_) vkDestroyFence(device_, fence_, nullptr);
      if (pool_) vkDestroyCommandPool(device_, pool_, nullptr);
      vkDestroyDevice(device_, nullptr);
      device_ = VK_NULL_HANDLE;
    }
    if (surface_) vkDestroySurfaceKHR(instance_, surface_, nullptr);
    surface_ = VK_NULL_HANDLE;
    if (instance_) vkDestroyInstance(instance_, nullptr);
    instance_ = VK_NULL_HANDLE;
    if (window_) SDL_DestroyWindow(window_);
    window_ = nullptr;
    if (sdl_) SDL_Quit();
    sdl_ = false;
  }

  void OnEvent(const SDL_Event& e) {
    if (e.type == SDL_WINDOWEVENT && (e.window.event == SDL_WINDOWEVENT_SIZE_CHANGED ||
                                      e.window.event == SDL_WINDOWEVENT_RESIZED))
      need_recreate_ = true;
  }

  PresenterOptions options_;
  bool sdl_ = false, imgui_ = false, imgui_vk_ = false;
  SDL_Window* window_ = nullptr;
  VkInstance instance_ = VK_NULL_HANDLE;
  VkSurfaceKHR surface_ = VK_NULL_HANDLE;
  VkPhysicalDevice physical_ = VK_NULL_HANDLE;
  uint32_t family_ = 0;
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  VkCommandPool pool_ = VK_NULL_HANDLE;
  VkCommandBuffer cmd_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;
  VkSemaphore acquired_ = VK_NULL_HANDLE, rendered_ = VK_NULL_HANDLE;
  VkSurfaceFormatKHR surface_format_{};
  VkRenderPass render_pass_ = VK_NULL_HANDLE;
  VkDescriptorPool descriptor_pool_ = VK_NULL_HANDLE;
  VkSwapchainKHR swapchain_ = VK_NULL_HANDLE;
  VkExtent2D extent_{};
  uint32_t min_images_ = 2;
  std::vector<VkImage> images_;
  std::vector<VkImageView> views_;
  std::vector<VkFramebuffer> framebuffers_;
  bool need_recreate_ = false;
  VkImage staging_ = VK_NULL_HANDLE;
  VkDeviceMemory staging_mem_ = VK_NULL_HANDLE;
  void* staging_map_ = nullptr;
  VkSubresourceLayout staging_layout_{};
  uint32_t staging_w_ = 0, staging_h_ = 0;
  bool staging_initialised_ = false, has_frame_ = false;
  std::string device_name_;
};

absl::StatusOr<std::unique_ptr<Presenter>> Presenter::Create(const PresenterOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  auto impl = std::make_unique<Impl>();
  EXO_RETURN_IF_ERROR(impl->Init(options));
  return std::unique_ptr<Presenter>(new Presenter(std::move(impl)));
}

Presenter::Presenter(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Presenter::~Presenter() = default;

bool Presenter::ProcessEvent(const SDL_Event& event) {
  impl_->OnEvent(event);
  ImGui_ImplSDL2_ProcessEvent(&event);
  const ImGuiIO& io = ImGui::GetIO();
  if (event.type == SDL_KEYDOWN || event.type == SDL_KEYUP) return io.WantCaptureKeyboard;
  if (event.type == SDL_MOUSEMOTION || event.type == SDL_MOUSEBUTTONDOWN ||
      event.type == SDL_MOUSEBUTTONUP || event.type == SDL_MOUSEWHEEL)
    return io.WantCaptureMouse;
  return false;
}

void Presenter::NewFrame() {
  ImGui_ImplVulkan_NewFrame();
  ImGui_ImplSDL2_NewFrame();
  ImGui::NewFrame();
}

absl::Status Presenter::Present(const ImageU8* frame, PresentTimings* timings) {
  return impl_->Present(frame, timings);
}

int Presenter::width() const { return int(impl_->extent_.width); }
int Presenter::height() const { return int(impl_->extent_.height); }
std::string Presenter::DeviceName() const { return impl_->device_name_; }

}  // namespace exo
