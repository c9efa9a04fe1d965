#version 450
// Proxy-mesh vertex stage shared by the blend, cell-id and view-depth passes.
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"

layout(location = 0) in vec3 in_p_local;
layout(location = 0) out vec3 out_p_local;
// The blend pass tests EQUAL against the depth pre-pass: both pipelines run this same module on
// the same vertices, so gl_Position is bit-identical (no `invariant`: glslang puts it on a
// gl_PerVertex member, which the SPIR-V validator warns about).

void main() {
  out_p_local = in_p_local;
  gl_Position = frame.clip_from_local * vec4(in_p_local, 1.0);
}
