#include "client/vulkan/vulkan_renderer.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <unordered_map>
#include <unordered_set>

#include <glm/gtc/type_ptr.hpp>

#include "absl/hash/hash.h"
#include "absl/types/span.h"
#include "client/vulkan/vk_core_internal.h"
#include "common/lumigraph/cpu_renderer.h"
#include "shaders/blend.comp.h"
#include "shaders/blend.frag.h"
#include "shaders/blend.vert.h"
#include "shaders/cellid.frag.h"
#include "shaders/viewdepth.frag.h"
#include "shaders/gbuffer.frag.h"
#include "shaders/fullscreen.vert.h"

namespace exo {
namespace {

using vk::Buffer;
using Clock = std::chrono::steady_clock;

double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// std430 record of one stored view (lumigraph_common.glsl BlendView), 96 bytes.
// A view record: 5 RGBA32F texels of the Views texel buffer (shaders/blend.frag): rows of
// P = K [R^T | -R^T c] (local point -> (z u, z v, z)), centre + exposure, and width, height,
// layer, valid as floats (exact below 2^24).
struct GpuView {
  glm::vec4 p0, p1, p2;
  glm::vec4 centre_exposure;
  glm::vec4 size_layer;
};
static_assert(sizeof(GpuView) == 80);

// std140 Frame block (lumigraph_common.glsl).
constexpr int kBgViewTexels = 5;  // per background view: cam_from_local columns, K, size/layer/E
struct GpuFrame {
  glm::mat4 clip_from_local;
  glm::vec4 cam_centre_cell;
  glm::vec4 weights;
  glm::vec4 background;
  glm::ivec4 iparams;
  // Background at infinity: columns of local_from_pixel (R K^-1), the number of background
  // views, and per view (blend::BlendView): cam_from_local columns 0..2, intrinsics,
  // (width, height, texture layer, exposure).
  glm::vec4 local_from_pixel[3];
  glm::ivec4 bg_params;
  glm::vec4 bg_views[kBgViewTexels * blend::kMaxBackgroundViews];
};
static_assert(sizeof(GpuFrame) == 128 + 48 + 16 + 16 * kBgViewTexels * blend::kMaxBackgroundViews);

// Colour layers: the stored sRGB8 texels decoded to LINEAR once at upload and kept as UNORM16
// (quantisation 1.5e-5 in linear, far below the golden tolerance), so the texture unit filters
// linear values directly: the decode-before-filter convention of blend_math.h without the
// per-texel sRGB decode of an _SRGB format in every fetch (measured: docs/vulkan.md).
constexpr VkFormat kColorFormat = VK_FORMAT_R16G16B16A16_UNORM;
constexpr uint32_t kColorTexelBytes = 8;

const std::array<uint16_t, 256>& Linear16Lut() {
  static const std::array<uint16_t, 256> lut = [] {
    std::array<uint16_t, 256> t{};
    for (int i = 0; i < 256; ++i)
      t[i] = uint16_t(std::lround(blend::SrgbToLinear(blend::U8ToUnit(uint8_t(i))) * 65535.0));
    return t;
  }();
  return lut;
}

constexpr uint32_t kEmptyKey = 0xFFFFFFFFu;
constexpr uint32_t kTombKeyLo = 0xFFFFFFFEu;
constexpr uint32_t kNoSlot = 0xFFFFFFFFu;

// Same function as CellHash32 in shaders/lumigraph_common.glsl.
uint32_t CellHash32(uint32_t lo, uint32_t hi) {
  uint32_t h = (lo * 0x9E3779B1u) ^ (hi * 0x85EBCA77u + 0x165667B1u);
  h ^= h >> 15;
  h *= 0x2C1B3C6Du;
  h ^= h >> 12;
  return h;
}

uint64_t Mix(uint64_t a, uint64_t b) { return absl::HashOf(a, b); }

uint64_t ViewFingerprint(const StoredView& v) {
  const auto& c = v.camera;
  uint64_t h = absl::HashOf(c.fx, c.fy, c.cx, c.cy, c.width, c.height, v.exposure,
                            v.local_from_cam.rotation.w, v.local_from_cam.rotation.x,
                            v.local_from_cam.rotation.y, v.local_from_cam.rotation.z,
                            v.local_from_cam.translation.x, v.local_from_cam.translation.y,
                            v.local_from_cam.translation.z);
  h = Mix(h, absl::Hash<absl::Span<const uint8_t>>{}(absl::MakeConstSpan(v.color.span())));
  h = Mix(h, absl::Hash<absl::Span<const float>>{}(absl::MakeConstSpan(v.depth_m.span())));
  return h;
}

// Vulkan clip space from a pinhole camera: x_ndc = 2 (u + 0.5) / W - 1 (pixel centres at
// integers, camera.h), y down (as Vulkan's NDC), depth in [0,1] between near and far.
glm::dmat4 ClipFromCam(const PinholeCamera& cam, double n, double f) {
  glm::dmat4 p(0.0);  // column-major: p[col][row]
  p[0][0] = 2.0 * cam.fx / cam.width;
  p[2][0] = 2.0 * (cam.cx + 0.5) / cam.width - 1.0;
  p[1][1] = 2.0 * cam.fy / cam.height;
  p[2][1] = 2.0 * (cam.cy + 0.5) / cam.height - 1.0;
  p[2][2] = f / (f - n);
  p[3][2] = -f * n / (f - n);
  p[2][3] = 1.0;
  return p;
}

}  // namespace

ImageF BakeDiscontinuities(const ImageF& depth_m, int radius_px, float delta_z_m,
                           float delta_z_rel) {
  const int w = depth_m.width(), h = depth_m.height();
  ImageF out(w, h, 1, 0.0f);
  const int r = radius_px;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const float z = depth_m.at(x, y);
      if (!blend::ValidDepth(z)) continue;  // stays 0: invalid
      bool keep = true;
      if (r > 0) {
        // blend::Validity's discontinuity loop, verbatim.
        const float dz = delta_z_m + delta_z_rel * z;
        for (int dy = -r; dy <= r && keep; dy += r) {
          for (int dx = -r; dx <= r; dx += r) {
            if (dx == 0 && dy == 0) continue;
            const int qx = x + dx, qy = y + dy;
            if (qx < 0 || qy < 0 || qx >= w || qy >= h) continue;
            const float zq = depth_m.at(qx, qy);
            if (!blend::ValidDepth(zq) || std::abs(zq - z) > dz) {
              keep = false;
              break;
            }
          }
        }
      }
      if (keep) out.at(x, y) = z;
    }
  }
  return out;
}

float BlendWeightUpperBound(const glm::dvec3& m, double r, const glm::dvec3& c_o,
                            const glm::dvec3& c_i, const blend::BlendOptions& bo) {
  // See Impl::RankRefs for the derivation. Directional: each ray turns by at most asin(r / D)
  // as x moves in the ball, so the angle at x is >= the angle at m minus both turns.
  const glm::dvec3 a = c_o - m, b = c_i - m;
  const double d_o = glm::length(a), d_i = glm::length(b);
  double w_d = 1.0;
  if (d_o > r && d_i > r) {
    // cos(max(0, theta - delta)) with theta = angle(a, b), delta = asin(r/d_o) + asin(r/d_i) < pi,
    // without trigonometric calls: cos/sin of delta by angle addition, then
    // theta <= delta <=> cos(theta) >= cos(delta), else cos(theta - delta) by angle subtraction.
    const double cos_t = std::clamp(glm::dot(a, b) / (d_o * d_i), -1.0, 1.0);
    const double sin_t = std::sqrt(std::max(0.0, 1.0 - cos_t * cos_t));
    const double so = r / d_o, si = r / d_i;
    const double co = std::sqrt(1.0 - so * so), ci = std::sqrt(1.0 - si * si);
    const double cos_d = co * ci - so * si, sin_d = so * ci + co * si;
    w_d = cos_t >= cos_d ? 1.0 : std::max(0.0, cos_t * cos_d + sin_t * sin_d);
  }
  // Positional: decreasing in |c_i - x| >= d_i - r, increasing in |c_o - x| <= d_o + r.
  const double ratio =
      std::max(0.0, d_i - r) / std::max(d_o + r, double(blend::kMinDistance));
  const double w_p = std::clamp(
      bo.positional_mode == blend::PositionalMode::kPrinted ? 1.0 - ratio : 2.0 - ratio, 0.0,
      1.0);
  const double w =
      std::max(bo.lambda * w_d + (1.0 - bo.lambda) * w_p, double(bo.min_weight));
  return float(w * (1.0 + 1e-4) + 1e-6);  // slack for the shader's float rounding
}

absl::Status VulkanRendererOptions::Validate() const {
  if (max_refs_per_cell < 1 || max_refs_per_cell > 1024)
    return absl::InvalidArgumentError(
        absl::StrCat("max_refs_per_cell must be in [1,1024], got ", max_refs_per_cell));
  if (!(near_m > 0.0f) || !(far_m > near_m) || !std::isfinite(far_m))
    return absl::InvalidArgumentError("need 0 < near_m < far_m < inf");
  blend::BlendOptions b;
  b.discontinuity_radius_px = bake_discontinuity_radius_px;
  b.discontinuity_delta_z_m = bake_discontinuity_delta_z_m;
  b.discontinuity_delta_z_rel = bake_discontinuity_delta_z_rel;
  b.background_guard_radius_px = bake_background_guard_radius_px;
  return b.Validate();
}

class VulkanRenderer::Impl {
 public:
  VulkanRendererOptions opt;
  std::unique_ptr<vk::Context> ctx;
  UploadStats stats;
  CellGrid grid;

  // ---- views ----
  struct ViewEntry {
    uint32_t slot = 0;
    uint64_t fingerprint = 0;
    blend::BlendView params;      // as the CPU reference builds it (MakeBlendView)
    bool has_background = false;  // some pixel of the baked background mask is set
  };
  std::unordered_map<ViewId, ViewEntry> views;
  std::vector<uint32_t> free_slots;
  uint32_t slot_capacity = 0;
  uint32_t layer_w = 1, layer_h = 1;
  vk::Image colors, depths;
  Buffer view_records;
  Buffer staging;

  // ---- cells ----
  struct CellEntry {
    uint32_t table_index = 0;
    uint32_t slab = 0;
    std::vector<ViewId> refs;
  };
  std::unordered_map<CellId, CellEntry> cells;
  std::unordered_map<ViewId, std::unordered_set<CellId>> cells_of_view;  // reverse index
  std::vector<glm::uvec4> table;  // host mirror of the GPU hash table
  uint32_t max_probe = 0;         // largest displacement of a resident key (lookup bound)
  uint32_t tombstones = 0;
  Buffer table_buf;
  std::vector<uint32_t> free_slabs;
  uint32_t slab_capacity = 0;
  Buffer refs_buf;
  // Per-frame ranked copy of every slab (RankRefs): 2 RGBA32UI texels per reference slot, same
  // slot index as refs_buf, sorted per cell by an upper bound of the blend weight this frame.
  Buffer ranked_buf;
  std::vector<std::pair<float, uint32_t>> rank_scratch;

  // ---- chunks ----
  struct ChunkGpu {
    uint64_t version = 0;
    Buffer vertices, indices;
    uint32_t index_count = 0;
  };
  std::map<uint64_t, ChunkGpu> chunks;

  // ---- pipelines ----
  vk::UniqueDescriptorSetLayout set_layout;
  vk::UniquePipelineLayout pipe_layout;
  vk::UniqueDescriptorPool desc_pool;
  VkDescriptorSet desc_set = VK_NULL_HANDLE;
  bool descriptors_dirty = true;
  vk::UniqueSampler sampler, linear_sampler;
  vk::UniqueBufferView buffer_views[4];  // views, cell table, refs, ranked refs (recreated when regrown)
  vk::UniqueRenderPass color_pass, cellid_pass, zdepth_pass, gbuffer_pass;
  vk::UniquePipeline gbuffer_pipe, cellid_pipe, zdepth_pipe;
  // Blend pipelines per n_best (specialisation constant 0 of blend.frag: the best-n slots and
  // the n-th-best pick are then compile-time; measured ~6 % of the frame), created on first use.
  vk::UniquePipeline blend_pipes[blend::kMaxBlendViews + 1];
  vk::UniquePipeline blend_comp_pipes[blend::kMaxBlendViews + 1];
  bool blend_compute = false;  // VulkanRendererOptions::blend_in_compute
  Buffer frame_ubo;

  // ---- render targets (per size) ----
  struct Target {
    uint32_t w = 0, h = 0;
    vk::Image color, depth;
    vk::UniqueFramebuffer fb;
    // Deferred blend only: RGBA32F surface point per pixel + its framebuffer (shares `depth`).
    vk::Image gbuffer;
    vk::UniqueFramebuffer gbuffer_fb;
    Buffer readback;
    Buffer blend_out;  // blend.comp output, W*H RGBA8 (host-visible)
  };
  Target color_target, cellid_target, zdepth_target;
  vk::Image placeholder_gbuffer;
  Buffer placeholder_out;

  // ===================== setup =====================
  absl::Status Init() {
    vk::ContextOptions copt;
    copt.enable_validation = opt.enable_validation;
    EXO_ASSIGN_OR_RETURN(ctx, vk::Context::Create(copt));
    EXO_ASSIGN_OR_RETURN(frame_ubo, Buffer::Create(*ctx, sizeof(GpuFrame),
                                                   VK_BUFFER_USAGE_UNIFORM_BUFFER_BIT));
    EXO_RETURN_IF_ERROR(CreateSampler());
    EXO_RETURN_IF_ERROR(CreateDescriptors());
    EXO_ASSIGN_OR_RETURN(color_pass, CreateRenderPass(VK_FORMAT_R8G8B8A8_UNORM));
    EXO_ASSIGN_OR_RETURN(gbuffer_pass,
                         CreateRenderPass(VK_FORMAT_R32G32B32A32_SFLOAT, /*sampled_output=*/true));
    EXO_ASSIGN_OR_RETURN(cellid_pass, CreateRenderPass(VK_FORMAT_R32G32_UINT));
    EXO_ASSIGN_OR_RETURN(zdepth_pass, CreateRenderPass(VK_FORMAT_R32_SFLOAT));
    blend_compute = opt.blend_in_compute;
    EXO_ASSIGN_OR_RETURN(placeholder_out, Buffer::Create(*ctx, 4, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT));
    EXO_RETURN_IF_ERROR(EnsureBlendPipe(blend::BlendOptions{}.n_best));
    EXO_ASSIGN_OR_RETURN(gbuffer_pipe, CreatePipeline(gbuffer_pass.get(), kSpvGbufferFrag,
                                                      sizeof(kSpvGbufferFrag)));
    EXO_ASSIGN_OR_RETURN(cellid_pipe, CreatePipeline(cellid_pass.get(), kSpvCellidFrag,
                                                     sizeof(kSpvCellidFrag)));
    EXO_ASSIGN_OR_RETURN(zdepth_pipe, CreatePipeline(zdepth_pass.get(), kSpvViewdepthFrag,
                                                     sizeof(kSpvViewdepthFrag)));
    // Binding 6 before any blend target exists (lavapipe reads every binding of a bound set): a
    // 1x1 G-buffer placeholder in SHADER_READ_ONLY_OPTIMAL.
    EXO_ASSIGN_OR_RETURN(placeholder_gbuffer,
                         vk::Image::Create(*ctx, 1, 1, 1, VK_FORMAT_R32G32B32A32_SFLOAT,
                                           VK_IMAGE_USAGE_SAMPLED_BIT, VK_IMAGE_ASPECT_COLOR_BIT,
                                           false));
    EXO_RETURN_IF_ERROR(ctx->Submit([&](VkCommandBuffer cmd) {
      vk::TransitionImage(cmd, placeholder_gbuffer.image.get(), VK_IMAGE_ASPECT_COLOR_BIT,
                          VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, 0, 1);
    }));
    // Empty store: 1 slot, 1x1 layers, a 64-entry table, 1 slab, so every descriptor is valid.
    EXO_RETURN_IF_ERROR(GrowViewStorage(1, 1, 1));
    EXO_RETURN_IF_ERROR(RebuildTable(64));
    EXO_RETURN_IF_ERROR(GrowSlabs(1));
    return absl::OkStatus();
  }

  absl::Status EnsureBlendPipe(int n_best) {
    if (n_best < 1 || n_best > blend::kMaxBlendViews)
      return absl::InvalidArgumentError("n_best out of range");
    if (blend_compute ? bool(blend_comp_pipes[n_best]) : bool(blend_pipes[n_best]))
      return absl::OkStatus();
    const int32_t value = n_best;
    VkSpecializationMapEntry entry{0, 0, sizeof(int32_t)};
    VkSpecializationInfo spec{1, &entry, sizeof(int32_t), &value};
    const uint32_t* code = kSpvBlendFrag;
    const size_t bytes = sizeof(kSpvBlendFrag);
    if (!blend_compute) {
      EXO_ASSIGN_OR_RETURN(blend_pipes[n_best],
                           CreatePipeline(color_pass.get(), code, bytes, true, &spec));
      return absl::OkStatus();
    }
    EXO_ASSIGN_OR_RETURN(auto cs, CreateModule(kSpvBlendComp, sizeof(kSpvBlendComp)));
    VkComputePipelineCreateInfo ci{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
    ci.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
    ci.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
    ci.stage.module = cs.get();
    ci.stage.pName = "main";
    ci.stage.pSpecializationInfo = &spec;
    ci.layout = pipe_layout.get();
    VkPipeline raw;
    EXO_VK_RETURN(vkCreateComputePipelines(ctx->device(), VK_NULL_HANDLE, 1, &ci, nullptr, &raw));
    blend_comp_pipes[n_best] = vk::UniquePipeline(ctx->device(), raw);
    return absl::OkStatus();
  }

  absl::Status CreateSampler() {
    // Nearest sampler for the depth array (texelFetch only) and a bilinear, clamp-to-edge one for
    // the sRGB colour array: one filtered texture() per blended view instead of four texelFetch
    // + float lerp (the texel decode to linear happens before filtering, as blend_math.h
    // specifies; measured 3-4x cheaper on llvmpipe, docs/vulkan.md).
    for (int k = 0; k < 2; ++k) {
      VkSamplerCreateInfo s{VK_STRUCTURE_TYPE_SAMPLER_CREATE_INFO};
      s.magFilter = s.minFilter = k == 0 ? VK_FILTER_NEAREST : VK_FILTER_LINEAR;
      s.mipmapMode = VK_SAMPLER_MIPMAP_MODE_NEAREST;
      s.addressModeU = s.addressModeV = s.addressModeW = VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE;
      s.maxLod = 0.0f;
      VkSampler raw;
      EXO_VK_RETURN(vkCreateSampler(ctx->device(), &s, nullptr, &raw));
      (k == 0 ? sampler : linear_sampler) = vk::UniqueSampler(ctx->device(), raw);
    }
    return absl::OkStatus();
  }

  absl::Status CreateDescriptors() {
    VkDescriptorSetLayoutBinding b[9]{};
    for (uint32_t i = 0; i < 9; ++i) {
      b[i].binding = i;
      b[i].descriptorCount = 1;
      b[i].stageFlags = VK_SHADER_STAGE_FRAGMENT_BIT | VK_SHADER_STAGE_COMPUTE_BIT;
    }
    b[0].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER;
    b[0].stageFlags |= VK_SHADER_STAGE_VERTEX_BIT;
    // Views, cell table and reference slots are uniform TEXEL buffers, not SSBOs: llvmpipe
    // lowers a divergent SSBO load to a per-lane scalar loop per component, a texel-buffer fetch
    // to a vector gather (measured: docs/vulkan.md).
    b[1].descriptorType = b[2].descriptorType = b[3].descriptorType =
        VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
    b[4].descriptorType = b[5].descriptorType = b[6].descriptorType =
        VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER;
    b[7].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;  // ranked refs (per frame)
    b[8].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;        // blend.comp output (RGBA8)
    VkDescriptorSetLayoutCreateInfo li{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    li.bindingCount = 9;
    li.pBindings = b;
    VkDescriptorSetLayout raw_layout;
    EXO_VK_RETURN(vkCreateDescriptorSetLayout(ctx->device(), &li, nullptr, &raw_layout));
    set_layout = vk::UniqueDescriptorSetLayout(ctx->device(), raw_layout);
    VkPipelineLayoutCreateInfo pli{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    pli.setLayoutCount = 1;
    pli.pSetLayouts = &raw_layout;
    VkPipelineLayout raw_pl;
    EXO_VK_RETURN(vkCreatePipelineLayout(ctx->device(), &pli, nullptr, &raw_pl));
    pipe_layout = vk::UniquePipelineLayout(ctx->device(), raw_pl);
    VkDescriptorPoolSize sizes[4] = {{VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER, 1},
                                     {VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, 4},
                                     {VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, 3},
                                     {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1}};
    VkDescriptorPoolCreateInfo pi{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    pi.maxSets = 1;
    pi.poolSizeCount = 4;
    pi.pPoolSizes = sizes;
    VkDescriptorPool raw_pool;
    EXO_VK_RETURN(vkCreateDescriptorPool(ctx->device(), &pi, nullptr, &raw_pool));
    desc_pool = vk::UniqueDescriptorPool(ctx->device(), raw_pool);
    VkDescriptorSetAllocateInfo ai{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
    ai.descriptorPool = raw_pool;
    ai.descriptorSetCount = 1;
    ai.pSetLayouts = &raw_layout;
    EXO_VK_RETURN(vkAllocateDescriptorSets(ctx->device(), &ai, &desc_set));
    return absl::OkStatus();
  }

  absl::StatusOr<vk::UniqueBufferView> MakeBufferView(const Buffer& b, VkFormat format) {
    VkBufferViewCreateInfo ci{VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO};
    ci.buffer = b.buffer.get();
    ci.format = format;
    ci.offset = 0;
    ci.range = VK_WHOLE_SIZE;
    VkBufferView raw;
    EXO_VK_RETURN(vkCreateBufferView(ctx->device(), &ci, nullptr, &raw));
    return vk::UniqueBufferView(ctx->device(), raw);
  }

  absl::Status UpdateDescriptors() {
    if (!descriptors_dirty) return absl::OkStatus();
    // The set may still be in use by nothing: every Submit waits for its fence.
    EXO_ASSIGN_OR_RETURN(buffer_views[0],
                         MakeBufferView(view_records, VK_FORMAT_R32G32B32A32_SFLOAT));
    EXO_ASSIGN_OR_RETURN(buffer_views[1], MakeBufferView(table_buf, VK_FORMAT_R32G32B32A32_UINT));
    EXO_ASSIGN_OR_RETURN(buffer_views[2], MakeBufferView(refs_buf, VK_FORMAT_R32_UINT));
    EXO_ASSIGN_OR_RETURN(buffer_views[3], MakeBufferView(ranked_buf, VK_FORMAT_R32G32B32A32_UINT));
    VkDescriptorBufferInfo ubo{frame_ubo.buffer.get(), 0, VK_WHOLE_SIZE};
    VkBufferView tb[3] = {buffer_views[0].get(), buffer_views[1].get(), buffer_views[2].get()};
    VkBufferView ranked_view = buffer_views[3].get();
    VkDescriptorImageInfo ii[2] = {
        {linear_sampler.get(), colors.view.get(), VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL},
        {sampler.get(), depths.view.get(), VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL}};
    VkDescriptorImageInfo gi{sampler.get(),
                             color_target.gbuffer.image ? color_target.gbuffer.view.get()
                                                        : placeholder_gbuffer.view.get(),
                             VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL};
    // Binding 8: the compute output of the colour target (a placeholder before one exists).
    VkDescriptorBufferInfo out_info{color_target.blend_out.buffer
                                        ? color_target.blend_out.buffer.get()
                                        : placeholder_out.buffer.get(),
                                    0, VK_WHOLE_SIZE};
    const uint32_t writes = 9;
    VkWriteDescriptorSet w[9]{};
    for (uint32_t i = 0; i < writes; ++i) {
      w[i].sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
      w[i].dstSet = desc_set;
      w[i].dstBinding = i;
      w[i].descriptorCount = 1;
      if (i == 0) {
        w[i].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER;
        w[i].pBufferInfo = &ubo;
      } else if (i < 4) {
        w[i].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
        w[i].pTexelBufferView = &tb[i - 1];
      } else if (i == 7) {
        w[i].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
        w[i].pTexelBufferView = &ranked_view;
      } else if (i == 8) {
        w[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
        w[i].pBufferInfo = &out_info;
      } else {
        w[i].descriptorType = VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER;
        w[i].pImageInfo = i == 6 ? &gi : &ii[i - 4];
      }
    }
    vkUpdateDescriptorSets(ctx->device(), writes, w, 0, nullptr);
    descriptors_dirty = false;
    return absl::OkStatus();
  }

  // sampled_output: the colour attachment ends in SHADER_READ_ONLY_OPTIMAL for a later pass's
  // fragment shader (the G-buffer); otherwise in TRANSFER_SRC_OPTIMAL for read-back.
  absl::StatusOr<vk::UniqueRenderPass> CreateRenderPass(VkFormat color_format,
                                                        bool sampled_output = false) {
    VkAttachmentDescription att[2]{};
    att[0].format = color_format;
    att[0].samples = VK_SAMPLE_COUNT_1_BIT;
    att[0].loadOp = VK_ATTACHMENT_LOAD_OP_CLEAR;
    att[0].storeOp = VK_ATTACHMENT_STORE_OP_STORE;
    att[0].stencilLoadOp = VK_ATTACHMENT_LOAD_OP_DONT_CARE;
    att[0].stencilStoreOp = VK_ATTACHMENT_STORE_OP_DONT_CARE;
    att[0].initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
    att[0].finalLayout = sampled_output ? VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL
                                        : VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL;
    att[1] = att[0];
    att[1].format = VK_FORMAT_D32_SFLOAT;
    att[1].storeOp = VK_ATTACHMENT_STORE_OP_DONT_CARE;
    att[1].finalLayout = VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL;
    VkAttachmentReference cref{0, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL};
    VkAttachmentReference dref{1, VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL};
    VkSubpassDescription sub{};
    sub.pipelineBindPoint = VK_PIPELINE_BIND_POINT_GRAPHICS;
    sub.colorAttachmentCount = 1;
    sub.pColorAttachments = &cref;
    sub.pDepthStencilAttachment = &dref;
    VkSubpassDependency dep[2]{};
    dep[0].srcSubpass = VK_SUBPASS_EXTERNAL;
    dep[0].dstSubpass = 0;
    dep[0].srcStageMask = VK_PIPELINE_STAGE_TRANSFER_BIT |
                          VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT |
                          VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT |
                          VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT;
    dep[0].dstStageMask = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT |
                          VK_PIPELINE_STAGE_EARLY_FRAGMENT_TESTS_BIT;
    dep[0].srcAccessMask = VK_ACCESS_TRANSFER_READ_BIT |
                           VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT;
    dep[0].dstAccessMask = VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT |
                           VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_READ_BIT |
                           VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT;
    dep[1].srcSubpass = 0;
    dep[1].dstSubpass = VK_SUBPASS_EXTERNAL;
    dep[1].srcStageMask = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT;
    dep[1].dstStageMask = sampled_output ? (VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT |
                                            VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT)
                                         : VK_PIPELINE_STAGE_TRANSFER_BIT;
    dep[1].srcAccessMask = VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
    dep[1].dstAccessMask = sampled_output ? VK_ACCESS_SHADER_READ_BIT : VK_ACCESS_TRANSFER_READ_BIT;
    VkRenderPassCreateInfo ri{VK_STRUCTURE_TYPE_RENDER_PASS_CREATE_INFO};
    ri.attachmentCount = 2;
    ri.pAttachments = att;
    ri.subpassCount = 1;
    ri.pSubpasses = &sub;
    ri.dependencyCount = 2;
    ri.pDependencies = dep;
    VkRenderPass raw;
    EXO_VK_RETURN(vkCreateRenderPass(ctx->device(), &ri, nullptr, &raw));
    return vk::UniqueRenderPass(ctx->device(), raw);
  }

  absl::StatusOr<vk::UniqueShaderModule> CreateModule(const uint32_t* code, size_t bytes) {
    VkShaderModuleCreateInfo si{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
    si.codeSize = bytes;
    si.pCode = code;
    VkShaderModule raw;
    EXO_VK_RETURN(vkCreateShaderModule(ctx->device(), &si, nullptr, &raw));
    return vk::UniqueShaderModule(ctx->device(), raw);
  }

  // fullscreen: one triangle over the viewport (no vertex input, no depth test) for the deferred
  // blend pass; otherwise the proxy-mesh pipeline (depth test LESS + write).
  absl::StatusOr<vk::UniquePipeline> CreatePipeline(VkRenderPass pass, const uint32_t* frag,
                                                    size_t frag_bytes, bool fullscreen = false,
                                                    const VkSpecializationInfo* spec = nullptr) {
    vk::UniqueShaderModule vs;
    if (fullscreen) {
      EXO_ASSIGN_OR_RETURN(vs, CreateModule(kSpvFullscreenVert, sizeof(kSpvFullscreenVert)));
    } else {
      EXO_ASSIGN_OR_RETURN(vs, CreateModule(kSpvBlendVert, sizeof(kSpvBlendVert)));
    }
    EXO_ASSIGN_OR_RETURN(auto fs, CreateModule(frag, frag_bytes));
    VkPipelineShaderStageCreateInfo stages[2]{};
    stages[0].sType = stages[1].sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
    stages[0].stage = VK_SHADER_STAGE_VERTEX_BIT;
    stages[0].module = vs.get();
    stages[0].pName = "main";
    stages[1].stage = VK_SHADER_STAGE_FRAGMENT_BIT;
    stages[1].module = fs.get();
    stages[1].pName = "main";
    stages[1].pSpecializationInfo = spec;
    VkVertexInputBindingDescription vb{0, sizeof(glm::vec3), VK_VERTEX_INPUT_RATE_VERTEX};
    VkVertexInputAttributeDescription va{0, 0, VK_FORMAT_R32G32B32_SFLOAT, 0};
    VkPipelineVertexInputStateCreateInfo vi{
        VK_STRUCTURE_TYPE_PIPELINE_VERTEX_INPUT_STATE_CREATE_INFO};
    vi.vertexBindingDescriptionCount = fullscreen ? 0 : 1;
    vi.pVertexBindingDescriptions = &vb;
    vi.vertexAttributeDescriptionCount = fullscreen ? 0 : 1;
    vi.pVertexAttributeDescriptions = &va;
    VkPipelineInputAssemblyStateCreateInfo ia{
        VK_STRUCTURE_TYPE_PIPELINE_INPUT_ASSEMBLY_STATE_CREATE_INFO};
    ia.topology = VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST;
    VkPipelineViewportStateCreateInfo vp{VK_STRUCTURE_TYPE_PIPELINE_VIEWPORT_STATE_CREATE_INFO};
    vp.viewportCount = 1;
    vp.scissorCount = 1;
    VkPipelineRasterizationStateCreateInfo rs{
        VK_STRUCTURE_TYPE_PIPELINE_RASTERIZATION_STATE_CREATE_INFO};
    rs.polygonMode = VK_POLYGON_MODE_FILL;
    rs.cullMode = VK_CULL_MODE_NONE;  // the CPU rasterizer does not cull by default either
    rs.frontFace = VK_FRONT_FACE_COUNTER_CLOCKWISE;
    rs.lineWidth = 1.0f;
    VkPipelineMultisampleStateCreateInfo ms{
        VK_STRUCTURE_TYPE_PIPELINE_MULTISAMPLE_STATE_CREATE_INFO};
    ms.rasterizationSamples = VK_SAMPLE_COUNT_1_BIT;
    VkPipelineDepthStencilStateCreateInfo ds{
        VK_STRUCTURE_TYPE_PIPELINE_DEPTH_STENCIL_STATE_CREATE_INFO};
    ds.depthTestEnable = fullscreen ? VK_FALSE : VK_TRUE;
    ds.depthWriteEnable = fullscreen ? VK_FALSE : VK_TRUE;
    ds.depthCompareOp = VK_COMPARE_OP_LESS;
    VkPipelineColorBlendAttachmentState cba{};
    cba.colorWriteMask = VK_COLOR_COMPONENT_R_BIT | VK_COLOR_COMPONENT_G_BIT |
                         VK_COLOR_COMPONENT_B_BIT | VK_COLOR_COMPONENT_A_BIT;
    VkPipelineColorBlendStateCreateInfo cb{VK_STRUCTURE_TYPE_PIPELINE_COLOR_BLEND_STATE_CREATE_INFO};
    cb.attachmentCount = 1;
    cb.pAttachments = &cba;
    VkDynamicState dyn[2] = {VK_DYNAMIC_STATE_VIEWPORT, VK_DYNAMIC_STATE_SCISSOR};
    VkPipelineDynamicStateCreateInfo dy{VK_STRUCTURE_TYPE_PIPELINE_DYNAMIC_STATE_CREATE_INFO};
    dy.dynamicStateCount = 2;
    dy.pDynamicStates = dyn;
    VkGraphicsPipelineCreateInfo gi{VK_STRUCTURE_TYPE_GRAPHICS_PIPELINE_CREATE_INFO};
    gi.stageCount = 2;
    gi.pStages = stages;
    gi.pVertexInputState = &vi;
    gi.pInputAssemblyState = &ia;
    gi.pViewportState = &vp;
    gi.pRasterizationState = &rs;
    gi.pMultisampleState = &ms;
    gi.pDepthStencilState = &ds;
    gi.pColorBlendState = &cb;
    gi.pDynamicState = &dy;
    gi.layout = pipe_layout.get();
    gi.renderPass = pass;
    VkPipeline raw;
    EXO_VK_RETURN(
        vkCreateGraphicsPipelines(ctx->device(), VK_NULL_HANDLE, 1, &gi, nullptr, &raw));
    return vk::UniquePipeline(ctx->device(), raw);
  }

  // ===================== view storage =====================
  // Grows the texture arrays to >= (w, h, slots); existing layers are copied GPU-side.
  absl::Status GrowViewStorage(uint32_t w, uint32_t h, uint32_t slots) {
    const uint32_t nw = std::max(w, layer_w), nh = std::max(h, layer_h);
    uint32_t ns = std::max<uint32_t>(slot_capacity, 1);
    while (ns < slots) ns *= 2;
    if (colors.image && nw == layer_w && nh == layer_h && ns == slot_capacity)
      return absl::OkStatus();
    const VkImageUsageFlags usage = VK_IMAGE_USAGE_SAMPLED_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT |
                                    VK_IMAGE_USAGE_TRANSFER_SRC_BIT;
    EXO_ASSIGN_OR_RETURN(vk::Image nc, vk::Image::Create(*ctx, nw, nh, ns,
                                                         kColorFormat, usage,
                                                         VK_IMAGE_ASPECT_COLOR_BIT, true));
    EXO_ASSIGN_OR_RETURN(vk::Image nd, vk::Image::Create(*ctx, nw, nh, ns, VK_FORMAT_R32_SFLOAT,
                                                         usage, VK_IMAGE_ASPECT_COLOR_BIT, true));
    EXO_ASSIGN_OR_RETURN(Buffer nrec, Buffer::Create(*ctx, ns * sizeof(GpuView),
                                                     VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT));
    std::memset(nrec.mapped, 0, ns * sizeof(GpuView));
    const bool had = static_cast<bool>(colors.image);
    if (had) std::memcpy(nrec.mapped, view_records.mapped, slot_capacity * sizeof(GpuView));
    EXO_RETURN_IF_ERROR(ctx->Submit([&](VkCommandBuffer cmd) {
      const VkImageAspectFlags a = VK_IMAGE_ASPECT_COLOR_BIT;
      for (vk::Image* img : {&nc, &nd}) {
        vk::TransitionImage(cmd, img->image.get(), a, VK_IMAGE_LAYOUT_UNDEFINED,
                            VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL);
        // Clear so unused texels are defined (depth 0 = invalid).
        VkClearColorValue zero{};
        VkImageSubresourceRange range{a, 0, 1, 0, VK_REMAINING_ARRAY_LAYERS};
        vkCmdClearColorImage(cmd, img->image.get(), VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, &zero,
                             1, &range);
      }
      if (had) {
        for (auto [src, dst] : {std::pair{&colors, &nc}, std::pair{&depths, &nd}}) {
          vk::TransitionImage(cmd, src->image.get(), a, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                              VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL);
          VkImageCopy region{};
          region.srcSubresource = {a, 0, 0, slot_capacity};
          region.dstSubresource = {a, 0, 0, slot_capacity};
          region.extent = {layer_w, layer_h, 1};
          vkCmdCopyImage(cmd, src->image.get(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                         dst->image.get(), VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &region);
        }
      }
      for (vk::Image* img : {&nc, &nd})
        vk::TransitionImage(cmd, img->image.get(), a, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                            VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL);
    }));
    for (uint32_t s = slot_capacity; s < ns; ++s) free_slots.push_back(s);
    std::sort(free_slots.begin(), free_slots.end(), std::greater<>());  // pop lowest first
    if (had) ++stats.array_regrowths;
    colors = std::move(nc);
    depths = std::move(nd);
    view_records = std::move(nrec);
    layer_w = nw;
    layer_h = nh;
    slot_capacity = ns;
    descriptors_dirty = true;
    return absl::OkStatus();
  }

  absl::Status UpsertView(const StoredView& v, uint64_t fingerprint) {
    EXO_RETURN_IF_ERROR(v.camera.Validate());
    const int w = v.camera.width, h = v.camera.height;
    if (w > 16384 || h > 16384)  // the ranked record packs width | height << 16
      return absl::InvalidArgumentError(
          absl::StrCat("view ", v.id, ": size ", w, "x", h, " above 16384"));
    if (v.color.width() != w || v.color.height() != h || v.color.channels() != 3)
      return absl::InvalidArgumentError(absl::StrCat(
          "view ", v.id, ": colour must be RGB8 ", w, "x", h, ", got ", v.color.width(), "x",
          v.color.height(), "x", v.color.channels()));
    if (v.depth_m.width() != w || v.depth_m.height() != h || v.depth_m.channels() != 1)
      return absl::InvalidArgumentError(
          absl::StrCat("view ", v.id, ": depth must be 1 channel ", w, "x", h));
    if (!std::isfinite(v.exposure) || v.exposure <= 0.0f)
      return absl::InvalidArgumentError(
          absl::StrCat("view ", v.id, ": exposure must be finite and > 0, got ", v.exposure));
    EXO_RETURN_IF_ERROR(ValidateQuaternion(v.local_from_cam.rotation));
    const glm::dvec3& t = v.local_from_cam.translation;
    if (!std::isfinite(t.x) || !std::isfinite(t.y) || !std::isfinite(t.z))
      return absl::InvalidArgumentError(absl::StrCat("view ", v.id, ": non-finite position"));

    auto it = views.find(v.id);
    const bool is_new = it == views.end();
    const uint32_t needed = static_cast<uint32_t>(views.size() + (is_new ? 1 : 0));
    EXO_RETURN_IF_ERROR(GrowViewStorage(w, h, needed));
    uint32_t slot;
    if (is_new) {
      slot = free_slots.back();
      free_slots.pop_back();
    } else {
      slot = it->second.slot;
    }

    // Staging: RGBA8 colour then R32F baked depth.
    const VkDeviceSize color_bytes = VkDeviceSize(w) * h * kColorTexelBytes,
                       depth_bytes = VkDeviceSize(w) * h * 4;
    if (!staging.buffer || staging.size < color_bytes + depth_bytes) {
      EXO_ASSIGN_OR_RETURN(staging, Buffer::Create(*ctx, color_bytes + depth_bytes,
                                                   VK_BUFFER_USAGE_TRANSFER_SRC_BIT));
    }
    uint8_t* dst = static_cast<uint8_t*>(staging.mapped);
    const uint8_t* src = v.color.data();
    {
      // sRGB8 -> linear UNORM16 (the texel decode of blend_math.h, done once at upload).
      const auto& lut = Linear16Lut();
      uint16_t* d16 = reinterpret_cast<uint16_t*>(dst);
      for (size_t i = 0, n = size_t(w) * h; i < n; ++i) {
        d16[4 * i + 0] = lut[src[3 * i + 0]];
        d16[4 * i + 1] = lut[src[3 * i + 1]];
        d16[4 * i + 2] = lut[src[3 * i + 2]];
        d16[4 * i + 3] = 65535;
      }
    }
    ImageF baked =
        BakeDiscontinuities(v.depth_m, opt.bake_discontinuity_radius_px,
                            opt.bake_discontinuity_delta_z_m, opt.bake_discontinuity_delta_z_rel);
    // Background at infinity: -1 marks the guarded background mask (invalid for surfaces too).
    const ImageU8 bg_mask = BackgroundMask(v.depth_m, opt.bake_background_guard_radius_px);
    bool has_background = false;
    for (size_t i = 0, n = baked.size(); i < n; ++i)
      if (bg_mask.data()[i]) {
        baked.data()[i] = -1.0f;
        has_background = true;
      }
    std::memcpy(dst + color_bytes, baked.data(), depth_bytes);
    EXO_RETURN_IF_ERROR(ctx->Submit([&](VkCommandBuffer cmd) {
      const VkImageAspectFlags a = VK_IMAGE_ASPECT_COLOR_BIT;
      VkDeviceSize offset = 0;
      for (vk::Image* img : {&colors, &depths}) {
        vk::TransitionImage(cmd, img->image.get(), a, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                            VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, slot, 1);
        VkBufferImageCopy region{};
        region.bufferOffset = offset;
        region.imageSubresource = {a, 0, slot, 1};
        region.imageExtent = {uint32_t(w), uint32_t(h), 1};
        vkCmdCopyBufferToImage(cmd, staging.buffer.get(), img->image.get(),
                               VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &region);
        vk::TransitionImage(cmd, img->image.get(), a, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                            VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, slot, 1);
        offset += color_bytes;
      }
    }));
    // The record (mirrors blend::BlendView as the CPU reference builds it).
    // P = K [R^T | -R^T c] in double, rounded once to float.
    const glm::dmat3 cam_from_local = glm::transpose(v.local_from_cam.RotationMatrix());
    const glm::dvec3 c = v.local_from_cam.translation;
    const glm::dvec3 tr = -(cam_from_local * c);
    GpuView rec;
    // Row r of R^T (glm is column-major: element (r, k) is [k][r]), with its translation.
    auto row_of = [&](int r) {
      return glm::dvec4(cam_from_local[0][r], cam_from_local[1][r], cam_from_local[2][r], tr[r]);
    };
    rec.p0 = glm::vec4(v.camera.fx * row_of(0) + v.camera.cx * row_of(2));
    rec.p1 = glm::vec4(v.camera.fy * row_of(1) + v.camera.cy * row_of(2));
    rec.p2 = glm::vec4(row_of(2));
    rec.centre_exposure = glm::vec4(glm::vec3(c), v.exposure);
    rec.size_layer = glm::vec4(float(w), float(h), float(slot), 1.0f);
    std::memcpy(static_cast<GpuView*>(view_records.mapped) + slot, &rec, sizeof(rec));
    stats.bytes += color_bytes + depth_bytes + sizeof(GpuView);
    ++stats.view_uploads;
    views[v.id] = ViewEntry{slot, fingerprint, MakeBlendView(v), has_background};
    if (is_new) {
      // Cells that already referenced this id now resolve to the slot.
      auto rit = cells_of_view.find(v.id);
      if (rit != cells_of_view.end())
        for (CellId c : rit->second) WriteCellSlab(cells.at(c));
    }
    return absl::OkStatus();
  }

  absl::Status RemoveView(ViewId id) {
    auto it = views.find(id);
    if (it == views.end()) return absl::NotFoundError(absl::StrCat("view ", id, " not resident"));
    const uint32_t slot = it->second.slot;
    GpuView* rec = static_cast<GpuView*>(view_records.mapped) + slot;
    rec->size_layer.w = 0.0f;
    stats.bytes += sizeof(GpuView);
    views.erase(it);
    free_slots.push_back(slot);
    auto rit = cells_of_view.find(id);
    if (rit != cells_of_view.end())
      for (CellId c : rit->second) WriteCellSlab(cells.at(c));
    return absl::OkStatus();
  }

  // ===================== cells =====================
  absl::Status GrowSlabs(uint32_t slabs) {
    uint32_t ns = std::max<uint32_t>(slab_capacity, 1);
    while (ns < slabs) ns *= 2;
    if (refs_buf.buffer && ns == slab_capacity) return absl::OkStatus();
    const size_t slab_bytes = size_t(opt.max_refs_per_cell) * sizeof(uint32_t);
    EXO_ASSIGN_OR_RETURN(Buffer nb, Buffer::Create(*ctx, ns * slab_bytes,
                                                   VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT));
    std::memset(nb.mapped, 0xFF, ns * slab_bytes);
    // Device-to-device copy of the old slabs (on lavapipe both are host memory).
    if (refs_buf.buffer) std::memcpy(nb.mapped, refs_buf.mapped, slab_capacity * slab_bytes);
    for (uint32_t s = ns; s-- > slab_capacity;) free_slabs.push_back(s);
    EXO_ASSIGN_OR_RETURN(Buffer nr, Buffer::Create(*ctx, ns * slab_bytes * 8,
                                                   VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT));
    std::memset(nr.mapped, 0, ns * slab_bytes * 8);
    refs_buf = std::move(nb);
    ranked_buf = std::move(nr);
    slab_capacity = ns;
    descriptors_dirty = true;
    return absl::OkStatus();
  }

  uint32_t Probe(CellId id, bool for_insert) const {
    const uint32_t lo = uint32_t(id), hi = uint32_t(id >> 32);
    const uint32_t mask = uint32_t(table.size() - 1);
    uint32_t h = CellHash32(lo, hi) & mask;
    uint32_t first_tomb = kNoSlot;
    for (uint32_t probe = 0; probe <= mask; ++probe) {
      const glm::uvec4& e = table[h];
      if (e.x == lo && e.y == hi) return h;
      if (e.x == kEmptyKey && e.y == kEmptyKey)
        return for_insert ? (first_tomb != kNoSlot ? first_tomb : h) : kNoSlot;
      if (for_insert && e.x == kTombKeyLo && e.y == kEmptyKey && first_tomb == kNoSlot)
        first_tomb = h;
      h = (h + 1) & mask;
    }
    return for_insert ? first_tomb : kNoSlot;
  }

  // Linear-probing displacement of table slot i from the home slot of `id`. The shader's lookup
  // loop runs max_probe + 1 probes at most: a resident key is never displaced further, so a miss
  // can stop there. (An unbounded "until empty" loop measured ~1000x slower on llvmpipe.)
  uint32_t Displacement(CellId id, uint32_t i) const {
    const uint32_t mask = uint32_t(table.size() - 1);
    return (i - (CellHash32(uint32_t(id), uint32_t(id >> 32)) & mask)) & mask;
  }

  glm::uvec4 EntryOf(CellId id, const CellEntry& c) const {
    return {uint32_t(id), uint32_t(id >> 32), c.slab * uint32_t(opt.max_refs_per_cell),
            uint32_t(c.refs.size())};
  }

  // Re-hashes every cell into a table of `capacity` entries and uploads it whole.
  absl::Status RebuildTable(uint32_t capacity) {
    table.assign(capacity, glm::uvec4(kEmptyKey, kEmptyKey, 0, 0));
    tombstones = 0;
    max_probe = 0;
    for (auto& [id, c] : cells) {
      const uint32_t i = Probe(id, true);
      c.table_index = i;
      max_probe = std::max(max_probe, Displacement(id, i));
      table[i] = EntryOf(id, c);
    }
    EXO_ASSIGN_OR_RETURN(table_buf, Buffer::Create(*ctx, capacity * sizeof(glm::uvec4),
                                                   VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT));
    std::memcpy(table_buf.mapped, table.data(), capacity * sizeof(glm::uvec4));
    stats.bytes += capacity * sizeof(glm::uvec4);
    ++stats.table_rebuilds;
    descriptors_dirty = true;
    return absl::OkStatus();
  }

  void UploadTableEntry(uint32_t i) {
    static_cast<glm::uvec4*>(table_buf.mapped)[i] = table[i];
    stats.bytes += sizeof(glm::uvec4);
  }

  void WriteCellSlab(const CellEntry& c) {
    uint32_t* dst =
        static_cast<uint32_t*>(refs_buf.mapped) + size_t(c.slab) * opt.max_refs_per_cell;
    for (size_t i = 0; i < c.refs.size(); ++i) {
      auto it = views.find(c.refs[i]);
      dst[i] = it == views.end() ? kNoSlot : it->second.slot;
    }
    stats.bytes += c.refs.size() * sizeof(uint32_t);
    ++stats.cell_uploads;
  }

  absl::Status SetCellRefs(CellId id, std::span<const ViewId> refs) {
    if (id == kNoCell || (id >> 63) != 0)
      return absl::InvalidArgumentError(absl::StrCat("invalid cell id ", id));
    if (refs.size() > size_t(opt.max_refs_per_cell))
      return absl::InvalidArgumentError(absl::StrCat("cell has ", refs.size(),
                                                     " references, max_refs_per_cell is ",
                                                     opt.max_refs_per_cell));
    auto it = cells.find(id);
    if (it != cells.end()) {
      for (ViewId v : it->second.refs) {
        auto rit = cells_of_view.find(v);
        if (rit != cells_of_view.end()) {
          rit->second.erase(id);
          if (rit->second.empty()) cells_of_view.erase(rit);
        }
      }
    }
    if (refs.empty()) {
      if (it == cells.end()) return absl::OkStatus();
      const uint32_t ti = it->second.table_index;
      table[ti] = glm::uvec4(kTombKeyLo, kEmptyKey, 0, 0);
      UploadTableEntry(ti);
      ++tombstones;
      free_slabs.push_back(it->second.slab);
      cells.erase(it);
      return absl::OkStatus();
    }
    if (it == cells.end()) {
      // Keep load (cells + tombstones) <= 1/2 of the table.
      if (2 * (cells.size() + 1 + tombstones) > table.size()) {
        uint32_t cap = uint32_t(table.size());
        while (2 * (cells.size() + 1) > cap / 2) cap *= 2;  // headroom: load <= 1/4 after
        EXO_RETURN_IF_ERROR(RebuildTable(cap));
      }
      if (free_slabs.empty()) EXO_RETURN_IF_ERROR(GrowSlabs(slab_capacity + 1));
      CellEntry c;
      c.slab = free_slabs.back();
      free_slabs.pop_back();
      const uint32_t ti = Probe(id, true);
      if (table[ti].x == kTombKeyLo) --tombstones;
      c.table_index = ti;
      max_probe = std::max(max_probe, Displacement(id, ti));
      it = cells.emplace(id, std::move(c)).first;
    }
    CellEntry& c = it->second;
    c.refs.assign(refs.begin(), refs.end());
    for (ViewId v : c.refs) cells_of_view[v].insert(id);
    WriteCellSlab(c);
    table[c.table_index] = EntryOf(id, c);
    UploadTableEntry(c.table_index);
    return absl::OkStatus();
  }

  // ===================== chunks =====================
  absl::Status UpsertChunk(const MeshChunk& chunk) {
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
      chunks.erase(chunk.id);
      return absl::OkStatus();
    }
    ChunkGpu g;
    g.version = chunk.version;
    g.index_count = uint32_t(m.indices.size());
    const size_t vb = m.positions.size() * sizeof(glm::vec3), ib = m.indices.size() * 4;
    EXO_ASSIGN_OR_RETURN(g.vertices, Buffer::Create(*ctx, vb, VK_BUFFER_USAGE_VERTEX_BUFFER_BIT));
    EXO_ASSIGN_OR_RETURN(g.indices, Buffer::Create(*ctx, ib, VK_BUFFER_USAGE_INDEX_BUFFER_BIT));
    std::memcpy(g.vertices.mapped, m.positions.data(), vb);
    std::memcpy(g.indices.mapped, m.indices.data(), ib);
    stats.bytes += vb + ib;
    ++stats.chunk_uploads;
    chunks[chunk.id] = std::move(g);
    return absl::OkStatus();
  }

  // ===================== rendering =====================
  absl::Status EnsureTarget(Target& t, VkRenderPass pass, VkFormat format, uint32_t w,
                            uint32_t h) {
    if (t.w == w && t.h == h && t.fb) return absl::OkStatus();
    t = Target{};
    EXO_ASSIGN_OR_RETURN(t.color, vk::Image::Create(*ctx, w, h, 1, format,
                                                    VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT |
                                                        VK_IMAGE_USAGE_TRANSFER_SRC_BIT,
                                                    VK_IMAGE_ASPECT_COLOR_BIT, false));
    EXO_ASSIGN_OR_RETURN(t.depth, vk::Image::Create(*ctx, w, h, 1, VK_FORMAT_D32_SFLOAT,
                                                    VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT,
                                                    VK_IMAGE_ASPECT_DEPTH_BIT, false));
    VkImageView atts[2] = {t.color.view.get(), t.depth.view.get()};
    VkFramebufferCreateInfo fi{VK_STRUCTURE_TYPE_FRAMEBUFFER_CREATE_INFO};
    fi.renderPass = pass;
    fi.attachmentCount = 2;
    fi.pAttachments = atts;
    fi.width = w;
    fi.height = h;
    fi.layers = 1;
    VkFramebuffer raw;
    EXO_VK_RETURN(vkCreateFramebuffer(ctx->device(), &fi, nullptr, &raw));
    t.fb = vk::UniqueFramebuffer(ctx->device(), raw);
    if (&t == &color_target) {
      EXO_ASSIGN_OR_RETURN(t.gbuffer, vk::Image::Create(*ctx, w, h, 1, VK_FORMAT_R32G32B32A32_SFLOAT,
                                                        VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT |
                                                            VK_IMAGE_USAGE_SAMPLED_BIT,
                                                        VK_IMAGE_ASPECT_COLOR_BIT, false));
      VkImageView gatts[2] = {t.gbuffer.view.get(), t.depth.view.get()};
      fi.renderPass = gbuffer_pass.get();
      fi.pAttachments = gatts;
      EXO_VK_RETURN(vkCreateFramebuffer(ctx->device(), &fi, nullptr, &raw));
      t.gbuffer_fb = vk::UniqueFramebuffer(ctx->device(), raw);
      EXO_ASSIGN_OR_RETURN(t.blend_out, Buffer::Create(*ctx, VkDeviceSize(w) * h * 4,
                                                       VK_BUFFER_USAGE_STORAGE_BUFFER_BIT));
      descriptors_dirty = true;  // binding 6 points at the new G-buffer
    }
    EXO_ASSIGN_OR_RETURN(t.readback,
                         Buffer::Create(*ctx, VkDeviceSize(w) * h * 8,
                                        VK_BUFFER_USAGE_TRANSFER_DST_BIT));
    t.w = w;
    t.h = h;
    return absl::OkStatus();
  }

  absl::Status CheckCamera(const PinholeCamera& camera, const Rigid3d& local_from_cam) const {
    EXO_RETURN_IF_ERROR(camera.Validate());
    EXO_RETURN_IF_ERROR(ValidateQuaternion(local_from_cam.rotation));
    const glm::dvec3& t = local_from_cam.translation;
    if (!std::isfinite(t.x) || !std::isfinite(t.y) || !std::isfinite(t.z))
      return absl::InvalidArgumentError("novel camera position is not finite");
    if (camera.width > 16384 || camera.height > 16384)
      return absl::InvalidArgumentError("render size above 16384");
    return absl::OkStatus();
  }

  void FillFrame(const PinholeCamera& camera, const Rigid3d& local_from_cam, GpuFrame* f) const {
    const glm::dmat4 cam_from_local = local_from_cam.Inverse().ToMatrix();
    f->clip_from_local =
        glm::mat4(ClipFromCam(camera, opt.near_m, opt.far_m) * cam_from_local);
    f->cam_centre_cell =
        glm::vec4(glm::vec3(local_from_cam.translation), float(grid.cell_size_m));
    f->iparams = glm::ivec4(0, 0, int(table.size() - 1), int(max_probe));
  }

  // Records the proxy draw with `pipe` into `t`, copies the colour attachment to t.readback.
  // deferred == false: draws the proxy chunks with `pipe` into t.fb. deferred == true (blend):
  // first the proxy into the G-buffer (gbuffer_pipe, t.gbuffer_fb), then one full-screen
  // triangle with `pipe` into t.fb; one command buffer, one submit. Then the colour attachment
  // is copied to t.readback.
  absl::Status Draw(Target& t, VkRenderPass pass, VkPipeline pipe, const VkClearValue& clear,
                    uint32_t texel_bytes, bool deferred = false,
                    VkPipeline compute_pipe = VK_NULL_HANDLE) {
    EXO_RETURN_IF_ERROR(UpdateDescriptors());
    return ctx->Submit([&](VkCommandBuffer cmd) {
      VkViewport vp{0, 0, float(t.w), float(t.h), 0.0f, 1.0f};
      VkRect2D sc{{0, 0}, {t.w, t.h}};
      auto draw_chunks = [&] {
        for (const auto& [id, c] : chunks) {
          VkBuffer vb = c.vertices.buffer.get();
          VkDeviceSize off = 0;
          vkCmdBindVertexBuffers(cmd, 0, 1, &vb, &off);
          vkCmdBindIndexBuffer(cmd, c.indices.buffer.get(), 0, VK_INDEX_TYPE_UINT32);
          vkCmdDrawIndexed(cmd, c.index_count, 1, 0, 0, 0);
        }
      };
      auto begin = [&](VkRenderPass rp, VkFramebuffer fb, const VkClearValue& c0,
                       VkPipeline p) {
        VkClearValue cv[2];
        cv[0] = c0;
        cv[1].depthStencil = {1.0f, 0};
        VkRenderPassBeginInfo bi{VK_STRUCTURE_TYPE_RENDER_PASS_BEGIN_INFO};
        bi.renderPass = rp;
        bi.framebuffer = fb;
        bi.renderArea = {{0, 0}, {t.w, t.h}};
        bi.clearValueCount = 2;
        bi.pClearValues = cv;
        vkCmdBeginRenderPass(cmd, &bi, VK_SUBPASS_CONTENTS_INLINE);
        vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, p);
        vkCmdSetViewport(cmd, 0, 1, &vp);
        vkCmdSetScissor(cmd, 0, 1, &sc);
        vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, pipe_layout.get(), 0, 1,
                                &desc_set, 0, nullptr);
      };
      if (deferred) {
        VkClearValue zero{};  // G-buffer w = 0: no surface
        begin(gbuffer_pass.get(), t.gbuffer_fb.get(), zero, gbuffer_pipe.get());
        draw_chunks();
        vkCmdEndRenderPass(cmd);
        if (compute_pipe != VK_NULL_HANDLE) {
          // blend.comp over the G-buffer (the render pass's dependency covers the compute read)
          // straight into t.blend_out; then make its writes visible to the host.
          vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, compute_pipe);
          vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe_layout.get(), 0, 1,
                                  &desc_set, 0, nullptr);
          vkCmdDispatch(cmd, (t.w + 7) / 8, (t.h + 7) / 8, 1);
          VkBufferMemoryBarrier ob{VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER};
          ob.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT;
          ob.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
          ob.srcQueueFamilyIndex = ob.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
          ob.buffer = t.blend_out.buffer.get();
          ob.size = VK_WHOLE_SIZE;
          vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                               VK_PIPELINE_STAGE_HOST_BIT, 0, 0, nullptr, 1, &ob, 0, nullptr);
          return;
        }
        begin(pass, t.fb.get(), clear, pipe);
        vkCmdDraw(cmd, 3, 1, 0, 0);
        vkCmdEndRenderPass(cmd);
      } else {
        begin(pass, t.fb.get(), clear, pipe);
        draw_chunks();
        vkCmdEndRenderPass(cmd);
      }
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
    });
  }

  // Per-frame reference ranking (exact). For every resident cell and every reference, an UPPER
  // BOUND of the blend weight (3.5) the fragment shader can compute for any surface point x of
  // the cell this frame (validity = 1):
  //   x lies in the ball B(m, r) around the cell centre (r = half diagonal, inflated for the
  //   float cell assignment); with D_o = |c_o - m|, D_i = |c_i - m|:
  //   w_d = cos(angle(c_o - x, c_i - x)) <= cos(max(0, angle(c_o - m, c_i - m) - asin(r / D_o)
  //         - asin(r / D_i)))  (each ray turns by at most asin(r / D) as x moves in the ball;
  //         1 when a camera is inside the ball),
  //   w_p is decreasing in |c_i - x| >= D_i - r and increasing in |c_o - x| <= D_o + r,
  //   bound = max(lambda W_d + (1 - lambda) W_p, min_weight), plus a slack for float rounding.
  // The cell's references are written to ranked_buf sorted by (bound desc, position in the
  // cell's list asc): per slot (c_i.xyz, bound) and (layer, position, width | height << 16,
  // exposure). blend.frag stops at the first reference whose bound is below the n-th best
  // weight found so far (no later one can enter the best n) and breaks weight ties by the
  // position in the cell's list, so the selection equals blend_math.h's in-order InsertBest.
  // Non-resident references get bound -1 (sorted last, never evaluated).
  // Cells whose ball lies entirely outside the novel camera's frustum (side planes through the
  // centre, z >= 0) are skipped: no pixel's surface point can fall in them this frame, so their
  // stale records are never read (exact).
  void RankRefs(const glm::vec3& c_o_f, const PinholeCamera& cam, const Rigid3d& local_from_cam,
                const blend::BlendOptions& bo) {
    const double q = grid.cell_size_m;
    const glm::dvec3 c_o(c_o_f);
    const glm::dmat3 cam_from_local = glm::transpose(local_from_cam.RotationMatrix());
    const glm::dvec3 planes[5] = {
        glm::normalize(glm::dvec3(cam.fx, 0.0, cam.cx + 0.5)),
        glm::normalize(glm::dvec3(-cam.fx, 0.0, cam.width - 0.5 - cam.cx)),
        glm::normalize(glm::dvec3(0.0, cam.fy, cam.cy + 0.5)),
        glm::normalize(glm::dvec3(0.0, -cam.fy, cam.height - 0.5 - cam.cy)),
        glm::dvec3(0.0, 0.0, 1.0)};
    const size_t per_slab = size_t(opt.max_refs_per_cell);
    const uint32_t* slabs = static_cast<const uint32_t*>(refs_buf.mapped);
    const GpuView* recs = static_cast<const GpuView*>(view_records.mapped);
    glm::uvec4* out = static_cast<glm::uvec4*>(ranked_buf.mapped);
    auto bits = [](float f) { uint32_t u; std::memcpy(&u, &f, 4); return u; };
    for (const auto& [id, c] : cells) {
      const glm::dvec3 m = (glm::dvec3(UnpackCell(id)) + 0.5) * q;
      // Half diagonal, + 0.1 % of q and 1e-5 relative to |m| for floor(x / q) in float.
      const double r = q * (0.5 * std::sqrt(3.0) * 1.001) + 1e-5 * (glm::length(m) + q);
      const glm::dvec3 m_cam = cam_from_local * (m - c_o);
      bool outside = false;
      for (const glm::dvec3& n : planes) outside = outside || glm::dot(n, m_cam) < -1.01 * r;
      if (outside) continue;
      const uint32_t* slots = slabs + size_t(c.slab) * per_slab;
      const size_t n = c.refs.size();
      rank_scratch.clear();
      for (size_t i = 0; i < n; ++i) {
        const uint32_t slot = slots[i];
        if (slot == kNoSlot || recs[slot].size_layer.w == 0.0f) {
          rank_scratch.emplace_back(-1.0f, uint32_t(i));
          continue;
        }
        const glm::dvec3 c_i(glm::vec3(recs[slot].centre_exposure));
        rank_scratch.emplace_back(BlendWeightUpperBound(m, r, c_o, c_i, bo), uint32_t(i));
      }
      std::stable_sort(rank_scratch.begin(), rank_scratch.end(),
                       [](const auto& x, const auto& y) { return x.first > y.first; });
      glm::uvec4* dst = out + 2 * size_t(c.slab) * per_slab;
      for (size_t k = 0; k < n; ++k) {
        const auto [bound, i] = rank_scratch[k];
        if (bound < 0.0f) {
          dst[2 * k] = glm::uvec4(0u, 0u, 0u, bits(-1.0f));
          dst[2 * k + 1] = glm::uvec4(0u);
          continue;
        }
        const GpuView& v = recs[slots[i]];
        dst[2 * k] = glm::uvec4(bits(v.centre_exposure.x), bits(v.centre_exposure.y),
                                bits(v.centre_exposure.z), bits(bound));
        dst[2 * k + 1] = glm::uvec4(uint32_t(v.size_layer.z), i,
                                    uint32_t(v.size_layer.x) | (uint32_t(v.size_layer.y) << 16),
                                    bits(v.centre_exposure.w));
      }
    }
  }

  // The per-frame background view list (SelectBackgroundViews over the resident views in id
  // order: the CPU reference's order) and the pixel-to-direction matrix, into the Frame block.
  void FillBackground(const PinholeCamera& camera, const Rigid3d& local_from_cam, int max_views,
                      GpuFrame* f, std::vector<ViewId>* chosen_ids) const {
    std::vector<std::pair<ViewId, const ViewEntry*>> sorted;
    sorted.reserve(views.size());
    for (const auto& [id, e] : views) sorted.emplace_back(id, &e);
    std::sort(sorted.begin(), sorted.end(),
              [](const auto& a, const auto& b) { return a.first < b.first; });
    std::vector<blend::BlendView> params;
    std::vector<ViewId> ids;
    params.reserve(sorted.size());
    ids.reserve(sorted.size());
    for (const auto& [id, e] : sorted) {
      params.push_back(e->params);
      ids.push_back(id);
    }
    const std::vector<int> chosen = SelectBackgroundViews(
        camera, local_from_cam, params, ids, max_views,
        [&](int i) { return sorted[i].second->has_background; });
    const glm::mat3 m = LocalFromPixel(camera, local_from_cam);
    for (int c = 0; c < 3; ++c) f->local_from_pixel[c] = glm::vec4(m[c], 0.0f);
    f->bg_params = glm::ivec4(int(chosen.size()), 0, 0, 0);
    for (size_t j = 0; j < chosen.size(); ++j) {
      const ViewEntry& e = *sorted[chosen[j]].second;
      glm::vec4* dst = f->bg_views + kBgViewTexels * j;
      for (int c = 0; c < 3; ++c) dst[c] = glm::vec4(e.params.cam_from_local[c], 0.0f);
      dst[3] = e.params.intrinsics;
      dst[4] = glm::vec4(float(e.params.size.x), float(e.params.size.y), float(e.slot),
                         e.params.exposure);
      chosen_ids->push_back(ids[chosen[j]]);
    }
  }

  absl::StatusOr<RenderResult> Render(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                      const blend::BlendOptions& bo) {
    EXO_RETURN_IF_ERROR(bo.Validate());
    EXO_RETURN_IF_ERROR(CheckCamera(camera, local_from_cam));
    if (bo.discontinuity_radius_px != opt.bake_discontinuity_radius_px ||
        bo.discontinuity_delta_z_m != opt.bake_discontinuity_delta_z_m ||
        bo.discontinuity_delta_z_rel != opt.bake_discontinuity_delta_z_rel)
      return absl::InvalidArgumentError(
          "BlendOptions discontinuity parameters differ from the ones baked into the resident "
          "depth layers (VulkanRendererOptions::bake_discontinuity_*)");
    const uint32_t w = camera.width, h = camera.height;
    EXO_RETURN_IF_ERROR(EnsureTarget(color_target, color_pass.get(), VK_FORMAT_R8G8B8A8_UNORM,
                                     w, h));
    GpuFrame f{};
    FillFrame(camera, local_from_cam, &f);
    f.weights = glm::vec4(bo.lambda, bo.min_weight, bo.occlusion_epsilon_m,
                          bo.occlusion_epsilon_rel);
    f.background = glm::vec4(bo.background_srgb, 0.0f);
    f.iparams.x = static_cast<int>(bo.positional_mode);
    f.iparams.y = bo.n_best;
    std::vector<ViewId> bg_ids;
    if (bo.background_views > 0) {
      if (bo.background_guard_radius_px != opt.bake_background_guard_radius_px)
        return absl::InvalidArgumentError(
            "BlendOptions::background_guard_radius_px differs from the one baked into the "
            "resident depth layers (VulkanRendererOptions::bake_background_guard_radius_px)");
      FillBackground(camera, local_from_cam, bo.background_views, &f, &bg_ids);
    }
    std::memcpy(frame_ubo.mapped, &f, sizeof(f));
    const auto tr = Clock::now();
    RankRefs(glm::vec3(f.cam_centre_cell), camera, local_from_cam, bo);
    const double rank_ms = MsSince(tr);
    VkClearValue clear{};
    clear.color = {{bo.background_srgb.x, bo.background_srgb.y, bo.background_srgb.z, 0.0f}};
    const auto t0 = Clock::now();
    EXO_RETURN_IF_ERROR(EnsureBlendPipe(bo.n_best));
    EXO_RETURN_IF_ERROR(Draw(color_target, color_pass.get(),
                             blend_compute ? VK_NULL_HANDLE : blend_pipes[bo.n_best].get(), clear, 4,
                             /*deferred=*/true,
                             blend_compute ? blend_comp_pipes[bo.n_best].get() : VK_NULL_HANDLE));
    RenderResult r;
    r.gpu_ms = MsSince(t0);
    r.rank_ms = rank_ms;
    r.background_views = std::move(bg_ids);
    const auto t1 = Clock::now();
    r.color = ImageU8(w, h, 3);
    r.coverage = ImageU8(w, h, 1);
    const uint8_t* src = static_cast<const uint8_t*>(
        blend_compute ? color_target.blend_out.mapped : color_target.readback.mapped);
    uint8_t* dst = r.color.data();
    uint8_t* cov = r.coverage.data();
    for (size_t i = 0, n = size_t(w) * h; i < n; ++i) {
      dst[3 * i + 0] = src[4 * i + 0];
      dst[3 * i + 1] = src[4 * i + 1];
      dst[3 * i + 2] = src[4 * i + 2];
      const uint8_t a = src[4 * i + 3];
      cov[i] = a == 0 ? 0 : a == 255 ? 2 : a == 64 ? 3 : 1;  // blend_shade.glsl alpha codes
    }
    r.readback_ms = MsSince(t1);
    if (bo.fill_holes) {  // host post-pass on the read-back frame, same function as the CPU oracle
      const auto tf = Clock::now();
      ImageU8 known(w, h, 1, 0);
      for (size_t i = 0; i < known.size(); ++i) known.data()[i] = cov[i] >= 2;
      r.filled_pixels = FillHoles(r.color, known);
      r.fill_ms = MsSince(tf);
    }
    return r;
  }

  absl::StatusOr<Image<uint64_t>> RenderCellIds(const PinholeCamera& camera,
                                                const Rigid3d& local_from_cam) {
    EXO_RETURN_IF_ERROR(CheckCamera(camera, local_from_cam));
    const uint32_t w = camera.width, h = camera.height;
    EXO_RETURN_IF_ERROR(EnsureTarget(cellid_target, cellid_pass.get(), VK_FORMAT_R32G32_UINT, w,
                                     h));
    GpuFrame f{};
    FillFrame(camera, local_from_cam, &f);
    std::memcpy(frame_ubo.mapped, &f, sizeof(f));
    VkClearValue clear{};
    clear.color.uint32[0] = clear.color.uint32[1] = 0xFFFFFFFFu;
    EXO_RETURN_IF_ERROR(Draw(cellid_target, cellid_pass.get(), cellid_pipe.get(), clear, 8));
    Image<uint64_t> out(w, h, 1, kNoCell);
    const uint32_t* src = static_cast<const uint32_t*>(cellid_target.readback.mapped);
    for (size_t i = 0, n = size_t(w) * h; i < n; ++i)
      out.data()[i] = CellIdFromUints(src[2 * i], src[2 * i + 1]);
    return out;
  }

  absl::StatusOr<ImageF> RenderProxyDepth(const PinholeCamera& camera,
                                          const Rigid3d& local_from_cam) {
    EXO_RETURN_IF_ERROR(CheckCamera(camera, local_from_cam));
    const uint32_t w = camera.width, h = camera.height;
    EXO_RETURN_IF_ERROR(EnsureTarget(zdepth_target, zdepth_pass.get(), VK_FORMAT_R32_SFLOAT, w, h));
    GpuFrame f{};
    FillFrame(camera, local_from_cam, &f);
    // viewdepth.frag: background.xyz = optical axis (third column of local_from_cam's rotation).
    f.background = glm::vec4(glm::vec3(local_from_cam.RotationMatrix()[2]), 0.0f);
    std::memcpy(frame_ubo.mapped, &f, sizeof(f));
    VkClearValue clear{};  // 0 = no surface (invalid depth)
    EXO_RETURN_IF_ERROR(Draw(zdepth_target, zdepth_pass.get(), zdepth_pipe.get(), clear, 4));
    ImageF out(w, h, 1, 0.0f);
    std::memcpy(out.data(), zdepth_target.readback.mapped, size_t(w) * h * sizeof(float));
    return out;
  }

  uint64_t ResidentBytes() const {
    uint64_t b = 0;
    b += uint64_t(layer_w) * layer_h * slot_capacity * (kColorTexelBytes + 4);  // colour + R32F
    b += view_records.size + table_buf.size + refs_buf.size + ranked_buf.size + staging.size;
    for (const auto& [id, c] : chunks) b += c.vertices.size + c.indices.size;
    return b;
  }
};

// ===================== public API =====================

absl::StatusOr<std::unique_ptr<VulkanRenderer>> VulkanRenderer::Create(
    const VulkanRendererOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  auto impl = std::make_unique<Impl>();
  impl->opt = options;
  EXO_RETURN_IF_ERROR(impl->Init());
  return std::unique_ptr<VulkanRenderer>(new VulkanRenderer(std::move(impl)));
}

VulkanRenderer::VulkanRenderer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
VulkanRenderer::~VulkanRenderer() {
  if (impl_ && impl_->ctx) vkDeviceWaitIdle(impl_->ctx->device());
}

absl::Status VulkanRenderer::SetGrid(const CellGrid& grid) {
  if (!std::isfinite(grid.cell_size_m) || grid.cell_size_m <= 0.0)
    return absl::InvalidArgumentError(
        absl::StrCat("cell size must be finite and > 0, got ", grid.cell_size_m));
  impl_->grid = grid;
  return absl::OkStatus();
}
absl::Status VulkanRenderer::UpsertView(const StoredView& view) {
  return impl_->UpsertView(view, ViewFingerprint(view));
}
absl::Status VulkanRenderer::RemoveView(ViewId id) { return impl_->RemoveView(id); }
absl::Status VulkanRenderer::SetCellRefs(CellId cell, std::span<const ViewId> refs) {
  return impl_->SetCellRefs(cell, refs);
}
absl::Status VulkanRenderer::UpsertChunk(const MeshChunk& chunk) {
  return impl_->UpsertChunk(chunk);
}
absl::Status VulkanRenderer::RemoveChunk(uint64_t chunk_id) {
  if (impl_->chunks.erase(chunk_id) == 0)
    return absl::NotFoundError(absl::StrCat("chunk ", chunk_id, " not resident"));
  return absl::OkStatus();
}

absl::Status VulkanRenderer::SyncModel(const LumigraphModel& model) {
  Impl& m = *impl_;
  if (model.grid.cell_size_m != m.grid.cell_size_m) {
    EXO_RETURN_IF_ERROR(SetGrid(model.grid));
  }
  // Chunks: by id + version.
  std::vector<uint64_t> gone;
  for (const auto& [id, c] : m.chunks)
    if (!model.chunks.count(id)) gone.push_back(id);
  for (uint64_t id : gone) m.chunks.erase(id);
  for (const auto& [id, c] : model.chunks) {
    auto it = m.chunks.find(id);
    if (it == m.chunks.end() || it->second.version != c.version)
      EXO_RETURN_IF_ERROR(m.UpsertChunk(c));
  }
  // Views: by content fingerprint.
  std::vector<ViewId> gone_views;
  for (const auto& [id, v] : m.views)
    if (!model.views.count(id)) gone_views.push_back(id);
  for (ViewId id : gone_views) EXO_RETURN_IF_ERROR(m.RemoveView(id));
  for (const auto& [id, v] : model.views) {
    if (v.id != id)
      return absl::InvalidArgumentError(
          absl::StrCat("view map key ", id, " differs from StoredView::id ", v.id));
    const uint64_t fp = ViewFingerprint(v);
    auto it = m.views.find(id);
    if (it == m.views.end() || it->second.fingerprint != fp)
      EXO_RETURN_IF_ERROR(m.UpsertView(v, fp));
  }
  // Cells: by reference list.
  std::vector<CellId> gone_cells;
  for (const auto& [id, c] : m.cells)
    if (!model.cell_refs.count(id)) gone_cells.push_back(id);
  for (CellId id : gone_cells) EXO_RETURN_IF_ERROR(m.SetCellRefs(id, {}));
  for (const auto& [id, refs] : model.cell_refs) {
    auto it = m.cells.find(id);
    if (it == m.cells.end() || it->second.refs != refs)
      EXO_RETURN_IF_ERROR(m.SetCellRefs(id, refs));
  }
  return absl::OkStatus();
}

absl::StatusOr<RenderResult> VulkanRenderer::Render(const PinholeCamera& camera,
                                                    const Rigid3d& local_from_cam,
                                                    const blend::BlendOptions& options) {
  return impl_->Render(camera, local_from_cam, options);
}
absl::StatusOr<ImageF> VulkanRenderer::RenderProxyDepth(const PinholeCamera& camera,
                                                        const Rigid3d& local_from_cam) {
  return impl_->RenderProxyDepth(camera, local_from_cam);
}
absl::StatusOr<Image<uint64_t>> VulkanRenderer::RenderCellIds(const PinholeCamera& camera,
                                                              const Rigid3d& local_from_cam) {
  return impl_->RenderCellIds(camera, local_from_cam);
}

const UploadStats& VulkanRenderer::stats() const { return impl_->stats; }
void VulkanRenderer::ResetStats() { impl_->stats = UploadStats{}; }
uint64_t VulkanRenderer::ResidentBytes() const { return impl_->ResidentBytes(); }
size_t VulkanRenderer::num_views() const { return impl_->views.size(); }
size_t VulkanRenderer::num_cells() const { return impl_->cells.size(); }
size_t VulkanRenderer::num_chunks() const { return impl_->chunks.size(); }
std::string VulkanRenderer::DeviceName() const { return impl_->ctx->device_name(); }
std::vector<std::string> VulkanRenderer::ValidationErrors() const {
  return impl_->ctx->ValidationErrors();
}

}  // namespace exo
