// GLSL mirror of common/lumigraph/blend_math.h, LINE BY LINE (same names, same order, same
// guards). Any change there must be made here too; the golden tests (client/vulkan) compare the
// two paths pixel by pixel. Also: the resident-store layout shared with client/vulkan
// (vk_view_store, vk_cell_table).

const float kMinDistance = 1e-6;
const int kMaxBlendViews = 4;
const int kMaxBackgroundViews = 8;
const int kMaxInpaintedViews = 8;  // cpu_renderer.h kMaxInpaintedViews
const int kBgViewTexels = 5;
const int kPositionalPrinted = 0;
const int kPositionalUlrResolution = 1;

// ---- colour space (IEC 61966-2-1 sRGB transfer function) ----
float SrgbToLinear(float c) {
  c = clamp(c, 0.0, 1.0);
  return c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4);
}
float LinearToSrgb(float l) {
  l = clamp(l, 0.0, 1.0);
  return l <= 0.0031308 ? l * 12.92 : 1.055 * pow(l, 1.0 / 2.4) - 0.055;
}
vec3 SrgbToLinear3(vec3 c) { return vec3(SrgbToLinear(c.x), SrgbToLinear(c.y), SrgbToLinear(c.z)); }
vec3 LinearToSrgb3(vec3 l) { return vec3(LinearToSrgb(l.x), LinearToSrgb(l.y), LinearToSrgb(l.z)); }

// ---- a stored view as the fragment stage sees it (std430 record in the Views buffer) ----
struct BlendView {
  vec4 cam_from_local_c0;  // columns of the rotation R^T of local_from_cam
  vec4 cam_from_local_c1;
  vec4 cam_from_local_c2;
  vec4 centre_exposure;    // xyz = p(M_i) in the local frame, w = exposure E_i
  vec4 intrinsics;         // fx, fy, cx, cy
  ivec4 size_layer;        // width, height, texture-array layer, valid (1) / removed (0)
};

float RangeFromZDepth(vec2 uv, float z_depth, vec4 intr) {
  const vec3 ray = vec3((uv.x - intr.z) / intr.x, (uv.y - intr.w) / intr.y, 1.0);
  return z_depth * length(ray);
}

// ---- weights ----
float DirectionalWeight(vec3 x, vec3 c_o, vec3 c_i) {
  const vec3 a = c_o - x;
  const vec3 b = c_i - x;
  const float la = length(a);
  const float lb = length(b);
  if (!(la > kMinDistance) || !(lb > kMinDistance)) return 0.0;
  const vec3 d = a / la - b / lb;  // well-conditioned cosine, see blend_math.h
  return max(0.0, 1.0 - 0.5 * dot(d, d));
}

float PositionalWeight(vec3 x, vec3 c_o, vec3 c_i, int mode) {
  const float d_o = max(length(c_o - x), kMinDistance);
  const float d_i = length(c_i - x);
  if (mode == kPositionalPrinted) return max(0.0, 1.0 - d_i / d_o);
  return max(0.0, 1.0 - max(0.0, d_i - d_o) / d_o);
}

float CombinedWeight(float validity, float w_d, float w_p, float lambda, float min_weight) {
  if (!(validity > 0.0)) return 0.0;
  const float w = lambda * w_d + (1.0 - lambda) * w_p;
  return validity * max(w, min_weight);
}

// ---- validity (3.4) ----
// isinf/isnan are kept even though fast-math drivers may fold them: the baked depth layer never
// holds NaN/Inf (BakeDiscontinuities maps them to 0 on upload).
bool ValidDepth(float z) { return !isnan(z) && !isinf(z) && z > 0.0; }

struct Projection {
  bool in_front;
  vec2 uv;
  float range_m;
};

Projection ProjectToView(vec3 x, BlendView view) {
  Projection p;
  p.in_front = false;
  p.uv = vec2(0.0);
  const mat3 cam_from_local = mat3(view.cam_from_local_c0.xyz, view.cam_from_local_c1.xyz,
                                   view.cam_from_local_c2.xyz);
  const vec3 p_cam = cam_from_local * (x - view.centre_exposure.xyz);
  p.range_m = length(p_cam);
  if (!(p_cam.z > kMinDistance)) return p;
  p.in_front = true;
  p.uv = vec2(view.intrinsics.x * p_cam.x / p_cam.z + view.intrinsics.z,
              view.intrinsics.y * p_cam.y / p_cam.z + view.intrinsics.w);
  return p;
}

bool InsideImage(vec2 uv, ivec2 size) {
  return uv.x >= -0.5 && uv.y >= -0.5 && uv.x < float(size.x) - 0.5 &&
         uv.y < float(size.y) - 0.5;
}

// ---- best-n selection (§3.1.4) ----
// Same result as blend_math.h InsertBest (slots 0..n-1 sorted by decreasing weight, w <= 0
// ignored, ties keep the earlier reference), written as an unrolled compare-and-swap chain over
// vec4/ivec4 components with CONSTANT indices: the array form with its data-dependent shift loop
// was lowered by llvmpipe to per-lane scratch memory and cost ~60 % of the whole blend pass
// (docs/vulkan.md). Once (w, idx) is placed at slot s, every later enabled slot shifts down by one
// (the "moving" flag), exactly like the C++ shift loop; the last enabled slot's entry falls off.
struct BestN {
  vec4 weight;
  ivec4 index;  // -1 = empty slot
};

BestN EmptyBestN() {
  BestN b;
  b.weight = vec4(0.0);
  b.index = ivec4(-1);
  return b;
}

void BestStep(inout float bw, inout int bi, inout float cw, inout int ci, inout bool moving,
              bool enabled) {
  if (enabled && (moving || bi < 0 || cw > bw)) {
    const float tw = bw;
    const int ti = bi;
    bw = cw;
    bi = ci;
    cw = tw;
    ci = ti;
    moving = true;
  }
}

void InsertBest(inout BestN b, int n, float w, int idx) {
  if (!(w > 0.0)) return;
  float cw = w;
  int ci = idx;
  bool moving = false;
  BestStep(b.weight.x, b.index.x, cw, ci, moving, 0 < n);
  BestStep(b.weight.y, b.index.y, cw, ci, moving, 1 < n);
  BestStep(b.weight.z, b.index.z, cw, ci, moving, 2 < n);
  BestStep(b.weight.w, b.index.w, cw, ci, moving, 3 < n);
}

// ---- blend (3.1) with exposure ----
struct BlendAccumulator {
  vec3 sum_linear;
  float sum_weight;
};

void Accumulate(inout BlendAccumulator acc, vec3 linear_sample, float exposure, float weight) {
  acc.sum_linear += weight * exposure * linear_sample;
  acc.sum_weight += weight;
}

bool Resolve(BlendAccumulator acc, vec3 background_srgb, out vec3 out_srgb) {
  if (!(acc.sum_weight > 0.0)) {
    out_srgb = background_srgb;
    return false;
  }
  vec3 lin = acc.sum_linear / acc.sum_weight;
  for (int c = 0; c < 3; ++c)
    if (isnan(lin[c]) || isinf(lin[c])) lin[c] = 0.0;
  out_srgb = LinearToSrgb3(lin);
  return true;
}

// ---- background at infinity (sky) ----
// blend_math.h ProjectDirection / BorderWeight / BackgroundWeight; the per-frame background views
// come from the Frame block (bg_views) instead of a BlendView record.
bool ProjectDirection(vec3 d_local, mat3 cam_from_local, vec4 intr, out vec2 uv) {
  const vec3 d_cam = cam_from_local * d_local;
  uv = vec2(0.0);
  if (!(d_cam.z > kMinDistance * length(d_cam))) return false;
  uv = vec2(intr.x * d_cam.x / d_cam.z + intr.z, intr.y * d_cam.y / d_cam.z + intr.w);
  return true;
}

float BorderWeight(vec2 uv, vec2 size) {
  const float dx = min(uv.x + 0.5, size.x - 0.5 - uv.x);
  const float dy = min(uv.y + 0.5, size.y - 0.5 - uv.y);
  return max(0.0, min(dx, dy)) / (0.5 * min(size.x, size.y));
}

// ---- cells (common/cells.h): 21 bits per axis, offset 2^20, lo word = x | y << 21 ----
uvec2 PackCell(ivec3 c) {
  const uint mask = (1u << 21) - 1u;
  const uvec3 u = uvec3(c + ivec3(1 << 20)) & uvec3(mask);
  return uvec2(u.x | (u.y << 21), (u.y >> 11) | (u.z << 10));
}

// Open-addressing hash of a packed CellId (same function as CellHash32 in client/vulkan/vk_cell_table).
uint CellHash32(uvec2 key) {
  uint h = key.x * 0x9E3779B1u ^ (key.y * 0x85EBCA77u + 0x165667B1u);
  h ^= h >> 15;
  h *= 0x2C1B3C6Du;
  h ^= h >> 12;
  return h;
}

// ---- per-frame uniforms ----
layout(std140, set = 0, binding = 0) uniform Frame {
  mat4 clip_from_local;
  vec4 cam_centre_cell;  // xyz = novel camera centre c_o (local), w = cell size q (metres)
  vec4 weights;          // lambda, min_weight, occlusion_epsilon_m, occlusion_epsilon_rel
  vec4 background;       // rgb = background sRGB
  ivec4 iparams;         // positional mode, n_best, hash mask (capacity-1), max probe displacement
  // Background at infinity (client/vulkan/vk_frame_renderer.cc FillBackground): ray direction of
  // pixel (x, y) is
  // mat3(local_from_pixel) * (x, y, 1); bg_params.x background views, each kBgViewTexels vec4:
  // cam_from_local columns 0..2, intrinsics (fx, fy, cx, cy), (width, height, layer, exposure).
  vec4 local_from_pixel[3];
  ivec4 bg_params;  // y: RenderApprox::max_candidates (0 = every reference)
  vec4 bg_views[kBgViewTexels * kMaxBackgroundViews];
  // InpaintFusion (SPEC §7): ip_params.x inpainted keyframes (nearest first), their layers.
  ivec4 ip_params;
  ivec4 ip_layers[kMaxInpaintedViews / 4];
  // RenderFloor only: rows 0..2 of one view's P = K [R^T | -R^T c]; then (width, height,
  // layer, 0) for floorproj.frag, (1 / width, 1 / height, 0, 0) of the floor texture
  // for floor.vert.
  vec4 floor_view[4];
  // The viewer's X-ray hole (xray_hole.glsl; VulkanRenderer::SetXrayHole): the disc's centre
  // in pixels (gl_FragCoord units) and its radius squared; the optical axis (local frame) and
  // the clip's z-depth in metres.
  vec4 xray_disc;  // x, y, radius^2, 0
  vec4 xray_axis;  // xyz = optical axis, w = clip z-depth (m)
} frame;
