// 3D regions of interest for InpaintFusion (SPEC §7, thesis 4.1): an operator's 2D stroke in a
// camera (intrinsics + pose) becomes the ROI of eq. 4.1 on that camera's depth (r_ROI on screen,
// d_ROI along the normal, RoiFromStroke), and the ROI's pixels are fused into the scene geometry
// as L_ROI labels: a sparse set of labelled voxels in the scene-local frame. Every later frame
// gets its ROI mask by re-projection: a pixel is in the ROI when its back-projected depth falls
// into a labelled voxel (so an occluder in front of the object is not part of it), small gaps
// (depth holes) are closed, and the mask is dilated by a safety margin.
// Pure library: glm + OpenCV imgproc, no service code.
#pragma once

#include <cstdint>
#include <span>
#include <unordered_set>
#include <vector>

#include <glm/glm.hpp>

#include "common/camera.h"
#include "common/image.h"
#include "common/rigid3.h"
#include "common/status.h"
#include "server/inpainting/roi.h"

namespace exo::inpainting {

struct RegionOptions {
  RoiOptions roi;             // r_ROI, d_ROI, 2D dilation of the stroke's ROI (4.1)
  double voxel_m = 0.02;      // size of a label voxel
  int grow_voxels = 1;        // the labelled set is dilated by this many voxels (depth noise)
  // The stroke's ROI may cover at most this fraction of the frame: a region that covers the
  // whole frame leaves nothing to inpaint it from.
  double max_frame_fraction = 0.9;
  int reproject_close_px = 3;   // closing of the re-projected mask (depth holes in the object)
  int reproject_dilate_px = 4;  // safety margin of the re-projected mask
  absl::Status Validate() const;
};

// One marked region: the L_ROI labels (sorted unique voxel keys, scene-local frame).
struct Region3D {
  uint32_t id = 0;
  double voxel_m = 0.02;
  std::vector<uint64_t> voxels;  // PackVoxel keys, sorted, unique
  int stroke_pixels = 0;         // pixels of the stroke's 2D ROI (in the marking camera)
  int labelled_pixels = 0;       // of those, pixels with depth that became labels
  glm::dvec3 centroid_local{0.0};
};

uint64_t PackVoxel(int x, int y, int z);            // 21 bits per axis, +-2^20 voxels
glm::ivec3 UnpackVoxel(uint64_t key);

// The stroke (pixels of `camera`) on `depth_m` (z-depth of the scene as seen from the camera at
// `local_from_cam`, e.g. the proxy rendered there, 0 = nothing) -> labelled voxels.
// Errors (all InvalidArgument unless noted): invalid options or camera, depth of the wrong size,
// an empty stroke, a stroke with non-finite points, a stroke entirely outside the image; a stroke
// on sky / void (no depth within r_ROI of any stroke point: FailedPrecondition); a ROI larger
// than max_frame_fraction of the frame.
absl::StatusOr<Region3D> RegionFromStroke(std::span<const glm::dvec2> stroke_px,
                                          const ImageF& depth_m, const PinholeCamera& camera,
                                          const Rigid3d& local_from_cam,
                                          const RegionOptions& options);

// Lookup structure for the union of several regions (overlaps are fine).
class RegionLabels {
 public:
  RegionLabels() = default;
  explicit RegionLabels(std::span<const Region3D* const> regions);
  bool empty() const { return voxels_.empty(); }
  bool Contains(const glm::dvec3& p_local) const;
  double voxel_m() const { return voxel_m_; }
  // The labelled voxels' bounding box (scene-local metres); false when empty.
  bool Bounds(glm::dvec3* lo, glm::dvec3* hi) const {
    if (empty()) return false;
    *lo = glm::dvec3(lo_) * voxel_m_;
    *hi = glm::dvec3(hi_ + 1) * voxel_m_;
    return true;
  }

 private:
  double voxel_m_ = 0.02;
  std::unordered_set<uint64_t> voxels_;
  glm::ivec3 lo_{0}, hi_{-1};  // bounding box of the voxels: most points are rejected by it
  // One bit per voxel of the bounding box (x fastest) when the box has at most kDenseMaxCells
  // cells (ProjectRegions tests every pixel of the object's box in every frame: a bit test
  // instead of a hash look-up); empty: the hash set alone.
  static constexpr int64_t kDenseMaxCells = int64_t{1} << 25;  // 4 MB of bits
  std::vector<uint64_t> dense_;
  int64_t dense_nx_ = 0, dense_nxy_ = 0;
};

// The ROI mask (1 channel, 255 = ROI) of a frame: its pixels whose depth back-projects into a
// labelled voxel, closed and dilated (RegionOptions). Empty labels or no hit: an all-zero mask.
ImageU8 ProjectRegions(const RegionLabels& labels, const ImageF& depth_m,
                       const PinholeCamera& camera, const Rigid3d& local_from_cam,
                       const RegionOptions& options);

int CountNonZero(const ImageU8& mask);

}  // namespace exo::inpainting
