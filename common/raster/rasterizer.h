// CPU reference rasterizer: renders a TriangleMesh (scene-local frame) through a PinholeCamera
// into per-pixel buffers (z-depth, range, local position, normal, triangle id, SPEC §4 cell id).
// It renders the synthetic ground truth and is the oracle for the Vulkan renderer.
//
// Conventions: integer pixel coordinates are pixel centres (camera.h); a pixel is covered when
// its centre is inside a triangle, with the top-left fill rule on exact fixed-point (1/256 px)
// edge functions, so two triangles sharing an edge hit every pixel along it exactly once.
// Attributes are interpolated perspective-correctly (1/z is linear in screen space). Triangles
// crossing the near plane are clipped (not dropped); a wide guard band (±16384 px) bounds the
// screen coordinates. The depth test keeps the closest fragment; on exact ties the triangle
// with the lower index wins, so output is deterministic for any thread count.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include "common/camera.h"
#include "common/cells.h"
#include "common/image.h"
#include "common/mesh.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo {

inline constexpr uint32_t kNoTriangle = ~uint32_t{0};

struct RasterOptions {
  // Which outputs to produce (each costs time; z-depth is always computed internally).
  bool z_depth = true;        // ImageF, metres along the optical axis, 0 = background
  bool range = false;         // ImageF, Euclidean distance from the camera centre, 0 = background
  bool position = false;      // ImageF 3 ch, scene-local position, 0 = background
  bool normal = false;        // ImageF 3 ch, unit normal in the local frame, 0 = background
  bool triangle_id = false;   // ImageU32, index into mesh triangles, kNoTriangle = background
  bool cell_id = false;       // Image<uint64_t>, CellId of the local position, kNoCell = bg
  // Normal source: interpolated per-vertex normals when the mesh has them and this is set;
  // otherwise the geometric face normal (from the winding: (p1-p0) x (p2-p0)).
  bool interpolate_normals = false;
  // Skip triangles whose screen winding is clockwise in the y-down image, i.e. whose geometric
  // normal points away from the camera.
  bool cull_backfaces = false;
  CellGrid cell_grid;          // used when cell_id is set
  double near_m = 0.01;        // near clipping plane (z in the camera frame), > 0
  // Render at a reduced resolution: 0 = camera's size, otherwise camera.Scaled(width, height).
  int width = 0, height = 0;
  int num_threads = 2;         // row bands are interleaved across threads; result independent
  // The caller has already checked every mesh with ValidateMesh() (e.g. once when caching it);
  // skips the per-call index scan. Unvalidated meshes with this set are undefined behaviour.
  bool meshes_prevalidated = false;

  absl::Status Validate() const;
};

struct RasterOutput {
  PinholeCamera camera;        // the camera actually rendered (scaled when requested)
  ImageF z_depth_m;
  ImageF range_m;
  ImageF position_local;       // 3 channels
  ImageF normal_local;         // 3 channels
  ImageU32 triangle_id;
  Image<uint64_t> cell_id;
  // Statistics.
  size_t triangles_in = 0;       // mesh triangles
  size_t triangles_setup = 0;    // screen triangles after culling/clipping
  size_t triangles_clipped = 0;  // input triangles that crossed the near plane or guard band
  size_t pixels_covered = 0;
};

// Renders `mesh` seen from a camera at `local_from_cam` (camera frame: x right, y down,
// z forward). Errors: invalid options/camera/pose, malformed mesh (index out of range, size of
// optional attributes mismatching).
absl::StatusOr<RasterOutput> Rasterize(const TriangleMesh& mesh, const PinholeCamera& camera,
                                       const Rigid3d& local_from_cam,
                                       const RasterOptions& options);

// Renders the concatenation of `parts` (in order) without building it: the output is identical
// to Rasterize() of the concatenated mesh (triangle ids are global: part k's triangles follow
// those of parts 0..k-1; depth ties go to the lower global id). Lets a caller keep its proxy
// as chunks and pass only the visible ones. Errors as Rasterize(), plus a null part.
absl::StatusOr<RasterOutput> RasterizeParts(const std::vector<const TriangleMesh*>& parts,
                                            const PinholeCamera& camera,
                                            const Rigid3d& local_from_cam,
                                            const RasterOptions& options);

// Checks index range and attribute sizes of a mesh.
absl::Status ValidateMesh(const TriangleMesh& mesh);

}  // namespace exo
