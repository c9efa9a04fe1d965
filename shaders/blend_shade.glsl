// Body of the lumigraph blend pass, shared by blend.frag (full-screen triangle) and blend.comp
// (compute dispatch over the G-buffer), included after lumigraph_common.glsl: ShadePixel().
// SPEC §6, eq. 3.1-3.5, deferred: per pixel of the G-buffer (surface point of the proxy mesh),
// look up the fragment's cell in the resident cell-hash table, evaluate validity and weights for every
// reference of the cell, keep the best n (<= 4, default 3) and blend their exposure-corrected
// linear colours. Mirrors common/lumigraph/blend_math.h (see lumigraph_common.glsl).

// Store tables as uniform texel buffers (a fetch is a vector gather on llvmpipe; a divergent SSBO
// load is a per-lane scalar loop per component, measured much slower, docs/vulkan.md):
// Views: 5 RGBA32F texels per view record (GpuView in client/vulkan/vk_view_store.h):
//   0..2 rows of P = K [R^T | -R^T c] (local -> homogeneous pixel; row 2 gives the camera z),
//   3    centre c (local) and exposure E, 4 width, height, layer, valid (floats, exact < 2^24).
layout(set = 0, binding = 1) uniform samplerBuffer view_texels;
// Cell hash: (key lo, key hi, offset into Refs, count); empty = (~0, ~0), tombstone = (~1, ~0).
layout(set = 0, binding = 2) uniform usamplerBuffer cell_entries;
// Reference slots: view-record indices (the views' texture-array layers), ~0 = not resident.
layout(set = 0, binding = 3) uniform usamplerBuffer ref_slots;
// Linear UNORM16 colour layers (bilinear sampler: the floors; the blend reads color_texels).
layout(set = 0, binding = 4) uniform sampler2DArray colors;
// R32F baked z-depth (0 = invalid), read with imageLoad (the nearest texel, as texelFetch): a
// storage image's load is addressed with the layer's scalar strides, texelFetch went through
// llvmpipe's per-lane mip-level path (docs/vulkan.md, issue 16 session 15).
layout(set = 0, binding = 5, r32f) uniform readonly image2DArray depths;

// Deferred: the surface point per pixel from gbuffer.frag (w = 0: no proxy surface).
layout(set = 0, binding = 6) uniform sampler2D gbuffer;
// Per-frame ranked references (CellTable::RankRefs, client/vulkan/vk_cell_table.cc),
// kRankedTexels texels per reference slot, same slot index as ref_slots, sorted per cell by an
// upper bound of the weight this frame: (c_i.xyz, bound) as float bits; the rows of M = K R^T
// with (layer | position in the cell's list << 16), (width | height << 16) and the exposure bits
// in w. bound = -1: reference not resident. A storage texel buffer (imageLoad): llvmpipe inlines
// the load, where a uniform texel buffer's texelFetch is a call that spills the reference loop's
// live vector registers (docs/vulkan.md, issue 16 session 15).
layout(set = 0, binding = 7, rgba32ui) uniform readonly uimageBuffer ranked_refs;

// The frame's background views, the same texels as frame.bg_views (kBgViewTexels per view):
// the background loop reads them with a loop-dependent index, which llvmpipe turns into a
// per-lane, per-component gather with bounds checks from a uniform block, a vector gather per
// texel from a texel buffer (docs/vulkan.md, issue 16 session 13).
layout(set = 0, binding = 10) uniform samplerBuffer bg_texels;
// The colour layers (binding 4) as a storage image: SampleLinear's 4 nearest loads.
layout(set = 0, binding = 11, rgba16) uniform readonly image2DArray color_texels;

const int kViewTexels = 5;
const int kRankedTexels = 4;  // client/vulkan/vk_cell_table.h
// n of §3.1.4 (BlendOptions::n_best), a specialisation constant: one pipeline per n, so the
// disabled best-n slots and the n-th-best pick fold away at compile time.
layout(constant_id = 0) const int kNBest = 3;
// Which pixels a pipeline shades: both kinds (ShadePixel, the compute path), only those with a
// proxy surface (ShadeSurface) or only those without (ShadeBackground); blend.frag.
const int kBlendPassBoth = 0;
const int kBlendPassSurface = 1;
const int kBlendPassBackground = 2;
layout(constant_id = 1) const int kBlendPass = kBlendPassBoth;
// Whether this frame has inpainted keyframes (frame.ip_params.x > 0); 0 compiles their loop out
// (llvmpipe runs a loop's body at least once, masked, even for a count of 0).
layout(constant_id = 2) const int kInpainted = 1;
// Whether frame.weights.x (lambda) is exactly 1: CombinedWeight is then max(w_d, min_weight)
// exactly (1 * w_d + 0 * w_p with a finite w_p), so the positional weight is compiled out.
layout(constant_id = 3) const int kLambdaOne = 0;
// Whether this pipeline has the frame's min_weight and occlusion epsilons (frame.weights.yzw)
// baked in as constants 6..8 (Pipelines::EnsureBlendPipe: the BlendOptions defaults, used when
// the frame's values equal them bit for bit). llvmpipe loads a Frame value in a fragment shader
// as 8 per-lane scalar loads with a bounds test; as constants they are immediates (the same
// floats, so the same pixels; docs/vulkan.md, issue 16 session 16).
layout(constant_id = 5) const int kBakedWeights = 0;
layout(constant_id = 6) const float kBakedMinWeight = 0.0;
layout(constant_id = 7) const float kBakedEpsAbs = 0.0;
layout(constant_id = 8) const float kBakedEpsRel = 0.0;

// Background pass (blend.frag, kBlendPassBackground): the screen is drawn as rectangles of
// 16x16-pixel tiles grouped by the list of background views that can be valid for some ray of
// the tile (FrameRenderer::BuildSkyDraws, a conservative test on the host), one push constant per
// group: the count in bits 0..3, the k-th view index j in bits 4 + 3k .. 6 + 3k (j ascending).
// A view left out is one every ray of the tile fails (behind it, outside its image or outside
// the box of its background mask), so the selection equals the loop over all views. The
// compute path (kBlendPassBoth) walks every view.
layout(push_constant) uniform SkyList { uint packed; } sky_list;

// ---- best-n with the sample parameters carried along ----
// Same selection as blend_math.h InsertBest (decreasing weight, w <= 0 ignored, ties keep the
// earlier reference), unrolled over slots with constant indices (see BestStep in
// lumigraph_common.glsl). An empty slot has weight 0 and every inserted weight is > 0, so
// "index < 0" needs no test. Each slot carries what the blend needs (clamped
// uv, layer, exposure), so the chosen views are not fetched and projected a second time.
struct BestSamples {
  vec4 weight;
  ivec4 index;          // position of the reference in the cell's list (ties: lower first)
  vec4 s0, s1, s2, s3;  // (u, v clamped to the view, layer, exposure)
};

// The references arrive in ranked (not list) order, so equal weights are ordered by the list
// position explicitly: (weight desc, position asc) is the order blend_math.h's in-order
// InsertBest produces (a later equal weight never displaces an earlier one).
void SampleStep(inout float bw, inout int bi, inout vec4 bs, inout float cw, inout int ci,
                inout vec4 cs, inout bool moving, bool enabled) {
  if (enabled && (moving || cw > bw || (cw == bw && ci < bi))) {
    const float tw = bw;
    const int ti = bi;
    const vec4 ts = bs;
    bw = cw;
    bi = ci;
    bs = cs;
    cw = tw;
    ci = ti;
    cs = ts;
    moving = true;
  }
}

void InsertSample(inout BestSamples b, int n, float w, int idx, vec4 sample_params) {
  if (!(w > 0.0)) return;
  float cw = w;
  int ci = idx;
  vec4 cs = sample_params;
  bool moving = false;
  SampleStep(b.weight.x, b.index.x, b.s0, cw, ci, cs, moving, 0 < n);
  SampleStep(b.weight.y, b.index.y, b.s1, cw, ci, cs, moving, 1 < n);
  SampleStep(b.weight.z, b.index.z, b.s2, cw, ci, cs, moving, 2 < n);
  SampleStep(b.weight.w, b.index.w, b.s3, cw, ci, cs, moving, 3 < n);
}

// Bilinear sample of SrgbToLinear(texels) at clamped continuous pixel uv (centres at integers):
// cpu_renderer.cc SampleLinear, the same float lerps of the 4 nearest texels of the linear
// UNORM16 layer (the decode of the stored sRGB8 texels done once at upload, quantised to
// 1.5e-5). Four imageLoads of the storage-image view and float weights: 3 % less CPU per frame
// than one filtered textureLod (llvmpipe's sampler path with per-lane mip strides and 8-bit
// fractional weights), and closer to the CPU reference (docs/vulkan.md, issue 16 session 15;
// with texelFetch the 4 fetches had measured ~3x slower). uv is clamped to the VIEW's
// [0, size-1] (layers can be larger than the view).
vec3 SampleLinear(vec2 uv, int layer, ivec2 layer_size) {
  const vec2 f = floor(uv);
  const vec2 t = uv - f;
  const ivec2 i0 = ivec2(f);
  // uv is clamped to the view's [0, size - 1]: at u = size - 1 the right neighbour (outside the
  // view) has weight t.x = 0, as the CPU's clamp to the view; clamped to the layer here so that
  // no load leaves the image.
  const ivec2 i1 = min(i0 + 1, layer_size - 1);
  const vec3 p00 = imageLoad(color_texels, ivec3(i0, layer)).rgb;
  const vec3 p10 = imageLoad(color_texels, ivec3(i1.x, i0.y, layer)).rgb;
  const vec3 p01 = imageLoad(color_texels, ivec3(i0.x, i1.y, layer)).rgb;
  const vec3 p11 = imageLoad(color_texels, ivec3(i1, layer)).rgb;
  const vec3 top = p00 + t.x * (p10 - p00);
  const vec3 bot = p01 + t.x * (p11 - p01);
  return top + t.y * (bot - top);
}

void AccumulateSample(inout BlendAccumulator acc, float weight, vec4 s, ivec2 layer_size,
                      bool enabled) {
  if (!enabled || !(weight > 0.0)) return;
  const vec3 lin = SampleLinear(s.xy, int(s.z), layer_size);
  Accumulate(acc, lin, s.w, weight);
}

// Normalised blend of the best n samples in linear intensity (with exposure), to sRGB; false
// (and the background colour) when no sample has weight.
bool BlendBest(BestSamples best, int n, out vec3 srgb) {
  BlendAccumulator acc;
  acc.sum_linear = vec3(0.0);
  acc.sum_weight = 0.0;
  const ivec2 layer_size = imageSize(color_texels).xy;
  AccumulateSample(acc, best.weight.x, best.s0, layer_size, 0 < n);
  AccumulateSample(acc, best.weight.y, best.s1, layer_size, 1 < n);
  AccumulateSample(acc, best.weight.z, best.s2, layer_size, 2 < n);
  AccumulateSample(acc, best.weight.w, best.s3, layer_size, 3 < n);
  return Resolve(acc, frame.background.rgb, srgb);
}

// Background at infinity for a pixel without proxy surface (cpu_renderer.cc, the no-cell branch;
// blend_math.h BackgroundWeight): the ray is a direction d, every background view j of this frame
// is a candidate, valid where its baked depth is -1 (the guarded background mask) at the nearest
// pixel of u_j, weighted by BorderWeight; best n (ties: lower j), normalised blend with exposure.
// a = 64/255 where filled, 0 (background colour) where no view is valid or the pass is off.
vec4 ShadeBackground(ivec2 pixel) {
  if (frame.bg_params.x == 0) return vec4(frame.background.rgb, 0.0);
  const bool listed = kBlendPass == kBlendPassBackground;
  const int count = listed ? int(sky_list.packed & 15u) : frame.bg_params.x;
  const vec3 d = mat3(frame.local_from_pixel[0].xyz, frame.local_from_pixel[1].xyz,
                      frame.local_from_pixel[2].xyz) * vec3(vec2(pixel), 1.0);
  const int n = kNBest;
  BestSamples best;
  best.weight = vec4(0.0);
  best.index = ivec4(0x7FFFFFFF);
  best.s0 = best.s1 = best.s2 = best.s3 = vec4(0.0);
  // The loop's exit is tested at the END of the body (as in ShadeSurface's reference loop):
  // llvmpipe checks the lanes only there, so a top-of-body "k < count" ran one more whole
  // masked body after the last view (docs/vulkan.md, issue 16 session 18). The same views in
  // the same order.
  if (count > 0) {
    for (int k = 0;;) {
      const int j = listed ? int((sky_list.packed >> (4u + 3u * uint(k))) & 7u) : k;
      const int b = kBgViewTexels * j;
      const mat3 cam_from_local = mat3(texelFetch(bg_texels, b).xyz,
                                       texelFetch(bg_texels, b + 1).xyz,
                                       texelFetch(bg_texels, b + 2).xyz);
      const vec4 wh = texelFetch(bg_texels, b + 4);
      vec2 uv;
      if (ProjectDirection(d, cam_from_local, texelFetch(bg_texels, b + 3), uv)) {
        const vec2 size = wh.xy;
        if (uv.x >= -0.5 && uv.y >= -0.5 && uv.x < size.x - 0.5 && uv.y < size.y - 0.5) {
          const vec2 pc = clamp(floor(uv + 0.5), vec2(0.0), size - 1.0);
          if (imageLoad(depths, ivec3(ivec2(pc), int(wh.z))).r < 0.0)
            InsertSample(best, n, BorderWeight(uv, size), j,
                         vec4(clamp(uv, vec2(0.0), size - 1.0), wh.z, wh.w));
        }
      }
      if (++k >= count) break;
    }
  }
  vec3 srgb;
  const bool filled = BlendBest(best, n, srgb);
  return vec4(srgb, filled ? 64.0 / 255.0 : 0.0);
}

// The blend at proxy surface point x: rgb = sRGB, a = coverage (1 blended, 128/255 surface
// without a valid view).
vec4 ShadeSurface(vec3 x) {
  const vec3 c_o = frame.cam_centre_cell.xyz;
  const float q = frame.cam_centre_cell.w;
  const uvec2 key = PackCell(ivec3(floor(x / q)));

  // Cell-hash lookup (linear probing), at most max_probe + 1 probes: no resident key is displaced
  // further from its home slot (tracked on the host), so a miss stops there. The former bound,
  // the table size, made llvmpipe run ~1000x slower (see docs/vulkan.md).
  const uint mask = uint(frame.iparams.z);
  const uint max_probe = uint(frame.iparams.w);
  uint h = CellHash32(key) & mask;
  uint offset = 0u, count = 0u;
  for (uint probe = 0u; probe <= max_probe; ++probe) {
    const uvec4 e = texelFetch(cell_entries, int(h));
    if (e.x == key.x && e.y == key.y) {
      offset = e.z;
      count = e.w;
      break;
    }
    if (e.x == 0xFFFFFFFFu && e.y == 0xFFFFFFFFu) break;
    h = (h + 1u) & mask;
  }

  const int n = kNBest;
  // Per-fragment parts of the weights (3.2)/(3.3): the ray to the novel camera.
  const vec3 a = c_o - x;
  const float la = length(a);
  const float d_o = max(la, kMinDistance);
  // Loop invariants read once per pixel. llvmpipe moves nothing out of a loop (no loop-invariant
  // code motion in its NIR or LLVM passes) and loads a Frame value under robust buffer access
  // as 8 per-lane scalar loads: written inside the reference loop, the two occlusion epsilons
  // alone were 16 loads per iteration. The same values and expressions, so bit-equal.
  const vec3 a_unit = a / la;
  const bool a_near = !(la > kMinDistance);
  const float lambda = frame.weights.x;
  const float min_weight = kBakedWeights != 0 ? kBakedMinWeight : frame.weights.y;
  const float eps_abs = kBakedWeights != 0 ? kBakedEpsAbs : frame.weights.z;
  const float eps_rel = kBakedWeights != 0 ? kBakedEpsRel : frame.weights.w;
  const int positional = frame.iparams.x;
  BestSamples best;
  best.weight = vec4(0.0);
  best.index = ivec4(0x7FFFFFFF);  // empty: weight 0 (every inserted weight is > 0)
  best.s0 = best.s1 = best.s2 = best.s3 = vec4(0.0);
  // Weight of the n-th best so far (0 while a slot is free). References come in decreasing
  // order of their per-frame weight BOUND: once a bound is below nth, neither this reference
  // nor any later one can enter the best n (break); a reference whose actual weight is below
  // nth is skipped before its validity test. Both exact: the selection is unchanged.
  float nth = 0.0;
  // InpaintFusion (SPEC §7, 4.17-4.18; cpu_renderer.cc): a surface point inside an inpainted
  // keyframe's ROI (colour alpha = label 1 at the point's nearest pixel) is blended from the
  // inpainted keyframes whose ROI holds it only; the cell's observed references are then skipped.
  bool in_roi = false;
  for (int j = 0; kInpainted != 0 && j < frame.ip_params.x; ++j) {
    const int layer = frame.ip_layers[j / 4][j % 4];
    const int base = layer * kViewTexels;
    const vec4 hx = vec4(x, 1.0);
    const float z = dot(texelFetch(view_texels, base + 2), hx);
    if (!(z > kMinDistance)) continue;
    const vec2 uv = vec2(dot(texelFetch(view_texels, base + 0), hx),
                         dot(texelFetch(view_texels, base + 1), hx)) / z;
    const vec4 sl = texelFetch(view_texels, base + 4);
    const vec2 size = sl.xy;
    if (!(uv.x >= -0.5 && uv.y >= -0.5 && uv.x < size.x - 0.5 && uv.y < size.y - 0.5)) continue;
    const vec2 pc = clamp(floor(uv + 0.5), vec2(0.0), size - 1.0);
    if (!(texelFetch(colors, ivec3(ivec2(pc), layer), 0).a > 0.5)) continue;
    const vec4 ce = texelFetch(view_texels, base + 3);
    const float lb = length(ce.xyz - x);
    const float z_stored = imageLoad(depths, ivec3(ivec2(pc), layer)).r;
    const float range_d = z_stored * lb / z;
    // The label holds only where x is not behind the keyframe's surface (blend_math.h InpaintedLabelHolds).
    const bool hidden = ValidDepth(z_stored) && lb > range_d + frame.weights.z + frame.weights.w * range_d;
    if (hidden) continue;
    in_roi = true;
    if (!ValidDepth(z_stored)) continue;
    // The shared weight functions (lumigraph_common.glsl = blend_math.h), not the inlined copies
    // of the reference loop below: this block follows any change of the weights by itself.
    const float w_d = DirectionalWeight(x, c_o, ce.xyz);
    const float w_p = PositionalWeight(x, c_o, ce.xyz, frame.iparams.x);
    InsertSample(best, n, CombinedWeight(1.0, w_d, w_p, frame.weights.x, frame.weights.y), j,
                 vec4(clamp(uv, vec2(0.0), size - 1.0), float(layer), ce.w));
  }
  if (in_roi) count = 0u;
  // RenderApprox::max_candidates (vulkan_renderer.h): at most this many references, in rank
  // order (0 = all: exact).
  if (frame.bg_params.y > 0) count = min(count, uint(frame.bg_params.y));
  // The stop is tested at the END of an iteration, for the next reference (a loop whose only
  // exits are the breaks at its end): llvmpipe runs a loop body as one 8-lane vector while any
  // lane is active and only checks the lanes at the end of the body, so a top-of-body "bound <
  // nth: break" cost every vector one more masked body after its last lane's final reference
  // (bodies per pixel -18 % on the village, -8 % on the apartment; measured -2.5 % CPU on the
  // village's surface pass). The continues of the old body are nested ifs (masked the same
  // way). The same references in the same order: the same selection (docs/vulkan.md, issue 16
  // session 18). A separate cheap loop over the references below nth measured slower.
  uvec4 r0 = uvec4(0u);
  if (count > 0u) r0 = imageLoad(ranked_refs, kRankedTexels * int(offset));
  // Bound -1 = not resident (sorted last): below nth = 0, so such a list is never entered.
  if (count > 0u && !(uintBitsToFloat(r0.w) < nth)) {
    for (uint i = 0u;;) {
      const int t = kRankedTexels * int(offset + i);
      // ---- weights: DirectionalWeight / PositionalWeight / CombinedWeight with v = 1 ----
      const vec3 b = uintBitsToFloat(r0.xyz) - x;
      const float lb = length(b);  // also the range of x from the view (a rotation keeps lengths)
      const vec3 dab = a_unit - b / lb;  // well-conditioned cosine (blend_math.h)
      const float w_d = (a_near || !(lb > kMinDistance))
                            ? 0.0 : max(0.0, 1.0 - 0.5 * dot(dab, dab));
      float w;
      if (kLambdaOne != 0) {
        w = max(w_d, min_weight);
      } else {
        const float w_p = positional == kPositionalPrinted
                              ? max(0.0, 1.0 - lb / d_o)
                              : max(0.0, 1.0 - max(0.0, lb - d_o) / d_o);
        w = CombinedWeight(1.0, w_d, w_p, lambda, min_weight);
      }
      if (w >= nth) {
        // The view's M = K R^T (the 3x3 part of P = K [R^T | -R^T c]) with the record's
        // integers and exposure in the w components (CellTable WriteRankedSlot).
        const uvec4 m0 = imageLoad(ranked_refs, t + 1);  // w: layer | list position << 16
        const uvec4 m1 = imageLoad(ranked_refs, t + 2);  // w: width | height << 16
        const uvec4 m2 = imageLoad(ranked_refs, t + 3);  // w: exposure bits
        const int layer = int(m0.w & 0xFFFFu);
        // ---- validity (3.4), blend_math.h Validity() with the discontinuity test baked into
        // the depth layer. Projection of x - c_i = -b by M: hp = (z u, z v, z) with z the
        // camera z-depth, so in_front is z > kMinDistance and uv = hp.xy / z, algebraically
        // K (R^T (x - c)) of ProjectToView. The range of x is |x - c| = lb, and the stored
        // range along the same ray is z_stored * range / z (= z_stored * |ray|,
        // RangeFromZDepth).
        const vec3 xc = -b;
        const float z = dot(uintBitsToFloat(m2.xyz), xc);
        if (z > kMinDistance) {
          const vec2 uv =
              vec2(dot(uintBitsToFloat(m0.xyz), xc), dot(uintBitsToFloat(m1.xyz), xc)) / z;
          const vec2 size = vec2(float(m1.w & 0xFFFFu), float(m1.w >> 16));
          if (uv.x >= -0.5 && uv.y >= -0.5 && uv.x < size.x - 0.5 && uv.y < size.y - 0.5) {
            const vec2 pc = clamp(floor(uv + 0.5), vec2(0.0), size - 1.0);
            const float z_stored = imageLoad(depths, ivec3(ivec2(pc), layer)).r;
            // ValidDepth(z_stored) is z_stored > 0 here: the baked layers hold only finite
            // values (0 invalid, -1 background, > 0 depth; BakeDiscontinuities maps NaN / Inf
            // to 0 at upload).
            const float range_m = lb;
            const float range_d = z_stored * range_m / z;
            if (z_stored > 0.0 && !(range_m > range_d + eps_abs + eps_rel * range_d)) {
              InsertSample(best, n, w, int(m0.w >> 16),
                           vec4(clamp(uv, vec2(0.0), size - 1.0), float(layer),
                                uintBitsToFloat(m2.w)));
              nth = n == 1 ? best.weight.x
                  : n == 2 ? best.weight.y
                  : n == 3 ? best.weight.z : best.weight.w;
            }
          }
        }
      }
      // Next reference; stop at the end of the list or once its bound is below nth (neither it
      // nor a later one can enter the best n).
      ++i;
      if (i >= count) break;
      r0 = imageLoad(ranked_refs, kRankedTexels * int(offset + i));
      if (uintBitsToFloat(r0.w) < nth) break;
    }
  }

  vec3 srgb;
  const bool covered = BlendBest(best, n, srgb);
  return vec4(srgb, covered ? (in_roi ? 224.0 / 255.0 : 1.0) : 128.0 / 255.0);  // 224: inpainted
}

// rgb = sRGB, a = coverage (1 blended, 224/255 blended from inpainted views, 128/255 surface
// without a valid view, 64/255 no surface but filled at infinity, 0 no surface).
vec4 ShadePixel(ivec2 pixel) {
  const vec4 g = texelFetch(gbuffer, pixel, 0);
  if (g.w == 0.0) return ShadeBackground(pixel);  // no proxy surface
  return ShadeSurface(g.xyz);
}
