// Per-fragment lumigraph blend math of SPEC §6 (thesis §3.1.1, §3.1.4), written ONCE in GLM float
// so that the CPU reference renderer (cpu_renderer.cc) and the Vulkan fragment shader (GLSL,
// mirrored line by line) compute the same thing. Everything is in the scene-local frame (see
// rigid3.h LocalOrigin), so float precision holds for scenes 1e5 m from the world origin.
//
// Per fragment at surface point x (local frame), novel camera centre c_o, for every reference
// F_i of the fragment's cell R(b_k):
//   w_d   = DirectionalWeight(x, c_o, c_i)                     (3.2)
//   w_p   = PositionalWeight(x, c_o, c_i, mode)                (3.3 as printed | ULR resolution)
//   v     = Validity(x, view_i, depth_i)                        (3.4) occlusion/FOV/discontinuity
//   w_i   = CombinedWeight(v, w_d, w_p, lambda, min_weight)    (3.5)
//   keep the n = 3 largest w_i (BestN / InsertBest)            (§3.1.4)
//   C_o   = LinearToSrgb( Σ w_i E_i SrgbToLinear(C_i) / Σ w_i ) (3.1) + exposure (SPEC §5/§6)
// Colour sampling convention (the Vulkan path must match): stored colours are sRGB8; a texel is
// decoded to linear BEFORE bilinear filtering (what a VK_FORMAT_*_SRGB texture does), the
// exposure factor multiplies linear intensity, the blend is done in linear, the result is
// clamped to [0,1] and encoded to sRGB once.
// Depth convention: stored depth images are z-depth (camera.h); the occlusion test of (3.4)
// compares RANGES, converted by RangeFromZDepth below (the same formula as
// PinholeCamera::RangeFromZDepth, in float).
#pragma once

#include <cmath>
#include <cstdint>

#include <glm/glm.hpp>

#include "common/status.h"

namespace exo::blend {

// Maximum number of views blended per fragment (n of §3.1.4 is configurable up to this).
inline constexpr int kMaxBlendViews = 4;
// Maximum number of background (sky) views per frame (BlendOptions::background_views).
inline constexpr int kMaxBackgroundViews = 8;
// Denominator guard: distances below this (metres) are treated as this.
inline constexpr float kMinDistance = 1e-6f;

enum class PositionalMode : int {
  kPrinted = 0,        // (3.3) as printed: max(0, 1 - |c_i - x| / |c_o - x|)
  kUlrResolution = 1,  // Buehler et al. ULR resolution penalty, as a weight in [0,1]
};

struct BlendOptions {
  // (3.5) directional vs positional (the thesis' 0.5). 1 since issue 15, session 8: the
  // directional penalty alone measured +0.03..+0.04 SSIM for every policy and store on real
  // 7-Scenes frames and is level or better on the synthetic scenes (docs/evaluation.md). It was
  // held back by a CPU/Vulkan disagreement on the golden sky scene (0.2 % of pixels > 2/255),
  // caused by the ill-conditioned cosine of DirectionalWeight, now computed well conditioned.
  float lambda = 1.0f;
  PositionalMode positional_mode = PositionalMode::kUlrResolution;  // kept what measured better
  float occlusion_epsilon_m = 0.05f;     // ε of (3.4), absolute part (metres)
  float occlusion_epsilon_rel = 0.02f;   // ε relative to the stored range
  // Δ_xy of (3.4); 0 = no discontinuity test (the default since issue 15: on real 7-Scenes
  // data the test only removed samples near depth edges, which the hole fill then smeared:
  // +0.0072 ± 0.0003 SSIM over ten folds without it, synthetic near-trajectory views level or
  // better; docs/evaluation.md "Issue 15"). The thesis' value was 2.
  int discontinuity_radius_px = 0;
  float discontinuity_delta_z_m = 0.10f;   // Δ_z of (3.4), absolute part (metres)
  float discontinuity_delta_z_rel = 0.05f; // Δ_z relative to the centre depth
  int n_best = 3;                // n of §3.1.4
  // A valid view whose geometric weight is 0 (e.g. exactly opposite direction with the printed
  // positional term) still gets this weight so a pixel seen by a valid view is never a hole.
  float min_weight = 1e-4f;
  glm::vec3 background_srgb{0.0f};  // colour of uncovered pixels, sRGB in [0,1]
  // Background at infinity (sky, docs/vulkan.md "Background at infinity"): a pixel whose ray
  // hits no proxy surface is blended, as a DIRECTION (a point at infinity: rotation only), from
  // the stored views that saw nothing within range there (depth 0). Up to this many views per
  // frame are candidates (SelectBackgroundViews), the best n_best of them per pixel by
  // BackgroundWeight. 0 = off: such pixels keep background_srgb (the output before this pass).
  int background_views = 8;
  // A stored pixel is background only if EVERY in-image pixel within this Chebyshev radius has
  // invalid depth (BackgroundMask): sensor holes next to surfaces and silhouette edges (incl. the
  // 2x2 bilinear footprint of the sample) never bring foreground colour into the sky.
  int background_guard_radius_px = 3;
  // Hole fill (a post-pass, not per-fragment math): pixels that end uncovered (no valid stored
  // view for the surface, or no surface and no background sample) are filled by push-pull from
  // the covered and background pixels of the same frame (FillHoles, cpu_renderer.h), in both
  // renderers. Coverage stays 0 there: it still measures what the lumigraph blended. Off: such
  // pixels keep background_srgb (the output before session 5).
  bool fill_holes = true;

  absl::Status Validate() const {
    auto finite = [](float v) { return std::isfinite(v); };
    if (!finite(lambda) || lambda < 0.0f || lambda > 1.0f)
      return absl::InvalidArgumentError(absl::StrCat("blend lambda must be in [0,1], got ", lambda));
    if (positional_mode != PositionalMode::kPrinted &&
        positional_mode != PositionalMode::kUlrResolution)
      return absl::InvalidArgumentError("unknown positional weight mode");
    if (!finite(occlusion_epsilon_m) || occlusion_epsilon_m < 0.0f || !finite(occlusion_epsilon_rel) ||
        occlusion_epsilon_rel < 0.0f)
      return absl::InvalidArgumentError("occlusion epsilon must be finite and >= 0");
    if (discontinuity_radius_px < 0 || discontinuity_radius_px > 16)
      return absl::InvalidArgumentError(
          absl::StrCat("discontinuity radius must be in [0,16] px, got ", discontinuity_radius_px));
    if (!finite(discontinuity_delta_z_m) || discontinuity_delta_z_m <= 0.0f ||
        !finite(discontinuity_delta_z_rel) || discontinuity_delta_z_rel < 0.0f)
      return absl::InvalidArgumentError("discontinuity delta_z must be > 0 (relative part >= 0)");
    if (n_best < 1 || n_best > kMaxBlendViews)
      return absl::InvalidArgumentError(
          absl::StrCat("n_best must be in [1,", kMaxBlendViews, "], got ", n_best));
    if (!finite(min_weight) || min_weight < 0.0f || min_weight > 1.0f)
      return absl::InvalidArgumentError("min_weight must be in [0,1]");
    if (background_views < 0 || background_views > kMaxBackgroundViews)
      return absl::InvalidArgumentError(absl::StrCat("background_views must be in [0,",
                                                     kMaxBackgroundViews, "], got ",
                                                     background_views));
    if (background_guard_radius_px < 1 || background_guard_radius_px > 16)
      return absl::InvalidArgumentError(absl::StrCat(
          "background_guard_radius_px must be in [1,16], got ", background_guard_radius_px));
    for (int c = 0; c < 3; ++c)
      if (!finite(background_srgb[c]) || background_srgb[c] < 0.0f || background_srgb[c] > 1.0f)
        return absl::InvalidArgumentError("background colour must be in [0,1]");
    return absl::OkStatus();
  }
};

// ---- colour space (IEC 61966-2-1 sRGB transfer function) ----

inline float SrgbToLinear(float c) {
  c = glm::clamp(c, 0.0f, 1.0f);
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}
inline float LinearToSrgb(float l) {
  l = glm::clamp(l, 0.0f, 1.0f);  // also maps NaN-free overexposure (E_i > 1) to white
  return l <= 0.0031308f ? l * 12.92f : 1.055f * std::pow(l, 1.0f / 2.4f) - 0.055f;
}
inline glm::vec3 SrgbToLinear(const glm::vec3& c) {
  return {SrgbToLinear(c.x), SrgbToLinear(c.y), SrgbToLinear(c.z)};
}
inline glm::vec3 LinearToSrgb(const glm::vec3& l) {
  return {LinearToSrgb(l.x), LinearToSrgb(l.y), LinearToSrgb(l.z)};
}

// ---- a stored view as the fragment stage sees it ----

struct BlendView {
  glm::mat3 cam_from_local{1.0f};  // rotation R^T of local_from_cam
  glm::vec3 centre_local{0.0f};    // p(M_i), camera centre in the local frame
  glm::vec4 intrinsics{0.0f};      // fx, fy, cx, cy (pixel centres at integers)
  glm::ivec2 size{0};              // width, height
  float exposure = 1.0f;           // E_i, linear-intensity factor
};

// Range (Euclidean distance from the camera centre) of the point at z-depth z on the ray through
// continuous pixel uv: z * |((u-cx)/fx, (v-cy)/fy, 1)|. Same formula as
// PinholeCamera::RangeFromZDepth (camera.h), in float.
inline float RangeFromZDepth(const glm::vec2& uv, float z_depth, const glm::vec4& intr) {
  const glm::vec3 ray((uv.x - intr.z) / intr.x, (uv.y - intr.w) / intr.y, 1.0f);
  return z_depth * glm::length(ray);
}

// ---- weights ----

// (3.2): clamped cosine between the rays from the surface point x to the novel camera c_o and to
// the stored camera c_i. Degenerate rays (a camera on the surface) give 0.
inline float DirectionalWeight(const glm::vec3& x, const glm::vec3& c_o, const glm::vec3& c_i) {
  const glm::vec3 a = c_o - x;
  const glm::vec3 b = c_i - x;
  const float la = glm::length(a);
  const float lb = glm::length(b);
  if (!(la > kMinDistance) || !(lb > kMinDistance)) return 0.0f;
  // cos = 1 - |a/|a| - b/|b||^2 / 2 (unit vectors): the same value as dot(a, b) / (|a| |b|), but
  // well conditioned for the small angles between nearby cameras, where the dot-product form
  // loses the angle to rounding (its error ~1e-7 is the whole difference between two views
  // 0.5 mrad apart) and the CPU oracle and the shader then rank such views differently.
  const glm::vec3 d = a / la - b / lb;
  return glm::max(0.0f, 1.0f - 0.5f * glm::dot(d, d));
}

// (3.3) and the ULR variant. d_i = |c_i - x|, d_o = |c_o - x| (guarded against 0).
//  kPrinted:       max(0, 1 - d_i / d_o)           (zeroes views at or beyond the novel distance)
//  kUlrResolution: max(0, 1 - max(0, d_i - d_o) / d_o)  (Buehler et al. 2001: only views farther
//                  than the novel camera lose resolution; 0 at twice the novel distance)
inline float PositionalWeight(const glm::vec3& x, const glm::vec3& c_o, const glm::vec3& c_i,
                              PositionalMode mode) {
  const float d_o = glm::max(glm::length(c_o - x), kMinDistance);
  const float d_i = glm::length(c_i - x);
  if (mode == PositionalMode::kPrinted) return glm::max(0.0f, 1.0f - d_i / d_o);
  return glm::max(0.0f, 1.0f - glm::max(0.0f, d_i - d_o) / d_o);
}

// (3.5): w_i = v * (λ w_d + (1-λ) w_p), with a floor min_weight for valid views (so that a pixel
// seen by a valid view is always covered). Invalid views (v = 0) get exactly 0.
inline float CombinedWeight(float validity, float w_d, float w_p, float lambda, float min_weight) {
  if (!(validity > 0.0f)) return 0.0f;
  const float w = lambda * w_d + (1.0f - lambda) * w_p;
  return validity * glm::max(w, min_weight);
}

// ---- validity (3.4) ----

inline bool ValidDepth(float z) { return std::isfinite(z) && z > 0.0f; }

struct Projection {
  bool in_front = false;  // z > 0 in the stored camera
  glm::vec2 uv{0.0f};     // continuous pixel coordinates (centres at integers)
  float range_m = 0.0f;   // |x - c_i|
};

inline Projection ProjectToView(const glm::vec3& x, const BlendView& view) {
  Projection p;
  const glm::vec3 p_cam = view.cam_from_local * (x - view.centre_local);
  p.range_m = glm::length(p_cam);
  if (!(p_cam.z > kMinDistance)) return p;
  p.in_front = true;
  p.uv = glm::vec2(view.intrinsics.x * p_cam.x / p_cam.z + view.intrinsics.z,
                   view.intrinsics.y * p_cam.y / p_cam.z + view.intrinsics.w);
  return p;
}

// Field of view: the projection must land inside the stored image [-0.5, W-0.5) x [-0.5, H-0.5).
inline bool InsideImage(const glm::vec2& uv, const glm::ivec2& size) {
  return uv.x >= -0.5f && uv.y >= -0.5f && uv.x < float(size.x) - 0.5f &&
         uv.y < float(size.y) - 0.5f;
}

// (3.4). `fetch_depth(ivec2 pixel) -> float z-depth` reads the stored view's depth image (only
// called with in-image pixels; GLSL: texelFetch). Returns 1 for a valid view, 0 otherwise:
//  - x behind the stored camera or outside its image (field of view);
//  - the stored depth at π(x) is invalid (0, NaN, Inf): nothing was observed there;
//  - occluded: |x - c_i| > D_i(π(x)) + ε, with D_i the stored z-depth converted to a range and
//    ε = occlusion_epsilon_m + occlusion_epsilon_rel * D_i;
//  - within discontinuity_radius_px of a depth jump larger than Δ_z (= delta_z_m + delta_z_rel *
//    centre depth): the 8 neighbours at offsets {-r,0,r}^2 \ {0} that lie in the image are
//    compared; a neighbour with invalid depth counts as a jump (depth holes at edges).
template <typename FetchDepth>
inline float Validity(const glm::vec3& x, const BlendView& view, const BlendOptions& opt,
                      FetchDepth&& fetch_depth) {
  const Projection proj = ProjectToView(x, view);
  if (!proj.in_front || !InsideImage(proj.uv, view.size)) return 0.0f;
  const glm::ivec2 px(static_cast<int>(std::floor(proj.uv.x + 0.5f)),
                      static_cast<int>(std::floor(proj.uv.y + 0.5f)));
  const glm::ivec2 pc = glm::clamp(px, glm::ivec2(0), view.size - 1);
  const float z = fetch_depth(pc);
  if (!ValidDepth(z)) return 0.0f;
  const float range_d = RangeFromZDepth(proj.uv, z, view.intrinsics);
  const float eps = opt.occlusion_epsilon_m + opt.occlusion_epsilon_rel * range_d;
  if (proj.range_m > range_d + eps) return 0.0f;
  const int r = opt.discontinuity_radius_px;
  if (r > 0) {
    const float dz = opt.discontinuity_delta_z_m + opt.discontinuity_delta_z_rel * z;
    for (int dy = -r; dy <= r; dy += r) {
      for (int dx = -r; dx <= r; dx += r) {
        if (dx == 0 && dy == 0) continue;
        const glm::ivec2 q = pc + glm::ivec2(dx, dy);
        if (q.x < 0 || q.y < 0 || q.x >= view.size.x || q.y >= view.size.y) continue;
        const float zq = fetch_depth(q);
        if (!ValidDepth(zq) || glm::abs(zq - z) > dz) return 0.0f;
      }
    }
  }
  return 1.0f;
}

// InpaintFusion's label rule (SPEC §7, 4.17-4.18), the same in both renderers
// (cpu_renderer.cc; blend_shade.glsl's inpainted loop): surface point x lies in an inpainted
// view's L_IP region when the view's label at x's nearest pixel is set (`label(pixel) -> bool`)
// AND x is not hidden behind the view's own surface there: the occlusion test of (3.4),
// |x - c_i| <= D_i + ε (a pixel without valid depth hides nothing). A point behind the view's
// surface is not what the view shows: a scene completion's hole surface does not claim an
// observed surface that another pose sees behind it, a DR keyframe's background does not claim
// what lies behind the background. A point IN FRONT of the view's surface is claimed: a removed
// object still in the proxy is replaced by the keyframe's background (4.17). One rule for every
// inpainted view (DR keyframes and scene completions alike).
template <typename FetchLabel, typename FetchDepth>
inline bool InpaintedLabelHolds(const glm::vec3& x, const BlendView& view, const BlendOptions& opt,
                                FetchLabel&& label, FetchDepth&& fetch_depth) {
  const Projection proj = ProjectToView(x, view);
  if (!proj.in_front || !InsideImage(proj.uv, view.size)) return false;
  const glm::ivec2 px(static_cast<int>(std::floor(proj.uv.x + 0.5f)),
                      static_cast<int>(std::floor(proj.uv.y + 0.5f)));
  const glm::ivec2 pc = glm::clamp(px, glm::ivec2(0), view.size - 1);
  if (!label(pc)) return false;
  const float z = fetch_depth(pc);
  if (!ValidDepth(z)) return true;
  const float range_d = RangeFromZDepth(proj.uv, z, view.intrinsics);
  return !(proj.range_m > range_d + opt.occlusion_epsilon_m + opt.occlusion_epsilon_rel * range_d);
}

// ---- best-n selection (§3.1.4) ----

struct BestN {
  float weight[kMaxBlendViews];
  int index[kMaxBlendViews];  // -1 = empty slot
};

inline BestN EmptyBestN() {
  BestN b;
  for (int s = 0; s < kMaxBlendViews; ++s) {
    b.weight[s] = 0.0f;
    b.index[s] = -1;
  }
  return b;
}

// Inserts (w, idx) keeping slots 0..n-1 sorted by decreasing weight; w <= 0 is ignored; ties keep
// the earlier reference (strict >), so the result is independent of evaluation order only up to
// ties, which the GLSL mirror resolves the same way (same iteration order over R(b_k)).
inline void InsertBest(BestN& b, int n, float w, int idx) {
  if (!(w > 0.0f)) return;
  for (int s = 0; s < n; ++s) {
    if (b.index[s] < 0 || w > b.weight[s]) {
      for (int t = n - 1; t > s; --t) {
        b.weight[t] = b.weight[t - 1];
        b.index[t] = b.index[t - 1];
      }
      b.weight[s] = w;
      b.index[s] = idx;
      return;
    }
  }
}

// ---- blend (3.1) with exposure ----

struct BlendAccumulator {
  glm::vec3 sum_linear{0.0f};
  float sum_weight = 0.0f;
};

// Adds one selected view's sample: `linear_sample` is the bilinear sample of SrgbToLinear(texels).
inline void Accumulate(BlendAccumulator& acc, const glm::vec3& linear_sample, float exposure,
                       float weight) {
  acc.sum_linear += weight * exposure * linear_sample;
  acc.sum_weight += weight;
}

// Normalised blend (3.1), encoded to sRGB. Returns false (and the background) when no view
// contributed: the pixel is uncovered. Never NaN.
inline bool Resolve(const BlendAccumulator& acc, const glm::vec3& background_srgb,
                    glm::vec3* out_srgb) {
  if (!(acc.sum_weight > 0.0f)) {
    *out_srgb = background_srgb;
    return false;
  }
  glm::vec3 lin = acc.sum_linear / acc.sum_weight;
  for (int c = 0; c < 3; ++c)
    if (!std::isfinite(lin[c])) lin[c] = 0.0f;
  *out_srgb = LinearToSrgb(lin);
  return true;
}

// ---- background at infinity (sky) ----
// A novel pixel without proxy surface has the local-frame ray direction d = local_from_pixel *
// (x, y, 1) (local_from_pixel = R_local_from_cam K^-1). A stored view sees the point at infinity
// in direction d at u = project(K, cam_from_local * d) (no translation). The sample is valid when
// u is inside the view, in front of it, and the view's background mask (BackgroundMask: depth
// invalid in the whole guard window) is set at the nearest pixel of u. Its weight is the
// feathering BorderWeight (all stored rays towards a point at infinity are parallel to d, so the
// direction term of (3.2) carries no information); the best n by weight are blended with
// exposure exactly like surface samples (Accumulate / Resolve).

// Projection of the direction d (local frame) into `view`; range_m is unused (infinite).
inline Projection ProjectDirection(const glm::vec3& d_local, const BlendView& view) {
  Projection p;
  const glm::vec3 d_cam = view.cam_from_local * d_local;
  if (!(d_cam.z > kMinDistance * glm::length(d_cam))) return p;
  p.in_front = true;
  p.uv = glm::vec2(view.intrinsics.x * d_cam.x / d_cam.z + view.intrinsics.z,
                   view.intrinsics.y * d_cam.y / d_cam.z + view.intrinsics.w);
  return p;
}

// Feathering weight: distance (px) of uv from the nearest border of the image area
// [-0.5, W-0.5) x [-0.5, H-0.5), divided by half the smaller side: 1 at the centre of a square
// image, -> 0 at its border (so the blend fades out instead of cutting at a view's edge).
inline float BorderWeight(const glm::vec2& uv, const glm::ivec2& size) {
  const float dx = glm::min(uv.x + 0.5f, float(size.x) - 0.5f - uv.x);
  const float dy = glm::min(uv.y + 0.5f, float(size.y) - 0.5f - uv.y);
  return glm::max(0.0f, glm::min(dx, dy)) / (0.5f * float(glm::min(size.x, size.y)));
}

// Weight of view `view` for the background direction d; 0 = invalid. `is_background(ivec2)`
// reads the view's background mask at an in-image pixel. *uv receives the sample position.
template <typename IsBackground>
inline float BackgroundWeight(const glm::vec3& d_local, const BlendView& view,
                              IsBackground&& is_background, glm::vec2* uv) {
  const Projection proj = ProjectDirection(d_local, view);
  if (!proj.in_front || !InsideImage(proj.uv, view.size)) return 0.0f;
  const glm::ivec2 px(static_cast<int>(std::floor(proj.uv.x + 0.5f)),
                      static_cast<int>(std::floor(proj.uv.y + 0.5f)));
  const glm::ivec2 pc = glm::clamp(px, glm::ivec2(0), view.size - 1);
  if (!is_background(pc)) return 0.0f;
  *uv = proj.uv;
  return BorderWeight(proj.uv, view.size);
}

// sRGB8 byte <-> [0,1] float, round to nearest.
inline float U8ToUnit(uint8_t v) { return float(v) * (1.0f / 255.0f); }
inline uint8_t UnitToU8(float v) {
  return static_cast<uint8_t>(glm::clamp(v, 0.0f, 1.0f) * 255.0f + 0.5f);
}

}  // namespace exo::blend
