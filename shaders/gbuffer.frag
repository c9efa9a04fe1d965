#version 450
// G-buffer pass of the deferred blend: the proxy surface point (scene-local frame) per pixel,
// w = 1 where there is a surface (the target is cleared to 0). blend.frag then shades every pixel
// exactly once from a full-screen triangle (see docs/vulkan.md for why this is faster on
// llvmpipe than shading the proxy triangles directly).
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"
#include "xray_hole.glsl"

layout(location = 0) in vec3 in_p_local;
layout(location = 0) out vec4 out_p_local;

void main() {
  if (CutByXrayHole(in_p_local)) discard;
  out_p_local = vec4(in_p_local, 1.0);
}
