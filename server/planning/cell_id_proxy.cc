#include "server/planning/cell_id_proxy.h"

#include <cmath>
#include <limits>
#include <unordered_map>

#include "common/cells.h"

namespace exo::planning {

absl::StatusOr<TriangleMesh> ClusterSimplify(const TriangleMesh& mesh, double cluster_m,
                                             ClusterStats* stats) {
  if (!std::isfinite(cluster_m) || !(cluster_m > 0.0))
    return absl::InvalidArgumentError("ClusterSimplify: cluster_m must be finite and > 0");
  if (mesh.indices.size() % 3 != 0)
    return absl::InvalidArgumentError("ClusterSimplify: index count is not a multiple of 3");
  for (uint32_t i : mesh.indices)
    if (i >= mesh.positions.size())
      return absl::InvalidArgumentError("ClusterSimplify: index out of range");
  TriangleMesh out;
  const CellGrid grid{cluster_m};
  std::vector<uint32_t> cluster(mesh.positions.size());
  std::vector<glm::dvec3> sum;
  std::vector<uint32_t> count;
  auto add = [&](size_t v, uint32_t& slot) {
    if (slot == ~0u) {
      slot = uint32_t(sum.size());
      sum.emplace_back(0.0);
      count.push_back(0);
    }
    cluster[v] = slot;
    sum[slot] += glm::dvec3(mesh.positions[v]);
    ++count[slot];
  };
  // A mesh chunk spans few clusters: a dense table over its cluster-coordinate bounding box
  // (no hashing); a hash map for large extents.
  glm::ivec3 lo(std::numeric_limits<int>::max()), hi(std::numeric_limits<int>::min());
  for (const glm::vec3& p : mesh.positions) {
    const glm::ivec3 c = grid.CoordOf(glm::dvec3(p));
    lo = glm::min(lo, c);
    hi = glm::max(hi, c);
  }
  const glm::i64vec3 dim = glm::i64vec3(hi) - glm::i64vec3(lo) + int64_t{1};
  if (!mesh.positions.empty() && dim.x * dim.y * dim.z <= int64_t{1} << 22) {
    std::vector<uint32_t> table(size_t(dim.x * dim.y * dim.z), ~0u);
    for (size_t v = 0; v < mesh.positions.size(); ++v) {
      const glm::i64vec3 c = glm::i64vec3(grid.CoordOf(glm::dvec3(mesh.positions[v]))) -
                             glm::i64vec3(lo);
      add(v, table[size_t(c.x + dim.x * (c.y + dim.y * c.z))]);
    }
  } else {
    std::unordered_map<CellId, uint32_t> table;
    table.reserve(mesh.positions.size() / 2 + 1);
    for (size_t v = 0; v < mesh.positions.size(); ++v)
      add(v, table.try_emplace(grid.IdOf(glm::dvec3(mesh.positions[v])), ~0u).first->second);
  }
  out.positions.resize(sum.size());
  for (size_t c = 0; c < sum.size(); ++c) out.positions[c] = glm::vec3(sum[c] / double(count[c]));
  for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
    const uint32_t a = cluster[mesh.indices[t]], b = cluster[mesh.indices[t + 1]],
                   c = cluster[mesh.indices[t + 2]];
    if (a == b || b == c || a == c) continue;
    out.indices.insert(out.indices.end(), {a, b, c});
  }
  // Drop clusters no triangle uses (keeps the vertex buffer small; indices remapped).
  std::vector<uint32_t> remap(out.positions.size(), ~0u);
  std::vector<glm::vec3> used;
  for (uint32_t& i : out.indices) {
    if (remap[i] == ~0u) {
      remap[i] = uint32_t(used.size());
      used.push_back(out.positions[i]);
    }
    i = remap[i];
  }
  out.positions = std::move(used);
  if (stats != nullptr) {
    stats->triangles_in = mesh.num_triangles();
    stats->triangles_out = out.num_triangles();
  }
  return out;
}

}  // namespace exo::planning
