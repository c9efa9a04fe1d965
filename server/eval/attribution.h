// Oracle ingredients for attributing the real-data error of the lumigraph (issue 15, item 1):
// each replaces one ingredient of a render with a better one that only the evaluation can know,
// so the metric gain measures how much that ingredient costs.
//  - MeshFromDepth: the held-out frame's own depth map as the proxy for its own pixels
//    (isolates proxy error: the TSDF surface vs what the camera measured);
//  - FitGainToReference: per-channel gains of the rendered frame fitted (least squares, linear
//    intensity) to the ground truth over the covered pixels (isolates global exposure / white
//    balance of the composite).
#pragma once

#include "common/camera.h"
#include "common/image.h"
#include "common/mesh.h"
#include "common/rigid3.h"

namespace exo::eval {

// Grid triangulation of a z-depth image in the frame of `local_from_cam`: every `step`-th pixel
// is a vertex (Unproject at the pixel centre); a quad of four valid vertices gives two
// triangles unless its depths spread more than max_jump_rel x its nearest depth (no skin across
// depth discontinuities). `camera` must describe `depth_m`'s pixels (same size).
TriangleMesh MeshFromDepth(const ImageF& depth_m, const PinholeCamera& camera,
                           const Rigid3d& local_from_cam, int step = 2,
                           float max_jump_rel = 0.05f);

// Per-channel gain g_c minimising sum over mask pixels of (g_c L(render) - L(reference))^2 in
// linear intensity (L = sRGB decode), applied to every pixel of `render` (re-encoded, clamped).
// Pixels with mask 0 do not enter the fit; an empty mask (or no mask pixel) leaves `render`
// unchanged. Returns the three gains.
glm::vec3 FitGainToReference(ImageU8& render, const ImageU8& reference, const ImageU8& mask);

}  // namespace exo::eval
