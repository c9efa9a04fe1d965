#include "server/geometry/mesh_lod.h"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include <meshoptimizer.h>

namespace exo::geometry {

absl::Status MeshLodOptions::Validate() const {
  if (!(max_error_m >= 0.0) || !std::isfinite(max_error_m))
    return absl::InvalidArgumentError("mesh LOD max_error_m must be finite and >= 0");
  return absl::OkStatus();
}

namespace {

// Edges (vertex pairs, smaller id first) used by a number of triangles other than two, with that
// number, sorted.
std::vector<std::pair<std::pair<uint32_t, uint32_t>, size_t>> OpenEdges(
    const std::vector<uint32_t>& idx) {
  std::vector<std::pair<uint32_t, uint32_t>> e;
  e.reserve(idx.size());
  for (size_t t = 0; t + 2 < idx.size(); t += 3)
    for (int j = 0; j < 3; ++j) {
      const uint32_t a = idx[t + j], b = idx[t + (j + 1) % 3];
      e.emplace_back(std::min(a, b), std::max(a, b));
    }
  std::sort(e.begin(), e.end());
  std::vector<std::pair<std::pair<uint32_t, uint32_t>, size_t>> open;
  for (size_t i = 0; i < e.size();) {
    size_t j = i;
    while (j < e.size() && e[j] == e[i]) ++j;
    if (j - i != 2) open.push_back({e[i], j - i});
    i = j;
  }
  return open;
}

}  // namespace

TriangleMesh SimplifyMesh(const TriangleMesh& mesh, const MeshLodOptions& options,
                          MeshLodStats* stats) {
  if (stats) *stats = {mesh.num_triangles(), mesh.num_triangles(), 0.0};
  if (!(options.max_error_m > 0.0) || mesh.num_triangles() < 2) return mesh;
  const size_t nv = mesh.positions.size();
  for (uint32_t i : mesh.indices)
    if (i >= nv) return mesh;
  // meshoptimizer takes the error relative to the mesh's extent.
  const float scale = meshopt_simplifyScale(&mesh.positions[0].x, nv, sizeof(glm::vec3));
  if (!(scale > 0.0f)) return mesh;
  // Marching cubes can place two vertices at one position (a zero crossing exactly on a grid
  // corner ends two cut edges there) and so emit zero-area triangles. Weld equal positions and
  // drop those triangles first: meshoptimizer would otherwise treat the pair as an attribute
  // seam, not as the chunk's locked border, and could collapse an edge of the seam.
  // Positions compared as values: -0 and +0 are one position (x + 0 turns -0 into +0).
  std::vector<glm::vec3> pos(mesh.positions);
  for (glm::vec3& p : pos) p += glm::vec3(0.0f);
  std::vector<uint32_t> weld(nv);  // input vertex -> welded vertex (UINT32_MAX: unused)
  const size_t nw = meshopt_generateVertexRemap(weld.data(), mesh.indices.data(),
                                                mesh.indices.size(), &pos[0].x, nv,
                                                sizeof(glm::vec3));
  std::vector<uint32_t> source(nw);  // welded vertex -> its first input vertex
  for (uint32_t i = static_cast<uint32_t>(nv); i-- > 0;)
    if (weld[i] != UINT32_MAX) source[weld[i]] = i;
  std::vector<glm::vec3> welded(nw);
  for (size_t w = 0; w < nw; ++w) welded[w] = pos[source[w]];
  std::vector<uint32_t> in;
  in.reserve(mesh.indices.size());
  for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
    const uint32_t a = weld[mesh.indices[t]], b = weld[mesh.indices[t + 1]],
                   c = weld[mesh.indices[t + 2]];
    if (a == b || b == c || a == c) continue;
    in.insert(in.end(), {a, b, c});
  }
  std::vector<uint32_t> out(in.size());
  float rel_error = 0.0f;
  const size_t n = meshopt_simplify(out.data(), in.data(), in.size(), &welded[0].x, nw,
                                    sizeof(glm::vec3), /*target_index_count=*/0,
                                    static_cast<float>(options.max_error_m) / scale,
                                    meshopt_SimplifyLockBorder, &rel_error);
  out.resize(n);
  // The guarantee the clients rely on (no crack between chunks) is checked, not assumed: the
  // edges not shared by exactly two triangles (the chunk's open boundary, and any non-manifold
  // edge) must be the same before and after. Near-degenerate marching-cubes output (a surface
  // lying exactly on a voxel plane) can break meshoptimizer's border classification; such a
  // chunk is published at full resolution.
  if (OpenEdges(out) != OpenEdges(in)) {
    if (stats) stats->fallback = true;
    return mesh;
  }
  // Keep only the vertices the simplified triangles use, in first-use order (the compact wire
  // encoding delta-codes the indices, so first-use order keeps them small).
  std::vector<uint32_t> remap(nw, UINT32_MAX);
  TriangleMesh r;
  r.indices.reserve(n);
  for (uint32_t w : out) {
    if (remap[w] == UINT32_MAX) {
      const uint32_t i = source[w];
      remap[w] = static_cast<uint32_t>(r.positions.size());
      r.positions.push_back(mesh.positions[i]);
      if (mesh.normals.size() == nv) r.normals.push_back(mesh.normals[i]);
      if (mesh.colors.size() == nv) r.colors.push_back(mesh.colors[i]);
    }
    r.indices.push_back(remap[w]);
  }
  if (stats) {
    stats->triangles_out = r.num_triangles();
    stats->error_m = static_cast<double>(rel_error) * scale;
  }
  return r;
}

}  // namespace exo::geometry
