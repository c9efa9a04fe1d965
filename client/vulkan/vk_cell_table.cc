#include "client/vulkan/vk_cell_table.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>

namespace exo::vk {
namespace {

constexpr uint32_t kEmptyKey = 0xFFFFFFFFu;
constexpr uint32_t kTombKeyLo = 0xFFFFFFFEu;

// Same function as CellHash32 in shaders/lumigraph_common.glsl.
uint32_t CellHash32(uint32_t lo, uint32_t hi) {
  uint32_t h = (lo * 0x9E3779B1u) ^ (hi * 0x85EBCA77u + 0x165667B1u);
  h ^= h >> 15;
  h *= 0x2C1B3C6Du;
  h ^= h >> 12;
  return h;
}

uint32_t FloatBits(float f) {
  uint32_t u;
  std::memcpy(&u, &f, 4);
  return u;
}

}  // namespace

absl::Status CellTable::Init() {
  EXO_RETURN_IF_ERROR(RebuildTable(64));
  return GrowSlabs(1);
}

absl::Status CellTable::GrowSlabs(uint32_t slabs) {
  uint32_t ns = std::max<uint32_t>(slab_capacity_, 1);
  while (ns < slabs) ns *= 2;
  if (refs_buf_.buffer && ns == slab_capacity_) return absl::OkStatus();
  const size_t slab_bytes = size_t(opt_.max_refs_per_cell) * sizeof(uint32_t);
  EXO_ASSIGN_OR_RETURN(
      Buffer nb, Buffer::Create(ctx_, ns * slab_bytes, VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT));
  std::memset(nb.mapped, 0xFF, ns * slab_bytes);
  // Device-to-device copy of the old slabs (on lavapipe both are host memory).
  if (refs_buf_.buffer) std::memcpy(nb.mapped, refs_buf_.mapped, slab_capacity_ * slab_bytes);
  for (uint32_t s = ns; s-- > slab_capacity_;) free_slabs_.push_back(s);
  // kRankedTexels RGBA32UI texels (16 bytes each) per 4-byte reference slot.
  const size_t ranked_bytes = ns * slab_bytes * 4 * kRankedTexels;
  EXO_ASSIGN_OR_RETURN(Buffer nr, Buffer::Create(ctx_, ranked_bytes,
                                                 VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                                     VK_BUFFER_USAGE_STORAGE_TEXEL_BUFFER_BIT));
  std::memset(nr.mapped, 0, ranked_bytes);
  refs_buf_ = std::move(nb);
  ranked_buf_ = std::move(nr);
  slab_capacity_ = ns;
  storage_changed_ = true;
  return absl::OkStatus();
}

uint32_t CellTable::Probe(CellId id, bool for_insert) const {
  const uint32_t lo = uint32_t(id), hi = uint32_t(id >> 32);
  const uint32_t mask = table_mask();
  uint32_t h = CellHash32(lo, hi) & mask;
  uint32_t first_tomb = kNoSlot;
  for (uint32_t probe = 0; probe <= mask; ++probe) {
    const glm::uvec4& e = table_[h];
    if (e.x == lo && e.y == hi) return h;
    if (e.x == kEmptyKey && e.y == kEmptyKey)
      return for_insert ? (first_tomb != kNoSlot ? first_tomb : h) : kNoSlot;
    if (for_insert && e.x == kTombKeyLo && e.y == kEmptyKey && first_tomb == kNoSlot)
      first_tomb = h;
    h = (h + 1) & mask;
  }
  return for_insert ? first_tomb : kNoSlot;
}

// Linear-probing displacement of table slot i from the home slot of `id`. The shader's lookup
// loop runs max_probe + 1 probes at most: a resident key is never displaced further, so a miss
// can stop there. (An unbounded "until empty" loop measured ~1000x slower on llvmpipe.)
uint32_t CellTable::Displacement(CellId id, uint32_t i) const {
  const uint32_t mask = table_mask();
  return (i - (CellHash32(uint32_t(id), uint32_t(id >> 32)) & mask)) & mask;
}

glm::uvec4 CellTable::EntryOf(CellId id, const Entry& c) const {
  return {uint32_t(id), uint32_t(id >> 32), c.slab * uint32_t(opt_.max_refs_per_cell),
          uint32_t(c.refs.size())};
}

absl::Status CellTable::RebuildTable(uint32_t capacity) {
  table_.assign(capacity, glm::uvec4(kEmptyKey, kEmptyKey, 0, 0));
  tombstones_ = 0;
  max_probe_ = 0;
  for (auto& [id, c] : cells_) {
    const uint32_t i = Probe(id, true);
    c.table_index = i;
    max_probe_ = std::max(max_probe_, Displacement(id, i));
    table_[i] = EntryOf(id, c);
  }
  EXO_ASSIGN_OR_RETURN(table_buf_, Buffer::Create(ctx_, capacity * sizeof(glm::uvec4),
                                                  VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT));
  std::memcpy(table_buf_.mapped, table_.data(), capacity * sizeof(glm::uvec4));
  stats_.bytes += capacity * sizeof(glm::uvec4);
  ++stats_.table_rebuilds;
  storage_changed_ = true;
  return absl::OkStatus();
}

void CellTable::UploadTableEntry(uint32_t i) {
  static_cast<glm::uvec4*>(table_buf_.mapped)[i] = table_[i];
  stats_.bytes += sizeof(glm::uvec4);
}

void CellTable::WriteSlab(const Entry& c) {
  uint32_t* dst =
      static_cast<uint32_t*>(refs_buf_.mapped) + size_t(c.slab) * opt_.max_refs_per_cell;
  for (size_t i = 0; i < c.refs.size(); ++i) dst[i] = views_.SlotOf(c.refs[i]);
  stats_.bytes += c.refs.size() * sizeof(uint32_t);
  ++stats_.cell_uploads;
}

void CellTable::RefreshCellsOf(ViewId view) {
  auto it = cells_of_view_.find(view);
  if (it != cells_of_view_.end())
    for (CellId c : it->second) WriteSlab(cells_.at(c));
}

void CellTable::Unlink(CellId id, const Entry& c) {
  for (ViewId v : c.refs) {
    auto rit = cells_of_view_.find(v);
    if (rit != cells_of_view_.end()) {
      rit->second.erase(id);
      if (rit->second.empty()) cells_of_view_.erase(rit);
    }
  }
}

void CellTable::Erase(std::unordered_map<CellId, Entry>::iterator it) {
  const uint32_t ti = it->second.table_index;
  table_[ti] = glm::uvec4(kTombKeyLo, kEmptyKey, 0, 0);
  UploadTableEntry(ti);
  ++tombstones_;
  free_slabs_.push_back(it->second.slab);
  cells_.erase(it);
}

absl::StatusOr<std::unordered_map<CellId, CellTable::Entry>::iterator> CellTable::Insert(
    CellId id) {
  // Keep load (cells + tombstones) <= 1/2 of the table.
  if (2 * (cells_.size() + 1 + tombstones_) > table_.size()) {
    uint32_t cap = uint32_t(table_.size());
    while (2 * (cells_.size() + 1) > cap / 2) cap *= 2;  // headroom: load <= 1/4 after
    EXO_RETURN_IF_ERROR(RebuildTable(cap));
  }
  if (free_slabs_.empty()) EXO_RETURN_IF_ERROR(GrowSlabs(slab_capacity_ + 1));
  Entry c;
  c.slab = free_slabs_.back();
  free_slabs_.pop_back();
  const uint32_t ti = Probe(id, true);
  if (table_[ti].x == kTombKeyLo) --tombstones_;
  c.table_index = ti;
  max_probe_ = std::max(max_probe_, Displacement(id, ti));
  return cells_.emplace(id, std::move(c)).first;
}

absl::Status CellTable::SetRefs(CellId id, std::span<const ViewId> refs) {
  if (id == kNoCell || (id >> 63) != 0)
    return absl::InvalidArgumentError(absl::StrCat("invalid cell id ", id));
  if (refs.size() > size_t(opt_.max_refs_per_cell))
    return absl::InvalidArgumentError(absl::StrCat(
        "cell has ", refs.size(), " references, max_refs_per_cell is ", opt_.max_refs_per_cell));
  auto it = cells_.find(id);
  if (it != cells_.end()) Unlink(id, it->second);
  if (refs.empty()) {
    if (it != cells_.end()) Erase(it);
    return absl::OkStatus();
  }
  if (it == cells_.end()) {
    EXO_ASSIGN_OR_RETURN(it, Insert(id));
  }
  Entry& c = it->second;
  c.refs.assign(refs.begin(), refs.end());
  for (ViewId v : c.refs) cells_of_view_[v].insert(id);
  WriteSlab(c);
  table_[c.table_index] = EntryOf(id, c);
  UploadTableEntry(c.table_index);
  return absl::OkStatus();
}

// Per-frame reference ranking (exact). For every resident cell and every reference, an UPPER
// BOUND of the blend weight (3.5) the fragment shader can compute for any surface point x of
// the cell this frame (validity = 1):
//   x lies in the ball B(m, r) around the cell centre (r = half diagonal, inflated for the
//   float cell assignment); with D_o = |c_o - m|, D_i = |c_i - m|:
//   w_d = cos(angle(c_o - x, c_i - x)) <= cos(max(0, angle(c_o - m, c_i - m) - asin(r / D_o)
//         - asin(r / D_i)))  (each ray turns by at most asin(r / D) as x moves in the ball;
//         1 when a camera is inside the ball),
//   w_p is decreasing in |c_i - x| >= D_i - r and increasing in |c_o - x| <= D_o + r,
//   bound = max(lambda W_d + (1 - lambda) W_p, min_weight), plus a slack for float rounding.
// The cell's references are written to ranked_buf_ sorted by (bound desc, position in the
// cell's list asc): per slot (c_i.xyz, bound) and the view's projection rows with layer,
// position, size and exposure (WriteRankedSlot). blend.frag stops at the first reference whose bound is below the n-th best
// weight found so far (no later one can enter the best n) and breaks weight ties by the
// position in the cell's list, so the selection equals blend_math.h's in-order InsertBest.
// Non-resident references get bound -1 (sorted last, never evaluated).
// Cells whose ball lies entirely outside the novel camera's frustum (side planes through the
// centre, z >= 0) are skipped: no pixel's surface point can fall in them this frame, so their
// stale records are never read (exact).
namespace {

// The novel camera's frustum as inward unit normals in camera coordinates: the four side planes
// through the centre (pixel-edge rays) and z >= 0.
std::array<glm::dvec3, 5> FrustumPlanes(const PinholeCamera& cam) {
  return {glm::normalize(glm::dvec3(cam.fx, 0.0, cam.cx + 0.5)),
          glm::normalize(glm::dvec3(-cam.fx, 0.0, cam.width - 0.5 - cam.cx)),
          glm::normalize(glm::dvec3(0.0, cam.fy, cam.cy + 0.5)),
          glm::normalize(glm::dvec3(0.0, -cam.fy, cam.height - 0.5 - cam.cy)),
          glm::dvec3(0.0, 0.0, 1.0)};
}

// The ranked texels of one reference (kRankedTexels): (c_i.xyz, bound), then the rows of
// M = K R^T (P's 3x3 part) with (layer | position << 16), (width | height << 16) and the
// exposure in their w; bound -1 and zeros for a non-resident one.
void WriteRankedSlot(const GpuView* v, float bound, uint32_t position, glm::uvec4* dst) {
  if (bound < 0.0f) {
    dst[0] = glm::uvec4(0u, 0u, 0u, FloatBits(-1.0f));
    for (int k = 1; k < kRankedTexels; ++k) dst[k] = glm::uvec4(0u);
    return;
  }
  dst[0] = glm::uvec4(FloatBits(v->centre_exposure.x), FloatBits(v->centre_exposure.y),
                      FloatBits(v->centre_exposure.z), FloatBits(bound));
  const uint32_t layer = uint32_t(v->size_layer.z);
  const uint32_t w[3] = {layer | (position << 16),
                         uint32_t(v->size_layer.x) | (uint32_t(v->size_layer.y) << 16),
                         FloatBits(v->centre_exposure.w)};
  const glm::vec4* rows[3] = {&v->p0, &v->p1, &v->p2};
  for (int k = 0; k < 3; ++k)
    dst[1 + k] =
        glm::uvec4(FloatBits(rows[k]->x), FloatBits(rows[k]->y), FloatBits(rows[k]->z), w[k]);
}

// The region of cell `id` (centre m) RankRefs bounds over: the cube's ball (half diagonal, +
// 0.1 % of q and 1e-5 relative to |m| for floor(x / q) in float) and the cube inflated alike;
// with a bound of the proxy surface in the cell, the surface's ball when smaller and its box
// (plus the slack) cut to the cube.
CellRegion CellRegionOf(CellId id, const glm::dvec3& m, double q, const CellSurfaceBounds* surface) {
  CellRegion g;
  g.m = m;
  g.r = q * (0.5 * std::sqrt(3.0) * 1.001) + 1e-5 * (glm::length(m) + q);
  const double e = 1e-3 * q + 1e-5 * (glm::length(m) + q);
  g.has_box = true;
  g.lo = m - 0.5 * q - e;
  g.hi = m + 0.5 * q + e;
  if (!surface) return g;
  auto it = surface->find(id);
  if (it == surface->end()) return g;
  const CellSurfaceBound& b = it->second;
  const double rs = CellSurfaceBallRadius(b, q);
  if (rs < g.r) {
    g.m = b.centre;
    g.r = rs;
  }
  const double s = CellSurfaceBoundSlackM(b, q);
  g.lo = glm::max(g.lo, b.lo - s);
  g.hi = glm::min(g.hi, b.hi + s);
  return g;
}

}  // namespace

void CellTable::RankCell(const Entry& c, const glm::dvec3& centre, const glm::dvec3& c_o,
                         bool by_centre, const blend::BlendOptions& bo) {
  const CellWeightBound bound(c.region, c_o);
  const size_t per_slab = size_t(opt_.max_refs_per_cell);
  const uint32_t* slots = static_cast<const uint32_t*>(refs_buf_.mapped) + c.slab * per_slab;
  const GpuView* recs = views_.records();
  const size_t n = c.refs.size();
  rank_scratch_.clear();
  for (size_t i = 0; i < n; ++i) {
    const uint32_t slot = slots[i];
    if (slot == kNoSlot || recs[slot].size_layer.w == 0.0f) {
      rank_scratch_.emplace_back(-1.0f, uint32_t(i));
      continue;
    }
    const glm::dvec3 c_i(glm::vec3(recs[slot].centre_exposure));
    if (!by_centre) {
      rank_scratch_.emplace_back(bound(c_i, bo), uint32_t(i));
      continue;
    }
    // Estimate: the weight at the centre (a ball of radius 0), times 1e-3 when the view does
    // not see the centre (behind it or outside its image: most likely invalid at the cell).
    float key = BlendWeightUpperBound(centre, 0.0, c_o, c_i, bo);
    const GpuView& v = recs[slot];
    const glm::vec4 hm(glm::vec3(centre), 1.0f);
    const float z = glm::dot(v.p2, hm);
    const float u = glm::dot(v.p0, hm) / z, w = glm::dot(v.p1, hm) / z;
    if (!(z > 0.0f && u >= -0.5f && w >= -0.5f && u < v.size_layer.x - 0.5f &&
          w < v.size_layer.y - 0.5f))
      key *= 1e-3f;
    rank_scratch_.emplace_back(key, uint32_t(i));
  }
  std::stable_sort(rank_scratch_.begin(), rank_scratch_.end(),
                   [](const auto& x, const auto& y) { return x.first > y.first; });
  glm::uvec4* dst =
      static_cast<glm::uvec4*>(ranked_buf_.mapped) + kRankedTexels * size_t(c.slab) * per_slab;
  for (size_t k = 0; k < n; ++k) {
    const auto [bound, i] = rank_scratch_[k];
    WriteRankedSlot(bound < 0.0f ? nullptr : &recs[slots[i]], bound, i, dst + kRankedTexels * k);
  }
}

// Per-frame reference ranking (exact). For every resident cell and every reference, an UPPER
// BOUND of the blend weight (3.5) the fragment shader can compute for any surface point x of
// the cell this frame (validity = 1):
//   x lies in the ball B(m, r) around the cell centre (r = half diagonal, inflated for the
//   float cell assignment); with D_o = |c_o - m|, D_i = |c_i - m|:
//   w_d = cos(angle(c_o - x, c_i - x)) <= cos(max(0, angle(c_o - m, c_i - m) - asin(r / D_o)
//         - asin(r / D_i)))  (each ray turns by at most asin(r / D) as x moves in the ball;
//         1 when a camera is inside the ball),
//   w_p is decreasing in |c_i - x| >= D_i - r and increasing in |c_o - x| <= D_o + r,
//   bound = max(lambda W_d + (1 - lambda) W_p, min_weight), plus a slack for float rounding.
// The cell's references are written to ranked_buf_ sorted by (bound desc, position in the
// cell's list asc): per slot (c_i.xyz, bound) and the view's projection rows with layer,
// position, size and exposure (WriteRankedSlot). blend.frag stops at the first reference whose bound is below the n-th best
// weight found so far (no later one can enter the best n) and breaks weight ties by the
// position in the cell's list, so the selection equals blend_math.h's in-order InsertBest.
// Non-resident references get bound -1 (sorted last, never evaluated).
// Cells whose ball lies entirely outside the novel camera's frustum (side planes through the
// centre, z >= 0) are skipped: no pixel's surface point can fall in them this frame, so their
// stale records are never read (exact).
// Surface ball (issue 16 session 17): a pixel's surface point x comes from the proxy mesh, so
// besides the cube's ball, x lies in the ball of the proxy surface inside the cell
// (common/cell_surface.h: the triangles clipped to the cell's box inflated for the float
// floor(x / q) and the slack, radius + a slack of 0.2 % of q for a rasterised point off its
// triangle); the smaller of the two balls is used. A flat cell's surface ball has radius
// ~0.71 q (q / sqrt 2 plus margins), 0.82 of the cube's. A cell without proxy surface keeps the
// cube's ball. The directional term's turns also use the box of the surface (its AABB plus the
// slack, cut to the inflated cube; the cube alone without surface): BlendWeightUpperBound's
// CellRegion takes the smaller turn of ball and box per camera.
void CellTable::RankRefs(const glm::vec3& c_o_f, const PinholeCamera& cam,
                         const Rigid3d& local_from_cam, double cell_size_m,
                         const blend::BlendOptions& bo, const CellSurfaceBounds* surface,
                         uint64_t surface_stamp, bool by_centre_weight) {
  const double q = cell_size_m;
  const glm::dvec3 c_o(c_o_f);
  const glm::dmat3 cam_from_local = glm::transpose(local_from_cam.RotationMatrix());
  const std::array<glm::dvec3, 5> planes = FrustumPlanes(cam);
  for (auto& [id, c] : cells_) {
    const glm::dvec3 m = (glm::dvec3(UnpackCell(id)) + 0.5) * q;
    if (c.region_stamp != surface_stamp || surface_stamp == 0) {
      c.region = CellRegionOf(id, m, q, surface);
      c.region_stamp = surface_stamp;
    }
    const CellRegion& g = c.region;
    const glm::dvec3 m_cam = cam_from_local * (g.m - c_o);
    bool outside = false;
    for (const glm::dvec3& n : planes) outside = outside || glm::dot(n, m_cam) < -1.01 * g.r;
    if (!outside) RankCell(c, m, c_o, by_centre_weight, bo);
  }
}

}  // namespace exo::vk
