// Occupancy view of the modelled space for safe flight (SPEC §8): a dense voxel grid over the
// flight zones whose cells are unknown, known free or occupied. Evidence comes from
//   - the TSDF proxy (server/geometry/tsdf_volume.h): observed voxels behind or at the surface
//     are occupied, observed voxels in front of it are free (only inside allocated blocks: the
//     TSDF stores nothing farther than its truncation band from a surface),
//   - depth images with their poses (stored views, drone frames): the space along each depth ray
//     up to the hit is free, the hit is occupied (space carving; what the TSDF does not keep),
//   - triangle meshes (the proxy as clients receive it): cells the triangles cross are occupied.
// Occupied is sticky: later free evidence never clears it (a conservative map for flying).
// Known free cells whose centre is farther than radius + one cell from every occupied (and, by
// default, unknown) cell centre are "clear": the drone's sphere of that radius around a clear
// cell centre touches only known free space, even when a surface hides in a neighbouring cell
// that grazing rays marked free. Coordinates are one frame chosen by the caller (the control
// frame).
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/mesh.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo {
class TsdfVolume;
}

namespace exo::control {

enum class Occupancy : uint8_t { kUnknown = 0, kFree = 1, kOccupied = 2 };

struct OccupancyOptions {
  glm::dvec3 min{0.0}, max{0.0};  // grid bounds (the union of the flight zones)
  double cell_m = 0.1;
  double drone_radius_m = 0.2;  // inflation radius
  bool inflate_unknown = true;  // the drone's sphere keeps out of unknown space too
  size_t max_cells = size_t{64} << 20;
  absl::Status Validate() const;
};

class OccupancyGrid {
 public:
  // Errors: invalid options (empty bounds, non-positive cell, too many cells).
  static absl::StatusOr<OccupancyGrid> Create(const OccupancyOptions& options);

  const OccupancyOptions& options() const { return options_; }
  glm::ivec3 dims() const { return dims_; }
  size_t num_cells() const { return cells_.size(); }
  size_t CountState(Occupancy s) const;
  bool AnyKnown() const { return known_ > 0; }

  bool InGrid(const glm::ivec3& c) const {
    return c.x >= 0 && c.y >= 0 && c.z >= 0 && c.x < dims_.x && c.y < dims_.y && c.z < dims_.z;
  }
  glm::ivec3 CellOf(const glm::dvec3& p) const;
  glm::dvec3 CentreOf(const glm::ivec3& c) const;
  size_t Index(const glm::ivec3& c) const {
    return (static_cast<size_t>(c.z) * dims_.y + c.y) * dims_.x + c.x;
  }
  glm::ivec3 CellOfIndex(size_t i) const;
  Occupancy At(const glm::ivec3& c) const {
    return InGrid(c) ? Occupancy(cells_[Index(c)]) : Occupancy::kUnknown;
  }
  Occupancy At(const glm::dvec3& p) const { return At(CellOf(p)); }
  void Set(const glm::ivec3& c, Occupancy s);  // occupied stays occupied
  // The cells whose centres lie within `radius_m` of p (and p's own cell) become known free.
  void MarkSphereFree(const glm::dvec3& p, double radius_m);

  // Space carving from one depth image (z-depth metres, 0/NaN = no measurement) seen from
  // `frame_from_cam`. Every `stride`-th pixel in both directions; measurements beyond
  // `max_range_m` carve free space up to max_range_m and mark nothing occupied.
  // `no_return_is_free`: a pixel without a measurement carves free space up to max_range_m as
  // well (a renderer's sky: nothing within range; not for real sensors, where a missing depth
  // may be a dark or shiny surface).
  void CarveDepth(const ImageF& depth_m, const PinholeCamera& camera, const Rigid3d& frame_from_cam,
                  int stride = 4, double max_range_m = 5.0, bool no_return_is_free = false);
  // Which pixels without a measurement are sky, for a real sensor (session 16): a missing
  // depth is taken as "nothing within range" only where the ray points above
  // `min_elevation_rad` (`up`: the scene's up; default 0.1 rad below the horizon, where from
  // an altitude the ground lies beyond any sensor's range and the renderer's sky carves the
  // air at the drone's own height; 0.05 above cost the village's drone 4 points of coverage
  // at 120 s, 3 seeds), every pixel above it in its
  // image column has no measurement either (the sky touches the image's top edge: a dark
  // window or a black car under something measured is not sky; the camera is assumed to have
  // no roll, as a gimbal's), and, with `color` (linear RGB, the depth image's size), the pixel
  // is bright and blue (b >= min_blue, b >= r + blue_margin, b >= g: a black or grey surface
  // is not). Still a guess: a bright blue surface filling the top of the view would be carved.
  struct SkyRule {
    glm::dvec3 up{0.0, 0.0, 1.0};
    double min_elevation_rad = -0.1;
    const ImageF* color = nullptr;
    double min_blue = 0.25, blue_margin = 0.08;
  };
  // As above; pixels without a measurement carve free space up to max_range_m where `sky`
  // says they are sky.
  void CarveDepth(const ImageF& depth_m, const PinholeCamera& camera, const Rigid3d& frame_from_cam,
                  int stride, double max_range_m, const SkyRule& sky);
  // SkyRule's colour from a camera's sRGB8 image of any size (a stored view's decoded JPEG,
  // often larger than its depth): linear RGB at width x height, the nearest pixel's.
  static ImageF SkyColour(const ImageU8& srgb, int width, int height);
  // The TSDF's evidence; `frame_from_local` maps the TSDF's local frame to the grid's frame.
  void MarkFromTsdf(const TsdfVolume& volume, const glm::dvec3& frame_from_local_offset);
  // Cells crossed by the triangles are occupied.
  void MarkMeshOccupied(const TriangleMesh& mesh, const glm::dvec3& frame_from_local_offset);

  // Clear = known free and no occupied (unknown when inflate_unknown) cell centre within the
  // drone radius. Recomputed lazily after changes.
  bool IsClear(const glm::ivec3& c) const;
  bool IsClear(const glm::dvec3& p) const { return IsClear(CellOf(p)); }
  // Every cell's clear flag (the recomputed mask).
  const std::vector<uint8_t>& ClearMask() const;

 private:
  // CarveDepth's loop: a pixel without a measurement carves free space where is_sky(x, y,
  // unit ray direction) says so.
  template <typename IsSky>
  void CarveDepthWhere(const ImageF& depth_m, const PinholeCamera& camera,
                       const Rigid3d& frame_from_cam, int stride, double max_range_m,
                       const IsSky& is_sky);
  explicit OccupancyGrid(const OccupancyOptions& options);
  void Recompute() const;

  OccupancyOptions options_;
  glm::ivec3 dims_{0};
  std::vector<uint8_t> cells_;
  size_t known_ = 0;
  mutable std::vector<uint8_t> clear_;
  mutable bool dirty_ = true;
};

}  // namespace exo::control
