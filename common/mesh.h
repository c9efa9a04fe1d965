// Triangle meshes in scene-local float coordinates (see LocalOrigin in rigid3.h).
#pragma once

#include <cstdint>
#include <vector>

#include <glm/glm.hpp>

namespace exo {

struct TriangleMesh {
  std::vector<glm::vec3> positions;
  std::vector<glm::vec3> normals;    // optional, per vertex
  std::vector<glm::vec3> colors;     // optional, per vertex, linear [0,1]
  std::vector<uint32_t> indices;     // 3 per triangle
  std::vector<uint32_t> material;    // optional, per triangle

  size_t num_triangles() const { return indices.size() / 3; }
  size_t num_vertices() const { return positions.size(); }
  bool empty() const { return indices.empty(); }
  // Appends another mesh (indices offset). Optional attributes must be present in both or none.
  void Append(const TriangleMesh& other);
  size_t bytes() const {
    return positions.size() * sizeof(glm::vec3) * (1 + !normals.empty() + !colors.empty()) +
           indices.size() * sizeof(uint32_t) + material.size() * sizeof(uint32_t);
  }
};

}  // namespace exo
