#version 450
// Lumigraph blend pass as a full-screen triangle over the G-buffer (see blend_shade.glsl).
#extension GL_GOOGLE_include_directive : require
#include "lumigraph_common.glsl"
#include "blend_shade.glsl"

layout(location = 0) out vec4 out_color;

void main() { out_color = ShadePixel(ivec2(gl_FragCoord.xy)); }
