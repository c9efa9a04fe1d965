#version 450
// Lumigraph blend pass (SPEC §6, eq. 3.1-3.5): per fragment of the proxy mesh, look up the
// fragment's cell in the resident cell-hash table, evaluate validity and weights for every
// reference of the cell, keep the best n (<= 4, default 3) and blend their exposure-corrected
// linear colours. Mirrors common/lumigraph/blend_math.h (see lumigraph_common.glsl).
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"

// Store tables as uniform texel buffers (a fetch is a vector gather on llvmpipe; a divergent SSBO
// load is a per-lane scalar loop, measured much slower):
// Views: 6 RGBA32F texels per view record (see LoadView; size/layer/valid stored as floats).
layout(set = 0, binding = 1) uniform samplerBuffer view_texels;
// Cell hash: (key lo, key hi, offset into Refs, count); empty = (~0, ~0), tombstone = (~1, ~0).
layout(set = 0, binding = 2) uniform usamplerBuffer cell_entries;
// Reference slots: view-record indices (the views' texture-array layers), ~0 = not resident.
layout(set = 0, binding = 3) uniform usamplerBuffer ref_slots;
layout(set = 0, binding = 4) uniform sampler2DArray colors;  // SRGB8_A8: fetch decodes to linear
layout(set = 0, binding = 5) uniform sampler2DArray depths;  // R32F baked z-depth (0 = invalid)

layout(location = 0) in vec3 in_p_local;
layout(location = 0) out vec4 out_color;  // rgb = sRGB, a = coverage (1 blended, 0.5 surface)

// Bilinear sample of SrgbToLinear(texels) at continuous pixel uv (centres at integers), edge
// texels clamped: the convention of blend_math.h. One filtered fetch from the SRGB8_A8 array with
// the linear sampler (the texture unit decodes to linear before filtering, as specified). uv is
// clamped to the VIEW's [0, size-1] first: layers can be larger than the view (common layer
// size), and at uv = size-1 the neighbour outside the view gets weight exactly 0. llvmpipe
// filters with 8-bit fractional weights, so this differs from the float lerp of the CPU
// reference by < 1/255 (the golden tests bound it). Four texelFetch + float lerp measured ~3x
// slower per frame on llvmpipe (docs/vulkan.md).
vec3 SampleLinear(int layer, vec2 uv, ivec2 size) {
  const vec2 uvc = clamp(uv, vec2(0.0), vec2(size - 1));
  const vec2 layer_size = vec2(textureSize(colors, 0).xy);
  return texture(colors, vec3((uvc + 0.5) / layer_size, float(layer))).rgb;
}

BlendView LoadView(uint slot) {
  const int base = int(slot) * 6;
  BlendView v;
  v.cam_from_local_c0 = texelFetch(view_texels, base + 0);
  v.cam_from_local_c1 = texelFetch(view_texels, base + 1);
  v.cam_from_local_c2 = texelFetch(view_texels, base + 2);
  v.centre_exposure = texelFetch(view_texels, base + 3);
  v.intrinsics = texelFetch(view_texels, base + 4);
  v.size_layer = ivec4(texelFetch(view_texels, base + 5));
  return v;
}

// blend_math.h Validity(), with the discontinuity test pre-baked into the depth layer.
float Validity(vec3 x, BlendView view) {
  const Projection proj = ProjectToView(x, view);
  if (!proj.in_front || !InsideImage(proj.uv, view.size_layer.xy)) return 0.0;
  const ivec2 px = ivec2(floor(proj.uv + 0.5));
  const ivec2 pc = clamp(px, ivec2(0), view.size_layer.xy - 1);
  const float z = texelFetch(depths, ivec3(pc, view.size_layer.z), 0).r;
  if (!ValidDepth(z)) return 0.0;
  const float range_d = RangeFromZDepth(proj.uv, z, view.intrinsics);
  const float eps = frame.weights.z + frame.weights.w * range_d;
  if (proj.range_m > range_d + eps) return 0.0;
  return 1.0;
}

void AccumulateSlot(inout BlendAccumulator acc, vec3 x, uint offset, int index, float weight,
                    bool enabled) {
  if (!enabled || index < 0) return;
  const BlendView view = LoadView(texelFetch(ref_slots, int(offset + uint(index))).x);
  const Projection proj = ProjectToView(x, view);
  const vec3 lin = SampleLinear(view.size_layer.z, proj.uv, view.size_layer.xy);
  Accumulate(acc, lin, view.centre_exposure.w, weight);
}

void main() {
  const vec3 x = in_p_local;
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

  const int n = frame.iparams.y;
  BestN best = EmptyBestN();
  for (uint i = 0u; i < count; ++i) {
    const uint slot = texelFetch(ref_slots, int(offset + i)).x;
    if (slot == 0xFFFFFFFFu) continue;
    const BlendView view = LoadView(slot);
    if (view.size_layer.w == 0) continue;
    const float v = Validity(x, view);
    const vec3 c_i = view.centre_exposure.xyz;
    const float w_d = DirectionalWeight(x, c_o, c_i);
    const float w_p = PositionalWeight(x, c_o, c_i, frame.iparams.x);
    const float w = CombinedWeight(v, w_d, w_p, frame.weights.x, frame.weights.y);
    InsertBest(best, n, w, int(i));
  }

  BlendAccumulator acc;
  acc.sum_linear = vec3(0.0);
  acc.sum_weight = 0.0;
  // Slots unrolled with constant component indices (see BestN); empty slots (-1) are the tail,
  // so skipping them equals blend_math.h's "break at the first empty slot".
  AccumulateSlot(acc, x, offset, best.index.x, best.weight.x, 0 < n);
  AccumulateSlot(acc, x, offset, best.index.y, best.weight.y, 1 < n);
  AccumulateSlot(acc, x, offset, best.index.z, best.weight.z, 2 < n);
  AccumulateSlot(acc, x, offset, best.index.w, best.weight.w, 3 < n);
  vec3 srgb;
  const bool covered = Resolve(acc, frame.background.rgb, srgb);
  out_color = vec4(srgb, covered ? 1.0 : 128.0 / 255.0);
}
