#include "client/vulkan/vk_pipelines.h"

#include <bit>

#include "client/vulkan/vk_view_store.h"

#include <glm/glm.hpp>

#include "shaders/blend.comp.h"
#include "shaders/blend.frag.h"
#include "shaders/blend.vert.h"
#include "shaders/cellid.frag.h"
#include "shaders/floor.frag.h"
#include "shaders/floor.vert.h"
#include "shaders/floorproj.frag.h"
#include "shaders/fullscreen.vert.h"
#include "shaders/gbuffer.frag.h"
#include "shaders/sky.vert.h"
#include "shaders/viewdepth.frag.h"

namespace exo::vk {
namespace {
// Descriptor bindings of the one set (DescriptorInputs, blend_shade.glsl).
constexpr uint32_t kBindings = 12;
}  // namespace

absl::StatusOr<std::unique_ptr<Pipelines>> Pipelines::Create(const Context& ctx,
                                                             bool blend_compute) {
  std::unique_ptr<Pipelines> p(new Pipelines(ctx, blend_compute));
  EXO_RETURN_IF_ERROR(p->CreateSamplers());
  EXO_RETURN_IF_ERROR(p->CreateSetLayout());
  EXO_RETURN_IF_ERROR(p->CreateDescriptorSet());
  EXO_ASSIGN_OR_RETURN(p->color_pass_, p->CreateRenderPass(VK_FORMAT_R8G8B8A8_UNORM));
  EXO_ASSIGN_OR_RETURN(p->blend_pass_, p->CreateRenderPass(VK_FORMAT_R8G8B8A8_UNORM,
                                                           /*sampled_output=*/false,
                                                           /*load_depth=*/true));
  EXO_ASSIGN_OR_RETURN(p->gbuffer_pass_, p->CreateRenderPass(VK_FORMAT_R32G32B32A32_SFLOAT,
                                                             /*sampled_output=*/true));
  EXO_ASSIGN_OR_RETURN(p->cellid_pass_, p->CreateRenderPass(VK_FORMAT_R32G32_UINT));
  EXO_ASSIGN_OR_RETURN(p->zdepth_pass_, p->CreateRenderPass(VK_FORMAT_R32_SFLOAT));
  BlendVariant v;  // the default options: no inpainted keyframe, lambda 1, default weights
  v.lambda_one = blend::BlendOptions{}.lambda == 1.0f;
  v.default_weights = true;
  EXO_RETURN_IF_ERROR(p->EnsureBlendPipe(blend::BlendOptions{}.n_best, v));
  EXO_ASSIGN_OR_RETURN(p->gbuffer_pipe_, p->CreatePipeline(p->gbuffer_pass_.get(), kSpvGbufferFrag,
                                                           sizeof(kSpvGbufferFrag)));
  EXO_ASSIGN_OR_RETURN(p->cellid_pipe_, p->CreatePipeline(p->cellid_pass_.get(), kSpvCellidFrag,
                                                          sizeof(kSpvCellidFrag)));
  EXO_ASSIGN_OR_RETURN(p->zdepth_pipe_, p->CreatePipeline(p->zdepth_pass_.get(), kSpvViewdepthFrag,
                                                          sizeof(kSpvViewdepthFrag)));
  // The same three with the X-ray hole (xray_hole.glsl: constant 4 = kXrayHole).
  const int32_t hole = 1;
  const VkSpecializationMapEntry hole_entry{4, 0, sizeof(int32_t)};
  const VkSpecializationInfo hole_spec{1, &hole_entry, sizeof(hole), &hole};
  EXO_ASSIGN_OR_RETURN(p->gbuffer_hole_pipe_,
                       p->CreatePipeline(p->gbuffer_pass_.get(), kSpvGbufferFrag,
                                         sizeof(kSpvGbufferFrag), Geometry::kMesh, &hole_spec));
  EXO_ASSIGN_OR_RETURN(p->cellid_hole_pipe_,
                       p->CreatePipeline(p->cellid_pass_.get(), kSpvCellidFrag,
                                         sizeof(kSpvCellidFrag), Geometry::kMesh, &hole_spec));
  EXO_ASSIGN_OR_RETURN(p->zdepth_hole_pipe_,
                       p->CreatePipeline(p->zdepth_pass_.get(), kSpvViewdepthFrag,
                                         sizeof(kSpvViewdepthFrag), Geometry::kMesh, &hole_spec));
  EXO_ASSIGN_OR_RETURN(p->floor_pipe_, p->CreatePipeline(p->color_pass_.get(), kSpvFloorFrag,
                                                         sizeof(kSpvFloorFrag), Geometry::kFloor));
  EXO_ASSIGN_OR_RETURN(p->floor_projective_pipe_,
                       p->CreatePipeline(p->color_pass_.get(), kSpvFloorprojFrag,
                                         sizeof(kSpvFloorprojFrag)));
  return p;
}

bool BlendVariant::DefaultWeights(const blend::BlendOptions& bo) {
  const blend::BlendOptions d;
  return std::bit_cast<uint32_t>(bo.min_weight) == std::bit_cast<uint32_t>(d.min_weight) &&
         std::bit_cast<uint32_t>(bo.occlusion_epsilon_m) ==
             std::bit_cast<uint32_t>(d.occlusion_epsilon_m) &&
         std::bit_cast<uint32_t>(bo.occlusion_epsilon_rel) ==
             std::bit_cast<uint32_t>(d.occlusion_epsilon_rel);
}

absl::Status Pipelines::EnsureBlendPipe(int n_best, BlendVariant v) {
  if (n_best < 1 || n_best > blend::kMaxBlendViews)
    return absl::InvalidArgumentError("n_best out of range");
  BlendPipes& b = blend_pipes_[n_best][v.index()];
  if (blend_compute_ ? bool(b.compute) : bool(b.surface)) return absl::OkStatus();
  // Specialisation constants of blend_shade.glsl: 0 = n_best, 1 = which pixels the pipeline
  // shades (kBlendPass: 0 both, the compute path; 1 surface; 2 background at infinity),
  // 2 = whether the frame has inpainted keyframes (kInpainted: 0 compiles their loop out),
  // 3 = whether lambda is exactly 1 (kLambdaOne: the positional weight is compiled out),
  // 5 = whether 6..8 hold the frame's min_weight, occlusion_epsilon_m and _rel (kBakedWeights:
  // the defaults; constant 4 is xray_hole.glsl's, not in the blend shaders).
  const blend::BlendOptions d;
  int32_t values[8] = {n_best,
                       0,
                       v.inpainted ? 1 : 0,
                       v.lambda_one ? 1 : 0,
                       v.default_weights ? 1 : 0,
                       std::bit_cast<int32_t>(d.min_weight),
                       std::bit_cast<int32_t>(d.occlusion_epsilon_m),
                       std::bit_cast<int32_t>(d.occlusion_epsilon_rel)};
  VkSpecializationMapEntry entries[8];
  const uint32_t ids[8] = {0, 1, 2, 3, 5, 6, 7, 8};
  for (uint32_t k = 0; k < 8; ++k)
    entries[k] = {ids[k], uint32_t(k * sizeof(int32_t)), sizeof(int32_t)};
  VkSpecializationInfo spec{8, entries, sizeof(values), values};
  if (blend_compute_) {
    EXO_ASSIGN_OR_RETURN(b.compute, CreateComputeBlendPipe(spec));
    return absl::OkStatus();
  }
  values[1] = 1;
  EXO_ASSIGN_OR_RETURN(b.surface,
                       CreatePipeline(blend_pass_.get(), kSpvBlendFrag, sizeof(kSpvBlendFrag),
                                      Geometry::kFullscreenSurface, &spec));
  values[1] = 2;
  EXO_ASSIGN_OR_RETURN(b.sky, CreatePipeline(blend_pass_.get(), kSpvBlendFrag, sizeof(kSpvBlendFrag),
                                             Geometry::kFullscreenSky, &spec));
  return absl::OkStatus();
}

absl::StatusOr<UniquePipeline> Pipelines::CreateComputeBlendPipe(
    const VkSpecializationInfo& spec) const {
  EXO_ASSIGN_OR_RETURN(auto cs, CreateModule(kSpvBlendComp, sizeof(kSpvBlendComp)));
  VkComputePipelineCreateInfo ci{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
  ci.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
  ci.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  ci.stage.module = cs.get();
  ci.stage.pName = "main";
  ci.stage.pSpecializationInfo = &spec;
  ci.layout = pipe_layout_.get();
  VkPipeline raw;
  EXO_VK_RETURN(vkCreateComputePipelines(ctx_.device(), VK_NULL_HANDLE, 1, &ci, nullptr, &raw));
  return UniquePipeline(ctx_.device(), raw);
}

absl::Status Pipelines::CreateSamplers() {
  // Nearest sampler for the depth array (texelFetch only) and a bilinear, clamp-to-edge one for
  // the colour array: one filtered texture() per blended view instead of four texelFetch + float
  // lerp (the texel decode to linear happens before filtering, as blend_math.h specifies;
  // measured 3-4x cheaper on llvmpipe, docs/vulkan.md).
  for (int k = 0; k < 2; ++k) {
    VkSamplerCreateInfo s{VK_STRUCTURE_TYPE_SAMPLER_CREATE_INFO};
    s.magFilter = s.minFilter = k == 0 ? VK_FILTER_NEAREST : VK_FILTER_LINEAR;
    s.mipmapMode = VK_SAMPLER_MIPMAP_MODE_NEAREST;
    s.addressModeU = s.addressModeV = s.addressModeW = VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE;
    s.maxLod = 0.0f;
    VkSampler raw;
    EXO_VK_RETURN(vkCreateSampler(ctx_.device(), &s, nullptr, &raw));
    (k == 0 ? sampler_ : linear_sampler_) = UniqueSampler(ctx_.device(), raw);
  }
  return absl::OkStatus();
}

absl::Status Pipelines::CreateSetLayout() {
  VkDescriptorSetLayoutBinding b[kBindings]{};
  for (uint32_t i = 0; i < kBindings; ++i) {
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
  b[4].descriptorType = b[6].descriptorType = VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER;
  // The baked depth layers as a storage image (imageLoad, nearest texel; docs/vulkan.md issue 16
  // session 15).
  b[5].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_IMAGE;
  // Ranked refs (per frame): a storage texel buffer read with imageLoad, which llvmpipe inlines
  // (a uniform texel buffer's texelFetch is a call, and every call spills the live vector
  // registers of the reference loop; docs/vulkan.md issue 16 session 15).
  b[7].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER;
  b[8].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;        // blend.comp output (RGBA8)
  b[9].descriptorType = VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER; // RenderFloor's texture
  // The frame's background views (blend_shade.glsl bg_texels): read with a loop-dependent index,
  // which llvmpipe makes a per-lane, per-component gather from a uniform block.
  b[10].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
  // The colour layers as a storage image: the blend's bilinear sample as 4 imageLoads + lerp
  // (blend_shade.glsl SampleLinear; docs/vulkan.md issue 16 session 15).
  b[11].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_IMAGE;
  VkDescriptorSetLayoutCreateInfo li{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
  li.bindingCount = kBindings;
  li.pBindings = b;
  VkDescriptorSetLayout raw_layout;
  EXO_VK_RETURN(vkCreateDescriptorSetLayout(ctx_.device(), &li, nullptr, &raw_layout));
  set_layout_ = UniqueDescriptorSetLayout(ctx_.device(), raw_layout);
  VkPipelineLayoutCreateInfo pli{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
  pli.setLayoutCount = 1;
  pli.pSetLayouts = &raw_layout;
  // The background pass's per-tile-group view list (blend_shade.glsl SkyList, one uint).
  const VkPushConstantRange push{VK_SHADER_STAGE_FRAGMENT_BIT | VK_SHADER_STAGE_COMPUTE_BIT, 0,
                                 sizeof(uint32_t)};
  pli.pushConstantRangeCount = 1;
  pli.pPushConstantRanges = &push;
  VkPipelineLayout raw_pl;
  EXO_VK_RETURN(vkCreatePipelineLayout(ctx_.device(), &pli, nullptr, &raw_pl));
  pipe_layout_ = UniquePipelineLayout(ctx_.device(), raw_pl);
  return absl::OkStatus();
}

absl::Status Pipelines::CreateDescriptorSet() {
  VkDescriptorPoolSize sizes[6] = {{VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER, 1},
                                   {VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, 4},
                                   {VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER, 1},
                                   {VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, 3},
                                   {VK_DESCRIPTOR_TYPE_STORAGE_IMAGE, 2},
                                   {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1}};
  VkDescriptorPoolCreateInfo pi{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
  pi.maxSets = 1;
  pi.poolSizeCount = 6;
  pi.pPoolSizes = sizes;
  VkDescriptorPool raw_pool;
  EXO_VK_RETURN(vkCreateDescriptorPool(ctx_.device(), &pi, nullptr, &raw_pool));
  desc_pool_ = UniqueDescriptorPool(ctx_.device(), raw_pool);
  const VkDescriptorSetLayout raw_layout = set_layout_.get();
  VkDescriptorSetAllocateInfo ai{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
  ai.descriptorPool = raw_pool;
  ai.descriptorSetCount = 1;
  ai.pSetLayouts = &raw_layout;
  EXO_VK_RETURN(vkAllocateDescriptorSets(ctx_.device(), &ai, &desc_set_));
  return absl::OkStatus();
}

absl::StatusOr<UniqueBufferView> Pipelines::MakeBufferView(const Buffer& b, VkFormat format) const {
  VkBufferViewCreateInfo ci{VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO};
  ci.buffer = b.buffer.get();
  ci.format = format;
  ci.offset = 0;
  ci.range = VK_WHOLE_SIZE;
  VkBufferView raw;
  EXO_VK_RETURN(vkCreateBufferView(ctx_.device(), &ci, nullptr, &raw));
  return UniqueBufferView(ctx_.device(), raw);
}

absl::Status Pipelines::WriteDescriptors(const DescriptorInputs& in) {
  // The set may still be in use by nothing: every Submit waits for its fence.
  EXO_ASSIGN_OR_RETURN(buffer_views_[0],
                       MakeBufferView(*in.view_records, VK_FORMAT_R32G32B32A32_SFLOAT));
  EXO_ASSIGN_OR_RETURN(buffer_views_[1],
                       MakeBufferView(*in.cell_table, VK_FORMAT_R32G32B32A32_UINT));
  EXO_ASSIGN_OR_RETURN(buffer_views_[2], MakeBufferView(*in.refs, VK_FORMAT_R32_UINT));
  EXO_ASSIGN_OR_RETURN(buffer_views_[3],
                       MakeBufferView(*in.ranked_refs, VK_FORMAT_R32G32B32A32_UINT));
  VkDescriptorBufferInfo ubo{in.frame_ubo->buffer.get(), 0, VK_WHOLE_SIZE};
  VkBufferView tb[3] = {buffer_views_[0].get(), buffer_views_[1].get(), buffer_views_[2].get()};
  VkBufferView ranked_view = buffer_views_[3].get();
  EXO_ASSIGN_OR_RETURN(buffer_views_[4], MakeBufferView(*in.bg_views, VK_FORMAT_R32G32B32A32_SFLOAT));
  VkBufferView bg_view = buffer_views_[4].get();
  VkDescriptorImageInfo ii[3] = {
      {linear_sampler_.get(), in.colors->view.get(), ViewStore::kColorLayout},
      {VK_NULL_HANDLE, in.depths->view.get(), ViewStore::kDepthLayout},
      {sampler_.get(), in.gbuffer->view.get(), VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL}};
  VkDescriptorImageInfo floor_info{linear_sampler_.get(), in.floor_colors->view.get(),
                                   VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL};
  VkDescriptorBufferInfo out_info{in.blend_out->buffer.get(), 0, VK_WHOLE_SIZE};
  VkDescriptorImageInfo color_texels{VK_NULL_HANDLE, in.colors->view.get(), ViewStore::kColorLayout};
  const uint32_t writes = kBindings;
  VkWriteDescriptorSet w[kBindings]{};
  for (uint32_t i = 0; i < writes; ++i) {
    w[i].sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
    w[i].dstSet = desc_set_;
    w[i].dstBinding = i;
    w[i].descriptorCount = 1;
    if (i == 0) {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER;
      w[i].pBufferInfo = &ubo;
    } else if (i < 4) {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
      w[i].pTexelBufferView = &tb[i - 1];
    } else if (i == 7) {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_TEXEL_BUFFER;
      w[i].pTexelBufferView = &ranked_view;
    } else if (i == 8) {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
      w[i].pBufferInfo = &out_info;
    } else if (i == 10) {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
      w[i].pTexelBufferView = &bg_view;
    } else if (i == 5) {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_IMAGE;
      w[i].pImageInfo = &ii[1];
    } else if (i == 11) {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_IMAGE;
      w[i].pImageInfo = &color_texels;
    } else if (i == 9) {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER;
      w[i].pImageInfo = &floor_info;
    } else {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER;
      w[i].pImageInfo = &ii[i - 4];
    }
  }
  vkUpdateDescriptorSets(ctx_.device(), writes, w, 0, nullptr);
  return absl::OkStatus();
}

namespace {

// The render pass's external dependencies: earlier transfer / attachment / shader use before the
// pass, and after it the read-back copy or (sampled_output) a later pass's shader read.
void SubpassDependencies(bool sampled_output, VkSubpassDependency dep[2]) {
  dep[0] = dep[1] = VkSubpassDependency{};
  dep[0].srcSubpass = VK_SUBPASS_EXTERNAL;
  dep[0].dstSubpass = 0;
  dep[0].srcStageMask =
      VK_PIPELINE_STAGE_TRANSFER_BIT | VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT |
      VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT | VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT;
  dep[0].dstStageMask =
      VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT | VK_PIPELINE_STAGE_EARLY_FRAGMENT_TESTS_BIT;
  dep[0].srcAccessMask = VK_ACCESS_TRANSFER_READ_BIT | VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT;
  dep[0].dstAccessMask = VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT |
                         VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_READ_BIT |
                         VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT;
  dep[1].srcSubpass = 0;
  dep[1].dstSubpass = VK_SUBPASS_EXTERNAL;
  dep[1].srcStageMask = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT;
  dep[1].dstStageMask =
      sampled_output
          ? (VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT)
          : VK_PIPELINE_STAGE_TRANSFER_BIT;
  dep[1].srcAccessMask = VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
  dep[1].dstAccessMask = sampled_output ? VK_ACCESS_SHADER_READ_BIT : VK_ACCESS_TRANSFER_READ_BIT;
}

}  // namespace

absl::StatusOr<UniqueRenderPass> Pipelines::CreateRenderPass(VkFormat color_format,
                                                             bool sampled_output,
                                                             bool load_depth) const {
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
  // The G-buffer pass stores its depth for the blend pass, which loads it (surface / sky test).
  att[1].storeOp = sampled_output ? VK_ATTACHMENT_STORE_OP_STORE : VK_ATTACHMENT_STORE_OP_DONT_CARE;
  if (load_depth) {
    att[1].loadOp = VK_ATTACHMENT_LOAD_OP_LOAD;
    att[1].initialLayout = VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL;
  }
  att[1].finalLayout = VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL;
  VkAttachmentReference cref{0, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL};
  VkAttachmentReference dref{1, VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL};
  VkSubpassDescription sub{};
  sub.pipelineBindPoint = VK_PIPELINE_BIND_POINT_GRAPHICS;
  sub.colorAttachmentCount = 1;
  sub.pColorAttachments = &cref;
  sub.pDepthStencilAttachment = &dref;
  VkSubpassDependency dep[2];
  SubpassDependencies(sampled_output, dep);
  VkRenderPassCreateInfo ri{VK_STRUCTURE_TYPE_RENDER_PASS_CREATE_INFO};
  ri.attachmentCount = 2;
  ri.pAttachments = att;
  ri.subpassCount = 1;
  ri.pSubpasses = &sub;
  ri.dependencyCount = 2;
  ri.pDependencies = dep;
  VkRenderPass raw;
  EXO_VK_RETURN(vkCreateRenderPass(ctx_.device(), &ri, nullptr, &raw));
  return UniqueRenderPass(ctx_.device(), raw);
}

absl::StatusOr<UniqueShaderModule> Pipelines::CreateModule(const uint32_t* code,
                                                           size_t bytes) const {
  VkShaderModuleCreateInfo si{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
  si.codeSize = bytes;
  si.pCode = code;
  VkShaderModule raw;
  EXO_VK_RETURN(vkCreateShaderModule(ctx_.device(), &si, nullptr, &raw));
  return UniqueShaderModule(ctx_.device(), raw);
}

namespace {

// The fixed-function state of every graphics pipeline (viewport and scissor are dynamic).
struct FixedFunctionState {
  VkVertexInputBindingDescription vb{0, sizeof(glm::vec3), VK_VERTEX_INPUT_RATE_VERTEX};
  VkVertexInputAttributeDescription va{0, 0, VK_FORMAT_R32G32B32_SFLOAT, 0};
  VkPipelineVertexInputStateCreateInfo vi{
      VK_STRUCTURE_TYPE_PIPELINE_VERTEX_INPUT_STATE_CREATE_INFO};
  VkPipelineInputAssemblyStateCreateInfo ia{
      VK_STRUCTURE_TYPE_PIPELINE_INPUT_ASSEMBLY_STATE_CREATE_INFO};
  VkPipelineViewportStateCreateInfo vp{VK_STRUCTURE_TYPE_PIPELINE_VIEWPORT_STATE_CREATE_INFO};
  VkPipelineRasterizationStateCreateInfo rs{
      VK_STRUCTURE_TYPE_PIPELINE_RASTERIZATION_STATE_CREATE_INFO};
  VkPipelineMultisampleStateCreateInfo ms{VK_STRUCTURE_TYPE_PIPELINE_MULTISAMPLE_STATE_CREATE_INFO};
  VkPipelineDepthStencilStateCreateInfo ds{
      VK_STRUCTURE_TYPE_PIPELINE_DEPTH_STENCIL_STATE_CREATE_INFO};
  VkPipelineColorBlendAttachmentState cba{};
  VkPipelineColorBlendStateCreateInfo cb{VK_STRUCTURE_TYPE_PIPELINE_COLOR_BLEND_STATE_CREATE_INFO};
  VkDynamicState dyn[2] = {VK_DYNAMIC_STATE_VIEWPORT, VK_DYNAMIC_STATE_SCISSOR};
  VkPipelineDynamicStateCreateInfo dy{VK_STRUCTURE_TYPE_PIPELINE_DYNAMIC_STATE_CREATE_INFO};

  // Not copyable: the create infos point into this object.
  FixedFunctionState(bool vertex_input, VkCompareOp depth_compare, bool depth_write) {
    vi.vertexBindingDescriptionCount = vertex_input ? 1 : 0;
    vi.pVertexBindingDescriptions = &vb;
    vi.vertexAttributeDescriptionCount = vertex_input ? 1 : 0;
    vi.pVertexAttributeDescriptions = &va;
    ia.topology = VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST;
    vp.viewportCount = 1;
    vp.scissorCount = 1;
    rs.polygonMode = VK_POLYGON_MODE_FILL;
    rs.cullMode = VK_CULL_MODE_NONE;  // the CPU rasterizer does not cull by default either
    rs.frontFace = VK_FRONT_FACE_COUNTER_CLOCKWISE;
    rs.lineWidth = 1.0f;
    ms.rasterizationSamples = VK_SAMPLE_COUNT_1_BIT;
    ds.depthTestEnable = VK_TRUE;
    ds.depthWriteEnable = depth_write ? VK_TRUE : VK_FALSE;
    ds.depthCompareOp = depth_compare;
    cba.colorWriteMask = VK_COLOR_COMPONENT_R_BIT | VK_COLOR_COMPONENT_G_BIT |
                         VK_COLOR_COMPONENT_B_BIT | VK_COLOR_COMPONENT_A_BIT;
    cb.attachmentCount = 1;
    cb.pAttachments = &cba;
    dy.dynamicStateCount = 2;
    dy.pDynamicStates = dyn;
  }
  FixedFunctionState(const FixedFunctionState&) = delete;
  FixedFunctionState& operator=(const FixedFunctionState&) = delete;
};

}  // namespace

absl::StatusOr<UniquePipeline> Pipelines::CreatePipeline(VkRenderPass pass, const uint32_t* frag,
                                                         size_t frag_bytes, Geometry geometry,
                                                         const VkSpecializationInfo* spec) const {
  const bool mesh = geometry == Geometry::kMesh || geometry == Geometry::kFloor;
  UniqueShaderModule vs;
  if (geometry == Geometry::kFullscreenSurface) {
    EXO_ASSIGN_OR_RETURN(vs, CreateModule(kSpvFullscreenVert, sizeof(kSpvFullscreenVert)));
  } else if (geometry == Geometry::kFloor) {
    EXO_ASSIGN_OR_RETURN(vs, CreateModule(kSpvFloorVert, sizeof(kSpvFloorVert)));
  } else if (geometry == Geometry::kFullscreenSky) {
    EXO_ASSIGN_OR_RETURN(vs, CreateModule(kSpvSkyVert, sizeof(kSpvSkyVert)));
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
  // The full-screen triangle (fullscreen.vert) and the background pass's tile rectangles
  // (sky.vert, vec3 vertices) lie at depth 1: GREATER passes where the G-buffer pass drew a
  // surface, LESS_OR_EQUAL where the depth kept its clear value 1.
  const FixedFunctionState st(geometry != Geometry::kFullscreenSurface,
                              mesh                                       ? VK_COMPARE_OP_LESS
                              : geometry == Geometry::kFullscreenSurface ? VK_COMPARE_OP_GREATER
                                                                         : VK_COMPARE_OP_LESS_OR_EQUAL,
                              /*depth_write=*/mesh);
  VkGraphicsPipelineCreateInfo gi{VK_STRUCTURE_TYPE_GRAPHICS_PIPELINE_CREATE_INFO};
  gi.stageCount = 2;
  gi.pStages = stages;
  gi.pVertexInputState = &st.vi;
  gi.pInputAssemblyState = &st.ia;
  gi.pViewportState = &st.vp;
  gi.pRasterizationState = &st.rs;
  gi.pMultisampleState = &st.ms;
  gi.pDepthStencilState = &st.ds;
  gi.pColorBlendState = &st.cb;
  gi.pDynamicState = &st.dy;
  gi.layout = pipe_layout_.get();
  gi.renderPass = pass;
  VkPipeline raw;
  EXO_VK_RETURN(vkCreateGraphicsPipelines(ctx_.device(), VK_NULL_HANDLE, 1, &gi, nullptr, &raw));
  return UniquePipeline(ctx_.device(), raw);
}

}  // namespace exo::vk
