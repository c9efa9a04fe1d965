// Per-cell surface area A(b_k) of SPEC §4 (thesis eq. 3.13) from the proxy mesh, maintained
// incrementally as mesh chunks are replaced: UpdateChunk subtracts the chunk's previous
// contribution and adds the new one; only the touched cells change.
//
// Assignment is exact: every triangle is clipped against the cell grid's planes (in double,
// Sutherland-Hodgman against x, then y, then z planes) and each piece's area goes to the cell
// that contains it, so Σ_k A(b_k) equals the mesh area up to rounding, for any cell size.
#pragma once

#include <cstdint>
#include <vector>

#include <absl/container/flat_hash_map.h>
#include <absl/container/flat_hash_set.h>

#include "common/cells.h"
#include "common/lumigraph/model.h"
#include "common/mesh.h"
#include "common/state_io.h"

namespace exo {

class CellAreas {
 public:
  explicit CellAreas(const CellGrid& grid);

  // Replaces the contribution of chunk.id (a chunk seen for the first time just adds).
  void UpdateChunk(const MeshChunk& chunk);
  // Removes a chunk's contribution (unknown ids are ignored).
  void RemoveChunk(uint64_t chunk_id);

  // A(b_k) in m^2; 0 for a cell without surface.
  double Area(CellId cell) const;
  double TotalArea() const;
  size_t num_cells() const { return area_.size(); }
  const CellGrid& grid() const { return grid_; }
  // Cells whose area changed since the last call (for planners that update incrementally).
  std::vector<CellId> TakeChangedCells();
  // Every cell with surface and its area.
  const absl::flat_hash_map<CellId, double>& areas() const { return area_; }

  // The whole bookkeeping, for the server's checkpoint (common/state_io.h).
  void SaveState(StateWriter* w) const;
  absl::Status LoadState(StateReader* r);

  // Area of one mesh per cell (the clipping used above; exposed for tests and tools).
  static absl::flat_hash_map<CellId, double> AreaPerCell(const TriangleMesh& mesh,
                                                         const CellGrid& grid);

 private:
  void Apply(const absl::flat_hash_map<CellId, double>& contrib, double sign);

  CellGrid grid_;
  absl::flat_hash_map<uint64_t, absl::flat_hash_map<CellId, double>> per_chunk_;
  absl::flat_hash_map<CellId, double> area_;
  // Chunks contributing to a cell; the cell is erased when it drops to 0 (no rounding drift).
  absl::flat_hash_map<CellId, int> chunk_count_;
  absl::flat_hash_set<CellId> changed_;
};

}  // namespace exo
