#include "client/vulkan/vulkan_renderer.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <memory>

#include <glm/gtc/type_ptr.hpp>

#include "absl/hash/hash.h"
#include "absl/types/span.h"
#include "client/vulkan/vk_cell_table.h"
#include "client/vulkan/vk_core_internal.h"
#include "client/vulkan/vk_mesh_chunks.h"
#include "client/vulkan/vk_pipelines.h"
#include "client/vulkan/vk_render_target.h"
#include "client/vulkan/vk_view_store.h"
#include "common/lumigraph/cpu_renderer.h"

namespace exo {
namespace {

using vk::Buffer;
using Clock = std::chrono::steady_clock;

double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

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

// Begins render pass `rp` on `fb` (clear colour c0, depth 1) over the whole target and binds
// `pipe` with the renderer's descriptor set.
void RecordBeginPass(VkCommandBuffer cmd, const vk::Pipelines& pipes, VkRenderPass rp,
                     VkFramebuffer fb, const VkClearValue& c0, VkPipeline pipe, uint32_t w,
                     uint32_t h) {
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
  vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_GRAPHICS, pipes.layout(), 0, 1,
                          pipes.set(), 0, nullptr);
}

// blend.comp over the G-buffer (the G-buffer pass's dependency covers the compute read)
// straight into t.blend_out; then makes its writes visible to the host.
void RecordComputeBlend(VkCommandBuffer cmd, const vk::Pipelines& pipes,
                        const vk::RenderTarget& t, VkPipeline compute_pipe) {
  vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, compute_pipe);
  vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipes.layout(), 0, 1,
                          pipes.set(), 0, nullptr);
  vkCmdDispatch(cmd, (t.w + 7) / 8, (t.h + 7) / 8, 1);
  VkBufferMemoryBarrier ob{VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER};
  ob.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT;
  ob.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
  ob.srcQueueFamilyIndex = ob.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  ob.buffer = t.blend_out.buffer.get();
  ob.size = VK_WHOLE_SIZE;
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0,
                       0, nullptr, 1, &ob, 0, nullptr);
}

// The RGBA8 blend output as RGB8 colour + coverage codes (blend_shade.glsl alpha codes).
void UnpackBlendOutput(const uint8_t* src, uint32_t w, uint32_t h, RenderResult* r) {
  r->color = ImageU8(w, h, 3);
  r->coverage = ImageU8(w, h, 1);
  uint8_t* dst = r->color.data();
  uint8_t* cov = r->coverage.data();
  for (size_t i = 0, n = size_t(w) * h; i < n; ++i) {
    dst[3 * i + 0] = src[4 * i + 0];
    dst[3 * i + 1] = src[4 * i + 1];
    dst[3 * i + 2] = src[4 * i + 2];
    const uint8_t a = src[4 * i + 3];
    cov[i] = a == 0 ? 0 : a == 255 ? 2 : a == 64 ? 3 : 1;
  }
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
  // See vk::CellTable::RankRefs (vk_cell_table.cc) for the derivation. Directional: each ray turns by at most asin(r / D)
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


// The composition of the renderer's parts: the device context, the pipelines, the three
// resident stores (views, cell table, mesh chunks) and one render target per pass.
class VulkanRenderer::Impl {
 public:
  VulkanRendererOptions opt;
  std::unique_ptr<vk::Context> ctx;  // declared first: destroyed after every object below
  UploadStats stats;
  CellGrid grid;
  std::unique_ptr<vk::Pipelines> pipes;
  std::unique_ptr<vk::ViewStore> views;
  std::unique_ptr<vk::CellTable> cells;
  std::unique_ptr<vk::MeshChunks> chunks;
  Buffer frame_ubo;
  vk::RenderTarget color_target, cellid_target, zdepth_target;
  // Binding 6 / 8 before any blend target exists (lavapipe reads every binding of a bound set).
  vk::Image placeholder_gbuffer;
  Buffer placeholder_out;
  bool descriptors_dirty = true;

  // ===================== setup =====================
  absl::Status Init() {
    vk::ContextOptions copt;
    copt.enable_validation = opt.enable_validation;
    EXO_ASSIGN_OR_RETURN(ctx, vk::Context::Create(copt));
    EXO_ASSIGN_OR_RETURN(frame_ubo, Buffer::Create(*ctx, sizeof(GpuFrame),
                                                   VK_BUFFER_USAGE_UNIFORM_BUFFER_BIT));
    EXO_ASSIGN_OR_RETURN(pipes, vk::Pipelines::Create(*ctx, opt.blend_in_compute));
    EXO_RETURN_IF_ERROR(CreatePlaceholders());
    views = std::make_unique<vk::ViewStore>(*ctx, opt, stats);
    cells = std::make_unique<vk::CellTable>(*ctx, opt, stats, *views);
    chunks = std::make_unique<vk::MeshChunks>(*ctx, stats);
    // Empty store: 1 slot, 1x1 layers, a 64-entry table, 1 slab, so every descriptor is valid.
    EXO_RETURN_IF_ERROR(views->Grow(1, 1, 1));
    return cells->Init();
  }

  // A 4-byte blend output and a 1x1 G-buffer in SHADER_READ_ONLY_OPTIMAL.
  absl::Status CreatePlaceholders() {
    EXO_ASSIGN_OR_RETURN(placeholder_out,
                         Buffer::Create(*ctx, 4, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT));
    EXO_ASSIGN_OR_RETURN(placeholder_gbuffer,
                         vk::Image::Create(*ctx, 1, 1, 1, VK_FORMAT_R32G32B32A32_SFLOAT,
                                           VK_IMAGE_USAGE_SAMPLED_BIT, VK_IMAGE_ASPECT_COLOR_BIT,
                                           false));
    return ctx->Submit([&](VkCommandBuffer cmd) {
      vk::TransitionImage(cmd, placeholder_gbuffer.image.get(), VK_IMAGE_ASPECT_COLOR_BIT,
                          VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, 0, 1);
    });
  }

  // Rewrites the descriptor set when a store replaced a buffer or the blend target changed.
  absl::Status UpdateDescriptors() {
    descriptors_dirty |= views->TakeStorageChanged();
    descriptors_dirty |= cells->TakeStorageChanged();
    if (!descriptors_dirty) return absl::OkStatus();
    vk::DescriptorInputs in;
    in.frame_ubo = &frame_ubo;
    in.view_records = &views->records_buffer();
    in.cell_table = &cells->table_buffer();
    in.refs = &cells->refs_buffer();
    in.colors = &views->colors();
    in.depths = &views->depths();
    in.gbuffer = color_target.gbuffer.image ? &color_target.gbuffer : &placeholder_gbuffer;
    in.ranked_refs = &cells->ranked_buffer();
    in.blend_out = color_target.blend_out.buffer ? &color_target.blend_out : &placeholder_out;
    EXO_RETURN_IF_ERROR(pipes->WriteDescriptors(in));
    descriptors_dirty = false;
    return absl::OkStatus();
  }

  // ===================== store =====================
  absl::Status UpsertView(const StoredView& v, uint64_t fingerprint) {
    EXO_ASSIGN_OR_RETURN(const bool is_new, views->Upsert(v, fingerprint));
    // Cells that already referenced this id now resolve to the slot.
    if (is_new) cells->RefreshCellsOf(v.id);
    return absl::OkStatus();
  }

  absl::Status RemoveView(ViewId id) {
    EXO_RETURN_IF_ERROR(views->Remove(id));
    cells->RefreshCellsOf(id);
    return absl::OkStatus();
  }

  // ===================== rendering =====================
  absl::Status EnsureBlendTarget(uint32_t w, uint32_t h) {
    EXO_ASSIGN_OR_RETURN(const bool recreated,
                         color_target.Ensure(*ctx, pipes->color_pass(), VK_FORMAT_R8G8B8A8_UNORM,
                                             w, h, pipes->gbuffer_pass()));
    if (recreated) descriptors_dirty = true;  // bindings 6 and 8 point at the new target
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

  // The render-time options must match what was baked into the resident depth layers.
  absl::Status CheckBakedOptions(const blend::BlendOptions& bo) const {
    if (bo.discontinuity_radius_px != opt.bake_discontinuity_radius_px ||
        bo.discontinuity_delta_z_m != opt.bake_discontinuity_delta_z_m ||
        bo.discontinuity_delta_z_rel != opt.bake_discontinuity_delta_z_rel)
      return absl::InvalidArgumentError(
          "BlendOptions discontinuity parameters differ from the ones baked into the resident "
          "depth layers (VulkanRendererOptions::bake_discontinuity_*)");
    if (bo.background_views > 0 &&
        bo.background_guard_radius_px != opt.bake_background_guard_radius_px)
      return absl::InvalidArgumentError(
          "BlendOptions::background_guard_radius_px differs from the one baked into the "
          "resident depth layers (VulkanRendererOptions::bake_background_guard_radius_px)");
    return absl::OkStatus();
  }

  void FillFrame(const PinholeCamera& camera, const Rigid3d& local_from_cam, GpuFrame* f) const {
    const glm::dmat4 cam_from_local = local_from_cam.Inverse().ToMatrix();
    f->clip_from_local =
        glm::mat4(ClipFromCam(camera, opt.near_m, opt.far_m) * cam_from_local);
    f->cam_centre_cell =
        glm::vec4(glm::vec3(local_from_cam.translation), float(grid.cell_size_m));
    f->iparams = glm::ivec4(0, 0, int(cells->table_mask()), int(cells->max_probe()));
  }

  // Records the proxy draw with `pipe` into `t`, copies the colour attachment to t.readback.
  // deferred == false: draws the proxy chunks with `pipe` into t.fb. deferred == true (blend):
  // first the proxy into the G-buffer (gbuffer_pipe, t.gbuffer_fb), then one full-screen
  // triangle with `pipe` into t.fb, or with a compute pipe blend.comp into t.blend_out and no
  // read-back; one command buffer, one submit.
  absl::Status Draw(vk::RenderTarget& t, VkRenderPass pass, VkPipeline pipe,
                    const VkClearValue& clear, uint32_t texel_bytes, bool deferred = false,
                    VkPipeline compute_pipe = VK_NULL_HANDLE) {
    EXO_RETURN_IF_ERROR(UpdateDescriptors());
    const vk::Pipelines& p = *pipes;
    return ctx->Submit([&](VkCommandBuffer cmd) {
      if (deferred) {
        VkClearValue zero{};  // G-buffer w = 0: no surface
        RecordBeginPass(cmd, p, p.gbuffer_pass(), t.gbuffer_fb.get(), zero, p.gbuffer_pipe(),
                        t.w, t.h);
        chunks->RecordDraws(cmd);
        vkCmdEndRenderPass(cmd);
        if (compute_pipe != VK_NULL_HANDLE) return RecordComputeBlend(cmd, p, t, compute_pipe);
        RecordBeginPass(cmd, p, pass, t.fb.get(), clear, pipe, t.w, t.h);
        vkCmdDraw(cmd, 3, 1, 0, 0);
        vkCmdEndRenderPass(cmd);
      } else {
        RecordBeginPass(cmd, p, pass, t.fb.get(), clear, pipe, t.w, t.h);
        chunks->RecordDraws(cmd);
        vkCmdEndRenderPass(cmd);
      }
      vk::RecordReadback(cmd, t, texel_bytes);
    });
  }

  // The per-frame background view list (SelectBackgroundViews over the resident views in id
  // order: the CPU reference's order) and the pixel-to-direction matrix, into the Frame block.
  void FillBackground(const PinholeCamera& camera, const Rigid3d& local_from_cam, int max_views,
                      GpuFrame* f, std::vector<ViewId>* chosen_ids) const {
    std::vector<std::pair<ViewId, const vk::ViewStore::Entry*>> sorted;
    sorted.reserve(views->entries().size());
    for (const auto& [id, e] : views->entries()) sorted.emplace_back(id, &e);
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
      const vk::ViewStore::Entry& e = *sorted[chosen[j]].second;
      glm::vec4* dst = f->bg_views + kBgViewTexels * j;
      for (int c = 0; c < 3; ++c) dst[c] = glm::vec4(e.params.cam_from_local[c], 0.0f);
      dst[3] = e.params.intrinsics;
      dst[4] = glm::vec4(float(e.params.size.x), float(e.params.size.y), float(e.slot),
                         e.params.exposure);
      chosen_ids->push_back(ids[chosen[j]]);
    }
  }

  // The blend pass's Frame block (camera, weights, background list) into frame_ubo.
  void UploadBlendFrame(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                        const blend::BlendOptions& bo, GpuFrame* f,
                        std::vector<ViewId>* bg_ids) const {
    FillFrame(camera, local_from_cam, f);
    f->weights = glm::vec4(bo.lambda, bo.min_weight, bo.occlusion_epsilon_m,
                           bo.occlusion_epsilon_rel);
    f->background = glm::vec4(bo.background_srgb, 0.0f);
    f->iparams.x = static_cast<int>(bo.positional_mode);
    f->iparams.y = bo.n_best;
    if (bo.background_views > 0) FillBackground(camera, local_from_cam, bo.background_views, f,
                                                bg_ids);
    std::memcpy(frame_ubo.mapped, f, sizeof(*f));
  }

  // The deferred blend of one frame into color_target (graphics or compute).
  absl::Status DrawBlend(const blend::BlendOptions& bo) {
    VkClearValue clear{};
    clear.color = {{bo.background_srgb.x, bo.background_srgb.y, bo.background_srgb.z, 0.0f}};
    EXO_RETURN_IF_ERROR(pipes->EnsureBlendPipe(bo.n_best));
    return Draw(color_target, pipes->color_pass(), pipes->blend_pipe(bo.n_best), clear, 4,
                /*deferred=*/true, pipes->blend_compute_pipe(bo.n_best));
  }

  absl::StatusOr<RenderResult> Render(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                      const blend::BlendOptions& bo) {
    EXO_RETURN_IF_ERROR(bo.Validate());
    EXO_RETURN_IF_ERROR(CheckCamera(camera, local_from_cam));
    EXO_RETURN_IF_ERROR(CheckBakedOptions(bo));
    const uint32_t w = camera.width, h = camera.height;
    EXO_RETURN_IF_ERROR(EnsureBlendTarget(w, h));
    GpuFrame f{};
    RenderResult r;
    UploadBlendFrame(camera, local_from_cam, bo, &f, &r.background_views);
    const auto tr = Clock::now();
    cells->RankRefs(glm::vec3(f.cam_centre_cell), camera, local_from_cam, grid.cell_size_m, bo);
    r.rank_ms = MsSince(tr);
    const auto t0 = Clock::now();
    EXO_RETURN_IF_ERROR(DrawBlend(bo));
    r.gpu_ms = MsSince(t0);
    const auto t1 = Clock::now();
    UnpackBlendOutput(static_cast<const uint8_t*>(pipes->blend_compute()
                                                      ? color_target.blend_out.mapped
                                                      : color_target.readback.mapped),
                      w, h, &r);
    r.readback_ms = MsSince(t1);
    if (bo.fill_holes) {  // host post-pass on the read-back frame, same function as the CPU oracle
      const auto tf = Clock::now();
      ImageU8 known(w, h, 1, 0);
      for (size_t i = 0; i < known.size(); ++i) known.data()[i] = r.coverage.data()[i] >= 2;
      r.filled_pixels = FillHoles(r.color, known);
      r.fill_ms = MsSince(tf);
    }
    return r;
  }

  absl::StatusOr<Image<uint64_t>> RenderCellIds(const PinholeCamera& camera,
                                                const Rigid3d& local_from_cam) {
    EXO_RETURN_IF_ERROR(CheckCamera(camera, local_from_cam));
    const uint32_t w = camera.width, h = camera.height;
    EXO_RETURN_IF_ERROR(
        cellid_target.Ensure(*ctx, pipes->cellid_pass(), VK_FORMAT_R32G32_UINT, w, h).status());
    GpuFrame f{};
    FillFrame(camera, local_from_cam, &f);
    std::memcpy(frame_ubo.mapped, &f, sizeof(f));
    VkClearValue clear{};
    clear.color.uint32[0] = clear.color.uint32[1] = 0xFFFFFFFFu;
    EXO_RETURN_IF_ERROR(
        Draw(cellid_target, pipes->cellid_pass(), pipes->cellid_pipe(), clear, 8));
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
    EXO_RETURN_IF_ERROR(
        zdepth_target.Ensure(*ctx, pipes->zdepth_pass(), VK_FORMAT_R32_SFLOAT, w, h).status());
    GpuFrame f{};
    FillFrame(camera, local_from_cam, &f);
    // viewdepth.frag: background.xyz = optical axis (third column of local_from_cam's rotation).
    f.background = glm::vec4(glm::vec3(local_from_cam.RotationMatrix()[2]), 0.0f);
    std::memcpy(frame_ubo.mapped, &f, sizeof(f));
    VkClearValue clear{};  // 0 = no surface (invalid depth)
    EXO_RETURN_IF_ERROR(
        Draw(zdepth_target, pipes->zdepth_pass(), pipes->zdepth_pipe(), clear, 4));
    ImageF out(w, h, 1, 0.0f);
    std::memcpy(out.data(), zdepth_target.readback.mapped, size_t(w) * h * sizeof(float));
    return out;
  }

  uint64_t ResidentBytes() const {
    return views->ResidentBytes() + cells->ResidentBytes() + chunks->ResidentBytes();
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
  return impl_->cells->SetRefs(cell, refs);
}
absl::Status VulkanRenderer::UpsertChunk(const MeshChunk& chunk) {
  return impl_->chunks->Upsert(chunk);
}
absl::Status VulkanRenderer::RemoveChunk(uint64_t chunk_id) {
  return impl_->chunks->Remove(chunk_id);
}

absl::Status VulkanRenderer::SyncModel(const LumigraphModel& model) {
  Impl& m = *impl_;
  if (model.grid.cell_size_m != m.grid.cell_size_m) {
    EXO_RETURN_IF_ERROR(SetGrid(model.grid));
  }
  // Chunks: by id + version.
  std::vector<uint64_t> gone;
  for (const auto& [id, c] : m.chunks->entries())
    if (!model.chunks.count(id)) gone.push_back(id);
  for (uint64_t id : gone) EXO_RETURN_IF_ERROR(m.chunks->Remove(id));
  for (const auto& [id, c] : model.chunks) {
    auto it = m.chunks->entries().find(id);
    if (it == m.chunks->entries().end() || it->second.version != c.version)
      EXO_RETURN_IF_ERROR(m.chunks->Upsert(c));
  }
  // Views: by content fingerprint.
  std::vector<ViewId> gone_views;
  for (const auto& [id, v] : m.views->entries())
    if (!model.views.count(id)) gone_views.push_back(id);
  for (ViewId id : gone_views) EXO_RETURN_IF_ERROR(m.RemoveView(id));
  for (const auto& [id, v] : model.views) {
    if (v.id != id)
      return absl::InvalidArgumentError(
          absl::StrCat("view map key ", id, " differs from StoredView::id ", v.id));
    const uint64_t fp = ViewFingerprint(v);
    auto it = m.views->entries().find(id);
    if (it == m.views->entries().end() || it->second.fingerprint != fp)
      EXO_RETURN_IF_ERROR(m.UpsertView(v, fp));
  }
  // Cells: by reference list.
  std::vector<CellId> gone_cells;
  for (const auto& [id, c] : m.cells->entries())
    if (!model.cell_refs.count(id)) gone_cells.push_back(id);
  for (CellId id : gone_cells) EXO_RETURN_IF_ERROR(m.cells->SetRefs(id, {}));
  for (const auto& [id, refs] : model.cell_refs) {
    auto it = m.cells->entries().find(id);
    if (it == m.cells->entries().end() || it->second.refs != refs)
      EXO_RETURN_IF_ERROR(m.cells->SetRefs(id, refs));
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
size_t VulkanRenderer::num_views() const { return impl_->views->entries().size(); }
size_t VulkanRenderer::num_cells() const { return impl_->cells->entries().size(); }
size_t VulkanRenderer::num_chunks() const { return impl_->chunks->entries().size(); }
std::string VulkanRenderer::DeviceName() const { return impl_->ctx->device_name(); }
std::vector<std::string> VulkanRenderer::ValidationErrors() const {
  return impl_->ctx->ValidationErrors();
}

}  // namespace exo
