#version 450
// One triangle covering the viewport (vertices 0, 1, 2 without vertex buffers): the blend pass
// runs once per pixel, reading the surface point from the G-buffer.
void main() {
  const vec2 p = vec2(float((gl_VertexIndex << 1) & 2), float(gl_VertexIndex & 2));
  gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
