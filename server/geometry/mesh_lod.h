// Level of detail of the proxy mesh the clients receive (the publisher's LOD; issue 15 / SPEC
// §10: the viewers' initial sync and steady bandwidth are dominated by the 2 cm proxy a real
// room needs). The server keeps the full-resolution mesh for planning and fusion; each published
// chunk is simplified with quadric error metrics (Garland & Heckbert 1997, as implemented by
// meshoptimizer's meshopt_simplify from Debian's libmeshoptimizer-dev) under an absolute
// geometric error bound, with the chunk's open boundary locked: the seam vertices two
// neighbouring chunks share stay bit-identical, so the simplified proxy stays closed across
// chunks (no cracks for the renderers' depth test to leak through). Pure, no I/O.
#pragma once

#include "common/mesh.h"
#include "common/status.h"

namespace exo::geometry {

struct MeshLodOptions {
  // Largest distance a simplified surface may move from the input (metres); 0 = no LOD (the
  // input is returned as it is).
  double max_error_m = 0.0;
  absl::Status Validate() const;
};

struct MeshLodStats {
  size_t triangles_in = 0;
  size_t triangles_out = 0;
  double error_m = 0.0;  // meshoptimizer's estimate of the error it made (absolute, metres)
  bool fallback = false;  // the simplified chunk would have changed its open boundary: the
                          // input was returned (see SimplifyMesh)
};

// The simplified mesh: a subset of the input's vertices (with their normals / colours when the
// input has them), re-indexed densely in first-use order; per-triangle `material` is dropped
// (chunks carry none). Meshes with fewer than 2 triangles, or a bad index, come back unchanged
// (a bad index is the caller's bug; MeshFromProto already refuses them on the wire). The edges not
// shared by exactly two triangles (open boundary, non-manifold edges) are checked to be the same
// after simplification; when they are not (near-degenerate input), the input is returned and
// stats->fallback is set, so a published chunk never opens a crack against its neighbours.
TriangleMesh SimplifyMesh(const TriangleMesh& mesh, const MeshLodOptions& options,
                          MeshLodStats* stats = nullptr);

}  // namespace exo::geometry
