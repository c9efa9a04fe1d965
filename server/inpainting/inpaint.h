// RGB-D keyframe inpainting (InpaintFusion, thesis chapter 4, SPEC §7): fills a masked region T
// of an RGB-D keyframe in colour AND depth so that the result stays consistent when the camera
// moves, and re-uses an earlier keyframe's solution for the next keyframe.
//
//   1. depth pre-fill outside T (sensor holes, push-pull), normals from depth (depth_maps.h);
//   2. coarse-to-fine PatchMatch for the source map f: T -> (image \ T) minimising
//      w * rho_t * rho_g + (1 - w) * rho_s  (4.7-4.10) with rho_t the mean 5x5 SSD of colour,
//      rho_g the mean of 1/max(kappa, n . n') over a 3x3 lattice at 2 px spacing of the same
//      5x5 window, rho_s the capped squared neighbour-offset incoherence;
//   3. colour and normals copied through f (4.11-4.12);
//   4. depth from a Poisson solve on the mean bidirectional gradients of the copied depth
//      samples (4.13-4.16), T's border as Dirichlet boundary (poisson.h). By default the
//      gradients are taken of inverse depth, which is affine in pixel coordinates on any plane,
//      so planar surfaces are reproduced exactly; kDepth follows the thesis literally.
//   5. keyframe propagation (4.3-4.6): the previous keyframe's map initialises the new one
//      through 3D reprojection; only pixels it leaves unmapped are searched.
//
// Determinism: the result depends only on the inputs and `seed`, not on `num_threads`: the
// sweep runs over fixed row bands in two phases (even bands, then odd bands), each band in
// raster order, and every random draw comes from a hash of (seed, level, iteration, pixel).
#pragma once

#include <cstdint>
#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo::inpainting {

using ImageI32 = Image<int32_t>;

enum class DepthDomain { kInverseDepth, kDepth };

// How the two copied samples of a pixel pair's depth gradient (4.13-4.16) become the Poisson
// target. kMean: their mean with unit weight (the thesis). kRobust: a sample that crosses a
// depth discontinuity at its source (|g| > jump_rel * value) while the other does not is
// dropped, two disagreeing samples keep the smaller one, and a pair whose target is still a
// discontinuity gets weight `jump_weight` (the solve then follows the boundary and the other
// paths instead of a copied occlusion edge).
enum class GradientFusion { kMean, kRobust };

struct InpaintOptions {
  double w = 0.9;            // texture*geometry vs spatial coherence weight (4.7), in (0, 1]
  double kappa = 0.6;        // lower bound of n . n' in rho_g (4.10), in (0, 1]; see docs
  bool use_geometry = true;  // false: colour-only PatchMatch (rho_g == 1), the baseline
  // Onion-peel initialisation (coarsest level): rho_g compares only against the window's
  // measured normals (outside T), not against normals the peel itself copied into T earlier
  // (which would reinforce its own earlier choices; measurement in docs/inpainting.md).
  bool peel_measured_normals_only = true;
  double spatial_cap_px2 = 16.0;  // cap of one neighbour's squared offset incoherence (4.9)
  int pyramid_levels = 0;         // 0 = automatic (coarsest side >= min_coarse_side)
  int min_coarse_side = 24;
  int coarse_iterations = 8;  // sweeps at the coarsest level ...
  int fine_iterations = 2;    // ... falling linearly to this at full resolution
  int propagated_iterations = 3;  // sweeps over the unmapped pixels of a propagated keyframe
  // A level stops sweeping once a sweep changes the source of at most this fraction of its T
  // pixels (0 = always run all sweeps).
  double converged_fraction = 0.0;
  int band_rows = 8;              // rows per band of the deterministic parallel sweep
  int num_threads = 2;
  uint64_t seed = 1;
  DepthDomain depth_domain = DepthDomain::kInverseDepth;
  double max_median_depth_m = 100.0;  // units check: larger medians are millimetres
  float normal_rel_discontinuity = 0.05f;
  double poisson_tolerance = 1e-4;  // relative CG residual of the depth solve
  GradientFusion gradient_fusion = GradientFusion::kRobust;
  double jump_rel = 0.02;     // relative gradient (in the depth domain) that counts as a jump
  double jump_weight = 0.01;  // weight of a pair whose fused target is a jump, in (0, 1]
  // Screening (data) term of the depth solve towards a surface prior: the least-squares plane
  // (affine in the depth domain) through the known pixels 4-adjacent to T, or with
  // prior_local_px > 0 a plane per 8x8 block fitted with Gaussian weights (sigma prior_local_px)
  // of the border pixels' distance, clamped to the range of the border values. Weight at u:
  //   neumann_prior_weight * (dD(u) / (dD(u) + dN(u)))^2,
  // dD / dN the distances to the nearest Dirichlet (known depth) / Neumann (image edge or a
  // pixel without depth) border pixel: ~0 near known depth, ~1 where only the free border is
  // near, so it anchors the parts of T that the copied gradients alone would let drift (regions
  // touching the image border). Chosen on the training masks (docs/inpainting.md).
  double neumann_prior_weight = 0.01;
  double prior_local_px = 50.0;
  // Layered depth (inverse-depth domain only; chosen on the two training mask sets,
  // docs/inpainting.md): T may hide an occlusion edge (a table in
  // front of a wall), which one Poisson surface cannot carry. T's border pixels with measured
  // depth are clustered in inverse depth (sorted; split where neighbouring values differ by
  // more than layer_gap_rel of their value; clusters below layer_min_share of the ring or 8 px
  // ignored; at most max_layers, the largest kept). With one layer nothing changes (bit-
  // identical). With 2-3 layers each gets a robust inverse-depth plane and every pixel of T a
  // layer: Potts labelling by alpha-expansion (s-t min cuts, graph_cut.h) on blocks of
  // layer_label_block^2 px. Seeds are the labelled border pixels (only measured ones with
  // layer_seed_measured_only); with layer_edge_seeds T's free border pixels (frame edge, next
  // to holes / push-pull fill) continue the seeds' labels along T's border. Data term:
  // layer_distance_weight * d_l / (d_l + d_other) (distances to the layers' seeds). Data terms
  // from the copied colour (per-layer colour histograms) and the copied normals (against the
  // layer planes' normals) lost on the training sets and were removed: what PatchMatch copies
  // into T does not tell reliably which surface is hidden (docs/inpainting.md). Pair
  // weight layer_smooth * exp(-|c_p - c_q|^2 / 2 layer_color_sigma^2) on the copied colour,
  // times layer_jump_factor where the fused copied gradient is a jump; seeds are fixed labels.
  // The depth solve then treats pairs between layers as natural (Neumann) boundaries, uses a
  // border pixel as a Dirichlet value only for T pixels of its layer (measured ring: its
  // cluster; others, e.g. push-pull-filled: the layer whose plane it matches within
  // layer_agree_rel, else none), and builds the surface prior per layer region
  // (BuildSurfacePrior on that region and that layer's border values).
  bool layered_depth = true;
  double layer_gap_rel = 0.15;
  double layer_min_share = 0.05;
  int max_layers = 2;
  double layer_agree_rel = 0.05;
  double layer_distance_weight = 1.0;
  double layer_smooth = 1.0;
  double layer_color_sigma = 20.0;
  double layer_jump_factor = 0.1;
  int layer_label_block = 4;  // the labelling graph has one node per block of this many px^2
  // Only measured border pixels seed the labelling (push-pull-filled ones still anchor a layer
  // they match as Dirichlet values).
  bool layer_seed_measured_only = true;
  // T's pixels on the frame's edge take the label of the nearest seed and become seeds.
  bool layer_edge_seeds = true;
  absl::Status Validate() const;
};

struct RgbdKeyframe {
  ImageU8 color;    // RGB8
  ImageF depth_m;   // z-depth in metres, 0 = invalid; registered to colour, same size
  PinholeCamera camera;
  Rigid3d world_from_cam;
};

struct InpaintStats {
  int target_pixels = 0;
  int source_pixels = 0;     // valid patch centres at full resolution
  int prefilled_pixels = 0;  // depth holes outside T filled before the search
  int propagated_pixels = 0; // pixels of T initialised from the previous keyframe
  int levels = 0;
  int sweeps = 0;  // PatchMatch sweeps run over all levels
  int poisson_iterations = 0;
  int neumann_components = 0;
  int invalid_depth_pixels = 0;  // T pixels whose solved depth came out non-finite
  int clamped_depth_pixels = 0;  // T pixels clamped to [zmin/2, 2 zmax] of the input depths
  int prior_pixels = 0;          // T pixels with a surface-prior (screening) term
  int depth_layers = 1;          // layers of the depth solve (layered_depth; 1 = single surface)
  std::vector<int> layer_pixels; // T pixels per layer (layered_depth, >= 2 layers only)
  float layer_seed_dist_px = 0.f; // largest distance of a T pixel to a layer seed (>= 2 layers)
  double ms_prepare = 0, ms_search = 0, ms_copy = 0, ms_poisson = 0, ms_total = 0;  // wall
  // Process CPU time (CLOCK_PROCESS_CPUTIME_ID, all threads; includes any other thread of the
  // calling process running at the same time): steadier than wall time on a shared machine.
  double cpu_ms_prepare = 0, cpu_ms_search = 0, cpu_ms_poisson = 0, cpu_ms_total = 0;
};

struct InpaintResult {
  ImageU8 color;     // RGB8, T filled
  ImageF depth_m;    // T inpainted, holes outside T pre-filled
  ImageF normals;    // 3 ch camera-frame unit normals of depth_m
  ImageI32 source;   // 2 ch: f(u) = (x, y) source pixel for u in T; (-1, -1) elsewhere
  ImageU8 mask;      // T (1 ch, 255 inside)
  ImageU8 layers;    // layered_depth with >= 2 layers: 1 + T pixel's layer (0 outside T); else empty
  PinholeCamera camera;
  Rigid3d world_from_cam;
  InpaintStats stats;
};

// Inpaints T (`mask` != 0, 1 channel, size of the frame) of `frame`. With `previous` (an earlier
// keyframe's result of the same scene, its pose and camera), the source map is initialised by
// keyframe propagation (4.3-4.6) and only the unmapped pixels are searched.
// Errors: invalid options or frame, mask of the wrong size, an empty mask, a mask covering the
// whole frame, no valid source patch, depth that looks like millimetres.
absl::StatusOr<InpaintResult> InpaintKeyframe(const RgbdKeyframe& frame, const ImageU8& mask,
                                              const InpaintOptions& options,
                                              const InpaintResult* previous = nullptr);

// The screening prior of the depth solve (see InpaintOptions::neumann_prior_weight) on a crop
// of the frame at (ox, oy): `region` (!= 0 = T) and `values` (known domain values, NaN =
// unknown) are the crop's, frame_w x frame_h the frame's size (its edge is a Neumann border).
// Writes `prior` / `prior_weight` (crop size, NaN = no term) and returns the number of T pixels
// with a term; 0 (outputs empty) when both weights are 0, or fewer than 3 / collinear border
// samples. Exposed for tests; InpaintKeyframe calls it on its Poisson crop.
int BuildSurfacePrior(const ImageU8& region, const ImageF& values, int ox, int oy, int frame_w,
                      int frame_h, const InpaintOptions& options, ImageF* prior,
                      ImageF* prior_weight);

// Robust / mean fusion of one pixel pair's two copied gradient samples (see GradientFusion):
// g1 (has1) sampled at u's source whose value is ref1, g2 (has2) at (u+v)'s source (ref2).
// Returns the Poisson target and the pair's weight. Exposed for tests.
struct FusedGradient {
  float g;
  float weight;
};
FusedGradient FuseGradientSamples(bool has1, float g1, float ref1, bool has2, float g2, float ref2,
                                  const InpaintOptions& options);

// rho_g of 4.10 for `count` normal pairs (3 floats each): mean of 1/max(kappa, a . b). Exposed
// for tests; opposite or zero normals cost 1/kappa instead of dividing by <= 0.
float GeometryCost(const float* normals_a, const float* normals_b, int count, float kappa);

}  // namespace exo::inpainting
