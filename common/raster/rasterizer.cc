#include "common/raster/rasterizer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <thread>
#include <vector>

namespace exo {
namespace {

constexpr int kSubpixelBits = 8;
constexpr int64_t kSubpixel = int64_t{1} << kSubpixelBits;
constexpr double kGuardBandPx = 16384.0;
constexpr int kBandRows = 16;
// Triangles whose clamped pixel box has at most this many pixel centres are tested for
// coverage before their floating-point setup (most LOD triangles of a 160x120 buffer).
constexpr int64_t kSmallBoxPixels = 16;

// A clip-polygon vertex: camera-frame position plus barycentric coordinates w.r.t. the
// original mesh triangle (so any attribute can be recovered exactly after clipping).
struct ClipVertex {
  glm::dvec3 p_cam;
  glm::dvec3 bary;
};

struct CamVertex;

// One screen-space triangle ready for scan conversion.
struct SetupTriangle {
  // What the scan reads first (the first 2 cache lines), what the resolve reads after.
  // Fixed-point vertex positions (1/256 px) and the edge data derived from them.
  int64_t x0, y0, x1, y1, x2, y2;
  int min_x, max_x, min_y, max_y;  // pixel bounding box, clamped to the image
  bool top_left[3];
  // Perspective weights w_k(u,v) = lambda_k(u,v) / z_k as planes a*u + b*v + c (double, from
  // the unrounded projection) and their sum, the 1/z plane.
  glm::dvec3 inv_z_plane;
  std::array<glm::dvec3, 3> w_plane;
  std::array<glm::dvec3, 3> bary;  // barycentrics (in the mesh triangle) of the 3 vertices
  uint32_t triangle;               // global index (over all parts, in order)
  uint32_t part;                   // which mesh of the part list
  uint32_t local_triangle;         // index inside that mesh
  // The mesh triangle's 3 transformed vertices (their local positions are what the resolve
  // interpolates; read there instead of the mesh's index and position arrays, which are
  // scattered over thousands of chunk allocations and missed the cache on every pixel).
  const CamVertex* vertex[3];
};

// A vertex transformed once per render (shared by ~6 triangles): camera-frame position, the
// outcode of the 5 clip planes (bit k set = outside plane k) and, when inside every plane, the
// projection (unrounded and 1/256 px fixed point) exactly as Setup::Emit computes it.
struct CamVertex {
  glm::dvec3 p_cam;
  glm::vec3 p_local;  // the mesh position, as stored
  glm::dvec2 s;
  int64_t fx, fy;
  uint32_t outcode;
};

// Clip plane f(p) = dot(n, p) + d >= 0 in the camera frame.
struct Plane {
  glm::dvec3 n;
  double d;
  double Eval(const glm::dvec3& p) const { return glm::dot(n, p) + d; }
};

bool LexLess(const glm::dvec3& a, const glm::dvec3& b) {
  if (a.x != b.x) return a.x < b.x;
  if (a.y != b.y) return a.y < b.y;
  return a.z < b.z;
}

// Intersection of edge (a,b) with a plane, computed from a canonical endpoint order so that
// the two triangles sharing the edge get bit-identical vertices (no cracks at the near plane).
ClipVertex Intersect(const Plane& plane, const ClipVertex& a, const ClipVertex& b) {
  const bool swap = LexLess(b.p_cam, a.p_cam);
  const ClipVertex& p = swap ? b : a;
  const ClipVertex& q = swap ? a : b;
  const double fp = plane.Eval(p.p_cam), fq = plane.Eval(q.p_cam);
  const double t = fp / (fp - fq);
  return {p.p_cam + t * (q.p_cam - p.p_cam), p.bary + t * (q.bary - p.bary)};
}

// Sutherland-Hodgman against one plane. Polygons have at most 3 + 5 vertices.
int ClipPolygon(const Plane& plane, const ClipVertex* in, int n, ClipVertex* out) {
  int m = 0;
  for (int i = 0; i < n; ++i) {
    const ClipVertex& a = in[i];
    const ClipVertex& b = in[(i + 1) % n];
    const double fa = plane.Eval(a.p_cam), fb = plane.Eval(b.p_cam);
    if (fa >= 0) out[m++] = a;
    if ((fa >= 0) != (fb >= 0)) out[m++] = Intersect(plane, a, b);
  }
  return m;
}

int64_t FloorDiv(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }
int64_t CeilDiv(int64_t a, int64_t b) { return -FloorDiv(-a, b); }

// Edge (a -> b) is top-left in the y-down image with positive-area orientation.
bool IsTopLeft(int64_t ax, int64_t ay, int64_t bx, int64_t by) {
  const int64_t dx = bx - ax, dy = by - ay;
  return dy < 0 || (dy == 0 && dx > 0);
}

class Setup {
 public:
  Setup(const PinholeCamera& cam, const RasterOptions& opt) : cam_(cam), opt_(opt) {
    const double g = kGuardBandPx;
    planes_[0] = {{0, 0, 1}, -opt.near_m};
    planes_[1] = {{cam.fx, 0, cam.cx + g}, 0};                          // u >= -g
    planes_[2] = {{-cam.fx, 0, (cam.width - 1 + g) - cam.cx}, 0};       // u <= W-1+g
    planes_[3] = {{0, cam.fy, cam.cy + g}, 0};                          // v >= -g
    planes_[4] = {{0, -cam.fy, (cam.height - 1 + g) - cam.cy}, 0};      // v <= H-1+g
  }

  glm::dvec2 Project(const glm::dvec3& p) const {
    return glm::dvec2(cam_.fx * p.x / p.z + cam_.cx, cam_.fy * p.y / p.z + cam_.cy);
  }
  // std::llround(x * kSubpixel) (half away from zero) without the libm call: x - trunc(x) is
  // exact, and |x| stays far below 2^53 inside the guard band.
  static int64_t Fix(double x) {
    const double v = x * kSubpixel;
    int64_t i = static_cast<int64_t>(v);
    const double frac = v - static_cast<double>(i);
    if (frac >= 0.5) ++i;
    else if (frac <= -0.5) --i;
    return i;
  }

  CamVertex MakeVertex(const glm::dvec3& p_cam) const {
    CamVertex v;
    v.p_cam = p_cam;
    v.outcode = 0;
    for (int k = 0; k < 5; ++k)
      if (!(planes_[k].Eval(p_cam) >= 0)) v.outcode |= 1u << k;  // NaN = outside
    if (v.outcode == 0) {
      v.s = Project(p_cam);
      v.fx = Fix(v.s.x);
      v.fy = Fix(v.s.y);
    }
    return v;
  }

  // Same result as Add(t, a.p_cam, b.p_cam, c.p_cam) from precomputed vertices: a triangle
  // outside one plane with all three vertices is rejected, one inside every plane is emitted
  // from the cached projections (no clipping), the rest go through the clipper.
  bool AddCached(uint32_t t, const CamVertex& a, const CamVertex& b, const CamVertex& c,
                 std::vector<SetupTriangle>* out) const {
    if ((a.outcode & b.outcode & c.outcode) != 0) return false;
    if ((a.outcode | b.outcode | c.outcode) != 0) return Add(t, a.p_cam, b.p_cam, c.p_cam, out);
    // Pixel bounding box first: most triangles of a fine mesh in a small buffer cover no pixel
    // centre and end here.
    const int64_t min_x = std::min({a.fx, b.fx, c.fx}), max_x = std::max({a.fx, b.fx, c.fx});
    const int64_t min_y = std::min({a.fy, b.fy, c.fy}), max_y = std::max({a.fy, b.fy, c.fy});
    const int64_t px0 = std::max<int64_t>(0, CeilDiv(min_x, kSubpixel));
    const int64_t px1 = std::min<int64_t>(cam_.width - 1, FloorDiv(max_x, kSubpixel));
    const int64_t py0 = std::max<int64_t>(0, CeilDiv(min_y, kSubpixel));
    const int64_t py1 = std::min<int64_t>(cam_.height - 1, FloorDiv(max_y, kSubpixel));
    if (px0 > px1 || py0 > py1) return false;
    // Small box: test its few pixel centres with the exact edge functions of the scan before
    // the floating-point setup; a triangle that covers none of them writes nothing.
    if ((px1 - px0 + 1) * (py1 - py0 + 1) <= kSmallBoxPixels &&
        !CoversAPixelCentre(a.fx, a.fy, b.fx, b.fy, c.fx, c.fy, px0, px1, py0, py1))
      return false;
    EmitProjected(t, {a.p_cam, {1, 0, 0}}, {b.p_cam, {0, 1, 0}}, {c.p_cam, {0, 0, 1}}, a.s, b.s,
                  c.s, a.fx, a.fy, b.fx, b.fy, c.fx, c.fy, out);
    return false;
  }

  // Whether the fixed-point triangle (any winding) covers a pixel centre of [px0,px1]x[py0,py1]
  // under the rules of the scan (EmitProjected + step 4 of RasterizeParts): zero area and, when
  // culling, back faces cover nothing; the winding is made positive; top-left fill rule.
  bool CoversAPixelCentre(int64_t x0, int64_t y0, int64_t x1, int64_t y1, int64_t x2,
                          int64_t y2, int64_t px0, int64_t px1, int64_t py0,
                          int64_t py1) const {
    const int64_t area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0);
    if (area == 0 || (area > 0 && opt_.cull_backfaces)) return false;
    if (area < 0) {
      std::swap(x1, x2);
      std::swap(y1, y2);
    }
    const int64_t ax[3] = {x0, x1, x2}, ay[3] = {y0, y1, y2};
    const int64_t bx[3] = {x1, x2, x0}, by[3] = {y1, y2, y0};
    int64_t bias[3];
    for (int k = 0; k < 3; ++k) bias[k] = IsTopLeft(ax[k], ay[k], bx[k], by[k]) ? 0 : -1;
    for (int64_t y = py0; y <= py1; ++y) {
      const int64_t py = y * kSubpixel;
      for (int64_t x = px0; x <= px1; ++x) {
        const int64_t px = x * kSubpixel;
        int64_t e[3];
        for (int k = 0; k < 3; ++k)
          e[k] = (bx[k] - ax[k]) * (py - ay[k]) - (by[k] - ay[k]) * (px - ax[k]) + bias[k];
        if ((e[0] | e[1] | e[2]) >= 0) return true;
      }
    }
    return false;
  }

  // Appends the screen triangles of mesh triangle `t`; returns true when it was clipped.
  bool Add(uint32_t t, const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c,
           std::vector<SetupTriangle>* out) const {
    {  // Trivial reject (every vertex outside the same plane), as AddCached does.
      uint32_t common = 31;
      for (const glm::dvec3* p : {&a, &b, &c}) {
        uint32_t oc = 0;
        for (int k = 0; k < 5; ++k)
          if (!(planes_[k].Eval(*p) >= 0)) oc |= 1u << k;
        common &= oc;
      }
      if (common != 0) return false;
    }
    ClipVertex poly[2][16];
    poly[0][0] = {a, {1, 0, 0}};
    poly[0][1] = {b, {0, 1, 0}};
    poly[0][2] = {c, {0, 0, 1}};
    int n = 3, cur = 0;
    bool clipped = false;
    for (const Plane& pl : planes_) {
      const double fa = pl.Eval(poly[cur][0].p_cam);
      bool all_in = fa >= 0, all_out = fa < 0;
      for (int i = 1; i < n; ++i) {
        const double f = pl.Eval(poly[cur][i].p_cam);
        all_in &= f >= 0;
        all_out &= f < 0;
      }
      if (all_out) return clipped;
      if (all_in) continue;
      clipped = true;
      n = ClipPolygon(pl, poly[cur], n, poly[1 - cur]);
      cur = 1 - cur;
      if (n < 3) return clipped;
    }
    for (int i = 1; i + 1 < n; ++i) Emit(t, poly[cur][0], poly[cur][i], poly[cur][i + 1], out);
    return clipped;
  }

 private:
  void Emit(uint32_t t, const ClipVertex& v0, const ClipVertex& v1, const ClipVertex& v2,
            std::vector<SetupTriangle>* out) const {
    const glm::dvec2 s0 = Project(v0.p_cam), s1 = Project(v1.p_cam), s2 = Project(v2.p_cam);
    EmitProjected(t, v0, v1, v2, s0, s1, s2, Fix(s0.x), Fix(s0.y), Fix(s1.x), Fix(s1.y),
                  Fix(s2.x), Fix(s2.y), out);
  }

  void EmitProjected(uint32_t t, ClipVertex v0, ClipVertex v1, ClipVertex v2, glm::dvec2 s0,
                     glm::dvec2 s1, glm::dvec2 s2, int64_t x0, int64_t y0, int64_t x1,
                     int64_t y1, int64_t x2, int64_t y2, std::vector<SetupTriangle>* out) const {
    int64_t area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0);
    if (area == 0) return;
    // Positive screen area (y down) <=> geometric normal points away from the camera.
    if (area > 0 && opt_.cull_backfaces) return;
    if (area < 0) {
      std::swap(v1, v2);
      std::swap(s1, s2);
      std::swap(x1, x2);
      std::swap(y1, y2);
    }
    SetupTriangle st;
    st.x0 = x0; st.y0 = y0; st.x1 = x1; st.y1 = y1; st.x2 = x2; st.y2 = y2;
    st.top_left[0] = IsTopLeft(x0, y0, x1, y1);  // edge 0: v0 -> v1 (weight of v2)
    st.top_left[1] = IsTopLeft(x1, y1, x2, y2);  // edge 1: v1 -> v2 (weight of v0)
    st.top_left[2] = IsTopLeft(x2, y2, x0, y0);  // edge 2: v2 -> v0 (weight of v1)
    const int64_t min_x = std::min({x0, x1, x2}), max_x = std::max({x0, x1, x2});
    const int64_t min_y = std::min({y0, y1, y2}), max_y = std::max({y0, y1, y2});
    st.min_x = static_cast<int>(std::max<int64_t>(0, CeilDiv(min_x, kSubpixel)));
    st.max_x = static_cast<int>(std::min<int64_t>(cam_.width - 1, FloorDiv(max_x, kSubpixel)));
    st.min_y = static_cast<int>(std::max<int64_t>(0, CeilDiv(min_y, kSubpixel)));
    st.max_y = static_cast<int>(std::min<int64_t>(cam_.height - 1, FloorDiv(max_y, kSubpixel)));
    if (st.min_x > st.max_x || st.min_y > st.max_y) return;
    // Screen barycentric planes from the unrounded projection (exact depth for planes).
    double d = (s1.x - s0.x) * (s2.y - s0.y) - (s1.y - s0.y) * (s2.x - s0.x);
    if (d == 0.0) {  // sliver whose unrounded area vanishes: use the fixed-point vertices
      s0 = glm::dvec2(x0, y0) / double(kSubpixel);
      s1 = glm::dvec2(x1, y1) / double(kSubpixel);
      s2 = glm::dvec2(x2, y2) / double(kSubpixel);
      d = (s1.x - s0.x) * (s2.y - s0.y) - (s1.y - s0.y) * (s2.x - s0.x);
    }
    const glm::dvec2 s[3] = {s0, s1, s2};
    const double z[3] = {v0.p_cam.z, v1.p_cam.z, v2.p_cam.z};
    st.inv_z_plane = glm::dvec3(0.0);
    for (int k = 0; k < 3; ++k) {
      const glm::dvec2& a = s[(k + 1) % 3];
      const glm::dvec2& b = s[(k + 2) % 3];
      // lambda_k(u,v) = ((b.x-a.x)*(v-a.y) - (b.y-a.y)*(u-a.x)) / d
      const glm::dvec3 lambda{-(b.y - a.y) / d, (b.x - a.x) / d,
                              ((b.y - a.y) * a.x - (b.x - a.x) * a.y) / d};
      st.w_plane[k] = lambda / z[k];
      st.inv_z_plane += st.w_plane[k];
    }
    st.bary = {v0.bary, v1.bary, v2.bary};
    st.triangle = t;
    out->push_back(st);
  }

  const PinholeCamera& cam_;
  const RasterOptions& opt_;
  Plane planes_[5];
};

// Working buffers of one render, kept per calling thread between renders: a small render
// (a 160x120 cell-id buffer) otherwise spends a good part of its time in page faults of freshly
// allocated buffers. Released after a render that needed more than kKeepBytes.
struct Scratch {
  static constexpr size_t kKeepBytes = size_t{32} << 20;
  std::vector<CamVertex> verts;
  std::vector<std::vector<SetupTriangle>> chunk_setups;
  std::vector<SetupTriangle> tris;  // the concatenation when setup ran in several chunks
  std::vector<std::vector<uint32_t>> bands;
  std::vector<double> inv_z;
  std::vector<uint32_t> winner;

  void ReleaseIfLarge() {
    size_t bytes = verts.capacity() * sizeof(CamVertex) + tris.capacity() * sizeof(SetupTriangle) +
                   inv_z.capacity() * sizeof(double) + winner.capacity() * sizeof(uint32_t);
    for (const auto& v : chunk_setups) bytes += v.capacity() * sizeof(SetupTriangle);
    for (const auto& b : bands) bytes += b.capacity() * sizeof(uint32_t);
    if (bytes > kKeepBytes) *this = Scratch();
  }
};

Scratch& ThreadScratch() {
  thread_local Scratch scratch;
  return scratch;
}

template <typename F>
void ParallelFor(int num_threads, int n, F&& f) {
  num_threads = std::max(1, std::min(num_threads, n));
  if (num_threads == 1) {
    for (int i = 0; i < n; ++i) f(i, 0);
    return;
  }
  std::vector<std::thread> threads;
  for (int t = 0; t < num_threads; ++t)
    threads.emplace_back([&, t] {
      for (int i = t; i < n; i += num_threads) f(i, t);
    });
  for (auto& th : threads) th.join();
}

}  // namespace

absl::Status RasterOptions::Validate() const {
  if (!(near_m > 0) || !std::isfinite(near_m))
    return absl::InvalidArgumentError(absl::StrCat("raster near_m must be > 0, got ", near_m));
  if (width < 0 || height < 0 || (width == 0) != (height == 0))
    return absl::InvalidArgumentError(absl::StrCat(
        "raster width/height must both be 0 (camera size) or both > 0, got ", width, "x", height));
  if (width > 32768 || height > 32768)
    return absl::InvalidArgumentError("raster size above 32768 px");
  if (num_threads < 1 || num_threads > 256)
    return absl::InvalidArgumentError(absl::StrCat("raster num_threads must be in [1,256], got ",
                                                   num_threads));
  if (cell_id && !(cell_grid.cell_size_m > 0 && std::isfinite(cell_grid.cell_size_m)))
    return absl::InvalidArgumentError("cell_id requested with a non-positive cell size");
  return absl::OkStatus();
}

absl::Status ValidateMesh(const TriangleMesh& mesh) {
  if (mesh.indices.size() % 3 != 0)
    return absl::InvalidArgumentError(
        absl::StrCat("mesh index count ", mesh.indices.size(), " is not a multiple of 3"));
  const size_t nv = mesh.positions.size();
  for (size_t i = 0; i < mesh.indices.size(); ++i)
    if (mesh.indices[i] >= nv)
      return absl::InvalidArgumentError(absl::StrCat("mesh index ", i, " = ", mesh.indices[i],
                                                     " out of range (", nv, " vertices)"));
  if (!mesh.normals.empty() && mesh.normals.size() != nv)
    return absl::InvalidArgumentError("mesh normals size differs from positions size");
  if (!mesh.colors.empty() && mesh.colors.size() != nv)
    return absl::InvalidArgumentError("mesh colors size differs from positions size");
  if (!mesh.material.empty() && mesh.material.size() != mesh.num_triangles())
    return absl::InvalidArgumentError("mesh material size differs from triangle count");
  return absl::OkStatus();
}

absl::StatusOr<RasterOutput> Rasterize(const TriangleMesh& mesh, const PinholeCamera& camera,
                                       const Rigid3d& local_from_cam,
                                       const RasterOptions& options) {
  return RasterizeParts({&mesh}, camera, local_from_cam, options);
}

absl::StatusOr<RasterOutput> RasterizeParts(const std::vector<const TriangleMesh*>& parts,
                                            const PinholeCamera& camera,
                                            const Rigid3d& local_from_cam,
                                            const RasterOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(camera.Validate());
  EXO_RETURN_IF_ERROR(ValidateQuaternion(local_from_cam.rotation));
  const glm::dvec3& tr = local_from_cam.translation;
  if (!std::isfinite(tr.x) || !std::isfinite(tr.y) || !std::isfinite(tr.z))
    return absl::InvalidArgumentError("raster pose translation has NaN or Inf");
  size_t total_tris = 0;
  for (const TriangleMesh* m : parts) {
    if (m == nullptr) return absl::InvalidArgumentError("raster part is null");
    if (!options.meshes_prevalidated) EXO_RETURN_IF_ERROR(ValidateMesh(*m));
    total_tris += m->num_triangles();
  }
  if (total_tris >= size_t{kNoTriangle})
    return absl::InvalidArgumentError("raster: too many triangles for 32-bit ids");

  RasterOutput out;
  out.camera = options.width > 0 ? camera.Scaled(options.width, options.height) : camera;
  const PinholeCamera& cam = out.camera;
  const int W = cam.width, H = cam.height;
  const int threads = options.num_threads;
  out.triangles_in = total_tris;

  // 1. Vertices into the camera frame (double), with clip outcodes and projections.
  const Rigid3d cam_from_local = local_from_cam.Inverse();
  const glm::dmat3 R = cam_from_local.RotationMatrix();
  const glm::dvec3 t = cam_from_local.translation;
  Setup setup(cam, options);
  // One buffer for all parts (a part list holds thousands of small chunks).
  std::vector<size_t> part_vertex_begin(parts.size() + 1, 0);
  for (size_t k = 0; k < parts.size(); ++k)
    part_vertex_begin[k + 1] = part_vertex_begin[k] + parts[k]->positions.size();
  Scratch& scratch = ThreadScratch();
  std::vector<CamVertex>& verts = scratch.verts;
  verts.resize(part_vertex_begin.back());
  for (size_t k = 0; k < parts.size(); ++k) {
    const auto& pos = parts[k]->positions;
    CamVertex* v = verts.data() + part_vertex_begin[k];
    for (size_t i = 0; i < pos.size(); ++i) {
      v[i] = setup.MakeVertex(R * glm::dvec3(pos[i]) + t);
      v[i].p_local = pos[i];
    }
  }

  // 2. Triangle setup (clipping, projection, edge and plane equations), in parallel chunks of
  // the global triangle sequence, concatenated in triangle order.
  std::vector<size_t> part_begin(parts.size() + 1, 0);  // global index of each part's first tri
  for (size_t k = 0; k < parts.size(); ++k)
    part_begin[k + 1] = part_begin[k] + parts[k]->num_triangles();
  const int num_tris = static_cast<int>(total_tris);
  // One chunk per thread when single-threaded (no concatenation copy), else 4 per thread.
  const int chunks =
      threads == 1 ? 1 : std::max(1, std::min(threads * 4, num_tris / 256 + 1));
  std::vector<std::vector<SetupTriangle>>& chunk_setups = scratch.chunk_setups;
  if (chunk_setups.size() < size_t(chunks)) chunk_setups.resize(chunks);
  for (int c = 0; c < chunks; ++c) chunk_setups[c].clear();
  std::vector<size_t> chunk_clipped(chunks, 0);
  ParallelFor(threads, chunks, [&](int c, int) {
    const int begin = static_cast<int>(int64_t{num_tris} * c / chunks);
    const int end = static_cast<int>(int64_t{num_tris} * (c + 1) / chunks);
    auto& v = chunk_setups[c];
    v.reserve(std::min<size_t>(end - begin, 4096));
    size_t part = static_cast<size_t>(
        std::upper_bound(part_begin.begin(), part_begin.end(), size_t(begin)) -
        part_begin.begin() - 1);
    for (int tri = begin; tri < end; ++tri) {
      while (size_t(tri) >= part_begin[part + 1]) ++part;
      const size_t local = size_t(tri) - part_begin[part];
      const uint32_t* idx = &parts[part]->indices[3 * local];
      const CamVertex* pv = verts.data() + part_vertex_begin[part];
      const size_t before = v.size();
      if (setup.AddCached(static_cast<uint32_t>(tri), pv[idx[0]], pv[idx[1]], pv[idx[2]], &v))
        ++chunk_clipped[c];
      for (size_t i = before; i < v.size(); ++i) {
        v[i].part = static_cast<uint32_t>(part);
        v[i].local_triangle = static_cast<uint32_t>(local);
        for (int k = 0; k < 3; ++k) v[i].vertex[k] = &pv[idx[k]];
      }
    }
  });
  std::vector<SetupTriangle>& tris = chunks == 1 ? chunk_setups[0] : scratch.tris;
  if (chunks == 1) out.triangles_clipped = chunk_clipped[0];
  if (chunks > 1) tris.clear();
  for (int c = 0; c < chunks && chunks > 1; ++c) {
    tris.insert(tris.end(), chunk_setups[c].begin(), chunk_setups[c].end());
    out.triangles_clipped += chunk_clipped[c];
  }
  out.triangles_setup = tris.size();

  // 3. Bin into row bands (in triangle order, so depth ties resolve deterministically).
  const int num_bands = (H + kBandRows - 1) / kBandRows;
  std::vector<std::vector<uint32_t>>& bands = scratch.bands;
  if (bands.size() < size_t(num_bands)) bands.resize(num_bands);
  for (int b = 0; b < num_bands; ++b) bands[b].clear();
  for (uint32_t i = 0; i < tris.size(); ++i)
    for (int b = tris[i].min_y / kBandRows; b <= tris[i].max_y / kBandRows; ++b)
      bands[b].push_back(i);

  // 4. Scan conversion with incremental fixed-point edge functions + 1/z depth test.
  std::vector<double>& inv_z = scratch.inv_z;
  std::vector<uint32_t>& winner = scratch.winner;
  inv_z.assign(static_cast<size_t>(W) * H, 0.0);
  winner.assign(static_cast<size_t>(W) * H, kNoTriangle);
  ParallelFor(threads, num_bands, [&](int b, int) {
    const int band_y0 = b * kBandRows, band_y1 = std::min(H - 1, band_y0 + kBandRows - 1);
    for (uint32_t ti : bands[b]) {
      const SetupTriangle& s = tris[ti];
      const int y_begin = std::max(s.min_y, band_y0), y_end = std::min(s.max_y, band_y1);
      // Edge k: from a to b; E(P) = (bx-ax)*(Py-ay) - (by-ay)*(Px-ax).
      const int64_t ax[3] = {s.x0, s.x1, s.x2}, ay[3] = {s.y0, s.y1, s.y2};
      const int64_t bx[3] = {s.x1, s.x2, s.x0}, by[3] = {s.y1, s.y2, s.y0};
      int64_t step_x[3], bias[3];
      for (int k = 0; k < 3; ++k) {
        step_x[k] = -(by[k] - ay[k]) * kSubpixel;
        bias[k] = s.top_left[k] ? 0 : -1;
      }
      const int64_t px0 = int64_t{s.min_x} * kSubpixel;
      for (int y = y_begin; y <= y_end; ++y) {
        const int64_t py = int64_t{y} * kSubpixel;
        int64_t e[3];
        for (int k = 0; k < 3; ++k)
          e[k] = (bx[k] - ax[k]) * (py - ay[k]) - (by[k] - ay[k]) * (px0 - ax[k]) + bias[k];
        const size_t row = static_cast<size_t>(y) * W;
        const double row_inv_z = s.inv_z_plane.y * y + s.inv_z_plane.z;
        bool was_inside = false;
        for (int x = s.min_x; x <= s.max_x; ++x) {
          if ((e[0] | e[1] | e[2]) >= 0) {
            was_inside = true;
            const double iz = s.inv_z_plane.x * x + row_inv_z;
            const size_t idx = row + x;
            if (iz > inv_z[idx]) {
              inv_z[idx] = iz;
              winner[idx] = ti;
            }
          } else if (was_inside) {
            break;  // convex: the span on this row has ended
          }
          e[0] += step_x[0];
          e[1] += step_x[1];
          e[2] += step_x[2];
        }
      }
    }
  });

  // 5. Resolve visible pixels into the requested outputs.
  if (options.z_depth) out.z_depth_m = ImageF(W, H, 1, 0.0f);
  if (options.range) out.range_m = ImageF(W, H, 1, 0.0f);
  if (options.position) out.position_local = ImageF(W, H, 3, 0.0f);
  if (options.normal) out.normal_local = ImageF(W, H, 3, 0.0f);
  if (options.triangle_id) out.triangle_id = ImageU32(W, H, 1, kNoTriangle);
  if (options.cell_id) out.cell_id = Image<uint64_t>(W, H, 1, kNoCell);
  const bool need_bary = options.position || options.cell_id || options.normal;
  const bool want_vertex_normals = options.interpolate_normals;
  std::vector<size_t> covered(threads, 0);
  ParallelFor(threads, H, [&](int y, int thread) {
    for (int x = 0; x < W; ++x) {
      const size_t idx = static_cast<size_t>(y) * W + x;
      const uint32_t ti = winner[idx];
      if (ti == kNoTriangle) continue;
      ++covered[thread];
      const SetupTriangle& s = tris[ti];
      const double z = 1.0 / inv_z[idx];
      if (options.z_depth) out.z_depth_m.at(x, y) = static_cast<float>(z);
      if (options.range)
        out.range_m.at(x, y) = static_cast<float>(cam.RangeFromZDepth({x, y}, z));
      if (options.triangle_id) out.triangle_id.at(x, y) = s.triangle;
      if (!need_bary) continue;
      glm::dvec3 beta(0.0);
      for (int k = 0; k < 3; ++k) {
        const double w = s.w_plane[k].x * x + s.w_plane[k].y * y + s.w_plane[k].z;
        beta += (w * z) * s.bary[k];
      }
      if (options.position || options.cell_id) {
        const glm::dvec3 p = beta.x * glm::dvec3(s.vertex[0]->p_local) +
                             beta.y * glm::dvec3(s.vertex[1]->p_local) +
                             beta.z * glm::dvec3(s.vertex[2]->p_local);
        if (options.position)
          for (int c = 0; c < 3; ++c) out.position_local.at(x, y, c) = static_cast<float>(p[c]);
        if (options.cell_id) out.cell_id.at(x, y) = options.cell_grid.IdOf(p);
      }
      if (options.normal) {
        const TriangleMesh& mesh = *parts[s.part];
        const uint32_t* vi = &mesh.indices[3 * static_cast<size_t>(s.local_triangle)];
        glm::dvec3 n;
        if (want_vertex_normals && !mesh.normals.empty()) {
          n = beta.x * glm::dvec3(mesh.normals[vi[0]]) + beta.y * glm::dvec3(mesh.normals[vi[1]]) +
              beta.z * glm::dvec3(mesh.normals[vi[2]]);
        } else {
          const glm::dvec3 p0(mesh.positions[vi[0]]);
          n = glm::cross(glm::dvec3(mesh.positions[vi[1]]) - p0,
                         glm::dvec3(mesh.positions[vi[2]]) - p0);
        }
        const double len = glm::length(n);
        if (len > 0) n /= len;
        for (int c = 0; c < 3; ++c) out.normal_local.at(x, y, c) = static_cast<float>(n[c]);
      }
    }
  });
  for (size_t c : covered) out.pixels_covered += c;
  scratch.ReleaseIfLarge();
  return out;
}

}  // namespace exo
