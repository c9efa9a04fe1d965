// Small scenes for the control tests: quads, a room with a wall and a door.
#pragma once

#include <glm/glm.hpp>

#include "common/mesh.h"

namespace exo::control::testing {

// A quad a, b, c, d (counter-clockwise seen from the front) as two triangles.
inline void AddQuad(TriangleMesh* m, glm::vec3 a, glm::vec3 b, glm::vec3 c, glm::vec3 d) {
  const uint32_t base = static_cast<uint32_t>(m->positions.size());
  m->positions.insert(m->positions.end(), {a, b, c, d});
  m->indices.insert(m->indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
}

}  // namespace exo::control::testing
