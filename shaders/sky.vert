#version 450
// Background pass of the deferred blend (blend.frag, kBlendPassBackground): rectangles of screen
// tiles in normalised device coordinates at depth 1 (FrameRenderer::BuildSkyDraws), so the depth
// test LESS_OR_EQUAL against the G-buffer pass's depth keeps the pixels without a surface.
layout(location = 0) in vec3 in_ndc;

void main() { gl_Position = vec4(in_ndc.xy, 1.0, 1.0); }
