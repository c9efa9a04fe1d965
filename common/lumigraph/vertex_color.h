// The fused-mesh baseline every evaluation compares the lumigraph with: a triangle mesh with
// per-vertex colour (KinectFusion / Open3D class) rendered with barycentric colour, no lighting.
#pragma once

#include "common/camera.h"
#include "common/image.h"
#include "common/mesh.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo {

// `mesh` (local frame, linear RGB in mesh.colors) seen from `local_from_cam` with `cam`: sRGB8
// `img` and `mask` (255 where a triangle is hit). A mesh without colours (or empty) gives a
// black image and an empty mask. Errors as Rasterize().
absl::Status RenderVertexColor(const TriangleMesh& mesh, const PinholeCamera& cam,
                               const Rigid3d& local_from_cam, ImageU8* img, ImageU8* mask);

}  // namespace exo
