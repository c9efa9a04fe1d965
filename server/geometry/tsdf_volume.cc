#include "server/geometry/tsdf_volume.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <thread>

#include "server/geometry/marching_cubes.h"

namespace exo {
namespace {

// Runs fn(i) for i in [0, n) on up to num_threads threads (the caller's thread included).
template <typename Fn>
void ParallelFor(size_t n, int num_threads, Fn&& fn) {
  const int nt = static_cast<int>(std::min<size_t>(std::max(1, num_threads), n));
  if (nt <= 1) {
    for (size_t i = 0; i < n; ++i) fn(i);
    return;
  }
  std::atomic<size_t> next{0};
  auto worker = [&] {
    for (size_t i; (i = next.fetch_add(1, std::memory_order_relaxed)) < n;) fn(i);
  };
  std::vector<std::thread> threads;
  for (int t = 1; t < nt; ++t) threads.emplace_back(worker);
  worker();
  for (auto& t : threads) t.join();
}

// sRGB8 -> linear [0,1].
const std::array<float, 256>& SrgbToLinearLut() {
  static const std::array<float, 256> lut = [] {
    std::array<float, 256> l{};
    for (int i = 0; i < 256; ++i) {
      const double c = i / 255.0;
      l[i] = static_cast<float>(c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4));
    }
    return l;
  }();
  return lut;
}

// Block coordinates must stay inside PackCell's signed 21-bit range.
constexpr int32_t kMaxBlockCoord = (1 << 20) - 64;

// Lower bound of the incidence cosine used to scale and weight an observation.
constexpr float kMinIncidenceCos = 0.1f;

bool PoseFinite(const Rigid3d& p) {
  const auto& t = p.translation;
  return std::isfinite(t.x) && std::isfinite(t.y) && std::isfinite(t.z) &&
         ValidateQuaternion(p.rotation).ok();
}


// De-duplicates block keys through a small direct-mapped cache before appending them.
class KeySink {
 public:
  explicit KeySink(std::vector<uint64_t>* out) : cache_(kCache, ~uint64_t{0}), out_(out) {}
  void Add(const glm::ivec3& c) {
    const uint64_t key = PackCell(c);
    const size_t h = (key * 0x9E3779B97F4A7C15ull) >> (64 - 12);
    if (cache_[h] != key) {
      cache_[h] = key;
      out_->push_back(key);
    }
  }

 private:
  static constexpr size_t kCache = 4096;
  std::vector<uint64_t> cache_;
  std::vector<uint64_t>* out_;
};

// Walks the segment a -> b (block units) through the block grid (3D DDA, Amanatides & Woo) and
// calls visit(cell, t_enter, t_exit) for every block it crosses (t along the segment, [0, 1]).
template <typename Visit>
void WalkSegment(const glm::dvec3& a, const glm::dvec3& b, Visit&& visit) {
  glm::ivec3 cur(std::floor(a.x), std::floor(a.y), std::floor(a.z));
  const glm::ivec3 end(std::floor(b.x), std::floor(b.y), std::floor(b.z));
  const glm::dvec3 delta = b - a;
  glm::ivec3 step;
  glm::dvec3 t_max, t_delta;
  for (int i = 0; i < 3; ++i) {
    step[i] = delta[i] > 0 ? 1 : (delta[i] < 0 ? -1 : 0);
    if (step[i] == 0) {
      t_max[i] = t_delta[i] = std::numeric_limits<double>::infinity();
    } else {
      const double inv = 1.0 / std::abs(delta[i]);
      t_delta[i] = inv;
      t_max[i] = (step[i] > 0 ? (cur[i] + 1 - a[i]) : (a[i] - cur[i])) * inv;
    }
  }
  double t_enter = 0.0;
  for (int guard = 0; guard < 4096; ++guard) {
    const int axis = t_max.x < t_max.y ? (t_max.x < t_max.z ? 0 : 2) : (t_max.y < t_max.z ? 1 : 2);
    const double t_exit = cur == end ? 1.0 : std::min(1.0, t_max[axis]);
    visit(cur, t_enter, t_exit);
    if (cur == end || t_max[axis] > 1.0) break;
    cur[axis] += step[axis];
    t_enter = t_max[axis];
    t_max[axis] += t_delta[axis];
  }
}

// Whether the segment p0 -> p1 meets the box [lo, hi] (slab test).
bool SegmentHitsBox(const glm::dvec3& p0, const glm::dvec3& p1, const glm::dvec3& lo,
                    const glm::dvec3& hi) {
  double t0 = 0.0, t1 = 1.0;
  const glm::dvec3 d = p1 - p0;
  for (int i = 0; i < 3; ++i) {
    if (d[i] == 0.0) {
      if (p0[i] < lo[i] || p0[i] > hi[i]) return false;
      continue;
    }
    double ta = (lo[i] - p0[i]) / d[i], tb = (hi[i] - p0[i]) / d[i];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1) return false;
  }
  return true;
}

}  // namespace

absl::Status TsdfOptions::Validate() const {
  if (!(voxel_size_m > 0.0f) || !std::isfinite(voxel_size_m))
    return absl::InvalidArgumentError("TsdfOptions.voxel_size_m must be > 0 and finite");
  if (!std::isfinite(truncation_m))
    return absl::InvalidArgumentError("TsdfOptions.truncation_m must be finite");
  if (truncation_m > 0 && truncation_m < voxel_size_m)
    return absl::InvalidArgumentError(
        "TsdfOptions.truncation_m must be >= voxel_size_m (or <= 0 for 4 voxels)");
  if (!(max_weight >= 1.0f))
    return absl::InvalidArgumentError("TsdfOptions.max_weight must be >= 1");
  if (!(min_depth_m >= 0.0f) || !(max_depth_m > min_depth_m) || !std::isfinite(max_depth_m))
    return absl::InvalidArgumentError(
        "TsdfOptions depth range must satisfy 0 <= min_depth_m < max_depth_m < inf");
  if (block_size < 2 || block_size > 32)
    return absl::InvalidArgumentError("TsdfOptions.block_size must be in [2, 32]");
  if (!(min_extract_weight > 0.0f))
    return absl::InvalidArgumentError("TsdfOptions.min_extract_weight must be > 0");
  if (num_threads < 1 || num_threads > 64)
    return absl::InvalidArgumentError("TsdfOptions.num_threads must be in [1, 64]");
  if (alloc_stride < 1 || alloc_stride > 64)
    return absl::InvalidArgumentError("TsdfOptions.alloc_stride must be in [1, 64]");
  return absl::OkStatus();
}

// Per-thread buffers of MeshBlock / MeshBlockFrom and MeshGrid (one block's neighbourhood).
struct MeshScratch {
  std::vector<const TsdfVoxel*> grid;  // nullptr = unobserved
  std::vector<uint8_t> observed, below;
  std::vector<int32_t> edge_vertex;
};
static MeshScratch& Scratch() {
  thread_local MeshScratch s;
  return s;
}

struct TsdfVolume::Block {
  glm::ivec3 coord{0};
  std::vector<TsdfVoxel> voxels;  // block_size^3, x fastest
  uint64_t version = 0;           // last chunk version handed out
  bool has_chunk = false;         // a non-empty chunk was handed out and not removed since
  uint64_t stamp = 0;             // last integration that touched it
};

struct TsdfVolume::Context {
  const ImageF* depth = nullptr;
  float* cos_incidence = nullptr;  // per depth pixel: CosIncidence, or -1 until computed
  const float* x_of_u = nullptr;   // (u - cx) / fx per column
  const float* y_of_v = nullptr;   // (v - cy) / fy per row
  float fx, fy, cx, cy;
  int width, height;
  glm::mat3 cam_from_local_r;
  glm::vec3 cam_from_local_t;
  float min_depth, max_depth, trunc, max_weight;
  // Colour.
  const ImageU8* color = nullptr;
  bool color_registered = false;
  float cfx, cfy, ccx, ccy;
  int cwidth, cheight;
  glm::mat3 color_from_depth_r;
  glm::vec3 color_from_depth_t;
};

// Incidence angle at depth pixel (u, v) (valid depth) from the depth map's own normals (central
// differences, one-sided at depth edges). The projective (along-ray) distance overestimates the
// Euclidean distance by 1/cos at oblique incidence; scaling by cos makes the fused field closer
// to a true SDF and the weight cos down-weights grazing observations (silhouettes, depth edges).
// Returns 0 without neighbours on one axis (isolated pixel or depth edge: treated as grazing).
float TsdfVolume::CosIncidence(const Context& c, int u, int v) {
  auto valid = [&](int uu, int vv) {
    if (uu < 0 || vv < 0 || uu >= c.width || vv >= c.height) return 0.0f;
    const float d = c.depth->row(vv)[uu];
    return (d >= c.min_depth && d <= c.max_depth) ? d : 0.0f;
  };
  const float edge_rel = 0.05f;
  const float d = valid(u, v);
  auto point = [&](int uu, int vv, float dd) {
    return glm::vec3(c.x_of_u[uu] * dd, c.y_of_v[vv] * dd, dd);
  };
  auto near = [&](float dn) { return dn > 0 && std::abs(dn - d) < edge_rel * d; };
  const float dl = valid(u - 1, v), dr = valid(u + 1, v), du = valid(u, v - 1),
              dd = valid(u, v + 1);
  const glm::vec3 p = point(u, v, d);
  glm::vec3 tx(0.0f), ty(0.0f);
  if (near(dl) && near(dr)) tx = point(u + 1, v, dr) - point(u - 1, v, dl);
  else if (near(dr)) tx = point(u + 1, v, dr) - p;
  else if (near(dl)) tx = p - point(u - 1, v, dl);
  if (near(du) && near(dd)) ty = point(u, v + 1, dd) - point(u, v - 1, du);
  else if (near(dd)) ty = point(u, v + 1, dd) - p;
  else if (near(du)) ty = p - point(u, v - 1, du);
  const glm::vec3 n = glm::cross(tx, ty);
  const float nl = glm::length(n);
  return nl > 0 ? std::abs(glm::dot(n, p)) / (nl * glm::length(p)) : 0.0f;
}

TsdfVolume::TsdfVolume(const TsdfOptions& options) : options_(options) {
  EXO_CHECK(options_.Validate().ok());
  truncation_m_ = options_.EffectiveTruncation();
}
TsdfVolume::~TsdfVolume() = default;

TsdfVolume::Block* TsdfVolume::FindBlock(const glm::ivec3& b) const {
  auto it = blocks_.find(PackCell(b));
  return it == blocks_.end() ? nullptr : it->second.get();
}

glm::ivec3 TsdfVolume::BlockCoordOf(const glm::vec3& p) const {
  const float bsm = block_size_m();
  return {static_cast<int32_t>(std::floor(p.x / bsm)), static_cast<int32_t>(std::floor(p.y / bsm)),
          static_cast<int32_t>(std::floor(p.z / bsm))};
}

std::vector<uint64_t> TsdfVolume::BlockKeys() const {
  std::vector<uint64_t> keys;
  keys.reserve(blocks_.size());
  for (const auto& [k, b] : blocks_) keys.push_back(k);
  return keys;
}

void TsdfVolume::SaveState(StateWriter* w) const {
  w->Put<float>(options_.voxel_size_m);
  w->Put<int32_t>(options_.block_size);
  w->Put<uint8_t>(origin_set_);
  w->Put(origin_.origin_in_world);
  w->Put(bmin_);
  w->Put(bmax_);
  w->Put<uint64_t>(stamp_);
  std::vector<uint64_t> dirty(dirty_.begin(), dirty_.end());
  std::sort(dirty.begin(), dirty.end());
  w->PutVec(dirty);
  w->PutVec(removed_);
  std::vector<uint64_t> keys = BlockKeys();
  std::sort(keys.begin(), keys.end());
  w->Put<uint64_t>(keys.size());
  for (uint64_t k : keys) {
    const Block& b = *blocks_.at(k);
    w->Put<uint64_t>(k);
    w->Put(b.coord);
    w->Put<uint64_t>(b.version);
    w->Put<uint8_t>(b.has_chunk);
    w->Put<uint64_t>(b.stamp);
    w->PutVec(b.voxels);
  }
}

absl::Status TsdfVolume::LoadState(StateReader* r) {
  float voxel = 0;
  int32_t block_size = 0;
  uint8_t origin_set = 0;
  r->Get(&voxel) && r->Get(&block_size);
  if (r->ok() && (voxel != options_.voxel_size_m || block_size != options_.block_size))
    return absl::FailedPreconditionError(absl::StrCat(
        "TSDF state of voxel ", voxel, " m / block ", block_size, " does not fit a volume of ",
        options_.voxel_size_m, " m / ", options_.block_size));
  std::vector<uint64_t> dirty;
  uint64_t n = 0;
  r->Get(&origin_set) && r->Get(&origin_.origin_in_world) && r->Get(&bmin_) && r->Get(&bmax_) &&
      r->Get(&stamp_) && r->GetVec(&dirty) && r->GetVec(&removed_) &&
      r->Count(&n, sizeof(uint64_t) * 3);
  origin_set_ = origin_set != 0;
  dirty_ = absl::flat_hash_set<uint64_t>(dirty.begin(), dirty.end());
  blocks_.clear();
  const size_t voxels = static_cast<size_t>(block_size) * block_size * block_size;
  for (uint64_t i = 0; r->ok() && i < n; ++i) {
    uint64_t key = 0;
    uint8_t has_chunk = 0;
    auto b = std::make_unique<Block>();
    r->Get(&key) && r->Get(&b->coord) && r->Get(&b->version) && r->Get(&has_chunk) &&
        r->Get(&b->stamp) && r->GetVec(&b->voxels);
    b->has_chunk = has_chunk != 0;
    if (r->ok() && (b->voxels.size() != voxels || PackCell(b->coord) != key))
      return absl::DataLossError("TSDF state: a block of the wrong size or key");
    blocks_[key] = std::move(b);
  }
  return r->Status("TSDF volume");
}

size_t TsdfVolume::bytes() const {
  const size_t per_block = sizeof(Block) + sizeof(TsdfVoxel) * options_.block_size *
                                               options_.block_size * options_.block_size;
  return blocks_.size() * per_block +
         blocks_.capacity() * (sizeof(std::pair<uint64_t, std::unique_ptr<Block>>) + 1) +
         dirty_.capacity() * (sizeof(uint64_t) + 1) + removed_.capacity() * sizeof(uint64_t) +
         cos_scratch_.capacity() * sizeof(float);
}

bool TsdfVolume::Bounds(glm::dvec3* min_local, glm::dvec3* max_local) const {
  if (blocks_.empty()) return false;
  const double bsm = block_size_m();
  *min_local = glm::dvec3(bmin_) * bsm;
  *max_local = glm::dvec3(bmax_ + 1) * bsm;
  return true;
}

absl::StatusOr<TsdfIntegrateStats> TsdfVolume::Integrate(const Frame& frame,
                                                         const LocalOrigin& origin) {
  if (origin_set_ && origin.origin_in_world != origin_.origin_in_world)
    return absl::InvalidArgumentError(
        "TsdfVolume: frame's LocalOrigin differs from the one the volume was built in");
  if (!PoseFinite(frame.world_from_cam))
    return absl::InvalidArgumentError("TsdfVolume: frame pose has NaN/Inf or a bad rotation");
  if (!PoseFinite(frame.color_from_depth))
    return absl::InvalidArgumentError("TsdfVolume: color_from_depth has NaN/Inf or a bad rotation");
  const Rigid3d local_from_depth = origin.ToLocal(frame.world_from_cam) * frame.color_from_depth;
  const bool use_color = options_.integrate_color && !frame.color.empty();
  auto stats = IntegrateDepth(frame.depth_m, frame.depth_camera, local_from_depth,
                              use_color ? &frame.color : nullptr,
                              use_color ? &frame.color_camera : nullptr, &frame.color_from_depth);
  if (stats.ok() && !origin_set_) {
    origin_ = origin;
    origin_set_ = true;
  }
  return stats;
}

absl::StatusOr<TsdfIntegrateStats> TsdfVolume::IntegrateDepth(
    const ImageF& depth_m, const PinholeCamera& cam, const Rigid3d& local_from_cam,
    const ImageU8* color, const PinholeCamera* color_camera, const Rigid3d* color_from_depth) {
  if (auto s = cam.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("TsdfVolume: depth camera: ", s.message()));
  if (depth_m.empty() || depth_m.channels() != 1 || depth_m.width() != cam.width ||
      depth_m.height() != cam.height)
    return absl::InvalidArgumentError(absl::StrCat(
        "TsdfVolume: depth image ", depth_m.width(), "x", depth_m.height(), "x",
        depth_m.channels(), " does not match the depth camera ", cam.width, "x", cam.height));
  if (!PoseFinite(local_from_cam))
    return absl::InvalidArgumentError("TsdfVolume: depth camera pose has NaN/Inf or a bad rotation");
  const double bsm = block_size_m();
  const glm::dvec3 cam_pos = local_from_cam.translation;
  const double reach_blocks = (options_.max_depth_m + truncation_m_) / bsm + 2;
  for (int i = 0; i < 3; ++i)
    if (std::abs(cam_pos[i] / bsm) + reach_blocks > kMaxBlockCoord)
      return absl::OutOfRangeError(
          "TsdfVolume: camera is too far from the local origin for the block index range; "
          "integrate in a LocalOrigin near the scene");

  Context ctx;
  ctx.depth = &depth_m;
  ctx.fx = float(cam.fx), ctx.fy = float(cam.fy), ctx.cx = float(cam.cx), ctx.cy = float(cam.cy);
  ctx.width = cam.width, ctx.height = cam.height;
  const Rigid3d cam_from_local = local_from_cam.Inverse();
  ctx.cam_from_local_r = glm::mat3(cam_from_local.RotationMatrix());
  ctx.cam_from_local_t = glm::vec3(cam_from_local.translation);
  ctx.min_depth = options_.min_depth_m, ctx.max_depth = options_.max_depth_m;
  ctx.trunc = truncation_m_, ctx.max_weight = options_.max_weight;
  if (color && color_camera && options_.integrate_color && color->channels() == 3 &&
      color->width() == color_camera->width && color->height() == color_camera->height &&
      color_camera->Validate().ok()) {
    const Rigid3d cfd = color_from_depth ? *color_from_depth : Rigid3d::Identity();
    if (!PoseFinite(cfd))
      return absl::InvalidArgumentError("TsdfVolume: color_from_depth has NaN/Inf");
    ctx.color = color;
    ctx.color_registered = cfd.translation == glm::dvec3(0.0) &&
                           RotationAngleRad(cfd.rotation, glm::dquat(1, 0, 0, 0)) < 1e-12 &&
                           color_camera->fx == cam.fx && color_camera->fy == cam.fy &&
                           color_camera->cx == cam.cx && color_camera->cy == cam.cy &&
                           color_camera->width == cam.width && color_camera->height == cam.height;
    ctx.cfx = float(color_camera->fx), ctx.cfy = float(color_camera->fy);
    ctx.ccx = float(color_camera->cx), ctx.ccy = float(color_camera->cy);
    ctx.cwidth = color_camera->width, ctx.cheight = color_camera->height;
    ctx.color_from_depth_r = glm::mat3(cfd.RotationMatrix());
    ctx.color_from_depth_t = glm::vec3(cfd.translation);
  }

  // 1. Visible-block selection (blocks the truncation bands cross).
  const int nt = options_.num_threads;
  std::vector<std::vector<uint64_t>> keys_per_task;
  std::vector<size_t> valid_per_task;
  CollectBandBlocks(depth_m, cam, local_from_cam, &keys_per_task, &valid_per_task);

  // 1b. Incidence angle per pixel, computed lazily by IntegrateBlock for the pixels voxels
  //     project to (-1 = not yet computed; at 2-4 cm voxels most pixels are never sampled).
  cos_scratch_.assign(size_t(cam.width) * cam.height, -1.0f);  // keeps its pages across frames
  ctx.cos_incidence = cos_scratch_.data();
  std::vector<float> x_of_u(cam.width), y_of_v(cam.height);
  for (int u = 0; u < cam.width; ++u) x_of_u[u] = (u - ctx.cx) / ctx.fx;
  for (int v = 0; v < cam.height; ++v) y_of_v[v] = (v - ctx.cy) / ctx.fy;
  ctx.x_of_u = x_of_u.data();
  ctx.y_of_v = y_of_v.data();

  // 2. Allocate missing blocks; list each touched block once.
  TsdfIntegrateStats stats;
  ++stamp_;
  std::vector<Block*> touched;
  const int bs = options_.block_size;
  for (size_t t = 0; t < keys_per_task.size(); ++t) {
    stats.valid_pixels += valid_per_task[t];
    for (uint64_t key : keys_per_task[t]) {
      auto [it, inserted] = blocks_.try_emplace(key);
      if (inserted) {
        it->second = std::make_unique<Block>();
        it->second->coord = UnpackCell(key);
        it->second->voxels.resize(size_t(bs) * bs * bs);
        ++stats.new_blocks;
        const glm::ivec3 c = it->second->coord;
        if (blocks_.size() == 1) {
          bmin_ = bmax_ = c;
        } else {
          bmin_ = glm::min(bmin_, c);
          bmax_ = glm::max(bmax_, c);
        }
      }
      Block* blk = it->second.get();
      if (blk->stamp != stamp_) {
        blk->stamp = stamp_;
        touched.push_back(blk);
      }
    }
  }
  stats.touched_blocks = touched.size();

  // 3. Projective TSDF update of every voxel of the touched blocks.
  ParallelFor(touched.size(), nt, [&](size_t i) { IntegrateBlock(touched[i], ctx); });
  for (Block* b : touched) dirty_.insert(PackCell(b->coord));
  return stats;
}

void TsdfVolume::CollectBandBlocks(const ImageF& depth_m, const PinholeCamera& cam,
                                   const Rigid3d& local_from_cam,
                                   std::vector<std::vector<uint64_t>>* keys,
                                   std::vector<size_t>* valid) const {
  const int s = options_.alloc_stride;
  const double bsm = block_size_m();
  const glm::dvec3 cam_pos = local_from_cam.translation;
  const glm::dmat3 rot = local_from_cam.RotationMatrix();
  const double trunc = truncation_m_;
  const double min_d = options_.min_depth_m, max_d = options_.max_depth_m;
  const int cell_rows = (cam.height + s - 1) / s;
  const int cell_rows_per_task = std::max(1, 16 / s);
  const size_t num_tasks = (cell_rows + cell_rows_per_task - 1) / cell_rows_per_task;
  keys->assign(num_tasks, {});
  valid->assign(num_tasks, 0);
  ParallelFor(num_tasks, options_.num_threads, [&](size_t task) {
    KeySink sink(&(*keys)[task]);
    size_t n_valid = 0;
    const int cy0 = int(task) * cell_rows_per_task, cy1 = std::min(cell_rows, cy0 + cell_rows_per_task);
    std::vector<double> depths;
    depths.reserve(size_t(s) * s);
    for (int cy = cy0; cy < cy1; ++cy) {
      const int v0 = cy * s, v1 = std::min(cam.height, v0 + s) - 1;
      for (int u0 = 0; u0 < cam.width; u0 += s) {
        const int u1 = std::min(cam.width, u0 + s) - 1;
        depths.clear();
        for (int v = v0; v <= v1; ++v) {
          const float* row = depth_m.row(v);
          for (int u = u0; u <= u1; ++u) {
            const double d = row[u];
            if (d >= min_d && d <= max_d) depths.push_back(d);  // 0, <0, NaN, Inf all fail
          }
        }
        if (depths.empty()) continue;
        n_valid += depths.size();
        if (s == 1) {
          // Exact per-pixel band: range +- trunc along the pixel's ray.
          const glm::dvec3 ray_cam = cam.RayZ1({double(u0), double(v0)});
          const double ray_len = glm::length(ray_cam);
          const glm::dvec3 dir = rot * (ray_cam / ray_len);
          const double range = depths[0] * ray_len;
          WalkSegment((cam_pos + dir * std::max(0.0, range - trunc)) / bsm,
                      (cam_pos + dir * (range + trunc)) / bsm,
                      [&](const glm::ivec3& c, double, double) { sink.Add(c); });
          continue;
        }
        // The cell's bands, parameterised by z-depth: pixel (u, v)'s band is range +- trunc
        // along its ray, i.e. z in [d - trunc / L, d + trunc / L] with L = |RayZ1(u, v)| >=
        // L_min (the cell's smallest), and its point at depth z is the central ray's point at z
        // plus the lateral offset R * ((x_u - x_c) z, (y_v - y_c) z, 0), whose bounding box is
        // z * e with e = |R col 0| * hu / fx + |R col 1| * hv / fy (hu, hv: the cell's half size
        // in pixels). So every block a pixel's band crosses meets the central segment over the
        // cell's z-interval swept by the box z * e: the walk below keeps, for each block the
        // central segment crosses, the blocks within that box of the piece inside it.
        const double uc = 0.5 * (u0 + u1), vc = 0.5 * (v0 + v1);
        const double hu = 0.5 * (u1 - u0), hv = 0.5 * (v1 - v0);
        const glm::dvec3 e = (glm::abs(rot[0]) * (hu / cam.fx) + glm::abs(rot[1]) * (hv / cam.fy)) / bsm;
        const glm::dvec3 dir_z = rot * cam.RayZ1({uc, vc});  // local step per metre of z
        const double nu = std::max({0.0, (u0 - cam.cx) / cam.fx, (cam.cx - u1) / cam.fx});
        const double nv = std::max({0.0, (v0 - cam.cy) / cam.fy, (cam.cy - v1) / cam.fy});
        const double t_z = trunc / std::sqrt(1.0 + nu * nu + nv * nv);  // trunc / L_min
        auto sweep = [&](double z0, double z1) {
          z0 = std::max(0.0, z0);
          const glm::dvec3 a = (cam_pos + dir_z * z0) / bsm, b = (cam_pos + dir_z * z1) / bsm;
          WalkSegment(a, b, [&](const glm::ivec3&, double t0, double t1) {
            const glm::dvec3 p0 = a + (b - a) * t0, p1 = a + (b - a) * t1;
            // z grows along the segment; 1e-9 blocks absorbs rounding against stride 1.
            const glm::dvec3 r = e * (z0 + (z1 - z0) * t1) + 1e-9;
            const glm::dvec3 lo = glm::min(p0, p1) - r, hi = glm::max(p0, p1) + r;
            const glm::ivec3 l(std::floor(lo.x), std::floor(lo.y), std::floor(lo.z));
            const glm::ivec3 h(std::floor(hi.x), std::floor(hi.y), std::floor(hi.z));
            for (int z = l.z; z <= h.z; ++z)
              for (int y = l.y; y <= h.y; ++y)
                for (int x = l.x; x <= h.x; ++x)
                  if (SegmentHitsBox(p0, p1, glm::dvec3(x, y, z) - r, glm::dvec3(x, y, z) + 1.0 + r))
                    sink.Add({x, y, z});
          });
        };
        // Depth intervals: one when the spread is within 2 * t_z (the bands overlap), else the
        // union of the per-pixel intervals (a depth edge inside the cell: no free-space blocks).
        auto [mn, mx] = std::minmax_element(depths.begin(), depths.end());
        if (*mx - *mn <= 2 * t_z) {
          sweep(*mn - t_z, *mx + t_z);
          continue;
        }
        std::sort(depths.begin(), depths.end());
        double lo = depths[0], hi = depths[0];
        for (size_t i = 1; i < depths.size(); ++i) {
          if (depths[i] - hi > 2 * t_z) {
            sweep(lo - t_z, hi + t_z);
            lo = depths[i];
          }
          hi = depths[i];
        }
        sweep(lo - t_z, hi + t_z);
      }
    }
    (*valid)[task] = n_valid;
  });
}

void TsdfVolume::IntegrateBlock(Block* block, const Context& c) const {
  const int bs = options_.block_size;
  const float vs = options_.voxel_size_m;
  const glm::ivec3 base = block->coord * bs;
  const float* depth = c.depth->data();
  const int w = c.width;
  const uint8_t* color = c.color ? c.color->data() : nullptr;
  const float max_cw = std::min(255.0f, c.max_weight);
  for (int z = 0; z < bs; ++z) {
    for (int y = 0; y < bs; ++y) {
      const glm::vec3 p_row(float(base.x) * vs, float(base.y + y) * vs, float(base.z + z) * vs);
      const glm::vec3 pc_row = c.cam_from_local_r * p_row + c.cam_from_local_t;
      const glm::vec3 dx = c.cam_from_local_r[0] * vs;  // column 0: image of the local x axis
      TsdfVoxel* vox = &block->voxels[(size_t(z) * bs + y) * bs];
      for (int x = 0; x < bs; ++x) {
        const glm::vec3 pc = pc_row + dx * float(x);
        if (!(pc.z > 1e-6f)) continue;  // behind (or at) the camera
        const float inv_z = 1.0f / pc.z;
        const float xz = pc.x * inv_z, yz = pc.y * inv_z;
        const float uf = c.fx * xz + c.cx, vf = c.fy * yz + c.cy;
        if (!(uf >= -0.5f && vf >= -0.5f && uf < w - 0.5f && vf < c.height - 0.5f)) continue;
        const int ui = int(uf + 0.5f), vi = int(vf + 0.5f);
        const size_t pix = size_t(vi) * w + ui;
        const float d = depth[pix];
        if (!(d >= c.min_depth && d <= c.max_depth)) continue;  // invalid depth (0/NaN/Inf)
        // Signed distance along the ray (range difference), positive in front of the surface.
        const float sdf = (d - pc.z) * std::sqrt(1.0f + xz * xz + yz * yz);
        if (sdf < -c.trunc) continue;  // occluded: beyond the band behind the surface
        // Lazily computed, shared by the threads: a pixel computed twice gets the same value.
        std::atomic_ref<float> cos_slot(c.cos_incidence[pix]);
        float cos_raw = cos_slot.load(std::memory_order_relaxed);
        if (cos_raw < 0.0f) {
          cos_raw = CosIncidence(c, ui, vi);
          cos_slot.store(cos_raw, std::memory_order_relaxed);
        }
        const float cos_i = std::max(cos_raw, kMinIncidenceCos);
        const float tsdf = std::clamp(sdf * cos_i, -c.trunc, c.trunc);
        TsdfVoxel& v = vox[x];
        const float nw = v.weight + cos_i;
        v.sdf_m = (v.sdf_m * v.weight + tsdf * cos_i) / nw;
        v.weight = std::min(nw, c.max_weight);
        if (color && sdf < c.trunc) {
          int cu = ui, cv = vi;
          if (!c.color_registered) {
            const glm::vec3 pcol = c.color_from_depth_r * pc + c.color_from_depth_t;
            if (!(pcol.z > 1e-6f)) continue;
            const float cuf = c.cfx * pcol.x / pcol.z + c.ccx, cvf = c.cfy * pcol.y / pcol.z + c.ccy;
            if (!(cuf >= -0.5f && cvf >= -0.5f && cuf < c.cwidth - 0.5f && cvf < c.cheight - 0.5f))
              continue;
            cu = int(cuf + 0.5f), cv = int(cvf + 0.5f);
          }
          const uint8_t* rgb = color + (size_t(cv) * c.cwidth + cu) * 3;
          const float cw = v.color_weight, ncw = cw + 1.0f;
          v.r = uint8_t(std::lround((v.r * cw + rgb[0]) / ncw));
          v.g = uint8_t(std::lround((v.g * cw + rgb[1]) / ncw));
          v.b = uint8_t(std::lround((v.b * cw + rgb[2]) / ncw));
          v.color_weight = uint8_t(std::min(ncw, max_cw));
        }
      }
    }
  }
}

TriangleMesh TsdfVolume::MeshBlock(const glm::ivec3& bc) const {
  TriangleMesh mesh;
  const Block* self = FindBlock(bc);
  if (!self) return mesh;
  const int bs = options_.block_size;
  const int n = bs + 3;  // local grid: voxels -1 .. bs+1 of this block along each axis
  const Block* nb[3][3][3];
  for (int dz = -1; dz <= 1; ++dz)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) nb[dz + 1][dy + 1][dx + 1] = FindBlock(bc + glm::ivec3(dx, dy, dz));
  // Early out (the usual case for blocks in the band in front of or behind the surface): a
  // surface needs observed voxels of both signs among the cube corners, i.e. voxels 0..bs of this
  // block's frame (this block and the first layer of the 7 blocks above it). Same test as the
  // any_neg / any_pos scan below, without building the neighbourhood grid.
  {
    bool neg = false, pos = false;
    for (int oz = 0; oz <= 1 && !(neg && pos); ++oz)
      for (int oy = 0; oy <= 1 && !(neg && pos); ++oy)
        for (int ox = 0; ox <= 1 && !(neg && pos); ++ox) {
          const Block* b = nb[oz + 1][oy + 1][ox + 1];
          if (!b) continue;
          // Own block: all bs voxels per axis; an upper neighbour: only its layer 0.
          const int ez = oz ? 1 : bs, ey = oy ? 1 : bs, ex = ox ? 1 : bs;
          for (int z = 0; z < ez; ++z)
            for (int y = 0; y < ey; ++y) {
              const TsdfVoxel* row = &b->voxels[(size_t(z) * bs + y) * bs];
              // Branch-free (observed = !(weight < min), as below; sign as below).
              for (int x = 0; x < ex; ++x) {
                const TsdfVoxel& v = row[x];
                const bool obs = !(v.weight < options_.min_extract_weight);
                const bool below = v.sdf_m < 0;
                neg |= obs & below;
                pos |= obs & !below;
              }
            }
        }
    if (!neg || !pos) return mesh;
  }
  // Scratch buffers reused per thread (MeshBlock runs for every re-meshed chunk of every frame).
  MeshScratch& sc = Scratch();
  std::vector<const TsdfVoxel*>& grid = sc.grid;
  grid.assign(size_t(n) * n * n, nullptr);  // nullptr = unobserved
  // The same neighbourhood as flat arrays for the cube classification below: corner observed
  // (1/0) and below the surface (sdf < 0), so the 512 cubes are classified without branches or
  // pointer chasing.
  std::vector<uint8_t>& observed = sc.observed;
  std::vector<uint8_t>& below = sc.below;
  observed.assign(size_t(n) * n * n, 0);
  below.assign(size_t(n) * n * n, 0);
  auto gi = [n](int x, int y, int z) { return (size_t(z) * n + y) * n + x; };
  // (Both signs among observed corners were established by the early out above, over the same
  // region and with the same tests.)
  for (int lz = 0; lz < n; ++lz) {
    const int gz = lz - 1, oz = gz < 0 ? -1 : (gz >= bs ? 1 : 0), iz = gz - oz * bs;
    for (int ly = 0; ly < n; ++ly) {
      const int gy = ly - 1, oy = gy < 0 ? -1 : (gy >= bs ? 1 : 0), iy = gy - oy * bs;
      for (int lx = 0; lx < n; ++lx) {
        const int gx = lx - 1, ox = gx < 0 ? -1 : (gx >= bs ? 1 : 0), ix = gx - ox * bs;
        const Block* b = nb[oz + 1][oy + 1][ox + 1];
        if (!b) continue;
        const TsdfVoxel* v = &b->voxels[(size_t(iz) * bs + iy) * bs + ix];
        const bool obs = !(v->weight < options_.min_extract_weight);
        const size_t i = gi(lx, ly, lz);
        grid[i] = obs ? v : nullptr;
        observed[i] = obs;
        below[i] = v->sdf_m < 0;
      }
    }
  }

  return MeshGrid(bc);
}

TriangleMesh TsdfVolume::MeshGrid(const glm::ivec3& bc) const {
  TriangleMesh mesh;
  const int bs = options_.block_size;
  const int n = bs + 3;
  MeshScratch& sc = Scratch();
  const std::vector<const TsdfVoxel*>& grid = sc.grid;
  const std::vector<uint8_t>& observed = sc.observed;
  const std::vector<uint8_t>& below = sc.below;
  auto gi = [n](int x, int y, int z) { return (size_t(z) * n + y) * n + x; };
  const auto& cases = mc::Cases();
  const auto& lut = SrgbToLinearLut();
  const float vs = options_.voxel_size_m;
  const glm::ivec3 base = bc * bs;
  const bool with_color = options_.integrate_color;
  // Vertex of the edge starting at cube-space corner (x,y,z) in 0..bs along `axis`.
  const int m = bs + 1;
  std::vector<int32_t>& edge_vertex = sc.edge_vertex;
  edge_vertex.assign(size_t(m) * m * m * 3, -1);
  auto gradient = [&](int x, int y, int z) {
    glm::vec3 g(0.0f);
    const float s = grid[gi(x, y, z)]->sdf_m;
    const int p[3] = {x, y, z};
    for (int a = 0; a < 3; ++a) {
      int lo[3] = {p[0], p[1], p[2]}, hi[3] = {p[0], p[1], p[2]};
      --lo[a];
      ++hi[a];
      const TsdfVoxel* vl = grid[gi(lo[0], lo[1], lo[2])];
      const TsdfVoxel* vh = grid[gi(hi[0], hi[1], hi[2])];
      if (vl && vh) g[a] = 0.5f * (vh->sdf_m - vl->sdf_m);
      else if (vh) g[a] = vh->sdf_m - s;
      else if (vl) g[a] = s - vl->sdf_m;
    }
    return g;
  };
  auto vertex_of = [&](int cx, int cy, int cz, int axis) -> uint32_t {
    int32_t& slot = edge_vertex[((size_t(cz) * m + cy) * m + cx) * 3 + axis];
    if (slot >= 0) return uint32_t(slot);
    const int ux = cx + (axis == 0), uy = cy + (axis == 1), uz = cz + (axis == 2);
    const TsdfVoxel* v0 = grid[gi(cx + 1, cy + 1, cz + 1)];
    const TsdfVoxel* v1 = grid[gi(ux + 1, uy + 1, uz + 1)];
    const float s0 = v0->sdf_m, s1 = v1->sdf_m;
    const float t = s0 / (s0 - s1);  // s0, s1 have different signs: denominator != 0
    glm::vec3 p(float(base.x + cx) * vs, float(base.y + cy) * vs, float(base.z + cz) * vs);
    p[axis] = (float((axis == 0 ? base.x + cx : axis == 1 ? base.y + cy : base.z + cz)) + t) * vs;
    const glm::vec3 g = glm::mix(gradient(cx + 1, cy + 1, cz + 1), gradient(ux + 1, uy + 1, uz + 1), t);
    const float gl = glm::length(g);
    slot = int32_t(mesh.positions.size());
    mesh.positions.push_back(p);
    mesh.normals.push_back(gl > 1e-12f ? g / gl : glm::vec3(0.0f));
    if (with_color) {
      const glm::vec3 c0(lut[v0->r], lut[v0->g], lut[v0->b]);
      const glm::vec3 c1(lut[v1->r], lut[v1->g], lut[v1->b]);
      glm::vec3 col(0.5f);
      if (v0->color_weight && v1->color_weight) col = glm::mix(c0, c1, t);
      else if (v0->color_weight) col = c0;
      else if (v1->color_weight) col = c1;
      mesh.colors.push_back(col);
    }
    return uint32_t(slot);
  };

  size_t corner_offset[8];
  for (int k = 0; k < 8; ++k) {
    const auto& o = mc::kCornerOffset[k];
    corner_offset[k] = gi(o[0], o[1], o[2]);
  }
  bool degenerate_normals = false;
  for (int z = 0; z < bs; ++z)
    for (int y = 0; y < bs; ++y)
      for (int x = 0; x < bs; ++x) {
        int ci = 0;
        int ok = 1;
        const size_t c0 = gi(x + 1, y + 1, z + 1);
        for (int k = 0; k < 8; ++k) {
          const size_t i = c0 + corner_offset[k];
          ok &= observed[i];
          ci |= int(below[i] & observed[i]) << k;
        }
        if (!ok || ci == 0 || ci == 255) continue;
        const auto& tri = cases.tris[ci];
        for (int k = 0; tri[k] >= 0; ++k) {
          const int e = tri[k];
          const auto& o = mc::kCornerOffset[mc::kEdgeCorners[e][0]];
          const uint32_t vi = vertex_of(x + o[0], y + o[1], z + o[2], mc::kEdgeAxis[e]);
          mesh.indices.push_back(vi);
          if (mesh.normals[vi] == glm::vec3(0.0f)) degenerate_normals = true;
        }
      }
  if (degenerate_normals) {
    // Flat gradient (rare): fall back to the area-weighted face normals.
    std::vector<glm::vec3> acc(mesh.positions.size(), glm::vec3(0.0f));
    for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
      const uint32_t a = mesh.indices[t], b = mesh.indices[t + 1], c = mesh.indices[t + 2];
      const glm::vec3 fn = glm::cross(mesh.positions[b] - mesh.positions[a],
                                      mesh.positions[c] - mesh.positions[a]);
      acc[a] += fn, acc[b] += fn, acc[c] += fn;
    }
    for (size_t i = 0; i < acc.size(); ++i)
      if (mesh.normals[i] == glm::vec3(0.0f) && glm::length(acc[i]) > 0)
        mesh.normals[i] = glm::normalize(acc[i]);
  }
  return mesh;
}

TriangleMesh TsdfVolume::MeshBlockFrom(
    const glm::ivec3& bc, const std::function<const TsdfVoxel*(const glm::ivec3&)>& voxel) const {
  const int bs = options_.block_size;
  const int n = bs + 3;
  MeshScratch& sc = Scratch();
  sc.grid.assign(size_t(n) * n * n, nullptr);
  sc.observed.assign(size_t(n) * n * n, 0);
  sc.below.assign(size_t(n) * n * n, 0);
  const glm::ivec3 base = bc * bs;
  bool neg = false, pos = false;
  for (int lz = 0; lz < n; ++lz)
    for (int ly = 0; ly < n; ++ly)
      for (int lx = 0; lx < n; ++lx) {
        const TsdfVoxel* v = voxel(base + glm::ivec3(lx - 1, ly - 1, lz - 1));
        if (!v || v->weight < options_.min_extract_weight) continue;
        const size_t i = (size_t(lz) * n + ly) * n + lx;
        sc.grid[i] = v;
        sc.observed[i] = 1;
        sc.below[i] = v->sdf_m < 0;
        // Cube corners of this block's cubes: voxels 0..bs (the early out of MeshBlock).
        if (lx >= 1 && ly >= 1 && lz >= 1 && lx <= bs + 1 && ly <= bs + 1 && lz <= bs + 1)
          (v->sdf_m < 0 ? neg : pos) = true;
      }
  if (!neg || !pos) return TriangleMesh();
  return MeshGrid(bc);
}

const TsdfVoxel* TsdfVolume::VoxelAt(const glm::ivec3& g) const {
  const int bs = options_.block_size;
  const glm::ivec3 b(g.x >= 0 ? g.x / bs : (g.x + 1) / bs - 1, g.y >= 0 ? g.y / bs : (g.y + 1) / bs - 1,
                     g.z >= 0 ? g.z / bs : (g.z + 1) / bs - 1);
  const Block* blk = FindBlock(b);
  if (!blk) return nullptr;
  const glm::ivec3 l = g - b * bs;
  return &blk->voxels[(size_t(l.z) * bs + l.y) * bs + l.x];
}

const TsdfVoxel* TsdfVolume::BlockVoxels(const glm::ivec3& b) const {
  const Block* blk = FindBlock(b);
  return blk ? blk->voxels.data() : nullptr;
}

TsdfVoxel* TsdfVolume::MutableVoxelAt(const glm::ivec3& g) {
  return const_cast<TsdfVoxel*>(static_cast<const TsdfVolume*>(this)->VoxelAt(g));
}

uint64_t TsdfVolume::ChunkVersion(uint64_t key) const {
  auto it = blocks_.find(key);
  return it == blocks_.end() ? 0 : it->second->version;
}

std::vector<uint64_t> TsdfVolume::TakeDirtyBlocks() {
  std::vector<uint64_t> keys(dirty_.begin(), dirty_.end());
  dirty_.clear();
  std::sort(keys.begin(), keys.end());
  return keys;
}

std::vector<MeshChunk> TsdfVolume::ExtractDirtyChunks() {
  absl::flat_hash_set<uint64_t> todo;
  for (uint64_t key : dirty_) {
    const glm::ivec3 b = UnpackCell(key);
    // A block's voxels are read by its own chunk and by the chunks of the 7 blocks below it.
    for (int dz = -1; dz <= 0; ++dz)
      for (int dy = -1; dy <= 0; ++dy)
        for (int dx = -1; dx <= 0; ++dx) {
          const uint64_t k = PackCell(b + glm::ivec3(dx, dy, dz));
          if (blocks_.contains(k)) todo.insert(k);
        }
  }
  dirty_.clear();
  std::vector<uint64_t> keys(todo.begin(), todo.end());
  std::sort(keys.begin(), keys.end());
  std::vector<TriangleMesh> meshes(keys.size());
  ParallelFor(keys.size(), options_.num_threads,
              [&](size_t i) { meshes[i] = MeshBlock(UnpackCell(keys[i])); });
  std::vector<MeshChunk> out;
  for (size_t i = 0; i < keys.size(); ++i) {
    Block* b = blocks_.at(keys[i]).get();
    if (!meshes[i].empty()) {
      out.push_back({keys[i], ++b->version, std::move(meshes[i])});
      b->has_chunk = true;
    } else if (b->has_chunk) {
      b->has_chunk = false;
      removed_.push_back(keys[i]);
    }
  }
  return out;
}

std::vector<uint64_t> TsdfVolume::TakeRemovedChunkIds() {
  std::vector<uint64_t> r;
  r.swap(removed_);
  return r;
}

TriangleMesh TsdfVolume::ExtractBlock(uint64_t key) const { return MeshBlock(UnpackCell(key)); }

TriangleMesh TsdfVolume::ExtractAll() const {
  std::vector<uint64_t> keys = BlockKeys();
  std::sort(keys.begin(), keys.end());
  std::vector<TriangleMesh> meshes(keys.size());
  ParallelFor(keys.size(), options_.num_threads,
              [&](size_t i) { meshes[i] = MeshBlock(UnpackCell(keys[i])); });
  TriangleMesh all;
  for (const auto& m : meshes)
    if (!m.empty()) all.Append(m);
  return all;
}

bool TsdfVolume::SdfAt(const glm::vec3& p, float* sdf_m) const {
  const float vs = options_.voxel_size_m;
  const int bs = options_.block_size;
  const glm::vec3 g = p / vs;
  const glm::ivec3 g0(std::floor(g.x), std::floor(g.y), std::floor(g.z));
  const glm::vec3 f = g - glm::vec3(g0);
  float acc = 0.0f;
  for (int k = 0; k < 8; ++k) {
    const auto& o = mc::kCornerOffset[k];
    const glm::ivec3 gv = g0 + glm::ivec3(o[0], o[1], o[2]);
    const glm::ivec3 b(gv.x >= 0 ? gv.x / bs : (gv.x + 1) / bs - 1,
                       gv.y >= 0 ? gv.y / bs : (gv.y + 1) / bs - 1,
                       gv.z >= 0 ? gv.z / bs : (gv.z + 1) / bs - 1);
    const Block* blk = FindBlock(b);
    if (!blk) return false;
    const glm::ivec3 l = gv - b * bs;
    const TsdfVoxel& v = blk->voxels[(size_t(l.z) * bs + l.y) * bs + l.x];
    if (v.weight < options_.min_extract_weight) return false;
    const float w = (o[0] ? f.x : 1 - f.x) * (o[1] ? f.y : 1 - f.y) * (o[2] ? f.z : 1 - f.z);
    acc += w * v.sdf_m;
  }
  *sdf_m = acc;
  return true;
}

}  // namespace exo
