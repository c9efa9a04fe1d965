// The regular scene-cell grid of SPEC §4: cell size q (metres), cell of a point = floor(P/q)
// in the scene-local frame, identified by a packed 64-bit key (21 bits per axis, signed range
// ±2^20 cells: ±314 km at q = 0.3 m). Shared by geometry (per-cell area), planning (cell-id
// buffers), the CPU lumigraph renderer and the Vulkan client (hash lookup per fragment).
#pragma once

#include <cmath>
#include <cstdint>

#include <glm/glm.hpp>

namespace exo {

using CellId = uint64_t;
inline constexpr CellId kNoCell = ~CellId{0};
inline constexpr int kCellAxisBits = 21;
inline constexpr int32_t kCellAxisOffset = 1 << (kCellAxisBits - 1);

inline CellId PackCell(const glm::ivec3& c) {
  const uint64_t mask = (uint64_t{1} << kCellAxisBits) - 1;
  return (static_cast<uint64_t>(c.x + kCellAxisOffset) & mask) |
         ((static_cast<uint64_t>(c.y + kCellAxisOffset) & mask) << kCellAxisBits) |
         ((static_cast<uint64_t>(c.z + kCellAxisOffset) & mask) << (2 * kCellAxisBits));
}
inline glm::ivec3 UnpackCell(CellId id) {
  const uint64_t mask = (uint64_t{1} << kCellAxisBits) - 1;
  return {static_cast<int32_t>(id & mask) - kCellAxisOffset,
          static_cast<int32_t>((id >> kCellAxisBits) & mask) - kCellAxisOffset,
          static_cast<int32_t>((id >> (2 * kCellAxisBits)) & mask) - kCellAxisOffset};
}

struct CellGrid {
  double cell_size_m = 0.5;  // q

  glm::ivec3 CoordOf(const glm::dvec3& p_local) const {
    return {static_cast<int32_t>(std::floor(p_local.x / cell_size_m)),
            static_cast<int32_t>(std::floor(p_local.y / cell_size_m)),
            static_cast<int32_t>(std::floor(p_local.z / cell_size_m))};
  }
  CellId IdOf(const glm::dvec3& p_local) const { return PackCell(CoordOf(p_local)); }
  // Centre p(b_k) of a cell in the local frame.
  glm::dvec3 Centre(CellId id) const {
    return (glm::dvec3(UnpackCell(id)) + 0.5) * cell_size_m;
  }
  // A_cell of SPEC (3.13): the cell's face area, an upper bound for a planar surface in it.
  double CellArea() const { return cell_size_m * cell_size_m; }
};

}  // namespace exo
