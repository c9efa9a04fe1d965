#version 450
// The speed floor of the blend as issue 16 defines it (VulkanRenderer::RenderFloor with
// FloorKind::kForward, vulkan_bench's "floor" fields): a forward draw of the proxy mesh with one
// bilinear fetch per pixel + read-back. The texture coordinate is the projection of each VERTEX
// into the resident view nearest the novel camera, interpolated over the triangle as any
// textured mesh's (floor.frag fetches at it from an RGBA8 copy of that view's stored sRGB colour).
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"

layout(location = 0) in vec3 in_p_local;
layout(location = 0) out vec2 out_uv;

void main() {
  const vec4 hx = vec4(in_p_local, 1.0);
  const float z = max(dot(frame.floor_view[2], hx), kMinDistance);
  // (u + 0.5) / W: texel centres at integer pixel coordinates (camera.h), normalised.
  out_uv = (vec2(dot(frame.floor_view[0], hx), dot(frame.floor_view[1], hx)) / z + 0.5) *
           frame.floor_view[3].xy;
  gl_Position = frame.clip_from_local * hx;
}
