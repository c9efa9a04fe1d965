// Marked regions of interest of the running server (InpaintFusion, SPEC §7): the operator's
// MarkRegion / ListRegions / ClearRegion calls land here, the inpainting stage reads immutable
// snapshots of the labels, the checkpoint stores them. Marking renders the published proxy mesh
// from the stroke's camera (the scene geometry as the clients see it) and turns the stroke into
// L_ROI voxel labels (server/inpainting/region_labels.h). Thread-safe. No gRPC here.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "common/status.h"
#include "proto/exoview.pb.h"
#include "server/inpainting/region_labels.h"
#include "server/service/model_store.h"

namespace exo {

struct RegionRegistryOptions {
  inpainting::RegionOptions region;  // r_ROI / d_ROI defaults, voxel size, growth, margins
  size_t max_regions = 32;
  size_t max_stroke_points = 4096;
  absl::Status Validate() const;
};

// An immutable view of the marked regions at one generation.
struct RegionSet {
  uint64_t generation = 0;  // increases with every mark / clear
  std::vector<inpainting::Region3D> regions;
  inpainting::RegionLabels labels;
  std::vector<uint32_t> ids() const;
};

class RegionRegistry {
 public:
  RegionRegistry(const RegionRegistryOptions& options, ModelStore* store);

  // The stroke in `camera` at `local_from_cam` (scene-local). radius_px / depth_tol_m <= 0:
  // defaults. Errors: see exoview.proto MarkRegion.
  absl::StatusOr<v1::RegionInfo> Mark(std::span<const glm::dvec2> stroke,
                                      const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                      double radius_px, double depth_tol_m,
                                      const std::string& label, const std::string& who);
  std::vector<v1::RegionInfo> List() const;
  // id 0 = every region. Returns how many were removed; NOT_FOUND for an unknown id.
  absl::StatusOr<uint32_t> Clear(uint32_t id);
  std::shared_ptr<const RegionSet> Get() const;
  uint64_t generation() const;

  void ToCheckpoint(v1::Checkpoint* c) const;
  absl::Status Restore(const v1::Checkpoint& c);

 private:
  void PublishLocked();  // rebuilds set_ from infos_/regions_
  const RegionRegistryOptions options_;
  ModelStore* store_;
  mutable std::mutex mu_;
  std::vector<v1::RegionInfo> infos_;          // parallel to regions_
  std::vector<inpainting::Region3D> regions_;
  uint32_t next_id_ = 1;
  std::shared_ptr<const RegionSet> set_ = std::make_shared<RegionSet>();
};

}  // namespace exo
