#version 450
// Lumigraph blend pass as a full-screen triangle over the G-buffer (see blend_shade.glsl). Two
// pipelines (specialisation constant kBlendPass): the surface pass runs where the G-buffer pass's
// depth test kept a proxy surface, the background pass where it kept none; llvmpipe runs every
// branch of a shader on every pixel (divergent ifs are masks, not jumps), so each pixel paying
// only its own path needs the split into passes (early depth test skips whole 4x4 blocks).
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"
#include "blend_shade.glsl"

layout(location = 0) out vec4 out_color;

void main() {
  const ivec2 pixel = ivec2(gl_FragCoord.xy);
  if (kBlendPass == kBlendPassSurface)
    out_color = ShadeSurface(texelFetch(gbuffer, pixel, 0).xyz);
  else if (kBlendPass == kBlendPassBackground)
    out_color = ShadeBackground(pixel);
  else
    out_color = ShadePixel(pixel);
}
