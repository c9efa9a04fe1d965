#version 450
// Cell-id pass (SPEC §4 ψ_vis): the packed CellId of floor(p_local / q) per pixel.
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"
#include "xray_hole.glsl"

layout(location = 0) in vec3 in_p_local;
layout(location = 0) out uvec2 out_cell;

void main() {
  if (CutByXrayHole(in_p_local)) discard;
  const float q = frame.cam_centre_cell.w;
  out_cell = PackCell(ivec3(floor(in_p_local / q)));
}
