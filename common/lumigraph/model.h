// The lumigraph model, the data both ends hold: the server's store (planning output) and each
// client's local copy (built from deltas). Proxy geometry as versioned mesh chunks, a bounded set
// of stored views with pose, intrinsics and exposure, and per-cell view references (SPEC §4, §6).
// All geometry is in the scene-local frame of `origin` (see rigid3.h).
#pragma once

#include <cstdint>
#include <map>
#include <unordered_map>
#include <vector>

#include "common/camera.h"
#include "common/cells.h"
#include "common/image.h"
#include "common/mesh.h"
#include "common/rigid3.h"

namespace exo {

using ViewId = uint32_t;

struct StoredView {
  ViewId id = 0;
  PinholeCamera camera;
  Rigid3d local_from_cam;   // pose in the scene-local frame
  ImageU8 color;            // RGB8 sRGB, camera.width x camera.height
  ImageF depth_m;           // z-depth in metres (0 = invalid), same size as colour
  float exposure = 1.0f;    // E_i: linear-intensity factor applied when blending (SPEC §5)
  // InpaintFusion (SPEC §7): an inpainted keyframe (colour and depth filled inside the regions
  // of interest). `labels`: 1 channel, colour size, 255 = inpainted (L_IP, inside the ROI),
  // 0 = observed (L_O); empty on an observed view. Renderers: inside an inpainted view's ROI only
  // inpainted views contribute, elsewhere only observed views (never referenced by cells).
  bool inpainted = false;
  ImageU8 labels;
  size_t bytes() const {
    return color.bytes() + depth_m.bytes() + labels.bytes() + sizeof(*this);
  }
};

struct MeshChunk {
  uint64_t id = 0;        // geometry block key
  uint64_t version = 0;   // increases whenever the chunk is re-extracted
  TriangleMesh mesh;
};

struct LumigraphModel {
  LocalOrigin origin;
  CellGrid grid;
  std::map<ViewId, StoredView> views;
  std::unordered_map<CellId, std::vector<ViewId>> cell_refs;  // R(b_k), |R| <= R_max
  // Coverage τ(b_k)/τ_max of the server's planner in whole percent (0..100; exoview.v1
  // CellCoverage), for display; empty when the model's source did not publish it.
  std::unordered_map<CellId, uint8_t> cell_coverage;
  std::map<uint64_t, MeshChunk> chunks;
  uint64_t version = 0;   // model version (publisher deltas)

  // Concatenation of every chunk (for renderers that want one mesh).
  TriangleMesh ProxyMesh() const {
    TriangleMesh m;
    for (const auto& [id, c] : chunks) m.Append(c.mesh);
    return m;
  }
};

}  // namespace exo
