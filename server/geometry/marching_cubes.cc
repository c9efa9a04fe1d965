#include "server/geometry/marching_cubes.h"

#include <glm/glm.hpp>

#include "common/status.h"

namespace exo::mc {
namespace {

// Faces as four corners in cyclic order, with their outward normals.
struct Face {
  std::array<int, 4> corners;
  glm::dvec3 normal;
};
constexpr std::array<Face, 6> kFaces = {{
    {{0, 1, 2, 3}, {0, 0, -1}},
    {{4, 5, 6, 7}, {0, 0, 1}},
    {{0, 1, 5, 4}, {0, -1, 0}},
    {{3, 2, 6, 7}, {0, 1, 0}},
    {{0, 3, 7, 4}, {-1, 0, 0}},
    {{1, 2, 6, 5}, {1, 0, 0}},
}};

int EdgeOf(int a, int b) {
  for (int e = 0; e < 12; ++e) {
    const auto& ec = kEdgeCorners[e];
    if ((ec[0] == a && ec[1] == b) || (ec[0] == b && ec[1] == a)) return e;
  }
  EXO_CHECK(false);
  return -1;
}

glm::dvec3 Corner(int c) {
  return {double(kCornerOffset[c][0]), double(kCornerOffset[c][1]), double(kCornerOffset[c][2])};
}
glm::dvec3 EdgeMid(int e) {
  return 0.5 * (Corner(kEdgeCorners[e][0]) + Corner(kEdgeCorners[e][1]));
}

CaseTable Build() {
  CaseTable t;
  for (int c = 0; c < 256; ++c) {
    auto inside = [c](int corner) { return (c >> corner) & 1; };
    uint16_t mask = 0;
    for (int e = 0; e < 12; ++e)
      if (inside(kEdgeCorners[e][0]) != inside(kEdgeCorners[e][1])) mask |= uint16_t(1u << e);
    t.edge_mask[c] = mask;

    // Directed contour segments on the faces: next[e] = the edge the contour goes to from e.
    std::array<int, 12> next;
    next.fill(-1);
    auto add_segment = [&](int e_a, int e_b, const glm::dvec3& n, const glm::dvec3& in_minus_out) {
      const glm::dvec3 a = EdgeMid(e_a), b = EdgeMid(e_b);
      // Orientation rule: cross(b - a, n) points towards the inside corners.
      if (glm::dot(glm::cross(b - a, n), in_minus_out) < 0) std::swap(e_a, e_b);
      EXO_CHECK(next[e_a] == -1);
      next[e_a] = e_b;
    };
    for (const Face& f : kFaces) {
      int n_in = 0;
      for (int k = 0; k < 4; ++k) n_in += inside(f.corners[k]);
      if (n_in == 0 || n_in == 4) continue;
      const bool ambiguous = n_in == 2 && inside(f.corners[0]) == inside(f.corners[2]);
      if (ambiguous) {
        // Separate the inside corners: cut each one off with its own segment.
        for (int k = 0; k < 4; ++k) {
          const int ci = f.corners[k];
          if (!inside(ci)) continue;
          const int cp = f.corners[(k + 3) % 4], cn = f.corners[(k + 1) % 4];
          add_segment(EdgeOf(cp, ci), EdgeOf(ci, cn), f.normal,
                      Corner(ci) - 0.5 * (Corner(cp) + Corner(cn)));
        }
      } else {
        int cut[2], m = 0;
        glm::dvec3 in_c(0.0), out_c(0.0);
        for (int k = 0; k < 4; ++k) {
          const int a = f.corners[k], b = f.corners[(k + 1) % 4];
          if (inside(a) != inside(b)) cut[m++] = EdgeOf(a, b);
          (inside(a) ? in_c : out_c) += Corner(a);
        }
        EXO_CHECK(m == 2);
        add_segment(cut[0], cut[1], f.normal, in_c / double(n_in) - out_c / double(4 - n_in));
      }
    }
    // Follow the loops and fan-triangulate each.
    std::array<bool, 12> used{};
    int n = 0;
    for (int e0 = 0; e0 < 12; ++e0) {
      if (!((mask >> e0) & 1) || used[e0]) continue;
      int loop[12], len = 0;
      for (int e = e0; !used[e]; e = next[e]) {
        EXO_CHECK(next[e] >= 0);
        used[e] = true;
        loop[len++] = e;
      }
      for (int k = 1; k + 1 < len; ++k) {
        t.tris[c][3 * n + 0] = int8_t(loop[0]);
        t.tris[c][3 * n + 1] = int8_t(loop[k]);
        t.tris[c][3 * n + 2] = int8_t(loop[k + 1]);
        ++n;
      }
    }
    EXO_CHECK(n <= 12);
    t.num_tris[c] = uint8_t(n);
    t.tris[c][3 * n] = -1;
  }
  return t;
}

}  // namespace

const CaseTable& Cases() {
  static const CaseTable table = Build();
  return table;
}

}  // namespace exo::mc
