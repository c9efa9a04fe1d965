#include "server/inpainting/region_labels.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

namespace exo::inpainting {
namespace {

constexpr int kBits = 21;
constexpr int64_t kOffset = int64_t{1} << (kBits - 1);
constexpr uint64_t kMask = (uint64_t{1} << kBits) - 1;

bool ValidDepth(float z) { return std::isfinite(z) && z > 0.f; }

glm::ivec3 VoxelOf(const glm::dvec3& p, double voxel_m) {
  return {static_cast<int>(std::floor(p.x / voxel_m)), static_cast<int>(std::floor(p.y / voxel_m)),
          static_cast<int>(std::floor(p.z / voxel_m))};
}

bool InRange(const glm::ivec3& v) {
  for (int i = 0; i < 3; ++i)
    if (v[i] <= -kOffset || v[i] >= kOffset - 1) return false;
  return true;
}

}  // namespace

absl::Status RegionOptions::Validate() const {
  EXO_RETURN_IF_ERROR(roi.Validate());
  if (!(voxel_m >= 0.001 && voxel_m <= 1.0))
    return absl::InvalidArgumentError("RegionOptions.voxel_m must be in [0.001, 1] m");
  if (grow_voxels < 0 || grow_voxels > 8)
    return absl::InvalidArgumentError("RegionOptions.grow_voxels must be in [0, 8]");
  if (!(max_frame_fraction > 0.0 && max_frame_fraction <= 1.0))
    return absl::InvalidArgumentError("RegionOptions.max_frame_fraction must be in (0, 1]");
  if (reproject_close_px < 0 || reproject_close_px > 64 || reproject_dilate_px < 0 ||
      reproject_dilate_px > 64)
    return absl::InvalidArgumentError("RegionOptions.reproject_*_px must be in [0, 64]");
  return absl::OkStatus();
}

uint64_t PackVoxel(int x, int y, int z) {
  return ((static_cast<uint64_t>(x + kOffset) & kMask) << (2 * kBits)) |
         ((static_cast<uint64_t>(y + kOffset) & kMask) << kBits) |
         (static_cast<uint64_t>(z + kOffset) & kMask);
}

glm::ivec3 UnpackVoxel(uint64_t key) {
  return {static_cast<int>(static_cast<int64_t>((key >> (2 * kBits)) & kMask) - kOffset),
          static_cast<int>(static_cast<int64_t>((key >> kBits) & kMask) - kOffset),
          static_cast<int>(static_cast<int64_t>(key & kMask) - kOffset)};
}

int CountNonZero(const ImageU8& mask) {
  int n = 0;
  for (size_t i = 0; i < mask.size(); ++i) n += mask.data()[i] != 0;
  return n;
}

absl::StatusOr<Region3D> RegionFromStroke(std::span<const glm::dvec2> stroke_px,
                                          const ImageF& depth_m, const PinholeCamera& camera,
                                          const Rigid3d& local_from_cam,
                                          const RegionOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(camera.Validate());
  if (depth_m.channels() != 1 || depth_m.width() != camera.width ||
      depth_m.height() != camera.height)
    return absl::InvalidArgumentError("region: depth must be 1-channel, the camera's size");
  if (stroke_px.empty()) return absl::InvalidArgumentError("region: the stroke has no points");
  for (const glm::dvec2& s : stroke_px)
    if (!std::isfinite(s.x) || !std::isfinite(s.y))
      return absl::InvalidArgumentError("region: a stroke point is not finite");
  bool inside = false;
  for (const glm::dvec2& s : stroke_px) inside |= camera.InImage(s);
  if (!inside)
    return absl::InvalidArgumentError(absl::StrCat(
        "region: every stroke point lies outside the ", camera.width, "x", camera.height,
        " image"));
  RoiOptions roi = options.roi;
  roi.include_invalid_depth = false;  // only pixels with depth can be placed in 3D
  EXO_ASSIGN_OR_RETURN(ImageU8 mask, RoiFromStroke(stroke_px, depth_m, camera, roi));
  Region3D r;
  r.voxel_m = options.voxel_m;
  r.stroke_pixels = CountNonZero(mask);
  const int total = camera.width * camera.height;
  if (r.stroke_pixels == 0)
    return absl::FailedPreconditionError(
        "region: the stroke hits no surface (sky or unobserved void: no depth within r_ROI)");
  if (r.stroke_pixels > options.max_frame_fraction * total)
    return absl::InvalidArgumentError(absl::StrCat(
        "region: the ROI covers ", std::lround(100.0 * r.stroke_pixels / total),
        " % of the frame (more than max_frame_fraction = ",
        std::lround(100.0 * options.max_frame_fraction),
        " %): nothing would be left to inpaint it from"));
  std::vector<uint64_t> keys;
  glm::dvec3 sum(0.0);
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x) {
      if (!mask.at(x, y) || !ValidDepth(depth_m.at(x, y))) continue;
      const glm::dvec3 p = local_from_cam * camera.Unproject({x, y}, depth_m.at(x, y));
      const glm::ivec3 v = VoxelOf(p, options.voxel_m);
      if (!InRange(v)) continue;
      sum += p;
      ++r.labelled_pixels;
      keys.push_back(PackVoxel(v.x, v.y, v.z));
    }
  if (r.labelled_pixels == 0)
    return absl::FailedPreconditionError("region: no pixel of the stroke's ROI has depth");
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  const int g = options.grow_voxels;
  if (g > 0) {
    std::vector<uint64_t> grown;
    grown.reserve(keys.size() * (2 * g + 1) * (2 * g + 1) * (2 * g + 1));
    for (uint64_t k : keys) {
      const glm::ivec3 v = UnpackVoxel(k);
      for (int dz = -g; dz <= g; ++dz)
        for (int dy = -g; dy <= g; ++dy)
          for (int dx = -g; dx <= g; ++dx) grown.push_back(PackVoxel(v.x + dx, v.y + dy, v.z + dz));
    }
    std::sort(grown.begin(), grown.end());
    grown.erase(std::unique(grown.begin(), grown.end()), grown.end());
    keys = std::move(grown);
  }
  r.voxels = std::move(keys);
  r.centroid_local = sum / static_cast<double>(r.labelled_pixels);
  return r;
}

RegionLabels::RegionLabels(std::span<const Region3D* const> regions) {
  for (const Region3D* r : regions) {
    if (!r) continue;
    voxel_m_ = r->voxel_m;  // every region of a server shares the configured voxel size
    voxels_.insert(r->voxels.begin(), r->voxels.end());
  }
  bool first = true;
  for (uint64_t k : voxels_) {
    const glm::ivec3 v = UnpackVoxel(k);
    lo_ = first ? v : glm::min(lo_, v);
    hi_ = first ? v : glm::max(hi_, v);
    first = false;
  }
  if (first) return;
  const int64_t nx = int64_t{hi_.x} - lo_.x + 1, ny = int64_t{hi_.y} - lo_.y + 1,
                nz = int64_t{hi_.z} - lo_.z + 1;
  if (nx * ny * nz > kDenseMaxCells) return;
  dense_nx_ = nx;
  dense_nxy_ = nx * ny;
  dense_.assign(static_cast<size_t>((nx * ny * nz + 63) / 64), 0);
  for (uint64_t k : voxels_) {
    const glm::ivec3 v = UnpackVoxel(k);
    if (!InRange(v)) continue;  // Contains never answers true outside the range
    const int64_t i = (v.x - lo_.x) + (v.y - lo_.y) * dense_nx_ + (v.z - lo_.z) * dense_nxy_;
    dense_[static_cast<size_t>(i >> 6)] |= uint64_t{1} << (i & 63);
  }
}

bool RegionLabels::Contains(const glm::dvec3& p_local) const {
  const glm::ivec3 v = VoxelOf(p_local, voxel_m_);
  if (v.x < lo_.x || v.y < lo_.y || v.z < lo_.z || v.x > hi_.x || v.y > hi_.y || v.z > hi_.z)
    return false;
  if (!dense_.empty()) {
    const int64_t i = (v.x - lo_.x) + (v.y - lo_.y) * dense_nx_ + (v.z - lo_.z) * dense_nxy_;
    return (dense_[static_cast<size_t>(i >> 6)] >> (i & 63)) & 1;
  }
  return InRange(v) && voxels_.count(PackVoxel(v.x, v.y, v.z)) != 0;
}

ImageU8 ProjectRegions(const RegionLabels& labels, const ImageF& depth_m,
                       const PinholeCamera& camera, const Rigid3d& local_from_cam,
                       const RegionOptions& options) {
  const int w = depth_m.width(), h = depth_m.height();
  ImageU8 mask(w, h, 1, 0);
  if (labels.empty() || w == 0 || h == 0) return mask;
  bool any = false;
  // Only the pixels inside the projection of the labels' bounding box can be labelled (the
  // whole frame when the box reaches behind the camera).
  int x0 = 0, y0 = 0, x1 = w, y1 = h;
  // The camera depth range of the labels' box (its corners bound it: depth is linear), widened by
  // 1 mm: a pixel whose depth lies outside cannot back-project into a labelled voxel.
  double zlo = -1e30, zhi = 1e30;
  glm::dvec3 lo, hi;
  if (labels.Bounds(&lo, &hi)) {
    const Rigid3d cam_from_local = local_from_cam.Inverse();
    zlo = 1e30;
    zhi = -1e30;
    for (int c = 0; c < 8; ++c) {
      const glm::dvec3 corner(c & 1 ? hi.x : lo.x, c & 2 ? hi.y : lo.y, c & 4 ? hi.z : lo.z);
      const double z = (cam_from_local * corner).z;
      zlo = std::min(zlo, z);
      zhi = std::max(zhi, z);
    }
    zlo -= 1e-3 + 1e-6 * std::abs(zlo);
    zhi += 1e-3 + 1e-6 * std::abs(zhi);
    double u0 = 1e30, v0 = 1e30, u1 = -1e30, v1 = -1e30;
    bool behind = false;
    for (int c = 0; c < 8 && !behind; ++c) {
      const glm::dvec3 corner(c & 1 ? hi.x : lo.x, c & 2 ? hi.y : lo.y, c & 4 ? hi.z : lo.z);
      glm::dvec2 uv;
      if (!camera.Project(cam_from_local * corner, &uv)) {
        behind = true;
        break;
      }
      u0 = std::min(u0, uv.x);
      v0 = std::min(v0, uv.y);
      u1 = std::max(u1, uv.x);
      v1 = std::max(v1, uv.y);
    }
    if (!behind) {
      x0 = static_cast<int>(std::clamp(std::floor(u0) - 1.0, 0.0, double(w)));
      y0 = static_cast<int>(std::clamp(std::floor(v0) - 1.0, 0.0, double(h)));
      x1 = static_cast<int>(std::clamp(std::ceil(u1) + 2.0, 0.0, double(w)));
      y1 = static_cast<int>(std::clamp(std::ceil(v1) + 2.0, 0.0, double(h)));
    }
  }
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      const float z = depth_m.at(x, y);
      if (!ValidDepth(z) || z < zlo || z > zhi) continue;
      if (labels.Contains(local_from_cam * camera.Unproject({x, y}, z))) {
        mask.at(x, y) = 255;
        any = true;
      }
    }
  if (!any) return mask;
  // The morphology runs on a crop: the labelled pixels lie in [x0, x1) x [y0, y1), the closing
  // and the dilation reach at most 2 close + dilate px beyond them, so a crop grown by one more
  // pixel (clamped to the frame, where both see the same constant border) gives the whole
  // frame's result bit for bit: outside the crop the mask stays 0, and an erosion that meets the
  // crop's edge (border = no erosion) sits where the dilated mask is 0 anyway.
  const int cr = std::max(0, options.reproject_close_px), dr = std::max(0, options.reproject_dilate_px);
  const int m = 2 * cr + dr + 1;
  const cv::Rect crop(cv::Point(std::max(0, x0 - m), std::max(0, y0 - m)),
                      cv::Point(std::min(w, x1 + m), std::min(h, y1 + m)));
  cv::Mat full(h, w, CV_8UC1, mask.data());
  cv::Mat part = full(crop).clone();
  if (cr > 0) {
    const int k = 2 * cr + 1;
    cv::morphologyEx(part, part, cv::MORPH_CLOSE,
                     cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(k, k)));
  }
  if (dr > 0) {
    const int k = 2 * dr + 1;
    cv::dilate(part, part, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(k, k)));
  }
  part.copyTo(full(crop));
  return mask;
}

}  // namespace exo::inpainting
