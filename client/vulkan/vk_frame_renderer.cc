#include "client/vulkan/vk_frame_renderer.h"

#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>

#include "absl/strings/str_cat.h"
#include "common/lumigraph/cpu_renderer.h"

namespace exo::vk {
namespace {

using Clock = std::chrono::steady_clock;

double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

}  // namespace

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
  // InpaintFusion (SPEC §7): ip_params.x inpainted keyframes of this frame (SelectInpaintedViews,
  // nearest first), their texture layers in ip_layers (4 per ivec4).
  glm::ivec4 ip_params;
  glm::ivec4 ip_layers[kMaxInpaintedViews / 4];
  // RenderFloor: rows of one view's P and (width, height, layer, 0) (floorproj.frag) or
  // (1 / width, 1 / height, 0, 0) of the floor texture (floor.vert).
  glm::vec4 floor_view[4];
  // The X-ray hole (shaders/xray_hole.glsl): (centre x, y in pixels, radius^2, 0) and (optical
  // axis, clip z-depth); read only by the pipelines with the hole.
  glm::vec4 xray_disc;
  glm::vec4 xray_axis;
};
static_assert(sizeof(GpuFrame) == 128 + 48 + 16 + 16 * kBgViewTexels * blend::kMaxBackgroundViews +
                                      16 + 16 * (kMaxInpaintedViews / 4) + 64 + 32);

namespace {

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

// Background pass tiles: kSkyTilePx x kSkyTilePx screen pixels (a multiple of llvmpipe's 4x4
// blocks, so a block never mixes two view lists).
constexpr int kSkyTilePx = 16;

// Where the corner ray of a tile grid point meets background view j (SkyViewCorners).
struct SkyCorner {
  enum State : uint8_t { kFront, kBehind, kUncertain } state = kUncertain;
  glm::dvec2 uv{0.0};
};

// Background view j of frame `f` at the (gx + 1) x (gy + 1) tile grid points (pixel
// (min(cx T, w - 1), min(cy T, h - 1)), T = kSkyTilePx), for SkyTileMayUseView. blend_shade.glsl
// ShadeBackground needs, for the ray d = local_from_pixel (x, y, 1) and p = cam_from_local_j d:
// p.z > 1e-6 |p|, uv = (fx p.x / p.z + cx, fy p.y / p.z + cy) inside the view and the baked
// background mask set at the nearest pixel. Margins: behind if p.z < -1e-3 |p|, in front if
// p.z > 1e-2 |p| (between: uncertain, the view is kept).
void SkyViewCorners(const GpuFrame& f, int j, int w, int h, int gx, int gy,
                    std::vector<SkyCorner>* out) {
  const glm::dvec3 m0(f.local_from_pixel[0]), m1(f.local_from_pixel[1]), m2(f.local_from_pixel[2]);
  const glm::vec4* v = f.bg_views + kBgViewTexels * j;
  const glm::dvec3 r0(v[0]), r1(v[1]), r2(v[2]);  // columns of cam_from_local
  const glm::dvec4 intr(v[3]);
  out->resize(size_t(gx + 1) * (gy + 1));
  for (int cy = 0; cy <= gy; ++cy)
    for (int cx = 0; cx <= gx; ++cx) {
      const glm::dvec3 d = m0 * double(std::min(cx * kSkyTilePx, w - 1)) +
                           m1 * double(std::min(cy * kSkyTilePx, h - 1)) + m2;
      const glm::dvec3 p = r0 * d.x + r1 * d.y + r2 * d.z;
      const double len = glm::length(p);
      SkyCorner& c = (*out)[size_t(cy) * (gx + 1) + cx];
      if (p.z < -1e-3 * len) {
        c.state = SkyCorner::kBehind;
      } else if (p.z > 1e-2 * len) {
        c.state = SkyCorner::kFront;
        c.uv = glm::dvec2(intr.x * p.x / p.z + intr.z, intr.y * p.y / p.z + intr.w);
      } else {
        c.state = SkyCorner::kUncertain;
      }
    }
}

// Whether background view `e` (corners `c` from SkyViewCorners) may be valid for the ray of some
// pixel of tile (tx, ty) (conservative). The tile's rays are convex combinations of its corner
// rays (d is affine in the pixel; the grid points enclose the tile's pixels), so p.z < 0 at all 4
// corners excludes every ray, and with p.z > 0 at all 4 the tile's image is inside the convex
// hull of the corners' uv (a projective map keeps segments in front of the camera): its box,
// widened by 1 px (the shader's float rays differ from these double ones by far less), gives the
// nearest pixels to test against the view's background mask (ViewStore::BackgroundMaskAny).
bool SkyTileMayUseView(const ViewStore::Entry& e, const std::vector<SkyCorner>& c, int gx, int tx,
                       int ty) {
  const SkyCorner* q[4] = {&c[size_t(ty) * (gx + 1) + tx], &c[size_t(ty) * (gx + 1) + tx + 1],
                           &c[size_t(ty + 1) * (gx + 1) + tx],
                           &c[size_t(ty + 1) * (gx + 1) + tx + 1]};
  int behind = 0, front = 0;
  glm::dvec2 lo(std::numeric_limits<double>::infinity()), hi(-lo);
  for (const SkyCorner* k : q) {
    behind += k->state == SkyCorner::kBehind;
    if (k->state != SkyCorner::kFront) continue;
    ++front;
    lo = glm::min(lo, k->uv);
    hi = glm::max(hi, k->uv);
  }
  if (behind == 4) return false;
  if (front < 4) return e.has_background;
  constexpr double kMarginPx = 1.0, kFar = 1e7;
  const auto pixel = [&](double u) { return int(std::floor(std::clamp(u + 0.5, -kFar, kFar))); };
  return ViewStore::BackgroundMaskAny(e, pixel(lo.x - kMarginPx), pixel(lo.y - kMarginPx),
                                      pixel(hi.x + kMarginPx), pixel(hi.y + kMarginPx));
}

// blend_shade.glsl SkyList: the count in bits 0..3, the k-th set bit's index in bits 4 + 3k.
uint32_t PackSkyList(uint32_t mask) {
  uint32_t packed = 0, count = 0;
  for (uint32_t j = 0; j < 32; ++j)
    if (mask & (1u << j)) packed |= j << (4 + 3 * count++);
  return packed | count;
}

// Begins render pass `rp` on `fb` (clear colour c0, depth 1) over the whole target and binds
// `pipe` with the renderer's descriptor set.
void RecordBeginPass(VkCommandBuffer cmd, const Pipelines& pipes, VkRenderPass rp, VkFramebuffer fb,
                     const VkClearValue& c0, VkPipeline pipe, uint32_t w, uint32_t h) {
  VkViewport vp{0, 0, float(w), float(h), 0.0f, 1.0f};
  VkRect2D sc{{0, 0}, {w, h}};
  VkClearValue cv[2];
  cv[0] = c0;
  cv[1].depthStencil = {1.0f, 0};
  VkRenderPassBeginInfo bi{VK_STRUCTURE_TYPE_RENDER_PASS_BEGIN_INFO};
  bi.renderPass = rp;
  bi.framebuffer = fb;
  bi.renderArea = {{0, 0}, {w, h}};
  bi.clearValueCount = 2;
  bi.pClearValues = cv;
  vkCmdBeginRenderPass(cmd, &bi, VK_SUBPASS_CONTENTS_INLINE);
  vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, pipe);
  vkCmdSetViewport(cmd, 0, 1, &vp);
  vkCmdSetScissor(cmd, 0, 1, &sc);
  vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, pipes.layout(), 0, 1, pipes.set(),
                          0, nullptr);
  // Every blend pipeline declares the background pass's push constant (blend_shade.glsl
  // SkyList; only kBlendPassBackground reads it), so it must be set before any draw.
  const uint32_t no_list = 0;
  vkCmdPushConstants(cmd, pipes.layout(), VK_SHADER_STAGE_FRAGMENT_BIT | VK_SHADER_STAGE_COMPUTE_BIT,
                     0, sizeof(no_list), &no_list);
}

// blend.comp over the G-buffer (the G-buffer pass's dependency covers the compute read)
// straight into t.blend_out; then makes its writes visible to the host.
void RecordComputeBlend(VkCommandBuffer cmd, const Pipelines& pipes, const RenderTarget& t,
                        VkPipeline compute_pipe) {
  vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, compute_pipe);
  vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipes.layout(), 0, 1, pipes.set(), 0,
                          nullptr);
  const uint32_t no_list = 0;  // SkyList (unread by the compute path, but declared)
  vkCmdPushConstants(cmd, pipes.layout(), VK_SHADER_STAGE_FRAGMENT_BIT | VK_SHADER_STAGE_COMPUTE_BIT,
                     0, sizeof(no_list), &no_list);
  vkCmdDispatch(cmd, (t.w + 7) / 8, (t.h + 7) / 8, 1);
  VkBufferMemoryBarrier ob{VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER};
  ob.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT;
  ob.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
  ob.srcQueueFamilyIndex = ob.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  ob.buffer = t.blend_out.buffer.get();
  ob.size = VK_WHOLE_SIZE;
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0, 0,
                       nullptr, 1, &ob, 0, nullptr);
}

// The RGBA8 blend output as RGB8 colour + coverage codes (blend_shade.glsl alpha codes) and,
// when `known` is not null, the hole fill's mask (coverage >= 2: blended or filled at infinity)
// in the same pass. Table lookups instead of the alpha compare chain (serial host time: the
// frame's wall time pays it 1:1).
void UnpackBlendOutput(const uint8_t* src, uint32_t w, uint32_t h, RenderResult* r,
                       ImageU8* known = nullptr) {
  struct Tables {
    std::array<uint8_t, 256> coverage, known;
  };
  static constexpr Tables kT = [] {
    Tables t{};
    for (int a = 0; a < 256; ++a) {
      t.coverage[a] = a == 0 ? 0 : a == 255 ? 2 : a == 64 ? 3 : a == 224 ? 4 : 1;
      t.known[a] = t.coverage[a] >= 2;
    }
    return t;
  }();
  r->color = ImageU8(w, h, 3);
  r->coverage = ImageU8(w, h, 1);
  uint8_t* dst = r->color.data();
  uint8_t* cov = r->coverage.data();
  const size_t n = size_t(w) * h;
  if (known) *known = ImageU8(w, h, 1);
  uint8_t* kn = known ? known->data() : nullptr;
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* p = src + 4 * i;
    dst[3 * i + 0] = p[0];
    dst[3 * i + 1] = p[1];
    dst[3 * i + 2] = p[2];
    cov[i] = kT.coverage[p[3]];
  }
  if (kn)
    for (size_t i = 0; i < n; ++i) kn[i] = kT.known[src[4 * i + 3]];
}

// RenderFloor's texture: layer `layer` of the linear colour array -> `stage` (R8G8B8A8_SRGB:
// the blit encodes, giving back the stored sRGB bytes) -> copied bit for bit into `tex`
// (R8G8B8A8_UNORM, same texel size), which ends in SHADER_READ_ONLY_OPTIMAL.
void RecordFloorTexture(VkCommandBuffer cmd, const Image& colors, uint32_t layer,
                        const Image& stage, const Image& tex) {
  const uint32_t w = tex.width, h = tex.height;
  TransitionImage(cmd, colors.image.get(), VK_IMAGE_ASPECT_COLOR_BIT,
                  ViewStore::kColorLayout, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                  layer, 1);
  TransitionImage(cmd, stage.image.get(), VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_UNDEFINED,
                  VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 0, 1);
  VkImageBlit blit{};
  blit.srcSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, layer, 1};
  blit.srcOffsets[1] = {int32_t(w), int32_t(h), 1};
  blit.dstSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  blit.dstOffsets[1] = {int32_t(w), int32_t(h), 1};
  vkCmdBlitImage(cmd, colors.image.get(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, stage.image.get(),
                 VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &blit, VK_FILTER_NEAREST);
  TransitionImage(cmd, colors.image.get(), VK_IMAGE_ASPECT_COLOR_BIT,
                  VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, ViewStore::kColorLayout,
                  layer, 1);
  TransitionImage(cmd, stage.image.get(), VK_IMAGE_ASPECT_COLOR_BIT,
                  VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, 0, 1);
  TransitionImage(cmd, tex.image.get(), VK_IMAGE_ASPECT_COLOR_BIT, VK_IMAGE_LAYOUT_UNDEFINED,
                  VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 0, 1);
  VkImageCopy copy{};
  copy.srcSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  copy.dstSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  copy.extent = {w, h, 1};
  vkCmdCopyImage(cmd, stage.image.get(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, tex.image.get(),
                 VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &copy);
  TransitionImage(cmd, tex.image.get(), VK_IMAGE_ASPECT_COLOR_BIT,
                  VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, 0,
                  1);
}

}  // namespace

absl::StatusOr<std::unique_ptr<FrameRenderer>> FrameRenderer::Create(
    const Context& ctx, const VulkanRendererOptions& opt, const CellGrid& grid, ViewStore& views,
    CellTable& cells, MeshChunks& chunks) {
  std::unique_ptr<FrameRenderer> r(new FrameRenderer(ctx, opt, grid, views, cells, chunks));
  EXO_ASSIGN_OR_RETURN(r->frame_ubo_,
                       Buffer::Create(ctx, sizeof(GpuFrame), VK_BUFFER_USAGE_UNIFORM_BUFFER_BIT));
  EXO_ASSIGN_OR_RETURN(r->bg_views_buf_,
                       Buffer::Create(ctx, sizeof(GpuFrame::bg_views),
                                      VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT));
  EXO_ASSIGN_OR_RETURN(r->pipes_, Pipelines::Create(ctx, opt.blend_in_compute));
  EXO_RETURN_IF_ERROR(r->CreatePlaceholders());
  return r;
}

absl::Status FrameRenderer::CreatePlaceholders() {
  EXO_ASSIGN_OR_RETURN(placeholder_out_,
                       Buffer::Create(ctx_, 4, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT));
  EXO_ASSIGN_OR_RETURN(placeholder_gbuffer_,
                       Image::Create(ctx_, 1, 1, 1, VK_FORMAT_R32G32B32A32_SFLOAT,
                                     VK_IMAGE_USAGE_SAMPLED_BIT, VK_IMAGE_ASPECT_COLOR_BIT, false));
  return ctx_.Submit([&](VkCommandBuffer cmd) {
    TransitionImage(cmd, placeholder_gbuffer_.image.get(), VK_IMAGE_ASPECT_COLOR_BIT,
                    VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, 0, 1);
  });
}

// Rewrites the descriptor set when a store replaced a buffer or the blend target changed.
absl::Status FrameRenderer::UpdateDescriptors() {
  descriptors_dirty_ |= views_.TakeStorageChanged();
  descriptors_dirty_ |= cells_.TakeStorageChanged();
  if (!descriptors_dirty_) return absl::OkStatus();
  DescriptorInputs in;
  in.frame_ubo = &frame_ubo_;
  in.view_records = &views_.records_buffer();
  in.cell_table = &cells_.table_buffer();
  in.refs = &cells_.refs_buffer();
  in.colors = &views_.colors();
  in.depths = &views_.depths();
  in.gbuffer = color_target_.gbuffer.image ? &color_target_.gbuffer : &placeholder_gbuffer_;
  in.ranked_refs = &cells_.ranked_buffer();
  in.blend_out = color_target_.blend_out.buffer ? &color_target_.blend_out : &placeholder_out_;
  in.floor_colors = floor_tex_.image ? &floor_tex_ : &placeholder_gbuffer_;
  in.bg_views = &bg_views_buf_;
  EXO_RETURN_IF_ERROR(pipes_->WriteDescriptors(in));
  descriptors_dirty_ = false;
  return absl::OkStatus();
}

absl::Status FrameRenderer::EnsureBlendTarget(uint32_t w, uint32_t h) {
  EXO_ASSIGN_OR_RETURN(const bool recreated,
                       color_target_.Ensure(ctx_, pipes_->color_pass(), VK_FORMAT_R8G8B8A8_UNORM, w,
                                            h, pipes_->gbuffer_pass()));
  if (recreated) descriptors_dirty_ = true;  // bindings 6 and 8 point at the new target
  return absl::OkStatus();
}

absl::Status FrameRenderer::CheckCamera(const PinholeCamera& camera,
                                        const Rigid3d& local_from_cam) const {
  EXO_RETURN_IF_ERROR(camera.Validate());
  EXO_RETURN_IF_ERROR(ValidateQuaternion(local_from_cam.rotation));
  const glm::dvec3& t = local_from_cam.translation;
  if (!std::isfinite(t.x) || !std::isfinite(t.y) || !std::isfinite(t.z))
    return absl::InvalidArgumentError("novel camera position is not finite");
  if (camera.width > 16384 || camera.height > 16384)
    return absl::InvalidArgumentError("render size above 16384");
  return absl::OkStatus();
}

// The render-time options must match what was baked into the resident depth layers.
absl::Status FrameRenderer::CheckBakedOptions(const blend::BlendOptions& bo) const {
  if (bo.discontinuity_radius_px != opt_.bake_discontinuity_radius_px ||
      bo.discontinuity_delta_z_m != opt_.bake_discontinuity_delta_z_m ||
      bo.discontinuity_delta_z_rel != opt_.bake_discontinuity_delta_z_rel)
    return absl::InvalidArgumentError(
        "BlendOptions discontinuity parameters differ from the ones baked into the resident "
        "depth layers (VulkanRendererOptions::bake_discontinuity_*)");
  if (bo.background_views > 0 &&
      bo.background_guard_radius_px != opt_.bake_background_guard_radius_px)
    return absl::InvalidArgumentError(
        "BlendOptions::background_guard_radius_px differs from the one baked into the "
        "resident depth layers (VulkanRendererOptions::bake_background_guard_radius_px)");
  return absl::OkStatus();
}

void FrameRenderer::FillFrame(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                              GpuFrame* f) const {
  const glm::dmat4 cam_from_local = local_from_cam.Inverse().ToMatrix();
  f->clip_from_local = glm::mat4(ClipFromCam(camera, opt_.near_m, opt_.far_m) * cam_from_local);
  f->cam_centre_cell = glm::vec4(glm::vec3(local_from_cam.translation), float(grid_.cell_size_m));
  f->iparams = glm::ivec4(0, 0, int(cells_.table_mask()), int(cells_.max_probe()));
  if (xray_hole_) {
    const XrayHole& x = *xray_hole_;
    const double r_px = x.radius * camera.height;
    f->xray_disc = glm::vec4(float(x.centre_x * camera.width), float(x.centre_y * camera.height),
                             float(r_px * r_px), 0.0f);
    f->xray_axis =
        glm::vec4(glm::vec3(local_from_cam.RotationMatrix()[2]), float(x.clip_m));
  }
}

absl::Status FrameRenderer::SetXrayHole(std::optional<XrayHole> hole) {
  if (hole) {
    const XrayHole& x = *hole;
    if (!std::isfinite(x.clip_m) || !(x.clip_m > 0.0) || !(x.clip_m < opt_.far_m))
      return absl::InvalidArgumentError(absl::StrCat(
          "X-ray hole: clip_m must be in (0, ", opt_.far_m, ") m, got ", x.clip_m));
    if (!std::isfinite(x.centre_x) || !std::isfinite(x.centre_y))
      return absl::InvalidArgumentError("X-ray hole: the centre must be finite");
    if (!std::isfinite(x.radius) || !(x.radius > 0.0))
      return absl::InvalidArgumentError(
          absl::StrCat("X-ray hole: radius must be > 0 (a fraction of the image height), got ",
                       x.radius));
  }
  xray_hole_ = hole;
  return absl::OkStatus();
}

// Records the proxy draw with `pipe` into `t`, copies the colour attachment to t.readback.
// deferred == false: draws the proxy chunks with `pipe` into t.fb. deferred == true (blend):
// first the proxy into the G-buffer (gbuffer_pipe, t.gbuffer_fb), then full-screen triangles
// with `pipe` (surface pixels) and `sky_pipe` (pixels without surface, if any) into t.fb, or
// with a compute pipe blend.comp into t.blend_out and no read-back; one command buffer, one
// submit.
absl::Status FrameRenderer::Draw(RenderTarget& t, VkRenderPass pass, VkPipeline pipe,
                                 const VkClearValue& clear, uint32_t texel_bytes, bool deferred,
                                 VkPipeline compute_pipe, VkPipeline sky_pipe) {
  EXO_RETURN_IF_ERROR(UpdateDescriptors());
  EXO_RETURN_IF_ERROR(chunks_.PrepareDraw());
  const Pipelines& p = *pipes_;
  return ctx_.Submit([&](VkCommandBuffer cmd) {
    if (deferred) {
      VkClearValue zero{};  // G-buffer w = 0: no surface
      RecordBeginPass(cmd, p, p.gbuffer_pass(), t.gbuffer_fb.get(), zero,
                      p.gbuffer_pipe(xray_hole_.has_value()), t.w, t.h);
      chunks_.RecordDraws(cmd);
      vkCmdEndRenderPass(cmd);
      if (compute_pipe != VK_NULL_HANDLE) return RecordComputeBlend(cmd, p, t, compute_pipe);
      // The surface pixels (pipe), then the pixels without a surface (sky_pipe; without it they
      // keep the clear value, the background colour with alpha 0, what the background pass
      // writes when it has no view).
      RecordBeginPass(cmd, p, pass, t.fb.get(), clear, pipe, t.w, t.h);
      vkCmdDraw(cmd, 3, 1, 0, 0);
      if (sky_pipe != VK_NULL_HANDLE && !sky_draws_.empty()) {
        vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, sky_pipe);
        const VkBuffer vb = sky_vb_.buffer.get();
        const VkDeviceSize offset = 0;
        vkCmdBindVertexBuffers(cmd, 0, 1, &vb, &offset);
        for (const SkyDraw& d : sky_draws_) {
          vkCmdPushConstants(cmd, p.layout(),
                             VK_SHADER_STAGE_FRAGMENT_BIT | VK_SHADER_STAGE_COMPUTE_BIT, 0,
                             sizeof(d.packed), &d.packed);
          vkCmdDraw(cmd, d.vertex_count, 1, d.first_vertex, 0);
        }
      }
      vkCmdEndRenderPass(cmd);
    } else {
      RecordBeginPass(cmd, p, pass, t.fb.get(), clear, pipe, t.w, t.h);
      chunks_.RecordDraws(cmd);
      vkCmdEndRenderPass(cmd);
    }
    RecordReadback(cmd, t, texel_bytes);
  });
}

// The per-frame background view list (SelectBackgroundViews over the resident views in id
// order: the CPU reference's order) and the pixel-to-direction matrix, into the Frame block.
void FrameRenderer::FillBackground(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                   int max_views, GpuFrame* f, std::vector<ViewId>* chosen_ids,
                                   std::vector<const ViewStore::Entry*>* bg_entries) const {
  std::vector<std::pair<ViewId, const ViewStore::Entry*>> sorted;
  sorted.reserve(views_.entries().size());
  for (const auto& [id, e] : views_.entries()) sorted.emplace_back(id, &e);
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
      camera, local_from_cam, params, ids, max_views, [&](int i) {
        return !sorted[i].second->inpainted && sorted[i].second->has_background;
      });
  const glm::mat3 m = LocalFromPixel(camera, local_from_cam);
  for (int c = 0; c < 3; ++c) f->local_from_pixel[c] = glm::vec4(m[c], 0.0f);
  f->bg_params = glm::ivec4(int(chosen.size()), 0, 0, 0);
  for (size_t j = 0; j < chosen.size(); ++j) {
    const ViewStore::Entry& e = *sorted[chosen[j]].second;
    glm::vec4* dst = f->bg_views + kBgViewTexels * j;
    for (int c = 0; c < 3; ++c) dst[c] = glm::vec4(e.params.cam_from_local[c], 0.0f);
    dst[3] = e.params.intrinsics;
    dst[4] =
        glm::vec4(float(e.params.size.x), float(e.params.size.y), float(e.slot), e.params.exposure);
    chosen_ids->push_back(ids[chosen[j]]);
    bg_entries->push_back(&e);
  }
}

// The background pass's geometry for frame `f` of w x h pixels: every kSkyTilePx tile whose view
// list (SkyTileMayUseView) is not empty, as rectangles (runs of equal lists along a tile row), drawn
// grouped by list with the list as push constant; tiles with an empty list are not drawn (their
// pixels keep the clear value, what ShadeBackground returns without a valid view).
absl::Status FrameRenderer::BuildSkyDraws(const GpuFrame& f,
                                          const std::vector<const ViewStore::Entry*>& bg_entries,
                                          uint32_t w, uint32_t h) {
  struct Rect {
    uint32_t mask;
    int x0, y0, x1, y1;  // pixel edges: [x0, x1) x [y0, y1)
  };
  const int iw = int(w), ih = int(h);
  const int gx = (iw + kSkyTilePx - 1) / kSkyTilePx, gy = (ih + kSkyTilePx - 1) / kSkyTilePx;
  std::vector<uint32_t> masks(size_t(gx) * gy, 0);
  std::vector<SkyCorner> corners;
  for (int j = 0; j < f.bg_params.x; ++j) {
    SkyViewCorners(f, j, iw, ih, gx, gy, &corners);
    for (int ty = 0; ty < gy; ++ty)
      for (int tx = 0; tx < gx; ++tx)
        if (SkyTileMayUseView(*bg_entries[size_t(j)], corners, gx, tx, ty))
          masks[size_t(ty) * gx + tx] |= 1u << j;
  }
  std::vector<Rect> rects;
  for (int ty = 0; ty < gy; ++ty) {
    const int y0 = ty * kSkyTilePx, y1 = std::min(y0 + kSkyTilePx, ih);
    Rect run{0, 0, y0, 0, y1};
    for (int tx = 0; tx < gx; ++tx) {
      const int x0 = tx * kSkyTilePx, x1 = std::min(x0 + kSkyTilePx, iw);
      const uint32_t m = masks[size_t(ty) * gx + tx];
      if (m != 0 && m == run.mask) {
        run.x1 = x1;
        continue;
      }
      if (run.mask != 0) rects.push_back(run);
      run = Rect{m, x0, y0, x1, y1};
    }
    if (run.mask != 0) rects.push_back(run);
  }
  std::stable_sort(rects.begin(), rects.end(),
                   [](const Rect& a, const Rect& b) { return a.mask < b.mask; });
  sky_draws_.clear();
  sky_listed_views_px_ = 0;
  if (rects.empty()) return absl::OkStatus();
  const VkDeviceSize bytes = rects.size() * 6 * sizeof(glm::vec3);
  if (!sky_vb_.buffer || sky_vb_.size < bytes) {
    EXO_ASSIGN_OR_RETURN(sky_vb_, Buffer::Create(ctx_, std::max<VkDeviceSize>(2 * bytes, 4096),
                                                 VK_BUFFER_USAGE_VERTEX_BUFFER_BIT));
  }
  glm::vec3* v = static_cast<glm::vec3*>(sky_vb_.mapped);
  const auto ndc_x = [&](int x) { return float(2.0 * x / iw - 1.0); };
  const auto ndc_y = [&](int y) { return float(2.0 * y / ih - 1.0); };
  for (size_t i = 0; i < rects.size(); ++i) {
    const Rect& r = rects[i];
    const glm::vec3 a(ndc_x(r.x0), ndc_y(r.y0), 1.0f), b(ndc_x(r.x1), ndc_y(r.y0), 1.0f),
        c(ndc_x(r.x1), ndc_y(r.y1), 1.0f), d(ndc_x(r.x0), ndc_y(r.y1), 1.0f);
    const glm::vec3 quad[6] = {a, b, c, a, c, d};
    std::memcpy(v + 6 * i, quad, sizeof(quad));
    if (i == 0 || r.mask != rects[i - 1].mask)
      sky_draws_.push_back(SkyDraw{PackSkyList(r.mask), uint32_t(6 * i), 0});
    sky_draws_.back().vertex_count += 6;
    sky_listed_views_px_ += double(std::popcount(r.mask)) * (r.x1 - r.x0) * (r.y1 - r.y0);
  }
  return absl::OkStatus();
}

// The inpainted keyframes of this frame (SPEC §7; the CPU reference's SelectInpaintedViews over
// the resident inpainted views in id order) into the Frame block.
void FrameRenderer::FillInpainted(const Rigid3d& local_from_cam, GpuFrame* f) const {
  std::vector<std::pair<ViewId, const ViewStore::Entry*>> sorted;
  for (const auto& [id, e] : views_.entries())
    if (e.inpainted) sorted.emplace_back(id, &e);
  f->ip_params = glm::ivec4(0);
  if (sorted.empty()) return;
  std::sort(sorted.begin(), sorted.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<glm::vec3> centres;
  std::vector<ViewId> ids;
  for (const auto& [id, e] : sorted) {
    centres.push_back(e->params.centre_local);
    ids.push_back(id);
  }
  const std::vector<int> chosen = SelectInpaintedViews(local_from_cam, centres, ids);
  f->ip_params.x = int(chosen.size());
  for (size_t j = 0; j < chosen.size(); ++j)
    f->ip_layers[j / 4][j % 4] = int(sorted[chosen[j]].second->slot);
}

// The blend pass's Frame block (camera, weights, background list) into frame_ubo_.
void FrameRenderer::UploadBlendFrame(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                     const blend::BlendOptions& bo, GpuFrame* f,
                                     std::vector<ViewId>* bg_ids,
                                     std::vector<const ViewStore::Entry*>* bg_entries) const {
  FillFrame(camera, local_from_cam, f);
  f->weights =
      glm::vec4(bo.lambda, bo.min_weight, bo.occlusion_epsilon_m, bo.occlusion_epsilon_rel);
  f->background = glm::vec4(bo.background_srgb, 0.0f);
  f->iparams.x = static_cast<int>(bo.positional_mode);
  f->iparams.y = bo.n_best;
  if (bo.background_views > 0)
    FillBackground(camera, local_from_cam, bo.background_views, f, bg_ids, bg_entries);
  FillInpainted(local_from_cam, f);
  std::memcpy(frame_ubo_.mapped, f, sizeof(*f));
}

// The deferred blend of one frame into color_target_ (graphics or compute).
absl::Status FrameRenderer::DrawBlend(const blend::BlendOptions& bo, int sky_views,
                                      bool inpainted) {
  VkClearValue clear{};
  clear.color = {{bo.background_srgb.x, bo.background_srgb.y, bo.background_srgb.z, 0.0f}};
  BlendVariant v;
  v.inpainted = inpainted;
  v.lambda_one = bo.lambda == 1.0f;
  v.default_weights = BlendVariant::DefaultWeights(bo);
  EXO_RETURN_IF_ERROR(pipes_->EnsureBlendPipe(bo.n_best, v));
  return Draw(color_target_, pipes_->blend_pass(), pipes_->blend_pipe(bo.n_best, v), clear, 4,
              /*deferred=*/true, pipes_->blend_compute_pipe(bo.n_best, v),
              sky_views > 0 ? pipes_->blend_sky_pipe(bo.n_best, v) : VK_NULL_HANDLE);
}

absl::StatusOr<RenderResult> FrameRenderer::Render(const PinholeCamera& camera,
                                                   const Rigid3d& local_from_cam,
                                                   const blend::BlendOptions& bo,
                                                   const RenderApprox& approx) {
  EXO_RETURN_IF_ERROR(bo.Validate());
  if (approx.max_candidates < 0)
    return absl::InvalidArgumentError("RenderApprox::max_candidates must be >= 0");
  EXO_RETURN_IF_ERROR(CheckCamera(camera, local_from_cam));
  EXO_RETURN_IF_ERROR(CheckBakedOptions(bo));
  const uint32_t w = camera.width, h = camera.height;
  EXO_RETURN_IF_ERROR(EnsureBlendTarget(w, h));
  GpuFrame f{};
  RenderResult r;
  std::vector<const ViewStore::Entry*> bg_entries;
  UploadBlendFrame(camera, local_from_cam, bo, &f, &r.background_views, &bg_entries);
  f.bg_params.y = approx.max_candidates;  // blend_shade.glsl: 0 = every reference (exact)
  std::memcpy(frame_ubo_.mapped, &f, sizeof(f));
  std::memcpy(bg_views_buf_.mapped, f.bg_views, sizeof(f.bg_views));
  sky_draws_.clear();
  sky_listed_views_px_ = 0;
  if (f.bg_params.x > 0 && !pipes_->blend_compute()) {
    const auto ts = Clock::now();
    EXO_RETURN_IF_ERROR(BuildSkyDraws(f, bg_entries, w, h));
    r.sky_tiles_ms = MsSince(ts);
    r.sky_views_per_px = sky_listed_views_px_ / (double(w) * h);
  }
  const auto tr = Clock::now();
  const CellSurfaceBounds& surface = chunks_.SurfaceBounds(grid_.cell_size_m);
  cells_.RankRefs(glm::vec3(f.cam_centre_cell), camera, local_from_cam, grid_.cell_size_m, bo,
                  &surface, chunks_.surface_stamp(),
                  /*by_centre_weight=*/approx.max_candidates > 0);
  r.rank_ms = MsSince(tr);
  const auto t0 = Clock::now();
  EXO_RETURN_IF_ERROR(DrawBlend(bo, f.bg_params.x, f.ip_params.x > 0));
  r.gpu_ms = MsSince(t0);
  const auto t1 = Clock::now();
  ImageU8 known;  // the fill's mask (coverage >= 2), unpacked with the frame
  UnpackBlendOutput(
      static_cast<const uint8_t*>(pipes_->blend_compute() ? color_target_.blend_out.mapped
                                                          : color_target_.readback.mapped),
      w, h, &r, bo.fill_holes ? &known : nullptr);
  r.readback_ms = MsSince(t1);
  if (bo.fill_holes) {  // host post-pass on the read-back frame, same function as the CPU oracle
    const auto tf = Clock::now();
    r.filled_pixels = FillHoles(r.color, known);
    r.fill_ms = MsSince(tf);
  }
  return r;
}

const ViewStore::Entry* FrameRenderer::NearestView(const Rigid3d& local_from_cam,
                                                   ViewId* id) const {
  const glm::vec3 c_o(local_from_cam.translation);
  const ViewStore::Entry* best = nullptr;
  float best_d = 0.0f;
  for (const auto& [vid, e] : views_.entries()) {
    const float d = glm::length(e.params.centre_local - c_o);
    if (!best || d < best_d || (d == best_d && vid < *id)) {
      best = &e;
      *id = vid;
      best_d = d;
    }
  }
  return best;
}

absl::Status FrameRenderer::PrepareFloor(const PinholeCamera& camera,
                                         const Rigid3d& local_from_cam) {
  EXO_RETURN_IF_ERROR(CheckCamera(camera, local_from_cam));
  ViewId id = 0;
  const ViewStore::Entry* e = NearestView(local_from_cam, &id);
  if (!e) return absl::FailedPreconditionError("RenderFloor needs a resident view");
  const uint32_t w = uint32_t(e->params.size.x), h = uint32_t(e->params.size.y);
  if (floor_tex_.image && id == floor_id_ && e->fingerprint == floor_fingerprint_ &&
      floor_tex_.width == w && floor_tex_.height == h)
    return absl::OkStatus();
  if (!floor_tex_.image || floor_tex_.width != w || floor_tex_.height != h) {
    EXO_ASSIGN_OR_RETURN(floor_stage_,
                         Image::Create(ctx_, w, h, 1, VK_FORMAT_R8G8B8A8_SRGB,
                                       VK_IMAGE_USAGE_TRANSFER_DST_BIT |
                                           VK_IMAGE_USAGE_TRANSFER_SRC_BIT |
                                           VK_IMAGE_USAGE_SAMPLED_BIT,  // Image::Create's view
                                       VK_IMAGE_ASPECT_COLOR_BIT, false));
    EXO_ASSIGN_OR_RETURN(floor_tex_,
                         Image::Create(ctx_, w, h, 1, VK_FORMAT_R8G8B8A8_UNORM,
                                       VK_IMAGE_USAGE_TRANSFER_DST_BIT | VK_IMAGE_USAGE_SAMPLED_BIT,
                                       VK_IMAGE_ASPECT_COLOR_BIT, false));
    descriptors_dirty_ = true;  // binding 9
  }
  const Image& colors = views_.colors();
  EXO_RETURN_IF_ERROR(ctx_.Submit([&](VkCommandBuffer cmd) {
    RecordFloorTexture(cmd, colors, e->slot, floor_stage_, floor_tex_);
  }));
  floor_id_ = id;
  floor_fingerprint_ = e->fingerprint;
  return absl::OkStatus();
}

absl::StatusOr<RenderResult> FrameRenderer::RenderFloor(const PinholeCamera& camera,
                                                        const Rigid3d& local_from_cam,
                                                        bool projective) {
  EXO_RETURN_IF_ERROR(CheckCamera(camera, local_from_cam));
  if (!projective) EXO_RETURN_IF_ERROR(PrepareFloor(camera, local_from_cam));
  const uint32_t w = camera.width, h = camera.height;
  EXO_RETURN_IF_ERROR(
      floor_target_.Ensure(ctx_, pipes_->color_pass(), VK_FORMAT_R8G8B8A8_UNORM, w, h).status());
  GpuFrame f{};
  FillFrame(camera, local_from_cam, &f);
  ViewId id = 0;
  const ViewStore::Entry* best = NearestView(local_from_cam, &id);
  if (!best) return absl::FailedPreconditionError("RenderFloor needs a resident view");
  const GpuView& v = views_.records()[best->slot];
  f.floor_view[0] = v.p0;
  f.floor_view[1] = v.p1;
  f.floor_view[2] = v.p2;
  f.floor_view[3] = projective ? glm::vec4(v.size_layer.x, v.size_layer.y, v.size_layer.z, 0.0f)
                               : glm::vec4(1.0f / float(floor_tex_.width),
                                           1.0f / float(floor_tex_.height), 0.0f, 0.0f);
  std::memcpy(frame_ubo_.mapped, &f, sizeof(f));
  VkClearValue clear{};
  RenderResult r;
  const auto t0 = Clock::now();
  EXO_RETURN_IF_ERROR(Draw(floor_target_, pipes_->color_pass(),
                           projective ? pipes_->floor_projective_pipe() : pipes_->floor_pipe(),
                           clear, 4));
  r.gpu_ms = MsSince(t0);
  const auto t1 = Clock::now();
  UnpackBlendOutput(static_cast<const uint8_t*>(floor_target_.readback.mapped), w, h, &r);
  r.readback_ms = MsSince(t1);
  return r;
}

absl::StatusOr<exo::Image<uint64_t>> FrameRenderer::RenderCellIds(const PinholeCamera& camera,
                                                                  const Rigid3d& local_from_cam) {
  EXO_RETURN_IF_ERROR(CheckCamera(camera, local_from_cam));
  const uint32_t w = camera.width, h = camera.height;
  EXO_RETURN_IF_ERROR(
      cellid_target_.Ensure(ctx_, pipes_->cellid_pass(), VK_FORMAT_R32G32_UINT, w, h).status());
  GpuFrame f{};
  FillFrame(camera, local_from_cam, &f);
  std::memcpy(frame_ubo_.mapped, &f, sizeof(f));
  VkClearValue clear{};
  clear.color.uint32[0] = clear.color.uint32[1] = 0xFFFFFFFFu;
  EXO_RETURN_IF_ERROR(Draw(cellid_target_, pipes_->cellid_pass(), pipes_->cellid_pipe(xray_hole_.has_value()),
                           clear, 8));
  exo::Image<uint64_t> out(w, h, 1, kNoCell);
  const uint32_t* src = static_cast<const uint32_t*>(cellid_target_.readback.mapped);
  for (size_t i = 0, n = size_t(w) * h; i < n; ++i)
    out.data()[i] = CellIdFromUints(src[2 * i], src[2 * i + 1]);
  return out;
}

absl::StatusOr<ImageF> FrameRenderer::RenderProxyDepth(const PinholeCamera& camera,
                                                       const Rigid3d& local_from_cam) {
  EXO_RETURN_IF_ERROR(CheckCamera(camera, local_from_cam));
  const uint32_t w = camera.width, h = camera.height;
  EXO_RETURN_IF_ERROR(
      zdepth_target_.Ensure(ctx_, pipes_->zdepth_pass(), VK_FORMAT_R32_SFLOAT, w, h).status());
  GpuFrame f{};
  FillFrame(camera, local_from_cam, &f);
  // viewdepth.frag: background.xyz = optical axis (third column of local_from_cam's rotation).
  f.background = glm::vec4(glm::vec3(local_from_cam.RotationMatrix()[2]), 0.0f);
  std::memcpy(frame_ubo_.mapped, &f, sizeof(f));
  VkClearValue clear{};  // 0 = no surface (invalid depth)
  EXO_RETURN_IF_ERROR(Draw(zdepth_target_, pipes_->zdepth_pass(), pipes_->zdepth_pipe(xray_hole_.has_value()),
                           clear, 4));
  ImageF out(w, h, 1, 0.0f);
  std::memcpy(out.data(), zdepth_target_.readback.mapped, size_t(w) * h * sizeof(float));
  return out;
}

}  // namespace exo::vk
