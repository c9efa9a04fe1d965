#include "common/mesh.h"

#include "common/status.h"

namespace exo {

void TriangleMesh::Append(const TriangleMesh& o) {
  EXO_CHECK(normals.empty() == o.normals.empty() || positions.empty());
  EXO_CHECK(colors.empty() == o.colors.empty() || positions.empty());
  EXO_CHECK(material.empty() == o.material.empty() || indices.empty());
  const uint32_t base = static_cast<uint32_t>(positions.size());
  positions.insert(positions.end(), o.positions.begin(), o.positions.end());
  normals.insert(normals.end(), o.normals.begin(), o.normals.end());
  colors.insert(colors.end(), o.colors.begin(), o.colors.end());
  for (uint32_t i : o.indices) indices.push_back(base + i);
  material.insert(material.end(), o.material.begin(), o.material.end());
}

}  // namespace exo
