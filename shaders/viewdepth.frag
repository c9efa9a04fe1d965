#version 450
// View-depth pass: z-depth (metres along the optical axis) of the proxy surface, written to an
// R32F target. Used to measure "proxy-rendered depth" against sensor depth for occlusion
// (docs/vulkan.md) and by tests. z = dot(third row of cam_from_local, p - c).
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"
#include "xray_hole.glsl"

layout(location = 0) in vec3 in_p_local;
layout(location = 0) out float out_z;

void main() {
  if (CutByXrayHole(in_p_local)) discard;
  // frame.background.xyz holds the camera's optical axis in the local frame for this pass.
  out_z = dot(frame.background.xyz, in_p_local - frame.cam_centre_cell.xyz);
}
