#version 450
// One triangle covering the viewport (vertices 0, 1, 2 without vertex buffers) at depth 1: the
// blend passes run once per pixel, reading the surface point from the G-buffer; their depth test
// against the G-buffer pass's depth (cleared to 1) picks the pixels with / without a surface.
void main() {
  const vec2 p = vec2(float((gl_VertexIndex << 1) & 2), float(gl_VertexIndex & 2));
  gl_Position = vec4(p * 2.0 - 1.0, 1.0, 1.0);
}
