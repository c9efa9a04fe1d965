#include "server/service/regions.h"

#include "common/raster/rasterizer.h"
#include "proto/frame_proto.h"

namespace exo {

absl::Status RegionRegistryOptions::Validate() const {
  EXO_RETURN_IF_ERROR(region.Validate());
  if (max_regions == 0 || max_regions > 4096)
    return absl::InvalidArgumentError("inpaint_max_regions must be in [1, 4096]");
  return absl::OkStatus();
}

std::vector<uint32_t> RegionSet::ids() const {
  std::vector<uint32_t> out;
  for (const auto& r : regions) out.push_back(r.id);
  return out;
}

RegionRegistry::RegionRegistry(const RegionRegistryOptions& options, ModelStore* store)
    : options_(options), store_(store) {}

absl::StatusOr<v1::RegionInfo> RegionRegistry::Mark(std::span<const glm::dvec2> stroke,
                                                    const PinholeCamera& camera,
                                                    const Rigid3d& local_from_cam,
                                                    double radius_px, double depth_tol_m,
                                                    const std::string& label,
                                                    const std::string& who) {
  if (stroke.size() > options_.max_stroke_points)
    return absl::InvalidArgumentError(absl::StrCat("the stroke has ", stroke.size(),
                                                   " points; at most ", options_.max_stroke_points));
  if (!(radius_px >= 0.0) || !(depth_tol_m >= 0.0) || !std::isfinite(radius_px) ||
      !std::isfinite(depth_tol_m))
    return absl::InvalidArgumentError("radius_px and depth_tolerance_m must be finite and >= 0");
  EXO_RETURN_IF_ERROR(camera.Validate());
  if (camera.width > 4096 || camera.height > 4096)
    return absl::InvalidArgumentError("the marking camera is larger than 4096x4096");
  {
    std::lock_guard lock(mu_);
    if (regions_.size() >= options_.max_regions)
      return absl::ResourceExhaustedError(absl::StrCat(
          "already ", regions_.size(), " regions (inpaint_max_regions); clear one first"));
  }
  if (!store_->Origin())
    return absl::FailedPreconditionError("no scene yet: upload frames before marking a region");
  // The scene depth seen from the marking camera: the published proxy mesh.
  std::vector<TriangleMesh> meshes;
  for (const auto& c : store_->Chunks()) {
    EXO_ASSIGN_OR_RETURN(TriangleMesh m, MeshFromProto(*c));
    meshes.push_back(std::move(m));
  }
  if (meshes.empty())
    return absl::FailedPreconditionError(
        "no scene geometry yet (no mesh chunk published): upload frames with depth first");
  std::vector<const TriangleMesh*> parts;
  for (const auto& m : meshes) parts.push_back(&m);
  RasterOptions ro;
  ro.z_depth = true;
  EXO_ASSIGN_OR_RETURN(RasterOutput raster, RasterizeParts(parts, camera, local_from_cam, ro));
  inpainting::RegionOptions o = options_.region;
  if (radius_px > 0) o.roi.radius_px = radius_px;
  if (depth_tol_m > 0) o.roi.depth_tol_m = depth_tol_m;
  EXO_ASSIGN_OR_RETURN(inpainting::Region3D r,
                       inpainting::RegionFromStroke(stroke, raster.z_depth_m, camera,
                                                    local_from_cam, o));
  std::lock_guard lock(mu_);
  if (regions_.size() >= options_.max_regions)
    return absl::ResourceExhaustedError("too many regions (inpaint_max_regions)");
  r.id = next_id_++;
  v1::RegionInfo info;
  info.set_region_id(r.id);
  info.set_label(label.substr(0, 256));
  info.set_num_voxels(static_cast<uint32_t>(r.voxels.size()));
  info.set_voxel_size_m(r.voxel_m);
  info.mutable_centroid_local()->set_x(r.centroid_local.x);
  info.mutable_centroid_local()->set_y(r.centroid_local.y);
  info.mutable_centroid_local()->set_z(r.centroid_local.z);
  info.set_stroke_pixels(r.stroke_pixels);
  info.set_labelled_pixels(r.labelled_pixels);
  info.set_created_by(who);
  info.set_model_version(store_->version());
  infos_.push_back(info);
  regions_.push_back(std::move(r));
  PublishLocked();
  return info;
}

std::vector<v1::RegionInfo> RegionRegistry::List() const {
  std::lock_guard lock(mu_);
  return infos_;
}

absl::StatusOr<uint32_t> RegionRegistry::Clear(uint32_t id) {
  std::lock_guard lock(mu_);
  uint32_t n = 0;
  for (size_t i = regions_.size(); i-- > 0;)
    if (id == 0 || regions_[i].id == id) {
      regions_.erase(regions_.begin() + i);
      infos_.erase(infos_.begin() + i);
      ++n;
    }
  if (id != 0 && n == 0)
    return absl::NotFoundError(absl::StrCat("no region ", id, " (ListRegions shows the marked ones)"));
  PublishLocked();
  return n;
}

std::shared_ptr<const RegionSet> RegionRegistry::Get() const {
  std::lock_guard lock(mu_);
  return set_;
}

uint64_t RegionRegistry::generation() const {
  std::lock_guard lock(mu_);
  return set_->generation;
}

void RegionRegistry::PublishLocked() {
  auto s = std::make_shared<RegionSet>();
  s->generation = set_->generation + 1;
  s->regions = regions_;
  std::vector<const inpainting::Region3D*> ptrs;
  for (const auto& r : s->regions) ptrs.push_back(&r);
  s->labels = inpainting::RegionLabels(ptrs);
  set_ = std::move(s);
}

void RegionRegistry::ToCheckpoint(v1::Checkpoint* c) const {
  std::lock_guard lock(mu_);
  for (size_t i = 0; i < regions_.size(); ++i) {
    v1::StoredRegion* s = c->add_regions();
    *s->mutable_info() = infos_[i];
    s->mutable_voxels()->Add(regions_[i].voxels.begin(), regions_[i].voxels.end());
  }
  c->set_next_region_id(next_id_);
}

absl::Status RegionRegistry::Restore(const v1::Checkpoint& c) {
  std::lock_guard lock(mu_);
  regions_.clear();
  infos_.clear();
  next_id_ = std::max<uint32_t>(1, c.next_region_id());
  for (const v1::StoredRegion& s : c.regions()) {
    inpainting::Region3D r;
    r.id = s.info().region_id();
    r.voxel_m = s.info().voxel_size_m();
    if (r.id == 0 || !(r.voxel_m > 0.0) || s.voxels().empty())
      return absl::DataLossError(absl::StrCat("checkpoint: region ", r.id, " is malformed"));
    r.voxels.assign(s.voxels().begin(), s.voxels().end());
    r.stroke_pixels = static_cast<int>(s.info().stroke_pixels());
    r.labelled_pixels = static_cast<int>(s.info().labelled_pixels());
    r.centroid_local = {s.info().centroid_local().x(), s.info().centroid_local().y(),
                        s.info().centroid_local().z()};
    next_id_ = std::max(next_id_, r.id + 1);
    infos_.push_back(s.info());
    regions_.push_back(std::move(r));
  }
  PublishLocked();
  return absl::OkStatus();
}

}  // namespace exo
