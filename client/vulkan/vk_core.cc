#include "client/vulkan/vk_core_internal.h"

#include <cstring>

#include "absl/strings/str_cat.h"

namespace exo::vk {

std::string ResultName(VkResult r) {
  const char* name = "VK_ERROR_UNKNOWN";
  switch (r) {
#define EXO_CASE(x) \
  case x:           \
    name = #x;      \
    break;
    EXO_CASE(VK_SUCCESS)
    EXO_CASE(VK_NOT_READY)
    EXO_CASE(VK_TIMEOUT)
    EXO_CASE(VK_INCOMPLETE)
    EXO_CASE(VK_ERROR_OUT_OF_HOST_MEMORY)
    EXO_CASE(VK_ERROR_OUT_OF_DEVICE_MEMORY)
    EXO_CASE(VK_ERROR_INITIALIZATION_FAILED)
    EXO_CASE(VK_ERROR_DEVICE_LOST)
    EXO_CASE(VK_ERROR_MEMORY_MAP_FAILED)
    EXO_CASE(VK_ERROR_LAYER_NOT_PRESENT)
    EXO_CASE(VK_ERROR_EXTENSION_NOT_PRESENT)
    EXO_CASE(VK_ERROR_FEATURE_NOT_PRESENT)
    EXO_CASE(VK_ERROR_INCOMPATIBLE_DRIVER)
    EXO_CASE(VK_ERROR_TOO_MANY_OBJECTS)
    EXO_CASE(VK_ERROR_FORMAT_NOT_SUPPORTED)
#undef EXO_CASE
    default:
      break;
  }
  return absl::StrCat(name, " (", static_cast<int>(r), ")");
}

absl::Status Check(VkResult r, const char* what) {
  if (r == VK_SUCCESS) return absl::OkStatus();
  const std::string msg = absl::StrCat("Vulkan call failed: ", what, " -> ", ResultName(r));
  if (r == VK_ERROR_OUT_OF_HOST_MEMORY || r == VK_ERROR_OUT_OF_DEVICE_MEMORY ||
      r == VK_ERROR_TOO_MANY_OBJECTS)
    return absl::ResourceExhaustedError(msg);
  if (r == VK_ERROR_INCOMPATIBLE_DRIVER || r == VK_ERROR_LAYER_NOT_PRESENT ||
      r == VK_ERROR_EXTENSION_NOT_PRESENT || r == VK_ERROR_FEATURE_NOT_PRESENT ||
      r == VK_ERROR_FORMAT_NOT_SUPPORTED)
    return absl::UnavailableError(msg);
  return absl::InternalError(msg);
}

absl::StatusOr<Buffer> Buffer::Create(const Context& ctx, VkDeviceSize size,
                                      VkBufferUsageFlags usage) {
  Buffer b;
  b.size = size;
  VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
  info.size = size == 0 ? 16 : size;
  info.usage = usage;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  VkBuffer raw = VK_NULL_HANDLE;
  EXO_VK_RETURN(vkCreateBuffer(ctx.device(), &info, nullptr, &raw));
  b.buffer = UniqueBuffer(ctx.device(), raw);
  VkMemoryRequirements req;
  vkGetBufferMemoryRequirements(ctx.device(), raw, &req);
  EXO_ASSIGN_OR_RETURN(uint32_t type,
                       ctx.FindMemoryType(req.memoryTypeBits,
                                          VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT |
                                              VK_MEMORY_PROPERTY_HOST_COHERENT_BIT));
  VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
  alloc.allocationSize = req.size;
  alloc.memoryTypeIndex = type;
  VkDeviceMemory mem = VK_NULL_HANDLE;
  EXO_VK_RETURN(vkAllocateMemory(ctx.device(), &alloc, nullptr, &mem));
  b.memory = UniqueMemory(ctx.device(), mem);
  EXO_VK_RETURN(vkBindBufferMemory(ctx.device(), raw, mem, 0));
  EXO_VK_RETURN(vkMapMemory(ctx.device(), mem, 0, VK_WHOLE_SIZE, 0, &b.mapped));
  return b;
}

absl::StatusOr<Image> Image::Create(const Context& ctx, uint32_t width, uint32_t height,
                                    uint32_t layers, VkFormat format, VkImageUsageFlags usage,
                                    VkImageAspectFlags aspect, bool array_view) {
  Image img;
  img.format = format;
  img.width = width;
  img.height = height;
  img.layers = layers;
  VkImageCreateInfo info{VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO};
  info.imageType = VK_IMAGE_TYPE_2D;
  info.format = format;
  info.extent = {width, height, 1};
  info.mipLevels = 1;
  info.arrayLayers = layers;
  info.samples = VK_SAMPLE_COUNT_1_BIT;
  info.tiling = VK_IMAGE_TILING_OPTIMAL;
  info.usage = usage;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  info.initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
  VkImage raw = VK_NULL_HANDLE;
  EXO_VK_RETURN(vkCreateImage(ctx.device(), &info, nullptr, &raw));
  img.image = UniqueImage(ctx.device(), raw);
  VkMemoryRequirements req;
  vkGetImageMemoryRequirements(ctx.device(), raw, &req);
  EXO_ASSIGN_OR_RETURN(uint32_t type, ctx.FindMemoryType(req.memoryTypeBits,
                                                         VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT));
  VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
  alloc.allocationSize = req.size;
  alloc.memoryTypeIndex = type;
  VkDeviceMemory mem = VK_NULL_HANDLE;
  EXO_VK_RETURN(vkAllocateMemory(ctx.device(), &alloc, nullptr, &mem));
  img.memory = UniqueMemory(ctx.device(), mem);
  EXO_VK_RETURN(vkBindImageMemory(ctx.device(), raw, mem, 0));
  VkImageViewCreateInfo vinfo{VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO};
  vinfo.image = raw;
  vinfo.viewType = array_view ? VK_IMAGE_VIEW_TYPE_2D_ARRAY : VK_IMAGE_VIEW_TYPE_2D;
  vinfo.format = format;
  vinfo.subresourceRange = {aspect, 0, 1, 0, array_view ? layers : 1};
  VkImageView view = VK_NULL_HANDLE;
  EXO_VK_RETURN(vkCreateImageView(ctx.device(), &vinfo, nullptr, &view));
  img.view = UniqueImageView(ctx.device(), view);
  return img;
}

void TransitionImage(VkCommandBuffer cmd, VkImage image, VkImageAspectFlags aspect,
                     VkImageLayout from, VkImageLayout to, uint32_t base_layer,
                     uint32_t layer_count) {
  VkImageMemoryBarrier b{VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER};
  b.oldLayout = from;
  b.newLayout = to;
  b.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.image = image;
  b.subresourceRange = {aspect, 0, 1, base_layer, layer_count};
  // Conservative (all-commands) barriers: transitions happen at upload time, not per draw.
  b.srcAccessMask = VK_ACCESS_MEMORY_WRITE_BIT;
  b.dstAccessMask = VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT;
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                       VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 0, 0, nullptr, 0, nullptr, 1, &b);
}

namespace {

constexpr const char* kValidationLayer = "VK_LAYER_KHRONOS_validation";

VKAPI_ATTR VkBool32 VKAPI_CALL DebugCallback(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                             VkDebugUtilsMessageTypeFlagsEXT,
                                             const VkDebugUtilsMessengerCallbackDataEXT* data,
                                             void* user) {
  if (severity & (VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT |
                  VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT)) {
    // Warnings count too: validation warnings on this renderer are real bugs (sync, layouts).
    static_cast<Context*>(user)->RecordValidationMessage(
        data && data->pMessage ? data->pMessage : "(no message)");
  }
  return VK_FALSE;
}

bool HasLayer(const char* name) {
  uint32_t n = 0;
  vkEnumerateInstanceLayerProperties(&n, nullptr);
  std::vector<VkLayerProperties> layers(n);
  vkEnumerateInstanceLayerProperties(&n, layers.data());
  for (const auto& l : layers)
    if (std::strcmp(l.layerName, name) == 0) return true;
  return false;
}

}  // namespace

void Context::RecordValidationMessage(std::string msg) {
  std::lock_guard<std::mutex> lock(mu_);
  if (validation_errors_.size() < 1000) validation_errors_.push_back(std::move(msg));
}

std::vector<std::string> Context::ValidationErrors() const {
  std::lock_guard<std::mutex> lock(mu_);
  return validation_errors_;
}

absl::StatusOr<std::unique_ptr<Context>> Context::Create(const ContextOptions& options) {
  std::unique_ptr<Context> ctx(new Context());
  if (options.enable_validation && !HasLayer(kValidationLayer)) {
    return absl::UnavailableError(
        "Vulkan validation requested but VK_LAYER_KHRONOS_validation is not installed "
        "(apt-get install vulkan-validationlayers)");
  }
  VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
  app.pApplicationName = "exoview";
  app.apiVersion = VK_API_VERSION_1_1;
  VkInstanceCreateInfo info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
  info.pApplicationInfo = &app;
  std::vector<const char*> layers, exts;
  VkDebugUtilsMessengerCreateInfoEXT dbg{VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT};
  dbg.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT |
                        VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT;
  dbg.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT |
                    VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                    VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
  dbg.pfnUserCallback = DebugCallback;
  dbg.pUserData = ctx.get();
  if (options.enable_validation) {
    layers.push_back(kValidationLayer);
    exts.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
    info.pNext = &dbg;  // also catches errors in vkCreateInstance/vkDestroyInstance
  }
  info.enabledLayerCount = static_cast<uint32_t>(layers.size());
  info.ppEnabledLayerNames = layers.data();
  info.enabledExtensionCount = static_cast<uint32_t>(exts.size());
  info.ppEnabledExtensionNames = exts.data();
  VkResult r = vkCreateInstance(&info, nullptr, &ctx->instance_);
  if (r == VK_ERROR_INCOMPATIBLE_DRIVER) {
    return absl::UnavailableError(
        "no Vulkan driver found (vkCreateInstance: VK_ERROR_INCOMPATIBLE_DRIVER); install "
        "mesa-vulkan-drivers and point VK_DRIVER_FILES at "
        "/usr/share/vulkan/icd.d/lvp_icd.x86_64.json for lavapipe");
  }
  EXO_RETURN_IF_ERROR(Check(r, "vkCreateInstance"));
  if (options.enable_validation) {
    auto create = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(ctx->instance_, "vkCreateDebugUtilsMessengerEXT"));
    if (create == nullptr) return absl::UnavailableError("VK_EXT_debug_utils unavailable");
    EXO_VK_RETURN(create(ctx->instance_, &dbg, nullptr, &ctx->messenger_));
  }

  uint32_t n = 0;
  EXO_VK_RETURN(vkEnumeratePhysicalDevices(ctx->instance_, &n, nullptr));
  if (n == 0) {
    return absl::UnavailableError(
        "no Vulkan physical device available (is VK_DRIVER_FILES / VK_ICD_FILENAMES pointing at "
        "a valid ICD such as /usr/share/vulkan/icd.d/lvp_icd.x86_64.json?)");
  }
  std::vector<VkPhysicalDevice> devices(n);
  EXO_VK_RETURN(vkEnumeratePhysicalDevices(ctx->instance_, &n, devices.data()));
  // Prefer a device with a graphics queue; discrete > integrated > cpu among them.
  int best_score = -1;
  for (VkPhysicalDevice d : devices) {
    VkPhysicalDeviceProperties props;
    vkGetPhysicalDeviceProperties(d, &props);
    uint32_t qn = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(d, &qn, nullptr);
    std::vector<VkQueueFamilyProperties> qs(qn);
    vkGetPhysicalDeviceQueueFamilyProperties(d, &qn, qs.data());
    for (uint32_t i = 0; i < qn; ++i) {
      if (!(qs[i].queueFlags & VK_QUEUE_GRAPHICS_BIT)) continue;
      const int score = props.deviceType == VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU     ? 3
                        : props.deviceType == VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU ? 2
                                                                                     : 1;
      if (score > best_score) {
        best_score = score;
        ctx->physical_ = d;
        ctx->queue_family_ = i;
        ctx->device_name_ = props.deviceName;
      }
      break;
    }
  }
  if (ctx->physical_ == VK_NULL_HANDLE)
    return absl::UnavailableError("no Vulkan device with a graphics queue");
  vkGetPhysicalDeviceMemoryProperties(ctx->physical_, &ctx->mem_props_);

  const float prio = 1.0f;
  VkDeviceQueueCreateInfo qinfo{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
  qinfo.queueFamilyIndex = ctx->queue_family_;
  qinfo.queueCount = 1;
  qinfo.pQueuePriorities = &prio;
  VkDeviceCreateInfo dinfo{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
  dinfo.queueCreateInfoCount = 1;
  dinfo.pQueueCreateInfos = &qinfo;
  EXO_VK_RETURN(vkCreateDevice(ctx->physical_, &dinfo, nullptr, &ctx->device_));
  vkGetDeviceQueue(ctx->device_, ctx->queue_family_, 0, &ctx->queue_);
  VkCommandPoolCreateInfo pinfo{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pinfo.flags = VK_COMMAND_POOL_CREATE_TRANSIENT_BIT;
  pinfo.queueFamilyIndex = ctx->queue_family_;
  EXO_VK_RETURN(vkCreateCommandPool(ctx->device_, &pinfo, nullptr, &ctx->pool_));
  VkFenceCreateInfo finfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
  EXO_VK_RETURN(vkCreateFence(ctx->device_, &finfo, nullptr, &ctx->fence_));
  return ctx;
}

Context::~Context() {
  if (device_ != VK_NULL_HANDLE) {
    vkDeviceWaitIdle(device_);
    if (fence_ != VK_NULL_HANDLE) vkDestroyFence(device_, fence_, nullptr);
    if (pool_ != VK_NULL_HANDLE) vkDestroyCommandPool(device_, pool_, nullptr);
    vkDestroyDevice(device_, nullptr);
  }
  if (messenger_ != VK_NULL_HANDLE) {
    auto destroy = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
    if (destroy) destroy(instance_, messenger_, nullptr);
  }
  if (instance_ != VK_NULL_HANDLE) vkDestroyInstance(instance_, nullptr);
}

absl::StatusOr<uint32_t> Context::FindMemoryType(uint32_t type_bits,
                                                 VkMemoryPropertyFlags props) const {
  for (uint32_t i = 0; i < mem_props_.memoryTypeCount; ++i) {
    if ((type_bits & (1u << i)) && (mem_props_.memoryTypes[i].propertyFlags & props) == props)
      return i;
  }
  return absl::ResourceExhaustedError(
      absl::StrCat("no Vulkan memory type with properties 0x", absl::Hex(props)));
}

absl::Status Context::Submit(const std::function<void(VkCommandBuffer)>& record) const {
  VkCommandBufferAllocateInfo ainfo{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  ainfo.commandPool = pool_;
  ainfo.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  ainfo.commandBufferCount = 1;
  VkCommandBuffer cmd = VK_NULL_HANDLE;
  EXO_VK_RETURN(vkAllocateCommandBuffers(device_, &ainfo, &cmd));
  struct Free {
    VkDevice d;
    VkCommandPool p;
    VkCommandBuffer c;
    ~Free() { vkFreeCommandBuffers(d, p, 1, &c); }
  } free_cmd{device_, pool_, cmd};
  VkCommandBufferBeginInfo binfo{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  binfo.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  EXO_VK_RETURN(vkBeginCommandBuffer(cmd, &binfo));
  record(cmd);
  EXO_VK_RETURN(vkEndCommandBuffer(cmd));
  VkSubmitInfo sinfo{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  sinfo.commandBufferCount = 1;
  sinfo.pCommandBuffers = &cmd;
  EXO_VK_RETURN(vkResetFences(device_, 1, &fence_));
  EXO_VK_RETURN(vkQueueSubmit(queue_, 1, &sinfo, fence_));
  EXO_VK_RETURN(vkWaitForFences(device_, 1, &fence_, VK_TRUE, UINT64_MAX));
  return absl::OkStatus();
}

}  // namespace exo::vk
