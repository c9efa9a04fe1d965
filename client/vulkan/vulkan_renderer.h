// Headless Vulkan render client engine (SPEC §6, client side): keeps the client store resident on
// the GPU (mesh chunks, stored views as sRGB texture-array layers with pose/intrinsics/exposure,
// depth for occlusion, per-cell reference table with an open-addressing cell-hash lookup),
// uploads incrementally (one view / one cell / one chunk at a time), and renders novel views by
// lumigraph blending (shaders/blend.frag, a line-by-line mirror of common/lumigraph/blend_math.h)
// plus a cell-id pass for view planning. Runs on lavapipe (Mesa llvmpipe Vulkan) on CPU-only
// machines. vulkan.h never appears in this header (pimpl).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/cells.h"
#include "common/image.h"
#include "common/lumigraph/blend_math.h"
#include "common/lumigraph/model.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo {

struct VulkanRendererOptions {
  // Enables VK_LAYER_KHRONOS_validation and records its errors/warnings (ValidationErrors()).
  bool enable_validation = false;
  // Reference slots reserved per cell on the GPU (a cell's refs beyond this are an error).
  int max_refs_per_cell = 64;  // >= the server's render_refs_max (64 by default)
  // Clip planes of the novel camera (metres along the optical axis).
  float near_m = 0.01f;
  float far_m = 10000.0f;
  // Discontinuity parameters are baked into each view's depth layer at upload time (an exact
  // refactoring of blend::Validity's discontinuity test: it depends only on the stored pixel).
  // The render-time BlendOptions must carry the same radius / delta_z (checked per Render()).
  int bake_discontinuity_radius_px = blend::BlendOptions{}.discontinuity_radius_px;
  float bake_discontinuity_delta_z_m = blend::BlendOptions{}.discontinuity_delta_z_m;
  float bake_discontinuity_delta_z_rel = blend::BlendOptions{}.discontinuity_delta_z_rel;
  // Background at infinity: each view's BackgroundMask (cpu_renderer.h) with this guard radius
  // is baked into its depth layer at upload (-1 = background, 0 = invalid, > 0 = depth), so the
  // shader needs one depth fetch per background view. Render() requires
  // BlendOptions::background_guard_radius_px to equal it when background_views > 0.
  int bake_background_guard_radius_px = blend::BlendOptions{}.background_guard_radius_px;
  // Runs the blend as a compute dispatch over the G-buffer (shaders/blend.comp) instead of a
  // full-screen triangle (blend.frag); same per-pixel code and result. Off by default: measured
  // 5-7 % slower on lavapipe (docs/vulkan.md); kept for devices where compute is the better path.
  bool blend_in_compute = false;

  absl::Status Validate() const;
};

// The X-ray hole (VulkanRenderer::SetXrayHole). The disc is resolution-independent: its centre
// as a fraction of the image (0, 0: the top-left corner; pixel (x, y)'s centre is at
// ((x + 0.5) / W, (y + 0.5) / H)), its radius as a fraction of the image height; a pixel is in
// the hole when its centre is within the radius (a radius larger than the image's diagonal cuts
// the whole picture).
struct XrayHole {
  double clip_m = 1.0;  // z-depth (metres along the optical axis) of the cut inside the disc
  double centre_x = 0.5, centre_y = 0.5;
  double radius = 0.25;
};

// Bytes and objects moved from host to GPU since the last ResetStats().
struct UploadStats {
  uint64_t bytes = 0;
  uint64_t view_uploads = 0;
  uint64_t cell_uploads = 0;
  uint64_t chunk_uploads = 0;
  uint64_t table_rebuilds = 0;   // cell-hash table regrowths (full table upload)
  uint64_t array_regrowths = 0;  // view texture arrays regrown (GPU-side copy, no host bytes)
};

struct RenderResult {
  ImageU8 color;     // RGB8, sRGB
  // 1 ch: 0 = no proxy surface, 1 = surface but no valid view, 2 = blended, 3 = no proxy
  // surface, filled at infinity from the stored views (BlendOptions::background_views), 4 =
  // blended from inpainted views (InpaintFusion's label rule; the window's tint, key I).
  ImageU8 coverage;
  double gpu_ms = 0;       // submit-to-fence time of the render pass
  double readback_ms = 0;  // copy-out of the colour attachment to ImageU8
  // BlendOptions::fill_holes: uncovered pixels (coverage 0 / 1) filled on the host after the
  // read-back by FillHoles (cpu_renderer.h), the CPU oracle's function.
  size_t filled_pixels = 0;
  double fill_ms = 0;
  double rank_ms = 0;      // host: per-frame ranking of every cell's references (RankRefs)
  // Background pass (fragment path): host time of the per-tile background-view lists, and the
  // mean list length over all pixels of the frame (views each tile's pixels may loop over).
  double sky_tiles_ms = 0;
  double sky_views_per_px = 0;
  std::vector<ViewId> background_views;  // this frame's background view list (rank order)
};

// Approximations Render() may take for interactive frames (the viewer window while the camera
// moves); the defaults are exact.
struct RenderApprox {
  // Evaluate at most this many of a pixel's cell references, in decreasing order of their
  // per-frame weight bound (CellTable::RankRefs), instead of every reference that could still
  // enter the best n (0 = every one: exact). The shader's cost per pixel is the references it
  // evaluates: on a 7-Scenes model (up to 64 references per cell) 4 cut a moving frame's CPU
  // time 3x (docs/viewer.md); the picture differs where a lower-ranked reference would have won.
  int max_candidates = 0;
};

// Packs a 64-bit CellId into the 2 x 32-bit form of the cell-id pass (R32G32_UINT, lo = x).
inline CellId CellIdFromUints(uint32_t lo, uint32_t hi) {
  return (static_cast<uint64_t>(hi) << 32) | lo;
}

class VulkanRenderer {
 public:
  // Creates the device (lavapipe or any Vulkan device with a graphics queue). Fails with
  // kUnavailable and a clear message when no Vulkan device exists.
  static absl::StatusOr<std::unique_ptr<VulkanRenderer>> Create(
      const VulkanRendererOptions& options);
  ~VulkanRenderer();
  VulkanRenderer(const VulkanRenderer&) = delete;
  VulkanRenderer& operator=(const VulkanRenderer&) = delete;

  // ---- store residency: incremental updates ----
  absl::Status SetGrid(const CellGrid& grid);
  // Adds or replaces a view (uploads its colour, baked depth and record only).
  absl::Status UpsertView(const StoredView& view);
  absl::Status RemoveView(ViewId id);
  // Sets R(b_k) (replaces); an empty list removes the cell. Refs to views not (yet) resident
  // are skipped on the GPU and picked up when the view arrives.
  absl::Status SetCellRefs(CellId cell, std::span<const ViewId> refs);
  absl::Status UpsertChunk(const MeshChunk& chunk);
  absl::Status RemoveChunk(uint64_t chunk_id);
  // Brings the resident store to `model`, uploading only what differs: chunks by version, views
  // by content fingerprint (pose, intrinsics, exposure, pixels), cells by reference list.
  absl::Status SyncModel(const LumigraphModel& model);

  // ---- rendering ----
  // Blends a novel view (camera at local_from_cam in the scene-local frame); exact unless
  // `approx` says otherwise.
  absl::StatusOr<RenderResult> Render(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                      const blend::BlendOptions& options,
                                      const RenderApprox& approx = {});
  // Cell-id pass: the CellId of the proxy surface per pixel (kNoCell where none).
  absl::StatusOr<Image<uint64_t>> RenderCellIds(const PinholeCamera& camera,
                                                const Rigid3d& local_from_cam);

  // The speed floor the blend is measured against (vulkan_bench): a forward draw of the resident
  // proxy with one bilinear fetch per pixel from the resident view nearest the camera (no
  // validity, weights or blending), the same read-back and unpack as Render; coverage 2 where
  // the proxy is drawn. FailedPrecondition without a resident view.
  //   kForward (default): issue 16's floor, the plain textured forward draw: the texture
  //     coordinate is each vertex's projection into the view, interpolated over the triangle,
  //     fetched from an RGBA8 copy of the view's stored sRGB colour and written out unchanged
  //     (shaders/floor.vert, floor.frag). The copy is made by PrepareFloor.
  //   kProjective: the session-9 floor: projected per fragment from the linear colour layers the
  //     blend reads, sRGB-encoded in the shader (floorproj.frag; ~1.7x kForward's CPU
  //     time at 720p, docs/vulkan.md session 13).
  enum class FloorKind { kForward, kProjective };
  absl::StatusOr<RenderResult> RenderFloor(const PinholeCamera& camera,
                                           const Rigid3d& local_from_cam,
                                           FloorKind kind = FloorKind::kForward);
  // Makes the kForward floor's texture (the nearest view's colour as RGBA8) resident for this
  // camera unless it already is (RenderFloor calls it too; vulkan_bench calls it before timing,
  // so the floor measures the draw with a resident texture).
  absl::Status PrepareFloor(const PinholeCamera& camera, const Rigid3d& local_from_cam);

  // Z-depth (metres along the optical axis) of the resident proxy mesh seen from a camera, 0
  // where there is no surface: what a client would use if views did not carry depth
  // (shaders/viewdepth.frag; measured against stored sensor depth in docs/vulkan.md).
  absl::StatusOr<ImageF> RenderProxyDepth(const PinholeCamera& camera,
                                          const Rigid3d& local_from_cam);

  // The novel camera's near clip plane from now on (metres along the optical axis; default
  // VulkanRendererOptions::near_m): the viewer's X-ray cut-away sets it behind a wall, so the
  // proxy nearer than it is not drawn and the modelled interior behind shows (Render,
  // RenderProxyDepth, RenderCellIds, RenderFloor). InvalidArgument unless 0 < near_m < far_m.
  absl::Status SetNearPlane(float near_m);
  float near_plane() const;
  // The viewer's X-ray cut-away as a "virtual hole in the wall" (thesis 5.2.7, issue 19): from
  // now on, inside the hole's disc on the image the proxy nearer than hole.clip_m is not drawn,
  // so the modelled interior behind the wall shows there; outside the disc the picture is the
  // normal one (Render, RenderProxyDepth, RenderCellIds; not RenderFloor). nullopt: no hole.
  // InvalidArgument (the hole unchanged) unless 0 < clip_m < far_m, radius > 0, all finite.
  absl::Status SetXrayHole(std::optional<XrayHole> hole);
  std::optional<XrayHole> xray_hole() const;

  // ---- introspection ----
  const UploadStats& stats() const;
  void ResetStats();
  // Bytes of GPU memory held for the store (buffers and texture arrays).
  uint64_t ResidentBytes() const;
  size_t num_views() const;
  size_t num_cells() const;
  size_t num_chunks() const;
  std::string DeviceName() const;
  std::vector<std::string> ValidationErrors() const;

  class Impl;

 private:
  explicit VulkanRenderer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// The per-view depth preprocessing the renderer uploads: pixels that fail (3.4)'s discontinuity
// test (a neighbour at offset {-r,0,r}^2 in the image with invalid depth or a jump > Δ_z) become
// 0 (invalid), so the fragment shader needs one depth fetch per candidate view instead of nine.
// Exactly equivalent to blend::Validity with the same radius / delta_z. Pure CPU, exposed for
// tests.
ImageF BakeDiscontinuities(const ImageF& depth_m, int radius_px, float delta_z_m,
                           float delta_z_rel);

// Upper bound of the blend weight (3.5) with validity 1, blend::CombinedWeight(1,
// DirectionalWeight(x, c_o, c_i), PositionalWeight(x, c_o, c_i, mode), lambda, min_weight), over
// every surface point x with |x - m| <= r, including a slack for float rounding. The renderer
// ranks each cell's references by it per frame (m, r: the cell's centre and inflated half
// diagonal) and stops evaluating a pixel's references once the bound is below the n-th best
// weight: exact as long as this is a true bound (tested by sampling). Pure CPU.
float BlendWeightUpperBound(const glm::dvec3& m, double r, const glm::dvec3& c_o,
                            const glm::dvec3& c_i, const blend::BlendOptions& options);

// Where a cell's surface points can lie for the bound below: the ball B(m, r) and, with has_box,
// also the box [lo, hi] (both must contain every point; the renderer uses the ball and box of
// the proxy surface in the cell, common/cell_surface.h, or the cell's cube).
struct CellRegion {
  glm::dvec3 m{0.0};
  double r = 0.0;
  bool has_box = false;
  glm::dvec3 lo{0.0}, hi{0.0};
};
// The same bound over the points of `region`, for one novel camera c_o and any reference c_i:
// the directional term's turn of the novel camera's ray is the smaller of asin(r / D_o) (ball)
// and the largest angle between the ray to m and the rays to the box's 8 corners (a box inside a
// cone of half-angle < 90 degrees around the ray has its corners in it, and the cone is convex),
// so a flat or thin box seen edge-on bounds tighter than its ball; computed once per cell and
// frame. With `box_turn_refs` the reference's ray gets the corner turn too (8 more corners per
// reference: host time for little, docs/vulkan.md session 17; off in the renderer).
class CellWeightBound {
 public:
  CellWeightBound(const CellRegion& region, const glm::dvec3& c_o, bool box_turn_refs = false);
  float operator()(const glm::dvec3& c_i, const blend::BlendOptions& options) const;

 private:
  CellRegion g_;
  glm::dvec3 a_;  // c_o - m
  double d_o_ = 0.0, cos_o_ = 1.0, sin_o_ = 0.0;
  bool box_turn_refs_ = false;
};

}  // namespace exo
