#include "proto/model_proto.h"

#include <algorithm>
#include <cstring>

#include "common/io/depth_codec.h"
#include "common/io/jpeg.h"

namespace exo {
namespace {

std::span<const uint8_t> Bytes(const std::string& s) {
  return {reinterpret_cast<const uint8_t*>(s.data()), s.size()};
}

template <typename T>
uint64_t HashPod(const T& v, uint64_t h) {
  return Fnv1a64(std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(&v), sizeof(T)), h);
}

// Nearest *valid* sample of each k x k block (centre first), so thin foreground is not lost.
ImageF DownscaleDepth(const ImageF& depth, int k) {
  if (k <= 1) return depth;
  const int w = (depth.width() + k - 1) / k, h = (depth.height() + k - 1) / k;
  ImageF out(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const int cx = std::min(x * k + k / 2, depth.width() - 1);
      const int cy = std::min(y * k + k / 2, depth.height() - 1);
      float v = depth.at(cx, cy);
      if (!(v > 0.0f)) {
        for (int yy = y * k; yy < std::min((y + 1) * k, depth.height()) && !(v > 0.0f); ++yy)
          for (int xx = x * k; xx < std::min((x + 1) * k, depth.width()); ++xx)
            if (depth.at(xx, yy) > 0.0f) {
              v = depth.at(xx, yy);
              break;
            }
      }
      out.at(x, y) = v > 0.0f ? v : 0.0f;
    }
  return out;
}

ImageF UpsampleNearest(const ImageF& depth, int width, int height) {
  if (depth.width() == width && depth.height() == height) return depth;
  ImageF out(width, height);
  for (int y = 0; y < height; ++y) {
    const int sy = std::min(static_cast<int>((y + 0.5) * depth.height() / height), depth.height() - 1);
    for (int x = 0; x < width; ++x) {
      const int sx = std::min(static_cast<int>((x + 0.5) * depth.width() / width), depth.width() - 1);
      out.at(x, y) = depth.at(sx, sy);
    }
  }
  return out;
}

}  // namespace

absl::Status ViewEncodeOptions::Validate() const {
  if (jpeg_quality < 1 || jpeg_quality > 100)
    return absl::InvalidArgumentError("view jpeg_quality must be in [1, 100]");
  if (depth_downscale < 1 || depth_downscale > 16)
    return absl::InvalidArgumentError("view depth_downscale must be in [1, 16]");
  if (depth_zstd_level < 1 || depth_zstd_level > 19)
    return absl::InvalidArgumentError("view depth_zstd_level must be in [1, 19]");
  if (!(depth_metres_per_unit > 0.0))
    return absl::InvalidArgumentError("view depth_metres_per_unit must be > 0");
  return absl::OkStatus();
}

absl::StatusOr<v1::ViewAdded> ViewToProto(const StoredView& view, const ViewEncodeOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  v1::ViewAdded msg;
  msg.set_view_id(view.id);
  IntrinsicsToProto(view.camera, msg.mutable_intrinsics());
  PoseToProto(view.local_from_cam, msg.mutable_local_from_cam());
  EXO_ASSIGN_OR_RETURN(std::vector<uint8_t> jpeg,
                       options.jpeg_optimize ? EncodeJpegOptimized(view.color, options.jpeg_quality)
                                             : EncodeJpeg(view.color, options.jpeg_quality));
  msg.set_color_jpeg(jpeg.data(), jpeg.size());
  if (!view.depth_m.empty())
    DepthToProto(DownscaleDepth(view.depth_m, options.depth_downscale),
                 options.depth_metres_per_unit, msg.mutable_depth(), options.depth_zstd_level);
  msg.set_exposure(view.exposure);
  if (view.inpainted) {
    if (view.labels.width() != view.color.width() || view.labels.height() != view.color.height() ||
        view.labels.channels() != 1)
      return absl::InvalidArgumentError("inpainted view: labels must be 1 channel, colour size");
    msg.set_inpainted(true);
    ImageF values(view.labels.width(), view.labels.height(), 1, 0.f);
    for (size_t i = 0; i < values.size(); ++i) values.data()[i] = view.labels.data()[i] ? 1.f : 0.f;
    DepthToProto(values, 1.0, msg.mutable_labels());
  }
  return msg;
}

absl::StatusOr<StoredView> ViewFromProto(const v1::ViewAdded& msg) {
  StoredView v;
  v.id = msg.view_id();
  EXO_ASSIGN_OR_RETURN(v.camera, IntrinsicsFromProto(msg.intrinsics()));
  EXO_ASSIGN_OR_RETURN(v.local_from_cam, PoseFromProto(msg.local_from_cam()));
  EXO_ASSIGN_OR_RETURN(v.color, DecodeJpeg(Bytes(msg.color_jpeg())));
  if (v.color.width() != v.camera.width || v.color.height() != v.camera.height)
    return absl::InvalidArgumentError("view colour size does not match its intrinsics");
  if (msg.has_depth()) {
    EXO_ASSIGN_OR_RETURN(ImageF d, DepthFromProto(msg.depth()));
    v.depth_m = UpsampleNearest(d, v.camera.width, v.camera.height);
  }
  v.exposure = msg.exposure();
  if (msg.inpainted()) {
    v.inpainted = true;
    if (!msg.has_labels())
      return absl::InvalidArgumentError("inpainted view without its label mask");
    EXO_ASSIGN_OR_RETURN(ImageF labels, DepthFromProto(msg.labels()));
    if (labels.width() != v.camera.width || labels.height() != v.camera.height)
      return absl::InvalidArgumentError("inpainted view: label mask size differs from the colour");
    v.labels = ImageU8(labels.width(), labels.height(), 1, 0);
    for (size_t i = 0; i < labels.size(); ++i) v.labels.data()[i] = labels.data()[i] > 0.5f ? 255 : 0;
  }
  return v;
}

uint64_t Fnv1a64(std::span<const uint8_t> bytes, uint64_t h) {
  for (uint8_t b : bytes) {
    h ^= b;
    h *= 0x100000001b3ull;
  }
  return h;
}

uint64_t MeshHash(const TriangleMesh& mesh) {
  uint64_t h = Fnv1a64(std::span<const uint8_t>(
      reinterpret_cast<const uint8_t*>(mesh.positions.data()), mesh.positions.size() * sizeof(glm::vec3)));
  h = Fnv1a64(std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(mesh.normals.data()),
                                       mesh.normals.size() * sizeof(glm::vec3)), h);
  return Fnv1a64(std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(mesh.indices.data()),
                                          mesh.indices.size() * sizeof(uint32_t)), h);
}

ViewDigestRecord DigestRecordFromProto(const v1::ViewAdded& msg) {
  ViewDigestRecord r;
  r.id = msg.view_id();
  const auto& in = msg.intrinsics();
  r.camera.fx = in.fx(); r.camera.fy = in.fy(); r.camera.cx = in.cx(); r.camera.cy = in.cy();
  r.camera.width = in.width(); r.camera.height = in.height();
  const auto& p = msg.local_from_cam();
  if (p.has_quaternion())
    r.local_from_cam.rotation = glm::dquat(p.quaternion().w(), p.quaternion().x(),
                                           p.quaternion().y(), p.quaternion().z());
  r.local_from_cam.translation = {p.translation().x(), p.translation().y(), p.translation().z()};
  r.exposure = msg.exposure();
  r.color_hash = Fnv1a64(Bytes(msg.color_jpeg()));
  r.depth_hash = Fnv1a64(Bytes(msg.depth().data()));
  if (msg.inpainted()) r.depth_hash = Fnv1a64(Bytes(msg.labels().data()), r.depth_hash ^ 1);
  return r;
}

uint64_t ModelDigest(const std::map<ViewId, ViewDigestRecord>& views,
                     const std::unordered_map<CellId, std::vector<ViewId>>& cell_refs,
                     const std::map<uint64_t, ChunkDigestRecord>& chunks) {
  uint64_t h = 0xcbf29ce484222325ull;
  for (const auto& [id, r] : views) {
    h = HashPod(id, h);
    const double cam[4] = {r.camera.fx, r.camera.fy, r.camera.cx, r.camera.cy};
    const int size[2] = {r.camera.width, r.camera.height};
    const double pose[7] = {r.local_from_cam.rotation.w, r.local_from_cam.rotation.x,
                            r.local_from_cam.rotation.y, r.local_from_cam.rotation.z,
                            r.local_from_cam.translation.x, r.local_from_cam.translation.y,
                            r.local_from_cam.translation.z};
    h = HashPod(cam, h);
    h = HashPod(size, h);
    h = HashPod(pose, h);
    h = HashPod(r.exposure, h);
    h = HashPod(r.color_hash, h);
    h = HashPod(r.depth_hash, h);
  }
  std::vector<CellId> cells;
  cells.reserve(cell_refs.size());
  for (const auto& [cell, refs] : cell_refs)
    if (!refs.empty()) cells.push_back(cell);
  std::sort(cells.begin(), cells.end());
  for (CellId cell : cells) {
    h = HashPod(cell, h);
    for (ViewId v : cell_refs.at(cell)) h = HashPod(v, h);
  }
  for (const auto& [id, c] : chunks) {
    h = HashPod(id, h);
    h = HashPod(c.version, h);
    h = HashPod(c.mesh_hash, h);
  }
  return h;
}

}  // namespace exo
