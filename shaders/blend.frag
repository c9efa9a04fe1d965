#version 450
// Lumigraph blend pass (SPEC §6, eq. 3.1-3.5): per fragment of the proxy mesh, look up the
// fragment's cell in the resident cell-hash table, evaluate validity and weights for every
// reference of the cell, keep the best n (<= 4, default 3) and blend their exposure-corrected
// linear colours. Mirrors common/lumigraph/blend_math.h (see lumigraph_common.glsl).
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"

layout(std430, set = 0, binding = 1) readonly buffer Views { BlendView views[]; };
// Cell hash: (key lo, key hi, offset into Refs, count); empty = (~0, ~0), tombstone = (~1, ~0).
layout(std430, set = 0, binding = 2) readonly buffer CellTable { uvec4 cell_entries[]; };
// Reference slots: view-record indices (the views' texture-array layers), ~0 = not resident.
layout(std430, set = 0, binding = 3) readonly buffer Refs { uint refs[]; };
layout(set = 0, binding = 4) uniform sampler2DArray colors;  // SRGB8_A8: fetch decodes to linear
layout(set = 0, binding = 5) uniform sampler2DArray depths;  // R32F baked z-depth (0 = invalid)

layout(location = 0) in vec3 in_p_local;
layout(location = 0) out vec4 out_color;  // rgb = sRGB, a = coverage (1 blended, 0.5 surface)

// Bilinear sample of SrgbToLinear(texels) at continuous pixel uv (centres at integers), edge
// texels clamped: the convention of blend_math.h (what a linear-filtered sRGB texture computes),
// done with texelFetch in float so it matches the CPU reference bit for bit up to float order.
vec3 SampleLinear(int layer, vec2 uv, ivec2 size) {
  const vec2 uvc = clamp(uv, vec2(0.0), vec2(size - 1));
  const ivec2 p0 = ivec2(floor(uvc));
  const ivec2 p1 = min(p0 + 1, size - 1);
  const vec2 f = uvc - vec2(p0);
  const vec3 c00 = texelFetch(colors, ivec3(p0.x, p0.y, layer), 0).rgb;
  const vec3 c10 = texelFetch(colors, ivec3(p1.x, p0.y, layer), 0).rgb;
  const vec3 c01 = texelFetch(colors, ivec3(p0.x, p1.y, layer), 0).rgb;
  const vec3 c11 = texelFetch(colors, ivec3(p1.x, p1.y, layer), 0).rgb;
  return mix(mix(c00, c10, f.x), mix(c01, c11, f.x), f.y);
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

void main() {
  const vec3 x = in_p_local;
  const vec3 c_o = frame.cam_centre_cell.xyz;
  const float q = frame.cam_centre_cell.w;
  const uvec2 key = PackCell(ivec3(floor(x / q)));

  // Cell-hash lookup (linear probing).
  const uint mask = uint(frame.iparams.z);
  uint h = CellHash32(key) & mask;
  uint offset = 0u, count = 0u;
  for (uint probe = 0u; probe <= mask; ++probe) {
    const uvec4 e = cell_entries[h];
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
    const uint slot = refs[offset + i];
    if (slot == 0xFFFFFFFFu) continue;
    const BlendView view = views[slot];
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
  for (int s = 0; s < n; ++s) {
    if (best.index[s] < 0) break;
    const BlendView view = views[refs[offset + uint(best.index[s])]];
    const Projection proj = ProjectToView(x, view);
    const vec3 lin = SampleLinear(view.size_layer.z, proj.uv, view.size_layer.xy);
    Accumulate(acc, lin, view.centre_exposure.w, best.weight[s]);
  }
  vec3 srgb;
  const bool covered = Resolve(acc, frame.background.rgb, srgb);
  out_color = vec4(srgb, covered ? 1.0 : 128.0 / 255.0);
}
