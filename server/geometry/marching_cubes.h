// Marching-cubes case tables (Lorensen & Cline, "Marching Cubes: A High Resolution 3D Surface
// Construction Algorithm", SIGGRAPH 1987), with the corner and edge numbering of Paul Bourke's
// widely used tables ("Polygonising a scalar field", 1994):
//   corners 0:(0,0,0) 1:(1,0,0) 2:(1,1,0) 3:(0,1,0) 4:(0,0,1) 5:(1,0,1) 6:(1,1,1) 7:(0,1,1)
//   edges   0:0-1 1:1-2 2:2-3 3:3-0 4:4-5 5:5-6 6:6-7 7:7-4 8:0-4 9:1-5 10:2-6 11:3-7
// and cube index bit i set when corner i is INSIDE (sdf < 0).
//
// The triangle table is not copied from a listing: it is generated once at start-up by walking
// the iso-contour over the six cube faces. Ambiguous faces (two diagonal corners inside, two
// outside) are always resolved the same way, by separating the inside corners. Because that
// rule depends only on the face's four corner signs, two cubes sharing a face produce the same
// contour segments on it, so the extracted surface is closed (no cracks, no holes from
// ambiguous faces, the known weakness of the original 1987 table). Triangles wind
// counter-clockwise seen from outside (their normal points towards positive sdf).
#pragma once

#include <array>
#include <cstdint>

namespace exo::mc {

inline constexpr std::array<std::array<int, 3>, 8> kCornerOffset = {{
    {0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}}};
inline constexpr std::array<std::array<int, 2>, 12> kEdgeCorners = {{
    {0, 1}, {1, 2}, {3, 2}, {0, 3}, {4, 5}, {5, 6}, {7, 6}, {4, 7}, {0, 4}, {1, 5}, {2, 6}, {3, 7}}};
// Every edge listed as (lower corner, upper corner); the axis it runs along (0 x, 1 y, 2 z).
inline constexpr std::array<int, 12> kEdgeAxis = {0, 1, 0, 1, 0, 1, 0, 1, 2, 2, 2, 2};

struct CaseTable {
  // edge_mask[c]: bit e set when edge e is cut in case c (Bourke's edgeTable).
  std::array<uint16_t, 256> edge_mask{};
  // tris[c]: up to 12 triangles as edge ids, terminated by -1 (Bourke's triTable, wider).
  std::array<std::array<int8_t, 37>, 256> tris{};
  std::array<uint8_t, 256> num_tris{};
};

// The generated table (built on first use, thread-safe).
const CaseTable& Cases();

}  // namespace exo::mc
