#version 450
// The issue-16 speed floor (floor.vert): one bilinear fetch per pixel from an RGBA8 texture
// holding the nearest view's stored sRGB bytes, written out as it is (no conversion).
layout(set = 0, binding = 9) uniform sampler2D floor_colors;

layout(location = 0) in vec2 in_uv;
layout(location = 0) out vec4 out_color;

void main() { out_color = vec4(textureLod(floor_colors, in_uv, 0.0).rgb, 1.0); }
