// CPU reference lumigraph renderer (SPEC §6): for each pixel of a novel view it rasterizes the
// proxy mesh (common/raster) for the surface point and its cell, takes the cell's references
// R(b_k) from LumigraphModel::cell_refs, evaluates validity and weights (blend_math.h), keeps the
// best n = 3 and blends their colours with exposure in linear intensity. This is the oracle the
// Vulkan client is golden-tested against, and the renderer of the evaluation benchmarks.
// Pixels whose ray hits no proxy surface are filled from the stored views' "nothing within range"
// pixels, treating the ray as a direction (background at infinity, e.g. sky;
// BlendOptions::background_views, blend_math.h BackgroundWeight).
// Output is always defined: pixels with no surface, an empty reference set or no valid view get
// coverage 0 (never NaN) and, by default, a push-pull fill from the covered pixels around them
// (BlendOptions::fill_holes; off: the background colour).
#pragma once

#include <functional>
#include <memory>
#include <mutex>
#include <span>
#include <unordered_map>
#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/lumigraph/blend_math.h"
#include "common/lumigraph/model.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo {

struct CpuRenderOptions {
  blend::BlendOptions blend;
  int num_threads = 2;
  bool cull_backfaces = false;   // proxy back faces (TSDF meshes are two-sided in practice)
  bool debug_weights = false;    // fill weight_sum and num_views
  absl::Status Validate() const;
};

struct CpuRenderOutput {
  ImageU8 color;       // RGB8 sRGB
  ImageU8 coverage;    // 1 channel: 255 = blended from >= 1 valid view, 0 = background
  // 1 channel: 255 = no proxy surface, filled at infinity from >= 1 stored view (coverage stays
  // 0 there: coverage measures the lumigraph's surface blend), 0 otherwise.
  ImageU8 background;
  // 1 channel: 255 = blended from inpainted views (InpaintFusion's label rule held there; the
  // Vulkan renderer's coverage code 4, the window's tint), 0 otherwise.
  ImageU8 inpainted;
  ImageF weight_sum;   // debug: Σ w_i of the selected views (0 where uncovered)
  ImageU8 num_views;   // debug: number of views blended per pixel
  size_t covered_pixels = 0;
  size_t surface_pixels = 0;  // pixels where the proxy was hit
  size_t background_pixels = 0;       // pixels filled at infinity (see `background`)
  std::vector<ViewId> background_views;  // this frame's background view list, in rank order
  size_t filled_pixels = 0;  // uncovered pixels filled by FillHoles (BlendOptions::fill_holes)
  double raster_ms = 0.0, blend_ms = 0.0;
  double fill_ms = 0.0;      // FillHoles (not in blend_ms)
  double background_ms = 0.0;  // view selection + masks of the background pass (in blend_ms)
};

class CpuLumigraphRenderer {
 public:
  // Snapshots what rendering needs from `model` (proxy mesh, per-view blend parameters,
  // references resolved to view indices). The model's images are referenced, not copied: the
  // model must outlive the renderer and not change while it is used (Create again after edits).
  static absl::StatusOr<std::unique_ptr<CpuLumigraphRenderer>> Create(
      const LumigraphModel& model, const CpuRenderOptions& options);

  // Renders the novel view `camera` at `local_from_cam` (scene-local frame).
  absl::StatusOr<CpuRenderOutput> Render(const PinholeCamera& camera,
                                         const Rigid3d& local_from_cam) const;

  size_t num_views() const { return views_.size(); }

 private:
  struct ViewData {
    blend::BlendView params;
    ViewId id = 0;
    const ImageU8* color = nullptr;
    const ImageF* depth = nullptr;
    const ImageU8* labels = nullptr;  // inpainted views only (SPEC §7)
  };
  struct BackgroundMaskEntry {
    bool computed = false;
    bool any = false;  // at least one background pixel
    ImageU8 mask;      // BackgroundMask of the view's depth
  };
  CpuLumigraphRenderer() = default;
  // The view's background mask, computed on first use (thread-safe; views never used as a
  // background view cost nothing).
  const BackgroundMaskEntry& MaskOf(int view_index) const;

  CpuRenderOptions options_;
  CellGrid grid_;
  TriangleMesh mesh_;
  std::vector<ViewData> views_;
  std::unordered_map<CellId, std::vector<int>> refs_;  // cell -> indices into views_
  std::vector<int> inpainted_;  // indices into views_ of the inpainted keyframes (SPEC §7)
  mutable std::mutex mask_mutex_;
  mutable std::vector<std::unique_ptr<BackgroundMaskEntry>> masks_;  // per view, lazily
};

// Hole fill of a rendered frame (BlendOptions::fill_holes; shared by the CPU reference and the
// Vulkan client, which runs it on the read-back frame): pixels where `known` (1 channel, same
// size) is 0 get a push-pull fill (PushPullFill, bilinear pull) of the known pixels' colour in
// linear intensity (sRGB decoded, filled, encoded). Known pixels are not changed. Returns the
// number of pixels filled: 0 when every pixel is known or none is.
size_t FillHoles(ImageU8& rgb, const ImageU8& known);

// InpaintFusion (SPEC §7): at most this many inpainted keyframes take part in one frame (the
// Vulkan Frame block holds their layers), the ones nearest the novel camera centre (ties: lower
// id). `centres`/`ids` of the inpainted views in id order; returns indices into them, nearest
// first. Identical in CPU and Vulkan.
inline constexpr int kMaxInpaintedViews = 8;
std::vector<int> SelectInpaintedViews(const Rigid3d& local_from_cam,
                                      std::span<const glm::vec3> centres,
                                      std::span<const ViewId> ids);

// Converts a stored view into the fragment-stage parameters of blend_math.h.
blend::BlendView MakeBlendView(const StoredView& view);

// ---- background at infinity (shared by the CPU reference and the Vulkan client) ----

// 1 where the pixel and every in-image pixel within Chebyshev radius `guard_radius_px` have
// invalid depth (0, NaN, Inf: nothing observed within range), else 0. O(W H) (separable).
ImageU8 BackgroundMask(const ImageF& depth_m, int guard_radius_px);

// Local-frame ray direction of pixel (x, y) is local_from_pixel * (x, y, 1): R K^-1, computed in
// double and rounded once to float (the same matrix is handed to the shader).
glm::mat3 LocalFromPixel(const PinholeCamera& camera, const Rigid3d& local_from_cam);

// Half-angle (radians) of the cone around the optical axis that contains every pixel ray of a
// view: the largest angle to the four image corners (-0.5, -0.5) .. (W-0.5, H-0.5).
double HalfDiagonalFov(const glm::vec4& intrinsics, const glm::ivec2& size);

// The per-frame background view list, identical in CPU and Vulkan: the views whose direction
// cone can overlap the novel view's (angle between the optical axes < the sum of both
// HalfDiagonalFov) and that have a background pixel (`has_background(i)`, asked only for views
// that pass the cone test, in rank order), ranked by the angle between optical axes (ties: lower
// id first), at most `max_views`. Returns indices into `views` / `ids` (same length).
std::vector<int> SelectBackgroundViews(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                       std::span<const blend::BlendView> views,
                                       std::span<const ViewId> ids, int max_views,
                                       const std::function<bool(int)>& has_background);

}  // namespace exo
