#version 450
// Lumigraph blend pass as a compute dispatch over the G-buffer (see blend_shade.glsl): 8x8
// pixels per workgroup, RGBA8 packed straight into a host-visible storage buffer (no colour
// attachment, no image-to-buffer copy).
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"
#include "blend_shade.glsl"

layout(local_size_x = 8, local_size_y = 8) in;
layout(std430, set = 0, binding = 8) writeonly buffer BlendOut { uint rgba8[]; } blend_out;

void main() {
  const ivec2 size = textureSize(gbuffer, 0);
  const ivec2 p = ivec2(gl_GlobalInvocationID.xy);
  if (p.x >= size.x || p.y >= size.y) return;
  blend_out.rgba8[p.y * size.x + p.x] = packUnorm4x8(ShadePixel(p));
}
