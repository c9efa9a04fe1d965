// A coarse level of detail of the proxy mesh used only for the planner's cell-id buffers
// (SPEC §4: ψ_vis per cell from a reduced-resolution render of the proxy). The TSDF mesh has a
// few 10^5 triangles, most of them far smaller than a pixel of a 160x120 id buffer, so the CPU
// rasterizer spends its time on triangle setup, not on pixels. Vertex clustering on a uniform
// grid of `cluster_m` (well below the cell size) keeps the silhouette and the cell each surface
// point falls into to within ~cluster_m / 2 while removing most triangles. Per mesh chunk, so
// only dirty chunks are simplified again. The lumigraph render itself keeps the full mesh.
//
// CellIdRenderer keeps the proxy as chunks (each with its LOD, built once per chunk version, and
// its bounding box) and renders the cell-id buffer from the chunks whose box meets the view
// frustum, without concatenating them (common/raster RasterizeParts, cell ids only). Its output
// is identical to rasterizing the concatenation of every cached render mesh (LOD or full chunk).
// Measured in planning_bench (docs/planning.md); server/eval renders its planner buffers with it.
// Not wired into server/service's planning stage (frame-depth ids by default).
#pragma once

#include <cstdint>
#include <unordered_map>
#include <vector>

#include "common/camera.h"
#include "common/cells.h"
#include "common/image.h"
#include "common/lumigraph/model.h"
#include "common/mesh.h"
#include "common/rigid3.h"
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

struct CellIdRendererOptions {
  CellGrid grid;                 // cell size > 0 (the planner's grid)
  // Vertex-clustering LOD per chunk (ClusterSimplify) of this cluster size; 0 = render the chunk
  // meshes themselves. Chosen per scene: see DefaultCellIdLodM().
  double lod_cluster_m = 0.0;
  // 0: the LOD is rebuilt for every new chunk version. > 0: a new version keeps the chunk's LOD
  // while its triangle count is within this fraction of the count the LOD was built from AND its
  // bounding box moved by at most half a cluster (a converging TSDF chunk moves by a fraction of
  // a voxel, far below a cluster; a surface appearing or carved away moves the box).
  double lod_keep_fraction = 0.0;
  // Chunks whose box lies entirely beyond this camera z are skipped (0 = no far limit).
  double max_range_m = 0.0;
  double near_m = 0.01;          // raster near plane (common/raster), > 0
  int num_threads = 1;           // raster threads; a 160x120 buffer is fastest on 1
  absl::Status Validate() const;
};

// Default cluster size: 0.5 x the cell size, at most 4 x the TSDF voxel (voxel_m <= 0: no
// voxel bound); its quality and speed are measured in docs/planning.md (planning_bench).
double DefaultCellIdLodM(double cell_size_m, double voxel_m);

struct CellIdBuffer {
  PinholeCamera camera;          // the camera rendered (the input camera scaled to width x height)
  Image<uint64_t> cell_id;       // kNoCell = background
  size_t chunks_rendered = 0;    // chunks that passed the frustum test
  size_t triangles_rendered = 0;
};

class CellIdRenderer {
 public:
  static absl::StatusOr<CellIdRenderer> Create(const CellIdRendererOptions& options);

  // New or re-extracted chunks. A chunk whose version is not newer than the cached one is
  // skipped; an empty mesh removes the chunk. Errors (the cache is unchanged for that chunk and
  // the rest are still applied): malformed mesh. A new version whose LOD is kept (see
  // lod_keep_fraction) is not read beyond its box and triangle count, so it is not validated.
  absl::Status Update(const std::vector<MeshChunk>& changed);
  void Remove(uint64_t chunk_id);
  void Clear() {
    chunks_.clear();
    items_.clear();
  }

  // Cell ids of the first surface per pixel of a width x height buffer of `camera` at
  // `local_from_cam` (per-pixel floor(p_local / q), as common/raster). Errors: bad camera, pose,
  // size.
  absl::StatusOr<CellIdBuffer> Render(const Rigid3d& local_from_cam, const PinholeCamera& camera,
                                      int width, int height) const;

  const CellIdRendererOptions& options() const { return options_; }
  size_t num_chunks() const { return chunks_.size(); }
  size_t render_triangles() const;   // triangles of every cached render mesh
  size_t source_triangles() const;   // triangles of the chunk meshes they came from
  size_t lod_builds() const { return lod_builds_; }
  // The mesh rendered for a chunk (its LOD or its copy), null if unknown.
  const TriangleMesh* RenderMesh(uint64_t chunk_id) const;
  // Every render mesh in chunk-id order (the concatenation Render is identical to).
  std::vector<const TriangleMesh*> RenderMeshes() const;

 private:
  struct Entry {
    uint64_t version = 0;
    size_t source_triangles = 0;     // of the current version
    size_t lod_source_triangles = 0; // of the version the LOD was built from
    glm::dvec3 lod_source_lo{0.0}, lod_source_hi{0.0};  // box of that version's mesh
    TriangleMesh mesh;               // rendered (LOD or copy)
    glm::dvec3 lo{0.0}, hi{0.0};     // box of `mesh`
  };
  // What Render reads per chunk, contiguous and in chunk-id order (the render order; walking a
  // std::map of thousands of chunks per render cost more than the frustum test itself).
  struct Item {
    uint64_t id;
    glm::dvec3 lo, hi;               // box of the render mesh
    const TriangleMesh* mesh;        // the node's mesh (stable while the node lives)
  };
  explicit CellIdRenderer(const CellIdRendererOptions& o) : options_(o) {}
  // Re-reads the items of the `touched` chunk ids (inserted, replaced or erased) from chunks_,
  // keeping items_ sorted by id; one merge pass, no walk of chunks_.
  void SyncItems(std::vector<uint64_t>* touched);
  CellIdRendererOptions options_;
  std::unordered_map<uint64_t, Entry> chunks_;
  std::vector<Item> items_;          // one per chunk, sorted by id
  size_t lod_builds_ = 0;
};

}  // namespace exo::planning
