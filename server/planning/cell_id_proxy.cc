#include "server/planning/cell_id_proxy.h"

#include <cmath>
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
  std::unordered_map<CellId, uint32_t> cluster_of_key;
  cluster_of_key.reserve(mesh.positions.size() / 2 + 1);
  std::vector<uint32_t> cluster(mesh.positions.size());
  std::vector<glm::dvec3> sum;
  std::vector<uint32_t> count;
  for (size_t v = 0; v < mesh.positions.size(); ++v) {
    const glm::dvec3 p(mesh.positions[v]);
    const CellId key = grid.IdOf(p);
    auto [it, inserted] = cluster_of_key.try_emplace(key, uint32_t(sum.size()));
    if (inserted) {
      sum.emplace_back(0.0);
      count.push_back(0);
    }
    cluster[v] = it->second;
    sum[it->second] += p;
    ++count[it->second];
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
