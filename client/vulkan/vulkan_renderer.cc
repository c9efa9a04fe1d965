#include "client/vulkan/vulkan_renderer.h"

#include <algorithm>
#include <cstring>
#include <memory>

#include <glm/gtc/type_ptr.hpp>

#include "absl/hash/hash.h"
#include "absl/types/span.h"
#include "client/vulkan/vk_cell_table.h"
#include "client/vulkan/vk_core_internal.h"
#include "client/vulkan/vk_frame_renderer.h"
#include "client/vulkan/vk_mesh_chunks.h"
#include "client/vulkan/vk_view_store.h"
#include "common/lumigraph/cpu_renderer.h"

namespace exo {
namespace {

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
  if (v.inpainted)
    h = Mix(h, absl::Hash<absl::Span<const uint8_t>>{}(absl::MakeConstSpan(v.labels.span())));
  return h;
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

namespace {

// Cosine and sine of an upper bound of the angle at apex c (|c - m| = d > r) between the ray to m
// and the ray to any point of the region: asin(r / d) for the ball, or, when smaller, the largest
// angle to a corner of the box (only when every corner is within 90 degrees of the ray: then the
// box lies in the convex cone of that half-angle).
void RegionTurn(const CellRegion& g, const glm::dvec3& c, double d, double* cos_turn,
                double* sin_turn) {
  double sn = g.r / d, cs = std::sqrt(1.0 - sn * sn);
  if (g.has_box) {
    const glm::dvec3 u = (g.m - c) / d;
    double cmin = 1.0;
    for (int k = 0; k < 8; ++k) {
      const glm::dvec3 v(k & 1 ? g.hi.x : g.lo.x, k & 2 ? g.hi.y : g.lo.y, k & 4 ? g.hi.z : g.lo.z);
      const glm::dvec3 w = v - c;
      const double lw = glm::length(w);
      cmin = std::min(cmin, lw > 0.0 ? glm::dot(u, w) / lw : -1.0);
    }
    if (cmin > cs) {
      cs = cmin;
      sn = std::sqrt(std::max(0.0, 1.0 - cmin * cmin));
    }
  }
  *cos_turn = cs;
  *sin_turn = sn;
}

}  // namespace

float BlendWeightUpperBound(const glm::dvec3& m, double r, const glm::dvec3& c_o,
                            const glm::dvec3& c_i, const blend::BlendOptions& bo) {
  CellRegion g;
  g.m = m;
  g.r = r;
  return CellWeightBound(g, c_o)(c_i, bo);
}

CellWeightBound::CellWeightBound(const CellRegion& g, const glm::dvec3& c_o, bool box_turn_refs)
    : g_(g), a_(c_o - g.m), d_o_(glm::length(a_)), box_turn_refs_(box_turn_refs) {
  if (d_o_ > g.r) RegionTurn(g_, c_o, d_o_, &cos_o_, &sin_o_);
}

float CellWeightBound::operator()(const glm::dvec3& c_i, const blend::BlendOptions& bo) const {
  // See vk::CellTable::RankRefs (vk_cell_table.cc) for the derivation. Directional: each ray
  // turns by at most its RegionTurn (the reference's: asin(r / D_i) unless box_turn_refs) as x
  // moves in the region, so the angle at x is >= the angle at m minus both turns.
  const double r = g_.r, d_o = d_o_;
  const glm::dvec3 b = c_i - g_.m;
  const double d_i = glm::length(b);
  double w_d = 1.0;
  if (d_o > r && d_i > r) {
    // cos(max(0, theta - delta)) with theta = angle(a, b), delta = turn_o + turn_i < pi, without
    // trigonometric calls: cos/sin of delta by angle addition, then
    // theta <= delta <=> cos(theta) >= cos(delta), else cos(theta - delta) by angle subtraction.
    const double cos_t = std::clamp(glm::dot(a_, b) / (d_o * d_i), -1.0, 1.0);
    const double sin_t = std::sqrt(std::max(0.0, 1.0 - cos_t * cos_t));
    const double co = cos_o_, so = sin_o_;
    double si = r / d_i, ci = std::sqrt(1.0 - si * si);
    if (box_turn_refs_) RegionTurn(g_, c_i, d_i, &ci, &si);
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

// The composition of the renderer's parts: the device context, the three resident stores
// (views, cell table, mesh chunks) and the frame renderer that draws them.
class VulkanRenderer::Impl {
 public:
  VulkanRendererOptions opt;
  std::unique_ptr<vk::Context> ctx;  // declared first: destroyed after every object below
  UploadStats stats;
  CellGrid grid;
  std::unique_ptr<vk::ViewStore> views;
  std::unique_ptr<vk::CellTable> cells;
  std::unique_ptr<vk::MeshChunks> chunks;
  std::unique_ptr<vk::FrameRenderer> frame;

  absl::Status Init() {
    vk::ContextOptions copt;
    copt.enable_validation = opt.enable_validation;
    EXO_ASSIGN_OR_RETURN(ctx, vk::Context::Create(copt));
    views = std::make_unique<vk::ViewStore>(*ctx, opt, stats);
    cells = std::make_unique<vk::CellTable>(*ctx, opt, stats, *views);
    chunks = std::make_unique<vk::MeshChunks>(*ctx, stats);
    EXO_ASSIGN_OR_RETURN(frame,
                         vk::FrameRenderer::Create(*ctx, opt, grid, *views, *cells, *chunks));
    // Empty store: 1 slot, 1x1 layers, a 64-entry table, 1 slab, so every descriptor is valid.
    EXO_RETURN_IF_ERROR(views->Grow(1, 1, 1));
    return cells->Init();
  }

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

  // SyncModel's steps: chunks by id + version, views by content fingerprint, cells by
  // reference list; what the model lacks is removed first.
  absl::Status SyncChunks(const LumigraphModel& model) {
    std::vector<uint64_t> gone;
    for (const auto& [id, c] : chunks->entries())
      if (!model.chunks.count(id)) gone.push_back(id);
    for (uint64_t id : gone) EXO_RETURN_IF_ERROR(chunks->Remove(id));
    for (const auto& [id, c] : model.chunks) {
      auto it = chunks->entries().find(id);
      if (it == chunks->entries().end() || it->second.version != c.version)
        EXO_RETURN_IF_ERROR(chunks->Upsert(c));
    }
    return absl::OkStatus();
  }

  absl::Status SyncViews(const LumigraphModel& model) {
    std::vector<ViewId> gone;
    for (const auto& [id, v] : views->entries())
      if (!model.views.count(id)) gone.push_back(id);
    for (ViewId id : gone) EXO_RETURN_IF_ERROR(RemoveView(id));
    for (const auto& [id, v] : model.views) {
      if (v.id != id)
        return absl::InvalidArgumentError(
            absl::StrCat("view map key ", id, " differs from StoredView::id ", v.id));
      const uint64_t fp = ViewFingerprint(v);
      auto it = views->entries().find(id);
      if (it == views->entries().end() || it->second.fingerprint != fp)
        EXO_RETURN_IF_ERROR(UpsertView(v, fp));
    }
    return absl::OkStatus();
  }

  absl::Status SyncCells(const LumigraphModel& model) {
    std::vector<CellId> gone;
    for (const auto& [id, c] : cells->entries())
      if (!model.cell_refs.count(id)) gone.push_back(id);
    for (CellId id : gone) EXO_RETURN_IF_ERROR(cells->SetRefs(id, {}));
    for (const auto& [id, refs] : model.cell_refs) {
      auto it = cells->entries().find(id);
      if (it == cells->entries().end() || it->second.refs != refs)
        EXO_RETURN_IF_ERROR(cells->SetRefs(id, refs));
    }
    return absl::OkStatus();
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
  if (model.grid.cell_size_m != impl_->grid.cell_size_m) {
    EXO_RETURN_IF_ERROR(SetGrid(model.grid));
  }
  EXO_RETURN_IF_ERROR(impl_->SyncChunks(model));
  EXO_RETURN_IF_ERROR(impl_->SyncViews(model));
  return impl_->SyncCells(model);
}

absl::StatusOr<RenderResult> VulkanRenderer::Render(const PinholeCamera& camera,
                                                    const Rigid3d& local_from_cam,
                                                    const blend::BlendOptions& options,
                                                    const RenderApprox& approx) {
  return impl_->frame->Render(camera, local_from_cam, options, approx);
}
absl::StatusOr<RenderResult> VulkanRenderer::RenderFloor(const PinholeCamera& camera,
                                                         const Rigid3d& local_from_cam,
                                                         FloorKind kind) {
  return impl_->frame->RenderFloor(camera, local_from_cam, kind == FloorKind::kProjective);
}
absl::Status VulkanRenderer::PrepareFloor(const PinholeCamera& camera,
                                          const Rigid3d& local_from_cam) {
  return impl_->frame->PrepareFloor(camera, local_from_cam);
}
absl::StatusOr<ImageF> VulkanRenderer::RenderProxyDepth(const PinholeCamera& camera,
                                                        const Rigid3d& local_from_cam) {
  return impl_->frame->RenderProxyDepth(camera, local_from_cam);
}
absl::StatusOr<Image<uint64_t>> VulkanRenderer::RenderCellIds(const PinholeCamera& camera,
                                                              const Rigid3d& local_from_cam) {
  return impl_->frame->RenderCellIds(camera, local_from_cam);
}

absl::Status VulkanRenderer::SetNearPlane(float near_m) {
  if (!(near_m > 0.0f) || !(near_m < impl_->opt.far_m))
    return absl::InvalidArgumentError(
        absl::StrCat("near plane must be in (0, ", impl_->opt.far_m, ") m, got ", near_m));
  impl_->opt.near_m = near_m;  // the frame renderer reads the options at every frame
  return absl::OkStatus();
}
float VulkanRenderer::near_plane() const { return impl_->opt.near_m; }
absl::Status VulkanRenderer::SetXrayHole(std::optional<XrayHole> hole) {
  return impl_->frame->SetXrayHole(hole);
}
std::optional<XrayHole> VulkanRenderer::xray_hole() const { return impl_->frame->xray_hole(); }

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
