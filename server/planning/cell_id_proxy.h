// A coarse level of detail of the proxy mesh used only for the planner's cell-id buffers
// (SPEC §4: ψ_vis per cell from a reduced-resolution render of the proxy). The TSDF mesh has a
// few 10^5 triangles, most of them far smaller than a pixel of a 160x120 id buffer, so the CPU
// rasterizer spends its time on triangle setup, not on pixels. Vertex clustering on a uniform
// grid of `cluster_m` (well below the cell size) keeps the silhouette and the cell each surface
// point falls into to within ~cluster_m / 2 while removing most triangles. Per mesh chunk, so
// only dirty chunks are simplified again. The lumigraph render itself keeps the full mesh.
#pragma once

#include "common/mesh.h"
#include "common/status.h"

namespace exo::planning {

struct ClusterStats {
  size_t triangles_in = 0, triangles_out = 0;
};

// Vertex clustering: every vertex is mapped to the cell floor(p / cluster_m) of a uniform grid;
// each occupied grid cell becomes one vertex at the MEAN of its members (not the grid centre,
// so a flat surface stays where it was); triangles whose three vertices do not fall into three
// distinct grid cells are dropped (they collapsed to a line or a point). Positions and indices
// only (normals, colours, materials dropped). cluster_m must be finite and > 0; an empty mesh
// gives an empty mesh. Malformed indices are an error.
absl::StatusOr<TriangleMesh> ClusterSimplify(const TriangleMesh& mesh, double cluster_m,
                                             ClusterStats* stats = nullptr);

}  // namespace exo::planning
