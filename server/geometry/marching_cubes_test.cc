#include "server/geometry/marching_cubes.h"

#include <map>
#include <set>
#include <utility>

#include <glm/glm.hpp>
#include <gtest/gtest.h>

namespace exo::mc {
namespace {

glm::dvec3 EdgeMid(int e) {
  const auto& a = kCornerOffset[kEdgeCorners[e][0]];
  const auto& b = kCornerOffset[kEdgeCorners[e][1]];
  return {0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2])};
}

// Two edge midpoints lie on a common cube face iff they share a coordinate equal to 0 or 1.
bool OnCommonFace(int e0, int e1) {
  const glm::dvec3 a = EdgeMid(e0), b = EdgeMid(e1);
  for (int i = 0; i < 3; ++i)
    if (a[i] == b[i] && (a[i] == 0.0 || a[i] == 1.0)) return true;
  return false;
}

TEST(MarchingCubesTable, EdgeListIsLowerToUpperAlongOneAxis) {
  for (int e = 0; e < 12; ++e) {
    const auto& a = kCornerOffset[kEdgeCorners[e][0]];
    const auto& b = kCornerOffset[kEdgeCorners[e][1]];
    int diffs = 0;
    for (int i = 0; i < 3; ++i) {
      EXPECT_LE(a[i], b[i]);
      diffs += a[i] != b[i];
      if (a[i] != b[i]) {
        EXPECT_EQ(i, kEdgeAxis[e]);
      }
    }
    EXPECT_EQ(diffs, 1);
  }
}

TEST(MarchingCubesTable, KnownCasesMatchLorensenCline) {
  const CaseTable& t = Cases();
  EXPECT_EQ(t.num_tris[0], 0);
  EXPECT_EQ(t.num_tris[255], 0);
  EXPECT_EQ(t.edge_mask[1], 0x109);   // Bourke's edgeTable[1]
  EXPECT_EQ(t.edge_mask[3], 0x30a);   // edgeTable[3]
  EXPECT_EQ(t.edge_mask[0x0f], 0xf00);
  EXPECT_EQ(t.num_tris[1], 1);        // one corner
  EXPECT_EQ(t.num_tris[3], 2);        // one edge
  EXPECT_EQ(t.num_tris[7], 3);        // three corners of a face
  EXPECT_EQ(t.num_tris[0x0f], 2);     // a whole face: a quad
  EXPECT_EQ(t.num_tris[0x41], 2);     // corners 0 and 6: two separate triangles
}

// Every case forms a surface patch whose boundary lies on the cube faces: each triangle edge
// is either interior (used once in each direction) or a contour segment on a face. Cut edges
// are all used, uncut ones never. Catches a broken loop walk or inconsistent winding.
TEST(MarchingCubesTable, EveryCaseIsAnOrientedPatchBoundedByFaceSegments) {
  const CaseTable& t = Cases();
  for (int c = 1; c < 255; ++c) {
    std::map<std::pair<int, int>, int> directed;
    std::set<int> used;
    for (int k = 0; t.tris[c][k] >= 0; k += 3) {
      for (int j = 0; j < 3; ++j) {
        const int a = t.tris[c][k + j], b = t.tris[c][k + (j + 1) % 3];
        ++directed[{a, b}];
        used.insert(a);
      }
    }
    for (int e = 0; e < 12; ++e) EXPECT_EQ(used.count(e) == 1, ((t.edge_mask[c] >> e) & 1) == 1) << c;
    for (const auto& [ab, n] : directed) {
      EXPECT_EQ(n, 1) << "case " << c << " repeats a directed edge";
      if (!directed.count({ab.second, ab.first})) {
        EXPECT_TRUE(OnCommonFace(ab.first, ab.second)) << "case " << c << " open inside the cube";
      }
    }
  }
}

// Normals (winding) point from inside (negative) to outside corners.
TEST(MarchingCubesTable, WindingPointsOutward) {
  const CaseTable& t = Cases();
  for (int c = 1; c < 255; ++c) {
    glm::dvec3 in(0.0), out(0.0);
    int ni = 0;
    for (int k = 0; k < 8; ++k) {
      const glm::dvec3 p(kCornerOffset[k][0], kCornerOffset[k][1], kCornerOffset[k][2]);
      if ((c >> k) & 1) in += p, ++ni;
      else out += p;
    }
    const glm::dvec3 in_to_out = out / double(8 - ni) - in / double(ni);
    glm::dvec3 area(0.0);
    for (int k = 0; t.tris[c][k] >= 0; k += 3) {
      const glm::dvec3 a = EdgeMid(t.tris[c][k]), b = EdgeMid(t.tris[c][k + 1]),
                       d = EdgeMid(t.tris[c][k + 2]);
      area += glm::cross(b - a, d - a);
    }
    // Symmetric cases (e.g. two opposite corners) have in_to_out == 0: skip those.
    if (glm::length(in_to_out) > 1e-9 && glm::length(area) > 1e-9) {
      EXPECT_GT(glm::dot(area, in_to_out), 0.0) << "case " << c;
    }
  }
}

}  // namespace
}  // namespace exo::mc
