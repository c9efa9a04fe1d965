#include "server/planning/cell_id_proxy.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>
#include <unordered_map>
#include <utility>

#include "common/cells.h"
#include "common/raster/rasterizer.h"

namespace exo::planning {

absl::StatusOr<TriangleMesh> ClusterSimplify(const TriangleMesh& mesh, double cluster_m,
                                             ClusterStats* stats) {
  if (!std::isfinite(cluster_m) || !(cluster_m > 0.0))
    return absl::InvalidArgumentError("ClusterSimplify: cluster_m must be finite and > 0");
  if (mesh.indices.size() % 3 != 0)
    return absl::InvalidArgumentError("ClusterSimplify: index count is not a multiple of 3");
  uint32_t max_index = 0;
  for (uint32_t i : mesh.indices) max_index = std::max(max_index, i);
  if (!mesh.indices.empty() && max_index >= mesh.positions.size())
    return absl::InvalidArgumentError("ClusterSimplify: index out of range");
  TriangleMesh out;
  const CellGrid grid{cluster_m};
  std::vector<uint32_t> cluster(mesh.positions.size());
  std::vector<glm::dvec3> sum;
  std::vector<uint32_t> count;
  auto add = [&](size_t v, uint32_t& slot) {
    if (slot == ~0u) {
      slot = uint32_t(sum.size());
      sum.emplace_back(0.0);
      count.push_back(0);
    }
    cluster[v] = slot;
    sum[slot] += glm::dvec3(mesh.positions[v]);
    ++count[slot];
  };
  // A mesh chunk spans few clusters: a dense table over its cluster-coordinate bounding box
  // (no hashing); a hash map for large extents.
  glm::ivec3 lo(std::numeric_limits<int>::max()), hi(std::numeric_limits<int>::min());
  std::vector<glm::ivec3> coords(mesh.positions.size());  // computed once (two floor divisions
  for (size_t v = 0; v < mesh.positions.size(); ++v) {    // per axis were half the cost)
    coords[v] = grid.CoordOf(glm::dvec3(mesh.positions[v]));
    lo = glm::min(lo, coords[v]);
    hi = glm::max(hi, coords[v]);
  }
  const glm::i64vec3 dim = glm::i64vec3(hi) - glm::i64vec3(lo) + int64_t{1};
  if (!mesh.positions.empty() && dim.x * dim.y * dim.z <= int64_t{1} << 22) {
    std::vector<uint32_t> table(size_t(dim.x * dim.y * dim.z), ~0u);
    for (size_t v = 0; v < mesh.positions.size(); ++v) {
      const glm::i64vec3 c = glm::i64vec3(coords[v]) - glm::i64vec3(lo);
      add(v, table[size_t(c.x + dim.x * (c.y + dim.y * c.z))]);
    }
  } else {
    std::unordered_map<CellId, uint32_t> table;
    table.reserve(mesh.positions.size() / 2 + 1);
    for (size_t v = 0; v < mesh.positions.size(); ++v)
      add(v, table.try_emplace(grid.IdOf(glm::dvec3(mesh.positions[v])), ~0u).first->second);
  }
  out.positions.resize(sum.size());
  for (size_t c = 0; c < sum.size(); ++c) out.positions[c] = glm::vec3(sum[c] / double(count[c]));
  for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
    const uint32_t a = cluster[mesh.indices[t]], b = cluster[mesh.indices[t + 1]],
                   c = cluster[mesh.indices[t + 2]];
    if (a == b || b == c || a == c) continue;
    out.indices.insert(out.indices.end(), {a, b, c});
  }
  // Drop clusters no triangle uses (keeps the vertex buffer small; indices remapped).
  std::vector<uint32_t> remap(out.positions.size(), ~0u);
  std::vector<glm::vec3> used;
  for (uint32_t& i : out.indices) {
    if (remap[i] == ~0u) {
      remap[i] = uint32_t(used.size());
      used.push_back(out.positions[i]);
    }
    i = remap[i];
  }
  out.positions = std::move(used);
  if (stats != nullptr) {
    stats->triangles_in = mesh.num_triangles();
    stats->triangles_out = out.num_triangles();
  }
  return out;
}

}  // namespace exo::planning

namespace exo::planning {
namespace {

// Bounding box of float positions, as doubles (min/max in float then widened: the same values
// as widening first, since float -> double is exact and monotonic).
// Bounding box of float positions, as doubles (min/max in float, then widened: the same values
// as widening each position first, since float -> double is exact and monotonic).
std::pair<glm::dvec3, glm::dvec3> Box(const std::vector<glm::vec3>& positions) {
  const float inf = std::numeric_limits<float>::infinity();
  float lo[3] = {inf, inf, inf}, hi[3] = {-inf, -inf, -inf};
  for (const glm::vec3& p : positions)
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], p[k]);
      hi[k] = std::max(hi[k], p[k]);
    }
  return {glm::dvec3(lo[0], lo[1], lo[2]), glm::dvec3(hi[0], hi[1], hi[2])};
}

}  // namespace

absl::Status CellIdRendererOptions::Validate() const {
  if (!std::isfinite(grid.cell_size_m) || !(grid.cell_size_m > 0.0))
    return absl::InvalidArgumentError("CellIdRenderer: grid cell size must be finite and > 0");
  if (!std::isfinite(lod_cluster_m) || lod_cluster_m < 0.0)
    return absl::InvalidArgumentError("CellIdRenderer: lod_cluster_m must be finite and >= 0");
  if (!std::isfinite(lod_keep_fraction) || lod_keep_fraction < 0.0 || lod_keep_fraction >= 1.0)
    return absl::InvalidArgumentError("CellIdRenderer: lod_keep_fraction must be in [0, 1)");
  if (!std::isfinite(max_range_m) || max_range_m < 0.0)
    return absl::InvalidArgumentError("CellIdRenderer: max_range_m must be finite and >= 0");
  if (!std::isfinite(near_m) || !(near_m > 0.0))
    return absl::InvalidArgumentError("CellIdRenderer: near_m must be finite and > 0");
  if (num_threads < 1 || num_threads > 64)
    return absl::InvalidArgumentError("CellIdRenderer: num_threads must be in [1, 64]");
  return absl::OkStatus();
}

double DefaultCellIdLodM(double cell_size_m, double voxel_m) {
  double m = 0.5 * cell_size_m;
  if (voxel_m > 0.0) m = std::min(m, 4.0 * voxel_m);
  return m;
}

absl::StatusOr<CellIdRenderer> CellIdRenderer::Create(const CellIdRendererOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  return CellIdRenderer(options);
}

void CellIdRenderer::SyncItems(std::vector<uint64_t>* touched) {
  std::sort(touched->begin(), touched->end());
  touched->erase(std::unique(touched->begin(), touched->end()), touched->end());
  std::vector<Item> merged;
  merged.reserve(items_.size() + touched->size());
  size_t j = 0;
  auto take = [&](uint64_t id) {  // the current state of a touched id (absent = erased)
    auto it = chunks_.find(id);
    if (it != chunks_.end()) merged.push_back({id, it->second.lo, it->second.hi, &it->second.mesh});
  };
  for (const Item& item : items_) {
    while (j < touched->size() && (*touched)[j] < item.id) take((*touched)[j++]);
    if (j < touched->size() && (*touched)[j] == item.id) {
      take((*touched)[j++]);
      continue;
    }
    merged.push_back(item);
  }
  while (j < touched->size()) take((*touched)[j++]);
  items_ = std::move(merged);
}

void CellIdRenderer::Remove(uint64_t chunk_id) {
  if (chunks_.erase(chunk_id) == 0) return;
  auto item = std::lower_bound(items_.begin(), items_.end(), chunk_id,
                               [](const Item& a, uint64_t id) { return a.id < id; });
  if (item != items_.end() && item->id == chunk_id) items_.erase(item);
}

absl::Status CellIdRenderer::Update(const std::vector<MeshChunk>& changed) {
  absl::Status first_error = absl::OkStatus();
  std::vector<uint64_t> touched;  // ids whose render mesh changed: items_ synced at the end
  for (const MeshChunk& c : changed) {
    auto it = chunks_.find(c.id);
    if (it != chunks_.end() && c.version <= it->second.version) continue;
    if (c.mesh.empty()) {
      if (it != chunks_.end()) {
        chunks_.erase(it);
        touched.push_back(c.id);
      }
      continue;
    }
    const size_t n = c.mesh.num_triangles();
    const auto [src_lo, src_hi] = Box(c.mesh.positions);
    if (it != chunks_.end() && options_.lod_cluster_m > 0.0 && options_.lod_keep_fraction > 0.0) {
      Entry& e = it->second;
      const double lo = double(std::min(n, e.lod_source_triangles));
      const double hi = double(std::max(n, e.lod_source_triangles));
      // Keep the LOD while the chunk's triangle count AND its bounding box stay put: a surface
      // that appeared or was carved away moves the box (the count alone kept stale LODs in
      // walks that look around: apartment eval -0.005 MSSIM, docs/evaluation.md).
      const glm::dvec3 moved = glm::max(glm::abs(src_lo - e.lod_source_lo),
                                        glm::abs(src_hi - e.lod_source_hi));
      const double max_moved = std::max(moved.x, std::max(moved.y, moved.z));
      if (hi <= (1.0 + options_.lod_keep_fraction) * lo &&
          max_moved <= 0.5 * options_.lod_cluster_m) {  // keep the LOD
        e.version = c.version;
        e.source_triangles = n;
        continue;
      }
    }
    // Validated only here, when the mesh is used (simplified or copied for rendering): a new
    // version whose LOD is kept above is never read beyond its box and triangle count, and
    // checking the ~10^5 indices of the chunks re-extracted every frame was a third of Update.
    if (absl::Status s = ValidateMesh(c.mesh); !s.ok()) {
      if (first_error.ok())
        first_error = absl::InvalidArgumentError(
            absl::StrCat("CellIdRenderer: chunk ", c.id, ": ", s.message()));
      continue;
    }
    Entry e;
    e.version = c.version;
    e.source_triangles = e.lod_source_triangles = n;
    e.lod_source_lo = src_lo;
    e.lod_source_hi = src_hi;
    if (options_.lod_cluster_m > 0.0) {
      absl::StatusOr<TriangleMesh> lod = ClusterSimplify(c.mesh, options_.lod_cluster_m);
      if (!lod.ok()) {  // not reached after ValidateMesh; the items must still be synced
        if (first_error.ok()) first_error = lod.status();
        continue;
      }
      e.mesh = std::move(*lod);
      ++lod_builds_;
    } else {
      e.mesh.positions = c.mesh.positions;  // cell ids need positions + indices only
      e.mesh.indices = c.mesh.indices;
    }
    if (e.mesh.empty()) {  // everything collapsed: nothing to render
      if (it != chunks_.end()) {
        chunks_.erase(it);
        touched.push_back(c.id);
      }
      continue;
    }
    std::tie(e.lo, e.hi) = Box(e.mesh.positions);
    chunks_[c.id] = std::move(e);
    touched.push_back(c.id);
  }
  if (!touched.empty()) SyncItems(&touched);
  return first_error;
}

absl::StatusOr<CellIdBuffer> CellIdRenderer::Render(const Rigid3d& local_from_cam,
                                                    const PinholeCamera& camera, int width,
                                                    int height) const {
  if (width < 1 || height < 1 || width > 32768 || height > 32768)
    return absl::InvalidArgumentError(
        absl::StrCat("CellIdRenderer: buffer size must be in [1, 32768], got ", width, "x", height));
  EXO_RETURN_IF_ERROR(camera.Validate());
  EXO_RETURN_IF_ERROR(ValidateQuaternion(local_from_cam.rotation));
  const glm::dvec3& tr = local_from_cam.translation;
  if (!std::isfinite(tr.x) || !std::isfinite(tr.y) || !std::isfinite(tr.z))
    return absl::InvalidArgumentError("CellIdRenderer: pose translation has NaN or Inf");
  const PinholeCamera cam = camera.Scaled(width, height);
  // Frustum half-spaces in the camera frame (n . p >= 0 inside), conservative by half a pixel
  // around the outermost pixel centres: a box entirely outside one of them cannot cover a pixel
  // centre, so skipping it leaves the buffer unchanged.
  const glm::dvec4 planes[5] = {
      {0, 0, 1, -options_.near_m},
      {cam.fx, 0, cam.cx + 0.5, 0},                        // u >= -0.5
      {-cam.fx, 0, (cam.width - 0.5) - cam.cx, 0},         // u <= W-0.5
      {0, cam.fy, cam.cy + 0.5, 0},                        // v >= -0.5
      {0, -cam.fy, (cam.height - 0.5) - cam.cy, 0},        // v <= H-0.5
  };
  const Rigid3d cam_from_local = local_from_cam.Inverse();
  const glm::dmat3 R = cam_from_local.RotationMatrix();
  const glm::dvec3 t = cam_from_local.translation;
  // The planes in the local frame (n_cam . (R p + t) + d = (R^T n_cam) . p + n_cam . t + d), so
  // a box is tested through its centre and half extent: its largest plane value is
  // n . centre + |n| . half. Culled only when that is below -margin (a relative bound far above
  // the rounding of either form): a conservative cull, it never drops a covering chunk.
  glm::dvec3 n_local[6], n_abs[6];
  double d_local[5], n_len[5];
  for (int p = 0; p < 5; ++p) {
    n_local[p] = glm::transpose(R) * glm::dvec3(planes[p]);
    n_abs[p] = glm::abs(n_local[p]);
    n_len[p] = glm::length(n_local[p]);
    d_local[p] = glm::dot(glm::dvec3(planes[p]), t) + planes[p].w;
  }
  const double t_len = glm::length(t);
  // The far limit is not a raster clip plane: which chunks it drops changes the buffer, so a
  // box near it is decided exactly as before (all 8 corners beyond max_range_m in camera z).
  const bool far_limit = options_.max_range_m > 0.0;
  n_local[5] = glm::transpose(R) * glm::dvec3(0, 0, -1);  // -(camera z axis) in local
  n_abs[5] = glm::abs(n_local[5]);
  CellIdBuffer out;
  std::vector<const TriangleMesh*> parts;
  parts.reserve(items_.size());
  for (const Item& e : items_) {
    const glm::dvec3 centre = 0.5 * (e.lo + e.hi), half = 0.5 * (e.hi - e.lo);
    const double scale = glm::dot(glm::abs(centre) + half, glm::dvec3(1.0)) + t_len;
    bool outside = false;
    for (int p = 0; p < 5 && !outside; ++p) {
      const double hi_value = glm::dot(n_local[p], centre) + glm::dot(n_abs[p], half);
      const double margin = 1e-9 * (n_len[p] * scale + std::abs(d_local[p]));
      outside = hi_value + d_local[p] < -margin;
    }
    if (outside) continue;
    if (far_limit) {
      // Smallest camera z over the box.
      const double z_lo = t.z - (glm::dot(n_local[5], centre) + glm::dot(n_abs[5], half));
      const double margin = 1e-9 * (scale + options_.max_range_m);
      if (z_lo > options_.max_range_m + margin) continue;  // surely beyond
      if (z_lo >= options_.max_range_m - margin) {         // close: the exact corner test
        bool beyond = true;
        for (int k = 0; k < 8 && beyond; ++k) {
          const glm::dvec3 corner =
              R * glm::dvec3((k & 1) ? e.hi.x : e.lo.x, (k & 2) ? e.hi.y : e.lo.y,
                             (k & 4) ? e.hi.z : e.lo.z) + t;
          beyond = glm::dot(glm::dvec3(0, 0, -1), corner) + options_.max_range_m < 0.0;
        }
        if (beyond) continue;
      }
    }
    parts.push_back(e.mesh);
    out.triangles_rendered += e.mesh->num_triangles();
  }
  out.chunks_rendered = parts.size();
  RasterOptions ro;
  ro.z_depth = false;
  ro.cell_id = true;
  ro.cell_grid = options_.grid;
  ro.near_m = options_.near_m;
  ro.width = width;
  ro.height = height;
  ro.num_threads = options_.num_threads;
  ro.meshes_prevalidated = true;  // every cached mesh passed ValidateMesh in Update()
  EXO_ASSIGN_OR_RETURN(RasterOutput r, RasterizeParts(parts, camera, local_from_cam, ro));
  out.camera = r.camera;
  out.cell_id = std::move(r.cell_id);
  return out;
}

size_t CellIdRenderer::render_triangles() const {
  size_t n = 0;
  for (const auto& [id, e] : chunks_) n += e.mesh.num_triangles();
  return n;
}

size_t CellIdRenderer::source_triangles() const {
  size_t n = 0;
  for (const auto& [id, e] : chunks_) n += e.source_triangles;
  return n;
}

const TriangleMesh* CellIdRenderer::RenderMesh(uint64_t chunk_id) const {
  auto it = chunks_.find(chunk_id);
  return it == chunks_.end() ? nullptr : &it->second.mesh;
}

std::vector<const TriangleMesh*> CellIdRenderer::RenderMeshes() const {
  std::vector<const TriangleMesh*> v;
  v.reserve(items_.size());
  for (const Item& item : items_) v.push_back(item.mesh);
  return v;
}

}  // namespace exo::planning
