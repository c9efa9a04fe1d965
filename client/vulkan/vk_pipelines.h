// PRIVATE to client/vulkan: the renderer's fixed GPU programme state. Samplers, the one
// descriptor set (bindings 0..8 of shaders/lumigraph_common.glsl) and its layout, the render
// passes (colour, deferred blend colour, G-buffer, cell id, view depth) and their pipelines; the
// blend pipelines are specialised per n_best and created on first use.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>

#include "client/vulkan/vk_core_internal.h"
#include "common/lumigraph/blend_math.h"

namespace exo::vk {

// Per-frame choices baked into a blend pipeline as specialisation constants (blend_shade.glsl):
// the frame has inpainted keyframes (else their loop is compiled out), the blend's lambda is
// exactly 1 (the positional weight is then multiplied by 0: compiled out, same weights), the
// frame's min_weight and occlusion epsilons are the BlendOptions defaults (baked in as
// constants instead of read per pixel from the Frame block; same floats).
struct BlendVariant {
  bool inpainted = false;
  bool lambda_one = false;
  bool default_weights = false;
  int index() const {
    return (inpainted ? 1 : 0) | (lambda_one ? 2 : 0) | (default_weights ? 4 : 0);
  }
  static constexpr int kCount = 8;
  // Whether `bo`'s min_weight and occlusion epsilons are the defaults, bit for bit.
  static bool DefaultWeights(const blend::BlendOptions& bo);
};

// What the descriptor set binds; every pointer must be non-null and outlive the next write.
struct DescriptorInputs {
  const Buffer* frame_ubo = nullptr;     // 0: Frame block (uniform buffer)
  const Buffer* view_records = nullptr;  // 1: GpuView texels (RGBA32F texel buffer)
  const Buffer* cell_table = nullptr;    // 2: cell hash table (RGBA32UI texel buffer)
  const Buffer* refs = nullptr;          // 3: reference slots (R32UI texel buffer)
  const Image* colors = nullptr;         // 4: colour layers (bilinear sampler)
  const Image* depths = nullptr;         // 5: baked depth layers (storage image)
  const Image* gbuffer = nullptr;        // 6: G-buffer of the blend target (nearest sampler)
  const Buffer* ranked_refs = nullptr;   // 7: per-frame ranked references (RGBA32UI)
  const Buffer* blend_out = nullptr;     // 8: blend.comp output (storage buffer)
  const Image* floor_colors = nullptr;   // 9: RenderFloor's RGBA8 texture (bilinear sampler)
  const Buffer* bg_views = nullptr;      // 10: the frame's background views (RGBA32F texel buffer)
  // 11: the colour layers (4) again, as a storage image (the blend's bilinear sample by 4 loads)
};

class Pipelines {
 public:
  // blend_compute: the blend runs as blend.comp over the G-buffer instead of blend.frag.
  static absl::StatusOr<std::unique_ptr<Pipelines>> Create(const Context& ctx, bool blend_compute);

  // Creates the blend pipelines for `n_best` (1..kMaxBlendViews) and `v` unless they exist.
  absl::Status EnsureBlendPipe(int n_best, BlendVariant v);
  // The blend pipelines of `n_best` for the mode in use; the other mode's are VK_NULL_HANDLE.
  // Fragment mode: two full-screen passes selected by the G-buffer pass's depth (early depth
  // test, so llvmpipe skips every 4x4 block where no fragment passes): blend_pipe shades the
  // pixels with a proxy surface (depth < 1), blend_sky_pipe the others (background at infinity).
  VkPipeline blend_pipe(int n_best, BlendVariant v) const {
    return blend_pipes_[n_best][v.index()].surface.get();
  }
  VkPipeline blend_sky_pipe(int n_best, BlendVariant v) const {
    return blend_pipes_[n_best][v.index()].sky.get();
  }
  VkPipeline blend_compute_pipe(int n_best, BlendVariant v) const {
    return blend_pipes_[n_best][v.index()].compute.get();
  }
  bool blend_compute() const { return blend_compute_; }

  // Points every binding at `in` (new texel-buffer views over the current buffers).
  absl::Status WriteDescriptors(const DescriptorInputs& in);

  VkRenderPass color_pass() const { return color_pass_.get(); }
  // Colour pass of the deferred blend: same attachments as color_pass (compatible framebuffer)
  // but the depth attachment is LOADED from the G-buffer pass (which stores it).
  VkRenderPass blend_pass() const { return blend_pass_.get(); }
  VkRenderPass gbuffer_pass() const { return gbuffer_pass_.get(); }
  VkRenderPass cellid_pass() const { return cellid_pass_.get(); }
  VkRenderPass zdepth_pass() const { return zdepth_pass_.get(); }
  // The proxy passes; xray_hole: the variant with the viewer's X-ray hole (shaders/
  // xray_hole.glsl, specialisation constant 4), whose `discard` would cost llvmpipe its early
  // depth test in every frame without a hole.
  VkPipeline gbuffer_pipe(bool xray_hole = false) const {
    return (xray_hole ? gbuffer_hole_pipe_ : gbuffer_pipe_).get();
  }
  VkPipeline cellid_pipe(bool xray_hole = false) const {
    return (xray_hole ? cellid_hole_pipe_ : cellid_pipe_).get();
  }
  VkPipeline zdepth_pipe(bool xray_hole = false) const {
    return (xray_hole ? zdepth_hole_pipe_ : zdepth_pipe_).get();
  }
  // RenderFloor: the issue-16 floor (floor.vert + floor.frag) and the session-9 one
  // (floorproj.frag).
  VkPipeline floor_pipe() const { return floor_pipe_.get(); }
  VkPipeline floor_projective_pipe() const { return floor_projective_pipe_.get(); }
  VkPipelineLayout layout() const { return pipe_layout_.get(); }
  const VkDescriptorSet* set() const { return &desc_set_; }

 private:
  Pipelines(const Context& ctx, bool blend_compute) : ctx_(ctx), blend_compute_(blend_compute) {}
  absl::Status CreateSamplers();
  absl::Status CreateSetLayout();
  absl::Status CreateDescriptorSet();
  absl::StatusOr<UniqueBufferView> MakeBufferView(const Buffer& b, VkFormat format) const;
  // sampled_output: the colour attachment ends in SHADER_READ_ONLY_OPTIMAL for a later pass's
  // shader (the G-buffer) and the depth attachment is stored; otherwise the colour ends in
  // TRANSFER_SRC_OPTIMAL for read-back. load_depth: the depth attachment is loaded (the blend
  // pass reads the G-buffer pass's depth) instead of cleared.
  absl::StatusOr<UniqueRenderPass> CreateRenderPass(VkFormat color_format,
                                                    bool sampled_output = false,
                                                    bool load_depth = false) const;
  absl::StatusOr<UniqueShaderModule> CreateModule(const uint32_t* code, size_t bytes) const;
  // kMesh: the proxy-mesh pipeline (depth test LESS + write). The others draw one triangle over
  // the viewport at depth 1 (no vertex input, no depth write) for the deferred blend pass:
  // kFullscreenSurface passes where the G-buffer pass left a surface (1 > depth),
  // kFullscreenSky where it left none (1 <= depth, i.e. the clear value 1); the latter draws the
  // background pass's tile rectangles (sky.vert, vec3 vertices at depth 1), not one triangle.
  // kFloor: the proxy mesh like kMesh but with floor.vert (per-vertex texture coordinate).
  enum class Geometry { kMesh, kFullscreenSurface, kFullscreenSky, kFloor };
  absl::StatusOr<UniquePipeline> CreatePipeline(VkRenderPass pass, const uint32_t* frag,
                                                size_t frag_bytes, Geometry geometry = Geometry::kMesh,
                                                const VkSpecializationInfo* spec = nullptr) const;
  absl::StatusOr<UniquePipeline> CreateComputeBlendPipe(const VkSpecializationInfo& spec) const;

  const Context& ctx_;
  const bool blend_compute_;
  UniqueSampler sampler_, linear_sampler_;
  UniqueDescriptorSetLayout set_layout_;
  UniquePipelineLayout pipe_layout_;
  UniqueDescriptorPool desc_pool_;
  VkDescriptorSet desc_set_ = VK_NULL_HANDLE;
  UniqueBufferView buffer_views_[5];  // views, cell table, refs, ranked refs, background views
  UniqueRenderPass color_pass_, blend_pass_, cellid_pass_, zdepth_pass_, gbuffer_pass_;
  UniquePipeline gbuffer_pipe_, cellid_pipe_, zdepth_pipe_, floor_pipe_, floor_projective_pipe_;
  UniquePipeline gbuffer_hole_pipe_, cellid_hole_pipe_, zdepth_hole_pipe_;
  // Blend pipelines per n_best (specialisation constant 0 of blend.frag / blend.comp: the
  // best-n slots and the n-th-best pick are then compile-time; measured ~6 % of the frame) and
  // per BlendVariant (constant 2, inpainted keyframes: their per-pixel loop cost ~8 % of the
  // frame even with no keyframe, llvmpipe runs a loop body at least once; constant 3, lambda 1;
  // constants 5..8, the default min_weight and occlusion epsilons).
  struct BlendPipes {
    UniquePipeline surface, sky, compute;
  };
  BlendPipes blend_pipes_[blend::kMaxBlendViews + 1][BlendVariant::kCount];
};

}  // namespace exo::vk
