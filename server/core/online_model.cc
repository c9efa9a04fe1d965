#include "server/core/online_model.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "server/geometry/scene_scale.h"

namespace exo::core {
namespace {

// FNV-1a over raw bytes (doubles hashed bit-exactly: both callers produce the same bits).
struct Fnv {
  uint64_t h = 1469598103934665603ull;
  void Bytes(const void* p, size_t n) {
    const auto* b = static_cast<const unsigned char*>(p);
    for (size_t i = 0; i < n; ++i) {
      h ^= b[i];
      h *= 1099511628211ull;
    }
  }
  template <typename T>
  void Add(const T& v) {
    Bytes(&v, sizeof(v));
  }
  uint64_t Get48() const { return (h ^ (h >> 48)) & ((uint64_t{1} << 48) - 1); }
};

TsdfOptions TsdfFor(const OnlineModelOptions& o, double voxel_m) {
  TsdfOptions t;
  t.voxel_size_m = static_cast<float>(voxel_m);
  t.max_depth_m = static_cast<float>(o.max_depth_m);
  t.min_depth_m = static_cast<float>(o.min_depth_m);
  t.num_threads = o.tsdf_threads;
  return t;
}

}  // namespace

double MedianDepth(const ImageF& depth) {
  std::vector<float> v;
  v.reserve(depth.size());
  for (float z : depth.span())
    if (z > 0 && std::isfinite(z)) v.push_back(z);
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

absl::Status OnlineModelOptions::Validate() const {
  EXO_RETURN_IF_ERROR(frame_quality.Validate());
  auto nonneg = [](double v) { return std::isfinite(v) && v >= 0.0; };
  if (!nonneg(voxel_m) || !nonneg(cell_m) || !nonneg(d_max_m) || !nonneg(sigma_m))
    return absl::InvalidArgumentError(
        "voxel_m, cell_m, d_max_m, sigma_m must be finite and >= 0 (0 = automatic)");
  if (!(max_depth_m > min_depth_m) || !(min_depth_m >= 0.0) || !std::isfinite(max_depth_m))
    return absl::InvalidArgumentError("need 0 <= min_depth_m < max_depth_m");
  if (fuse_depth_downscale < 1 || fuse_depth_downscale > 8)
    return absl::InvalidArgumentError("fuse_depth_downscale must be in [1, 8]");
  if (mesh_every_n_frames < 1)
    return absl::InvalidArgumentError("mesh_every_n_frames must be >= 1");
  {
    // The planner's own checks of the selection options, at configuration time.
    planning::PlannerOptions po;
    po.policy = policy;
    po.baseline_m_per_rad = baseline_m_per_rad;
    po.baseline_stream_frames = baseline_stream_frames;
    po.dispersion = dispersion;
    po.dispersion_m_per_rad = dispersion_m_per_rad;
    po.dispersion_rotation_scale = dispersion_rotation_scale;
    po.dispersion_turn_overlap_rad = dispersion_turn_overlap_rad;
    po.dispersion_turn_overlap_scale = dispersion_turn_overlap_scale;
    po.dispersion_turn_axis = dispersion_turn_axis;
    po.dispersion_guard = dispersion_guard;
    po.dispersion_guard_relative = dispersion_guard_relative;
    po.dispersion_guard_unique = dispersion_guard_unique;
    po.dispersion_guard_unique_after = dispersion_guard_unique_after;
    po.dispersion_weight_exponent = dispersion_weight_exponent;
    po.dispersion_weight_after = dispersion_weight_after;
    po.dispersion_keep_nearest = dispersion_keep_nearest;
    po.dispersion_recency = dispersion_recency;
    po.dispersion_drop_older = dispersion_drop_older;
    po.dispersion_time_steps = dispersion_time_steps;
    po.dispersion_time_max = dispersion_time_max;
    po.dispersion_time_arc = dispersion_time_arc;
    po.dispersion_time_auto_ref = dispersion_time_auto_ref;
    po.observe_zero_coverage = observe_zero_coverage;
    po.dispersion_weight_until = dispersion_weight_until;
    EXO_RETURN_IF_ERROR(po.Validate());
  }
  if (tsdf_threads < 1) return absl::InvalidArgumentError("tsdf_threads must be >= 1");
  if (id_buffer_stride < 1 || id_buffer_stride > 32)
    return absl::InvalidArgumentError("id_buffer_stride must be in [1, 32]");
  if (max_views < 1 || max_bytes < 1)
    return absl::InvalidArgumentError("max_views and max_bytes must be >= 1");
  if (r_max < 2) return absl::InvalidArgumentError("r_max must be >= 2");
  // Clients hold up to 64 references per cell (VulkanRendererOptions::max_refs_per_cell).
  if (render_refs_max < 0 || render_refs_max > 64)
    return absl::InvalidArgumentError(
        "render_refs_max must be in [0, 64] (clients hold at most 64 references per cell)");
  if (!(lambda >= 0.0 && lambda <= 1.0))
    return absl::InvalidArgumentError("lambda must be in [0, 1]");
  if (!(tau_max > 0.0) || !nonneg(delta_tau_sum))
    return absl::InvalidArgumentError("tau_max must be > 0 and delta_tau_sum >= 0");
  if (!nonneg(max_candidates_per_s_when_full))
    return absl::InvalidArgumentError("max_candidates_per_s_when_full must be >= 0");
  if (!std::isfinite(cellid_lod_m) || !nonneg(cellid_lod_keep) || !nonneg(cellid_max_range_m))
    return absl::InvalidArgumentError(
        "cellid_lod_m must be finite, cellid_lod_keep and cellid_max_range_m >= 0");
  return absl::OkStatus();
}

absl::StatusOr<SceneSetup> ChooseSceneSetup(const Frame& first, const OnlineModelOptions& o,
                                            std::optional<LocalOrigin> restored_origin,
                                            std::optional<double> restored_cell_m) {
  EXO_RETURN_IF_ERROR(o.Validate());
  SceneSetup s;
  if (restored_origin) {
    s.origin = *restored_origin;
  } else {
    s.origin.origin_in_world = first.world_from_cam.translation;
  }
  // D from the first frame's surface fused alone.
  const double probe_voxel = o.voxel_m > 0 ? o.voxel_m : 0.02;
  glm::dvec3 lo(0.0), hi(0.0);
  if (!first.depth_m.empty()) {
    TsdfOptions to = TsdfFor(o, probe_voxel);
    TsdfVolume probe(to);
    if (probe.Integrate(first, s.origin).ok() && !probe.Bounds(&lo, &hi)) lo = hi = glm::dvec3(0.0);
    s.view_depth_m = MedianDepth(first.depth_m);
  }
  const SceneScale scale = DeriveSceneScale(lo, hi);
  s.scale = scale;
  s.diameter_m = scale.diameter_m;
  s.voxel_m = o.voxel_m > 0 ? o.voxel_m : std::clamp(scale.diameter_m / 600.0, 0.02, 0.15);
  s.cell_m = restored_cell_m ? *restored_cell_m : o.cell_m > 0 ? o.cell_m : scale.cell_size_m;
  s.d_max_m = scale.d_max_m;
  s.sigma_m = scale.sigma_m;
  if (s.view_depth_m > 0) {
    const planning::PlannerOptions f =
        planning::PlannerOptions::ForScene(scale.diameter_m, s.view_depth_m);
    s.d_max_m = f.d_max_m;
    s.sigma_m = f.sigma_m;
  }
  if (o.d_max_m > 0) s.d_max_m = o.d_max_m;
  if (o.sigma_m > 0) s.sigma_m = o.sigma_m;
  return s;
}

// ---- geometry ----

OnlineGeometry::OnlineGeometry(const TsdfOptions& tsdf, const OnlineModelOptions& options,
                               const SceneSetup& setup)
    : volume_(tsdf), options_(options), setup_(setup) {}

absl::StatusOr<std::unique_ptr<OnlineGeometry>> OnlineGeometry::Create(
    const OnlineModelOptions& options, const SceneSetup& setup) {
  EXO_RETURN_IF_ERROR(options.Validate());
  const TsdfOptions t = TsdfFor(options, setup.voxel_m);
  EXO_RETURN_IF_ERROR(t.Validate());
  return std::unique_ptr<OnlineGeometry>(new OnlineGeometry(t, options, setup));
}

absl::StatusOr<GeometryUpdate> OnlineGeometry::Integrate(const Frame& f) {
  GeometryUpdate u;
  if (f.depth_m.empty()) return u;  // colour-only frame: nothing to fuse
  const int k = options_.fuse_depth_downscale;
  if (k == 1) {
    EXO_RETURN_IF_ERROR(volume_.Integrate(f, setup_.origin).status());
  } else {
    // Every k-th depth sample with the depth camera scaled to match (pixel centres kept).
    const ImageF& d = f.depth_m;
    const int w = d.width() / k, h = d.height() / k;
    ImageF small(w, h);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) small.at(x, y) = d.at(x * k + k / 2, y * k + k / 2);
    PinholeCamera cam = f.depth_camera;
    cam.fx /= k;
    cam.fy /= k;
    cam.cx = (cam.cx - k / 2) / k;
    cam.cy = (cam.cy - k / 2) / k;
    cam.width = w;
    cam.height = h;
    const Rigid3d local_from_depth = setup_.origin.ToLocal(f.world_from_cam) * f.color_from_depth;
    EXO_RETURN_IF_ERROR(volume_
                            .IntegrateDepth(small, cam, local_from_depth, &f.color, &f.color_camera,
                                            &f.color_from_depth)
                            .status());
  }
  if (++fused_ % options_.mesh_every_n_frames != 0) return u;
  u.chunks = volume_.ExtractDirtyChunks();
  u.removed = volume_.TakeRemovedChunkIds();
  for (const MeshChunk& c : u.chunks) live_[c.id] = c.version;
  for (uint64_t id : u.removed) live_.erase(id);
  return u;
}

uint64_t OnlineGeometry::Digest() const {
  Fnv h;
  for (const auto& [id, version] : live_) {
    h.Add(id);
    h.Add(version);
  }
  return h.Get48();
}

void OnlineGeometry::SaveState(StateWriter* w) const {
  w->Put<uint64_t>(fused_);
  w->Put<uint64_t>(live_.size());
  for (const auto& [id, version] : live_) {
    w->Put(id);
    w->Put(version);
  }
  volume_.SaveState(w);
}

absl::Status OnlineGeometry::LoadState(StateReader* r) {
  uint64_t n = 0;
  r->Get(&fused_) && r->Count(&n, 2 * sizeof(uint64_t));
  live_.clear();
  for (uint64_t i = 0; r->ok() && i < n; ++i) {
    uint64_t id = 0, version = 0;
    if (r->Get(&id) && r->Get(&version)) live_[id] = version;
  }
  EXO_RETURN_IF_ERROR(r->Status("online geometry"));
  return volume_.LoadState(r);
}

void ProxyMesh::Apply(const GeometryUpdate& u) {
  for (const MeshChunk& c : u.chunks) chunks_[c.id] = c;
  for (uint64_t id : u.removed) chunks_.erase(id);
}
void ProxyMesh::Set(MeshChunk c) { chunks_[c.id] = std::move(c); }
TriangleMesh ProxyMesh::All() const {
  TriangleMesh m;
  for (const auto& [id, chunk] : chunks_) {
    const TriangleMesh& c = chunk.mesh;
    if (m.empty() && m.positions.empty()) {
      m = c;
      m.normals.clear();
      m.material.clear();
      continue;
    }
    const uint32_t base = static_cast<uint32_t>(m.positions.size());
    m.positions.insert(m.positions.end(), c.positions.begin(), c.positions.end());
    if (!m.colors.empty() && c.colors.size() == c.positions.size())
      m.colors.insert(m.colors.end(), c.colors.begin(), c.colors.end());
    else
      m.colors.clear();
    for (uint32_t i : c.indices) m.indices.push_back(base + i);
  }
  return m;
}
size_t ProxyMesh::bytes() const {
  size_t b = 0;
  for (const auto& [id, c] : chunks_) b += c.mesh.bytes();
  return b;
}
size_t ProxyMesh::triangles() const {
  size_t t = 0;
  for (const auto& [id, c] : chunks_) t += c.mesh.num_triangles();
  return t;
}

// ---- planning ----

PlanFrame PlanFrame::Of(const Frame& f, const LocalOrigin& origin) {
  PlanFrame p;
  p.local_from_cam = origin.ToLocal(f.world_from_cam);
  p.camera = f.color_camera;
  if (!f.depth_m.empty()) p.depth = &f.depth_m;
  if (!f.color.empty()) p.color = &f.color;
  p.depth_camera = f.depth_camera;
  p.local_from_depth = p.local_from_cam * f.color_from_depth;
  p.timestamp_s = f.timestamp_s;
  p.bytes = f.color.bytes() +
            static_cast<size_t>(f.color.width()) * f.color.height() * sizeof(float) +
            sizeof(StoredView);
  return p;
}

absl::StatusOr<planning::Candidate> CandidateFromDepth(ViewId id, const ImageF& depth,
                                                       const PinholeCamera& depth_camera,
                                                       const Rigid3d& local_from_depth,
                                                       const Rigid3d& local_from_cam,
                                                       const CellGrid& grid, int stride,
                                                       size_t bytes) {
  planning::Candidate cand;
  EXO_ASSIGN_OR_RETURN(cand.cells,
                       planning::CountDepthCellPixels(depth, depth_camera, local_from_depth, grid,
                                                      stride, &cand.id_camera));
  cand.id = id;
  cand.local_from_cam = local_from_cam;
  cand.bytes = bytes;
  return cand;
}

OnlinePlanner::OnlinePlanner(planning::ViewPlanner planner, const OnlineModelOptions& options,
                             const SceneSetup& setup,
                             std::unique_ptr<planning::CellIdRenderer> cell_ids)
    : planner_(std::move(planner)),
      options_(options),
      setup_(setup),
      areas_(CellGrid{setup.cell_m}),
      cell_ids_(std::move(cell_ids)),
      quality_(options.frame_quality),
      drift_(planning::StreamDriftOptions{}) {}

absl::StatusOr<std::unique_ptr<OnlinePlanner>> OnlinePlanner::Create(
    const OnlineModelOptions& options, const SceneSetup& setup) {
  EXO_RETURN_IF_ERROR(options.Validate());
  planning::PlannerOptions po;
  po.r_max = options.r_max;
  po.render_refs_max = options.render_refs_max;
  po.max_views = options.max_views;
  po.max_bytes = options.max_bytes;
  po.lambda = options.lambda;
  po.tau_max = options.tau_max;
  po.delta_tau_sum = options.delta_tau_sum;
  po.novelty_positional = options.novelty_positional;
  po.soft_saturation = options.soft_saturation;
  po.dispersion = options.dispersion;
  po.policy = options.policy;
  po.baseline_m_per_rad = options.baseline_m_per_rad;
  po.baseline_stream_frames = options.baseline_stream_frames;
  po.dispersion_m_per_rad = options.dispersion_m_per_rad;
  po.dispersion_rotation_scale = options.dispersion_rotation_scale;
  po.dispersion_turn_overlap_rad = options.dispersion_turn_overlap_rad;
  po.dispersion_turn_overlap_scale = options.dispersion_turn_overlap_scale;
  po.dispersion_turn_axis = options.dispersion_turn_axis;
  po.dispersion_guard = options.dispersion_guard;
  po.dispersion_guard_relative = options.dispersion_guard_relative;
  po.dispersion_guard_unique = options.dispersion_guard_unique;
  po.dispersion_guard_unique_after = options.dispersion_guard_unique_after;
  po.dispersion_weight_exponent = options.dispersion_weight_exponent;
  po.dispersion_weight_after = options.dispersion_weight_after;
  po.dispersion_keep_nearest = options.dispersion_keep_nearest;
  po.dispersion_recency = options.dispersion_recency;
  po.dispersion_drop_older = options.dispersion_drop_older;
  po.dispersion_time_steps = options.dispersion_time_steps;
  po.dispersion_time_max = options.dispersion_time_max;
  po.dispersion_time_arc = options.dispersion_time_arc;
  po.dispersion_time_auto_ref = options.dispersion_time_auto_ref;
  po.observe_zero_coverage = options.observe_zero_coverage;
  po.dispersion_weight_until = options.dispersion_weight_until;
  po.cell_size_m = setup.cell_m;
  po.d_max_m = setup.d_max_m;
  po.sigma_m = setup.sigma_m;
  EXO_ASSIGN_OR_RETURN(planning::ViewPlanner planner, planning::ViewPlanner::Create(po));
  std::unique_ptr<planning::CellIdRenderer> cell_ids;
  if (options.id_from_proxy) {
    planning::CellIdRendererOptions co;
    co.grid = planner.grid();
    co.lod_cluster_m = options.cellid_lod_m >= 0.0
                           ? options.cellid_lod_m
                           : planning::DefaultCellIdLodM(setup.cell_m, setup.voxel_m);
    co.lod_keep_fraction = options.cellid_lod_keep;
    co.max_range_m =
        options.cellid_max_range_m > 0 ? options.cellid_max_range_m : 2.0 * options.max_depth_m;
    EXO_ASSIGN_OR_RETURN(auto r, planning::CellIdRenderer::Create(co));
    cell_ids = std::make_unique<planning::CellIdRenderer>(std::move(r));
  }
  return std::unique_ptr<OnlinePlanner>(
      new OnlinePlanner(std::move(planner), options, setup, std::move(cell_ids)));
}

absl::Status OnlinePlanner::Apply(const GeometryUpdate& u) {
  if (u.empty()) return absl::OkStatus();
  for (const MeshChunk& c : u.chunks) areas_.UpdateChunk(c);
  for (uint64_t id : u.removed) areas_.RemoveChunk(id);
  if (cell_ids_) {
    // A malformed chunk is skipped (the rest applied) and counted; planning goes on.
    if (!cell_ids_->Update(u.chunks).ok()) ++counters_.cellid_update_errors;
    for (uint64_t id : u.removed) cell_ids_->Remove(id);
  }
  const std::vector<CellId> changed = areas_.TakeChangedCells();
  if (!options_.cell_areas) return absl::OkStatus();
  for (CellId k : changed) {
    EXO_RETURN_IF_ERROR(planner_.SetCellArea(k, areas_.Area(k)));
    ++counters_.areas_set;
  }
  return absl::OkStatus();
}

std::vector<std::pair<CellId, std::vector<ViewId>>> OnlinePlanner::RefsOf(
    const std::vector<CellId>& cells) const {
  std::vector<std::pair<CellId, std::vector<ViewId>>> out;
  out.reserve(cells.size());
  for (CellId c : cells) out.emplace_back(c, planner_.PublishedRefs(c));
  return out;
}

absl::StatusOr<HandOff> OnlinePlanner::Decide(planning::Candidate cand) {
  HandOff h;
  h.id = cand.id;
  h.candidate = true;
  ++counters_.candidates;
  EXO_ASSIGN_OR_RETURN(planning::Decision d, planner_.Consider(cand));
  h.tau_sum = d.tau_sum;
  if (!d.accepted) return h;
  ++counters_.accepted;
  h.accepted = true;
  h.removed = d.removed;
  for (ViewId v : d.removed) poses_.erase(v);
  poses_[cand.id] = cand.local_from_cam;
  h.cell_refs = RefsOf(d.changed_cells);
  return h;
}

absl::StatusOr<HandOff> OnlinePlanner::Plan(const PlanFrame& f) {
  ++counters_.frames;
  const ViewId id = ++last_id_;
  HandOff none;
  none.id = id;
  // Every frame with depth enters the drift measurement (also frames the governor skips): the
  // time term follows the stream's own time-correlated error.
  if (options_.dispersion_time_auto_ref > 0.0 && f.depth != nullptr && !f.depth->empty()) {
    drift_.Next(*f.depth, f.depth_camera, f.local_from_depth);
    planner_.SetTimeScale(drift_.TimeScale(options_.dispersion_time_auto_ref));  // 0 until measured
  }
  // Every frame enters the quality reference window (also frames the governor skips).
  const double quality = options_.frame_quality.gamma > 0 && f.color != nullptr
                             ? quality_.Next(planning::LaplacianVariance(*f.color))
                             : 1.0;
  if (options_.max_candidates_per_s_when_full > 0 && planner_.num_views() >= options_.max_views) {
    const double min_gap_s = 1.0 / options_.max_candidates_per_s_when_full;
    if (f.timestamp_s - last_candidate_s_ < min_gap_s && f.timestamp_s >= last_candidate_s_) {
      ++counters_.governed;
      none.governed = true;
      return none;
    }
    last_candidate_s_ = f.timestamp_s;
  }
  const int stride = options_.id_buffer_stride;
  if (cell_ids_ && cell_ids_->num_chunks() > 0) {
    EXO_ASSIGN_OR_RETURN(planning::CellIdBuffer r,
                         cell_ids_->Render(f.local_from_cam, f.camera, f.camera.width / stride,
                                           f.camera.height / stride));
    planning::Candidate cand;
    cand.id = id;
    cand.local_from_cam = f.local_from_cam;
    cand.id_camera = r.camera;
    cand.cells = planning::CountCellPixels(r.cell_id.data(), r.cell_id.size());
    cand.bytes = f.bytes;
    cand.quality = quality;
    ++counters_.ids_from_proxy;
    return Decide(std::move(cand));
  }
  if (f.depth == nullptr || f.depth->empty()) return none;  // no depth, no proxy: no cells
  EXO_ASSIGN_OR_RETURN(planning::Candidate cand,
                       CandidateFromDepth(id, *f.depth, f.depth_camera, f.local_from_depth,
                                          f.local_from_cam, planner_.grid(), stride, f.bytes));
  cand.quality = quality;
  return Decide(std::move(cand));
}

absl::StatusOr<HandOff> OnlinePlanner::Readmit(const StoredView& v) {
  last_id_ = std::max(last_id_, v.id);
  const size_t bytes = v.color.bytes() +
                       static_cast<size_t>(v.color.width()) * v.color.height() * sizeof(float) +
                       sizeof(StoredView);
  EXO_ASSIGN_OR_RETURN(
      planning::Candidate cand,
      CandidateFromDepth(v.id, v.depth_m, v.camera, v.local_from_cam, v.local_from_cam,
                         planner_.grid(), options_.id_buffer_stride, bytes));
  cand.readmit = true;  // a baseline policy keeps it (no stream position after a restart)
  return Decide(std::move(cand));
}

absl::StatusOr<std::vector<std::pair<CellId, std::vector<ViewId>>>> OnlinePlanner::Remove(
    ViewId id) {
  EXO_ASSIGN_OR_RETURN(std::vector<CellId> changed, planner_.Remove(id));
  poses_.erase(id);
  return RefsOf(changed);
}

absl::Status OnlinePlanner::SaveState(StateWriter* w) const {
  if (cell_ids_)
    return absl::UnimplementedError("planner state with cell ids from the proxy (id_from_proxy)");
  planner_.SaveState(w);
  areas_.SaveState(w);
  w->Put<uint64_t>(poses_.size());
  for (const auto& [id, pose] : poses_) {
    w->Put(id);
    w->Put(pose);
  }
  w->Put(last_id_);
  w->Put(last_candidate_s_);
  w->PutVec(quality_.State());
  w->Put(counters_);
  w->PutVec(drift_.State());
  return absl::OkStatus();
}

absl::Status OnlinePlanner::LoadState(StateReader* r) {
  if (cell_ids_)
    return absl::UnimplementedError("planner state with cell ids from the proxy (id_from_proxy)");
  EXO_RETURN_IF_ERROR(planner_.LoadState(r));
  EXO_RETURN_IF_ERROR(areas_.LoadState(r));
  uint64_t n = 0;
  r->Count(&n, sizeof(ViewId) + sizeof(Rigid3d));
  poses_.clear();
  for (uint64_t i = 0; r->ok() && i < n; ++i) {
    ViewId id = 0;
    Rigid3d pose;
    if (r->Get(&id) && r->Get(&pose)) poses_[id] = pose;
  }
  std::vector<double> recent, drift;
  r->Get(&last_id_) && r->Get(&last_candidate_s_) && r->GetVec(&recent) && r->Get(&counters_) &&
      r->GetVec(&drift);
  quality_.SetState(recent);
  drift_.SetState(drift);
  return r->Status("online planner");
}

uint64_t OnlinePlanner::Digest() const {
  Fnv h;
  for (const auto& [id, p] : poses_) {
    h.Add(id);
    h.Add(p.translation.x);
    h.Add(p.translation.y);
    h.Add(p.translation.z);
    h.Add(p.rotation.w);
    h.Add(p.rotation.x);
    h.Add(p.rotation.y);
    h.Add(p.rotation.z);
  }
  const auto refs = planner_.CellPublishedRefs();
  std::map<CellId, const std::vector<ViewId>*> sorted;
  for (const auto& [c, r] : refs) sorted[c] = &r;
  for (const auto& [c, r] : sorted) {
    h.Add(c);
    for (ViewId v : *r) h.Add(v);
    h.Add(ViewId{0});
  }
  return h.Get48();
}

// ---- store hand-off ----

ImageF RegisterDepthToColor(const Frame& f) {
  const PinholeCamera& dc = f.depth_camera;
  const PinholeCamera& cc = f.color_camera;
  const bool same_camera = dc.fx == cc.fx && dc.fy == cc.fy && dc.cx == cc.cx && dc.cy == cc.cy &&
                           dc.width == cc.width && dc.height == cc.height;
  const bool identity = f.color_from_depth.translation == glm::dvec3(0.0) &&
                        std::abs(std::abs(f.color_from_depth.rotation.w) - 1.0) < 1e-12;
  if (same_camera && identity) return f.depth_m;
  ImageF out(cc.width, cc.height);
  for (int y = 0; y < f.depth_m.height(); ++y)
    for (int x = 0; x < f.depth_m.width(); ++x) {
      const float z = f.depth_m.at(x, y);
      if (!(z > 0.0f) || !std::isfinite(z)) continue;
      const glm::dvec3 p_color = f.color_from_depth * dc.Unproject({x, y}, z);
      glm::dvec2 uv;
      if (!cc.Project(p_color, &uv)) continue;
      const int u = static_cast<int>(std::lround(uv.x)), v = static_cast<int>(std::lround(uv.y));
      if (!out.Contains(u, v)) continue;
      float& dst = out.at(u, v);
      if (dst == 0.0f || p_color.z < dst) dst = static_cast<float>(p_color.z);
    }
  return out;
}

StoredView StoredViewOf(const Frame& f, ViewId id, const LocalOrigin& origin) {
  StoredView view;
  view.id = id;
  view.camera = f.color_camera;
  view.local_from_cam = origin.ToLocal(f.world_from_cam);
  view.color = f.color;
  view.depth_m = RegisterDepthToColor(f);
  view.exposure = f.exposure ? static_cast<float>(*f.exposure) : 1.0f;
  return view;
}

// ---- both halves ----

absl::StatusOr<std::unique_ptr<OnlineModel>> OnlineModel::Create(const OnlineModelOptions& options,
                                                                 const SceneSetup& setup) {
  auto m = std::make_unique<OnlineModel>();
  EXO_ASSIGN_OR_RETURN(m->geometry_, OnlineGeometry::Create(options, setup));
  EXO_ASSIGN_OR_RETURN(m->planner_, OnlinePlanner::Create(options, setup));
  return m;
}

absl::StatusOr<HandOff> OnlineModel::Step(const Frame& frame) {
  EXO_ASSIGN_OR_RETURN(last_update_, geometry_->Integrate(frame));
  EXO_RETURN_IF_ERROR(planner_->Apply(last_update_));
  return planner_->Plan(PlanFrame::Of(frame, planner_->setup().origin));
}

uint64_t OnlineModel::Digest() const {
  return ModelDigest(geometry_->Digest(), planner_->Digest());
}

uint64_t ModelDigest(uint64_t geometry_digest, uint64_t planner_digest) {
  Fnv h;
  h.Add(geometry_digest);
  h.Add(planner_digest);
  return h.Get48();
}

std::string DigestHex(uint64_t digest) {
  char buf[24];
  std::snprintf(buf, sizeof(buf), "%012llx", static_cast<unsigned long long>(digest));
  return buf;
}

}  // namespace exo::core
