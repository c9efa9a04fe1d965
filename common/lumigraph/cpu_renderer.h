// CPU reference lumigraph renderer (SPEC §6): for each pixel of a novel view it rasterizes the
// proxy mesh (common/raster) for the surface point and its cell, takes the cell's references
// R(b_k) from LumigraphModel::cell_refs, evaluates validity and weights (blend_math.h), keeps the
// best n = 3 and blends their colours with exposure in linear intensity. This is the oracle the
// Vulkan client is golden-tested against, and the renderer of the evaluation benchmarks.
// Output is always defined: pixels with no surface, an empty reference set or no valid view get
// the background colour and coverage 0 (never NaN).
#pragma once

#include <memory>
#include <unordered_map>
#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/lumigraph/blend_math.h"
#include "common/lumigraph/model.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo {

struct CpuRenderOptions {
  blend::BlendOptions blend;
  int num_threads = 2;
  bool cull_backfaces = false;   // proxy back faces (TSDF meshes are two-sided in practice)
  bool debug_weights = false;    // fill weight_sum and num_views
  absl::Status Validate() const;
};

struct CpuRenderOutput {
  ImageU8 color;       // RGB8 sRGB
  ImageU8 coverage;    // 1 channel: 255 = blended from >= 1 valid view, 0 = background
  ImageF weight_sum;   // debug: Σ w_i of the selected views (0 where uncovered)
  ImageU8 num_views;   // debug: number of views blended per pixel
  size_t covered_pixels = 0;
  size_t surface_pixels = 0;  // pixels where the proxy was hit
  double raster_ms = 0.0, blend_ms = 0.0;
};

class CpuLumigraphRenderer {
 public:
  // Snapshots what rendering needs from `model` (proxy mesh, per-view blend parameters,
  // references resolved to view indices). The model's images are referenced, not copied: the
  // model must outlive the renderer and not change while it is used (Create again after edits).
  static absl::StatusOr<std::unique_ptr<CpuLumigraphRenderer>> Create(
      const LumigraphModel& model, const CpuRenderOptions& options);

  // Renders the novel view `camera` at `local_from_cam` (scene-local frame).
  absl::StatusOr<CpuRenderOutput> Render(const PinholeCamera& camera,
                                         const Rigid3d& local_from_cam) const;

  size_t num_views() const { return views_.size(); }

 private:
  struct ViewData {
    blend::BlendView params;
    const ImageU8* color = nullptr;
    const ImageF* depth = nullptr;
  };
  CpuLumigraphRenderer() = default;

  CpuRenderOptions options_;
  CellGrid grid_;
  TriangleMesh mesh_;
  std::vector<ViewData> views_;
  std::unordered_map<CellId, std::vector<int>> refs_;  // cell -> indices into views_
};

// Converts a stored view into the fragment-stage parameters of blend_math.h.
blend::BlendView MakeBlendView(const StoredView& view);

}  // namespace exo
