// PRIVATE to client/vulkan: the render passes over the resident stores. Owns the pipelines,
// the Frame uniform block and one render target per pass: the deferred blend (G-buffer pass,
// then blend.frag or blend.comp, read-back, optional host hole fill), the cell-id pass and the
// proxy-depth pass. Reads the view store, cell table and mesh chunks; ranks the cell table's
// references once per blended frame.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "client/vulkan/vk_cell_table.h"
#include "client/vulkan/vk_core_internal.h"
#include "client/vulkan/vk_mesh_chunks.h"
#include "client/vulkan/vk_pipelines.h"
#include "client/vulkan/vk_render_target.h"
#include "client/vulkan/vk_view_store.h"
#include "client/vulkan/vulkan_renderer.h"

namespace exo::vk {

struct GpuFrame;

class FrameRenderer {
 public:
  // Every argument must outlive the renderer; `grid` is read at each frame.
  static absl::StatusOr<std::unique_ptr<FrameRenderer>> Create(const Context& ctx,
                                                               const VulkanRendererOptions& opt,
                                                               const CellGrid& grid,
                                                               ViewStore& views, CellTable& cells,
                                                               MeshChunks& chunks);

  absl::StatusOr<RenderResult> Render(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                      const blend::BlendOptions& options,
                                      const RenderApprox& approx = {});
  absl::StatusOr<exo::Image<uint64_t>> RenderCellIds(const PinholeCamera& camera,
                                                     const Rigid3d& local_from_cam);
  // VulkanRenderer::RenderFloor (kForward: shaders/floor.vert + floor.frag; projective:
  // floorproj.frag) and PrepareFloor.
  absl::StatusOr<RenderResult> RenderFloor(const PinholeCamera& camera,
                                           const Rigid3d& local_from_cam, bool projective);
  absl::Status PrepareFloor(const PinholeCamera& camera, const Rigid3d& local_from_cam);
  absl::StatusOr<ImageF> RenderProxyDepth(const PinholeCamera& camera,
                                          const Rigid3d& local_from_cam);
  // VulkanRenderer::SetXrayHole: Render's G-buffer pass, RenderCellIds and RenderProxyDepth use
  // the pipelines with the hole while one is set (the floor passes do not).
  absl::Status SetXrayHole(std::optional<XrayHole> hole);
  const std::optional<XrayHole>& xray_hole() const { return xray_hole_; }

 private:
  FrameRenderer(const Context& ctx, const VulkanRendererOptions& opt, const CellGrid& grid,
                ViewStore& views, CellTable& cells, MeshChunks& chunks)
      : ctx_(ctx), opt_(opt), grid_(grid), views_(views), cells_(cells), chunks_(chunks) {}
  // A 4-byte blend output and a 1x1 G-buffer in SHADER_READ_ONLY_OPTIMAL for bindings 8 and 6
  // before any blend target exists (lavapipe reads every binding of a bound set).
  absl::Status CreatePlaceholders();
  // Rewrites the descriptor set when a store replaced a buffer or the blend target changed.
  absl::Status UpdateDescriptors();
  absl::Status EnsureBlendTarget(uint32_t w, uint32_t h);
  absl::Status CheckCamera(const PinholeCamera& camera, const Rigid3d& local_from_cam) const;
  // The render-time options must match what was baked into the resident depth layers.
  absl::Status CheckBakedOptions(const blend::BlendOptions& bo) const;
  void FillFrame(const PinholeCamera& camera, const Rigid3d& local_from_cam, GpuFrame* f) const;
  // The resident view nearest the camera centre (ties: lower id), nullptr without views.
  const ViewStore::Entry* NearestView(const Rigid3d& local_from_cam, ViewId* id) const;
  void FillInpainted(const Rigid3d& local_from_cam, GpuFrame* f) const;
  // Also the chosen views' store entries in *bg_entries (their background masks).
  void FillBackground(const PinholeCamera& camera, const Rigid3d& local_from_cam, int max_views,
                      GpuFrame* f, std::vector<ViewId>* chosen_ids,
                      std::vector<const ViewStore::Entry*>* bg_entries) const;
  // The blend pass's Frame block (camera, weights, background list) into frame_ubo_.
  void UploadBlendFrame(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                        const blend::BlendOptions& bo, GpuFrame* f, std::vector<ViewId>* bg_ids,
                        std::vector<const ViewStore::Entry*>* bg_entries) const;
  // The background pass's tile rectangles into sky_vb_ and their draws (grouped by the tiles'
  // background-view list) into sky_draws_.
  absl::Status BuildSkyDraws(const GpuFrame& f,
                             const std::vector<const ViewStore::Entry*>& bg_entries, uint32_t w,
                             uint32_t h);
  // The deferred blend of one frame into color_target_ (graphics or compute); sky_views: the
  // frame's background views (0: the pass for pixels without surface is not drawn);
  // inpainted: the frame has inpainted keyframes (else the pipeline without their loop); the
  // pipeline variant also follows bo.lambda == 1 and the default weights (BlendVariant).
  absl::Status DrawBlend(const blend::BlendOptions& bo, int sky_views, bool inpainted);
  absl::Status Draw(RenderTarget& t, VkRenderPass pass, VkPipeline pipe, const VkClearValue& clear,
                    uint32_t texel_bytes, bool deferred = false,
                    VkPipeline compute_pipe = VK_NULL_HANDLE, VkPipeline sky_pipe = VK_NULL_HANDLE);

  const Context& ctx_;
  const VulkanRendererOptions& opt_;
  const CellGrid& grid_;
  ViewStore& views_;
  CellTable& cells_;
  MeshChunks& chunks_;
  std::unique_ptr<Pipelines> pipes_;
  Buffer frame_ubo_;
  // The Frame block's background views again as an RGBA32F texel buffer (binding 10,
  // blend_shade.glsl bg_texels), written with it.
  Buffer bg_views_buf_;
  RenderTarget color_target_, cellid_target_, zdepth_target_, floor_target_;
  Image placeholder_gbuffer_;
  // The kForward floor's texture: view floor_id_ (fingerprint floor_fingerprint_) as RGBA8
  // holding its sRGB bytes (floor_stage_: the same as R8G8B8A8_SRGB, the blit's target).
  Image floor_tex_, floor_stage_;
  ViewId floor_id_ = 0;
  uint64_t floor_fingerprint_ = 0;
  Buffer placeholder_out_;
  bool descriptors_dirty_ = true;
  // Background pass (fragment path): one draw per distinct tile view list (blend_shade.glsl
  // SkyList); the rectangles' vertices (vec3 NDC) in sky_vb_.
  struct SkyDraw {
    uint32_t packed = 0;
    uint32_t first_vertex = 0;
    uint32_t vertex_count = 0;
  };
  std::vector<SkyDraw> sky_draws_;
  Buffer sky_vb_;
  double sky_listed_views_px_ = 0;  // sum over drawn pixels of their list's length
  std::optional<XrayHole> xray_hole_;
};

}  // namespace exo::vk
