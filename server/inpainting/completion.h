// Scene completion (InpaintFusion's second mode, SPEC §7, thesis ch. 4; issue 18 item 4): where a
// viewer looks at what no stored view observed, the holes of the lumigraph render are completed
// by an inpainted keyframe at the viewer's camera.
//
//   1. the model (proxy mesh, stored views, cell references) is rendered at the viewer's camera
//      with the CPU lumigraph oracle (common/lumigraph/cpu_renderer.h, no hole fill) and the
//      proxy's z-depth; a HOLE is a pixel that the render leaves uncovered: a proxy surface that
//      no valid stored view sees ("surface hole"), or no proxy surface and no background-at-
//      infinity view either ("void hole");
//   2. the holes are inpainted (InpaintKeyframe: PatchMatch colour + Poisson depth anchored on
//      the proxy depth around them) in a keyframe whose colour is the render and whose depth is
//      the proxy's; a surface hole keeps the proxy's depth (the renderers blend the keyframe at
//      the proxy's surface point), a void hole keeps the solved depth;
//   3. the result is an inpainted view (StoredView::inpainted, labels 255 = the holes), and for
//      the void holes a mesh of the solved depth (scene-local; without it the renderers, which
//      rasterize the proxy, would have no surface to blend the keyframe on).
// Pure: no threads of its own beyond the renderer's / inpainting's, no gRPC.
#pragma once

#include <cstdint>

#include "common/camera.h"
#include "common/image.h"
#include "common/lumigraph/cpu_renderer.h"
#include "common/lumigraph/model.h"
#include "common/mesh.h"
#include "common/rigid3.h"
#include "common/status.h"
#include "server/inpainting/inpaint.h"

namespace exo::inpainting {

struct CompletionOptions {
  InpaintOptions inpaint;
  CpuRenderOptions render;  // blend.fill_holes is ignored (always off: holes are what we want)
  // Fewer hole pixels than this (and than min_hole_fraction of the frame): nothing to complete.
  int min_hole_px = 32;
  double min_hole_fraction = 0.01;
  // Fewer known pixels (covered or background) than this fraction of the frame: the camera looks
  // at nothing modelled, there is nothing to copy from (FAILED_PRECONDITION).
  double min_known_fraction = 0.05;
  // The void mesh: vertices on a grid of this step (px) over the void holes dilated by one step
  // (it meets the proxy around them), quads whose corners differ by more than mesh_jump_rel of
  // their depth are skipped (an occlusion edge).
  int mesh_step_px = 4;
  double mesh_jump_rel = 0.1;
  // The colour in the holes (session 16): PatchMatch copies plausible texture, but where the
  // hidden surface differs it copies the wrong texture, and its mean colour with it (session 15:
  // 2.1-2.7 dB below a push-pull fill inside the holes). With detail_gain >= 0 the holes take the
  // push-pull fill of the render (its low frequencies: the MSE-optimal smooth guess) plus
  // detail_gain times PatchMatch's high frequencies (its colour minus its Gaussian blur of
  // detail_sigma_px): texture without shifting the mean. < 0: PatchMatch's colour as it is.
  // completion_bench (docs/inpainting.md "Session 16"): in PSNR and SSIM every gain > 0 loses to
  // 0 (PatchMatch's texture is uncorrelated with the hidden surface), but at 0 the completion's
  // colour IS the push-pull fill the viewer already sees (no texture at all); 0.5 keeps half the
  // texture for -0.38 dB against push-pull (session 15's PatchMatch colour: -2.09 dB).
  double detail_gain = 0.5;
  double detail_sigma_px = 3.0;
  // Session 16: where a surface hole's proxy surface carries fused colour (the chunks' vertex
  // colours: the TSDF's running mean over every frame fused there, an observation even where no
  // stored view covers it), that colour is the keyframe's there (known to PatchMatch, which then
  // fills only the pixels without it: void holes, uncoloured surface). Chunks without vertex
  // colours (the wire's format 3 carries none) are not used.
  bool use_vertex_color = true;
  // The coloured surface must lie within this of the proxy's depth at the pixel (max with 0.1 %
  // of the depth): a separate coloured mesh (CompleteView's `coloured_proxy`, the server's
  // full-resolution chunks) differs from the published, simplified proxy by the LOD's error.
  double vertex_color_depth_tol_m = 0.02;
  absl::Status Validate() const;
};

// The holes of the model's render at one camera.
struct CompletionHoles {
  ImageU8 color;       // the render, RGB8 (holes black)
  ImageF proxy_depth;  // the proxy's z-depth (m), 0 = no surface
  ImageU8 holes;       // 255 = hole (surface or void)
  ImageU8 known;       // 255 = covered or background (the render shows something there)
  int hole_px = 0, surface_hole_px = 0, void_hole_px = 0;
  int fused_color_px = 0;  // CompleteView: surface-hole pixels coloured from the proxy's vertex colour
  int covered_px = 0, background_px = 0;
  double render_ms = 0;
};

struct CompletionResult {
  // false: the holes are negligible (below min_hole_px / min_hole_fraction): nothing was
  // inpainted, `view` and `void_mesh` are empty.
  bool completed = false;
  CompletionHoles before;
  StoredView view;         // inpainted = true, labels = the holes; id left 0 (the caller's)
  TriangleMesh void_mesh;  // scene-local, may be empty (no void holes)
  InpaintStats stats;
  double render_ms = 0, inpaint_ms = 0, mesh_ms = 0, total_ms = 0;  // wall
  // Process CPU time (all threads, CLOCK_PROCESS_CPUTIME_ID: includes other threads of the
  // calling process running meanwhile, as InpaintStats' cpu_ms).
  double total_cpu_ms = 0;
};

// The holes of `model` rendered at `camera` / `local_from_cam` (scene-local).
absl::StatusOr<CompletionHoles> FindHoles(const LumigraphModel& model, const PinholeCamera& camera,
                                          const Rigid3d& local_from_cam,
                                          const CompletionOptions& options);

// Completes the holes of `model` at the camera (see the file comment). Errors: invalid options or
// camera, non-finite pose (INVALID_ARGUMENT); nothing modelled in view or no valid source patch
// (FAILED_PRECONDITION).
// `coloured_proxy` (may be null): a mesh with vertex colours for the colour guide
// (use_vertex_color) instead of the model's chunks that carry colours.
absl::StatusOr<CompletionResult> CompleteView(const LumigraphModel& model,
                                              const PinholeCamera& camera,
                                              const Rigid3d& local_from_cam,
                                              const CompletionOptions& options,
                                              const TriangleMesh* coloured_proxy = nullptr);

// A mesh (scene-local) of `depth_m` over the pixels of `mask` (!= 0) dilated by `step_px`: grid
// vertices every `step_px`, quads with all four corners at valid depth whose depths differ by at
// most `jump_rel` of their smallest. Empty when no quad qualifies.
TriangleMesh MeshFromDepth(const ImageF& depth_m, const ImageU8& mask, const PinholeCamera& camera,
                           const Rigid3d& local_from_cam, int step_px, double jump_rel);

}  // namespace exo::inpainting
