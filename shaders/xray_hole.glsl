// The viewer's X-ray cut-away as a "virtual hole in the wall" (thesis 5.2.7, issue 19;
// VulkanRenderer::SetXrayHole): inside a disc on the image, the proxy nearer than a clip
// z-depth is not drawn (the fragment is discarded, so the depth test keeps the surface behind
// it: the modelled interior); outside the disc nothing changes. Included by the proxy passes
// (gbuffer.frag, cellid.frag, viewdepth.frag) after lumigraph_common.glsl. The pipelines with
// the hole are separate (specialisation constant 4 = 1): with 0 the test and its `discard`
// compile out, so the passes without a hole keep llvmpipe's early depth test.
layout(constant_id = 4) const int kXrayHole = 0;

bool CutByXrayHole(vec3 p_local) {
  if (kXrayHole == 0) return false;
  const vec2 d = gl_FragCoord.xy - frame.xray_disc.xy;
  return dot(d, d) <= frame.xray_disc.z &&
         dot(frame.xray_axis.xyz, p_local - frame.cam_centre_cell.xyz) < frame.xray_axis.w;
}
