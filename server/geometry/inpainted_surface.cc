#include "server/geometry/inpainted_surface.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"

namespace exo::geometry {

absl::Status InpaintedSurfaceOptions::Validate() const {
  if (carve_margin_voxels < 0 || carve_margin_voxels > 16)
    return absl::InvalidArgumentError("carve_margin_voxels must be in [0, 16]");
  return absl::OkStatus();
}

InpaintedSurface::InpaintedSurface(const TsdfOptions& tsdf, const InpaintedSurfaceOptions& options)
    : tsdf_(tsdf), options_(options), ip_(std::make_unique<TsdfVolume>(tsdf)) {
  EXO_CHECK(options_.Validate().ok());
}

glm::ivec3 InpaintedSurface::BlockOf(const glm::ivec3& g) const {
  const int bs = tsdf_.block_size;
  return {g.x >= 0 ? g.x / bs : (g.x + 1) / bs - 1, g.y >= 0 ? g.y / bs : (g.y + 1) / bs - 1,
          g.z >= 0 ? g.z / bs : (g.z + 1) / bs - 1};
}

// A block's voxels are read by its own cubes and by those of the 7 blocks below it (as
// TsdfVolume::ExtractDirtyChunks; the normals of the blocks above, which read one layer of it
// for their gradients, follow with their next re-mesh).
void InpaintedSurface::MarkDirty(uint64_t key) {
  const glm::ivec3 b = UnpackCell(key);
  for (int dz = -1; dz <= 0; ++dz)
    for (int dy = -1; dy <= 0; ++dy)
      for (int dx = -1; dx <= 0; ++dx) dirty_.insert(PackCell(b + glm::ivec3(dx, dy, dz)));
}

// A block holding ROI or inpainted voxels changes the meshes of the blocks whose cubes read it:
// its own and the 7 below it (the normals of its other neighbours, which read one layer of it
// for their gradients, keep the observed field's).
void InpaintedSurface::RebuildAffected() {
  affected_.clear();
  for (const auto* set : {&roi_blocks_, &ip_blocks_})
    for (uint64_t key : *set) {
      const glm::ivec3 b = UnpackCell(key);
      for (int dz = -1; dz <= 0; ++dz)
        for (int dy = -1; dy <= 0; ++dy)
          for (int dx = -1; dx <= 0; ++dx) affected_.insert(PackCell(b + glm::ivec3(dx, dy, dz)));
    }
}

void InpaintedSurface::SetRoi(std::span<const glm::ivec3> label_voxels, double label_voxel_m) {
  for (uint64_t key : roi_blocks_) MarkDirty(key);  // the old ROI's blocks
  roi_.clear();
  roi_blocks_.clear();
  roi_voxels_ = 0;
  const int bs = tsdf_.block_size;
  const double vs = tsdf_.voxel_size_m;
  const double m = options_.carve_margin_voxels * vs;
  if (label_voxel_m > 0.0) {
    for (const glm::ivec3& l : label_voxels) {
      // TSDF voxels g whose sample point g * vs lies in the label cube grown by the margin.
      glm::ivec3 lo, hi;
      for (int a = 0; a < 3; ++a) {
        lo[a] = static_cast<int>(std::ceil((l[a] * label_voxel_m - m) / vs - 1e-6));
        hi[a] = static_cast<int>(std::floor(((l[a] + 1) * label_voxel_m + m) / vs + 1e-6));
      }
      for (int z = lo.z; z <= hi.z; ++z)
        for (int y = lo.y; y <= hi.y; ++y)
          for (int x = lo.x; x <= hi.x; ++x) {
            const glm::ivec3 g(x, y, z), b = BlockOf(g), l = g - b * bs;
            std::vector<uint8_t>& bits = roi_[PackCell(b)];
            if (bits.empty()) bits.assign(size_t(bs) * bs * bs, 0);
            uint8_t& f = bits[(size_t(l.z) * bs + l.y) * bs + l.x];
            roi_voxels_ += !f;
            f = 1;
          }
    }
  }
  for (const auto& [key, bits] : roi_) roi_blocks_.insert(key);
  for (uint64_t key : roi_blocks_) MarkDirty(key);
  RebuildAffected();
}

bool InpaintedSurface::InRoi(const glm::ivec3& g) const {
  const int bs = tsdf_.block_size;
  const glm::ivec3 b = BlockOf(g), l = g - b * bs;
  auto it = roi_.find(PackCell(b));
  return it != roi_.end() && it->second[(size_t(l.z) * bs + l.y) * bs + l.x];
}

void InpaintedSurface::ClearInpainted() {
  for (uint64_t key : ip_blocks_) MarkDirty(key);
  ip_ = std::make_unique<TsdfVolume>(tsdf_);
  ip_blocks_.clear();
  RebuildAffected();
}

absl::StatusOr<InpaintedFuseStats> InpaintedSurface::IntegrateInpainted(
    const TsdfVolume& observed, const ImageF& depth_m, const ImageU8& mask, const ImageU8* color,
    const PinholeCamera& camera, const Rigid3d& local_from_cam) {
  if (mask.width() != depth_m.width() || mask.height() != depth_m.height() ||
      mask.channels() != 1)
    return absl::InvalidArgumentError(absl::StrCat(
        "InpaintedSurface: mask ", mask.width(), "x", mask.height(), "x", mask.channels(),
        " does not match the depth ", depth_m.width(), "x", depth_m.height()));
  if (color && (color->width() != depth_m.width() || color->height() != depth_m.height() ||
                color->channels() != 3))
    return absl::InvalidArgumentError("InpaintedSurface: colour must be RGB8 of the depth's size");
  InpaintedFuseStats st;
  ImageF masked = depth_m;
  for (size_t i = 0; i < masked.size(); ++i) {
    if (!mask.data()[i]) masked.data()[i] = 0.0f;
    else if (masked.data()[i] > 0.0f) ++st.pixels;
  }
  const Rigid3d identity;
  EXO_ASSIGN_OR_RETURN(TsdfIntegrateStats is,
                       ip_->IntegrateDepth(masked, camera, local_from_cam, color,
                                           color ? &camera : nullptr, &identity));
  (void)is;
  // Only L_IP voxels keep inpainted values: erase the ones observed outside the ROI.
  const int bs = tsdf_.block_size;
  for (uint64_t key : ip_->TakeDirtyBlocks()) {
    ++st.blocks;
    size_t kept = 0;
    const glm::ivec3 bc = UnpackCell(key);
    TsdfVoxel* ipv = ip_->MutableVoxelAt(bc * bs);
    const TsdfVoxel* obv = observed.BlockVoxels(bc);
    auto rit = roi_.find(key);
    const uint8_t* roi = rit == roi_.end() ? nullptr : rit->second.data();
    if (!ipv) continue;
    for (size_t i = 0, n = size_t(bs) * bs * bs; i < n; ++i) {
          TsdfVoxel* v = ipv + i;
          if (!(v->weight > 0.0f)) continue;
          const TsdfVoxel* o = (roi && roi[i]) || !obv ? nullptr : obv + i;
          if (o && !(o->weight < tsdf_.min_extract_weight)) {
            *v = TsdfVoxel{};
            ++st.voxels_erased;
          } else {
            ++kept;
          }
    }
    st.voxels_kept += kept;
    // A block whose inpainted values were all erased (observed) changes nothing for the clients.
    if (kept > 0) {
      ip_blocks_.insert(key);
      MarkDirty(key);
    } else if (ip_blocks_.erase(key)) {
      MarkDirty(key);
    }
  }
  RebuildAffected();
  return st;
}

VoxelLabel InpaintedSurface::Label(const TsdfVolume& observed, const glm::ivec3& g) const {
  const float w = tsdf_.min_extract_weight;
  const TsdfVoxel* ip = ip_->VoxelAt(g);
  const bool has_ip = ip && !(ip->weight < w);
  const TsdfVoxel* o = observed.VoxelAt(g);
  const bool has_obs = o && !(o->weight < w);
  if (InRoi(g)) return has_ip ? VoxelLabel::kInpainted : (has_obs ? VoxelLabel::kRoi : VoxelLabel::kNone);
  return has_obs ? VoxelLabel::kObserved : (has_ip ? VoxelLabel::kInpainted : VoxelLabel::kNone);
}

const TsdfVoxel* InpaintedSurface::ClientVoxel(const TsdfVolume& observed,
                                               const glm::ivec3& g) const {
  switch (Label(observed, g)) {
    case VoxelLabel::kObserved: return observed.VoxelAt(g);
    case VoxelLabel::kInpainted: return ip_->VoxelAt(g);
    default: return nullptr;
  }
}

TriangleMesh InpaintedSurface::ExtractBlock(const TsdfVolume& observed, uint64_t key) const {
  if (!Affects(key)) return observed.ExtractBlock(key);
  // ClientVoxel over the block's neighbourhood with the 27 blocks' voxels looked up once.
  const int bs = tsdf_.block_size;
  const glm::ivec3 bc = UnpackCell(key);
  struct Nb {
    const TsdfVoxel* obs = nullptr;
    const TsdfVoxel* ip = nullptr;
    const uint8_t* roi = nullptr;
  } nb[27];
  bool any = false;
  for (int dz = -1; dz <= 1; ++dz)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        const glm::ivec3 b = bc + glm::ivec3(dx, dy, dz);
        Nb& n = nb[(dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)];
        n.obs = observed.BlockVoxels(b);
        n.ip = ip_->BlockVoxels(b);
        auto it = roi_.find(PackCell(b));
        if (it != roi_.end()) n.roi = it->second.data();
        any |= (n.obs || n.ip) && dz >= 0 && dy >= 0 && dx >= 0;
      }
  if (!any) return TriangleMesh();
  const float w = tsdf_.min_extract_weight;
  const glm::ivec3 base = bc * bs;
  return observed.MeshBlockFrom(bc, [&](const glm::ivec3& g) -> const TsdfVoxel* {
    const glm::ivec3 r = g - base;
    const int ox = r.x < 0 ? -1 : (r.x >= bs ? 1 : 0), oy = r.y < 0 ? -1 : (r.y >= bs ? 1 : 0),
              oz = r.z < 0 ? -1 : (r.z >= bs ? 1 : 0);
    const Nb& n = nb[(oz + 1) * 9 + (oy + 1) * 3 + (ox + 1)];
    const size_t i = (size_t(r.z - oz * bs) * bs + (r.y - oy * bs)) * bs + (r.x - ox * bs);
    const TsdfVoxel* ip = n.ip ? n.ip + i : nullptr;
    const bool has_ip = ip && !(ip->weight < w);
    if (n.roi && n.roi[i]) return has_ip ? ip : nullptr;  // L_IP or carved L_ROI
    const TsdfVoxel* o = n.obs ? n.obs + i : nullptr;
    if (o && !(o->weight < w)) return o;                  // L_O
    return has_ip ? ip : nullptr;                          // L_IP in vacant space
  });
}

std::vector<uint64_t> InpaintedSurface::TakeDirtyBlocks() {
  std::vector<uint64_t> keys(dirty_.begin(), dirty_.end());
  dirty_.clear();
  std::sort(keys.begin(), keys.end());
  return keys;
}

}  // namespace exo::geometry
