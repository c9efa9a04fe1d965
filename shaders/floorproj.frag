#version 450
// The session-9 speed floor of the blend (VulkanRenderer::RenderFloor with
// FloorKind::kProjective, vulkan_bench's "floor_proj" fields): a forward draw of the proxy mesh
// with ONE bilinear fetch per pixel from the resident view nearest the novel camera, projected
// per fragment as the blend does (no validity or weights) from the linear colour layers the
// blend reads, sRGB-encoded. Heavier than the issue's floor (floor.vert/floor.frag): the
// per-fragment projection and the encode cost ~12 CPU ms at 720p (docs/vulkan.md, session 13).
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"

layout(set = 0, binding = 4) uniform sampler2DArray colors;

layout(location = 0) in vec3 in_p_local;
layout(location = 0) out vec4 out_color;

void main() {
  const vec4 hx = vec4(in_p_local, 1.0);
  const float z = dot(frame.floor_view[2], hx);
  const vec2 size = frame.floor_view[3].xy;
  const vec2 uv = clamp(vec2(dot(frame.floor_view[0], hx), dot(frame.floor_view[1], hx)) / z,
                        vec2(0.0), size - 1.0);
  const vec2 layer_size = vec2(textureSize(colors, 0).xy);
  const vec3 lin =
      textureLod(colors, vec3((uv + 0.5) / layer_size, frame.floor_view[3].z), 0.0).rgb;
  out_color = vec4(LinearToSrgb3(lin), 1.0);
}
