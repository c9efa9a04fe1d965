#include "common/raster/rasterizer.h"

#include <algorithm>
#include <cmath>
#include <random>

#include <glm/gtc/quaternion.hpp>
#include <gtest/gtest.h>

namespace exo {
namespace {

// See StreamChecksumUnchangedBySpeedWork.
constexpr uint64_t kStreamChecksum = 0x3db44c0612f02b58ull;

// A camera whose pixel -> z=1 plane mapping is exact in float: f = 64, c = 31.5.
PinholeCamera ExactCamera() {
  PinholeCamera c;
  c.fx = c.fy = 64;
  c.cx = c.cy = 31.5;
  c.width = c.height = 64;
  return c;
}

// Point on the z = depth plane (camera frame) that projects to pixel (u, v) of ExactCamera.
glm::vec3 AtPixel(double u, double v, double depth = 1.0) {
  const PinholeCamera c = ExactCamera();
  return glm::vec3(c.Unproject({u, v}, depth));
}

void AddQuad(TriangleMesh* m, glm::vec3 a, glm::vec3 b, glm::vec3 c, glm::vec3 d) {
  const uint32_t base = static_cast<uint32_t>(m->positions.size());
  m->positions.insert(m->positions.end(), {a, b, c, d});
  m->indices.insert(m->indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
}

RasterOptions AllOutputs() {
  RasterOptions o;
  o.z_depth = o.range = o.position = o.normal = o.triangle_id = o.cell_id = true;
  return o;
}

int CountCovered(const ImageF& z) {
  int n = 0;
  for (float v : z.span()) n += v > 0;
  return n;
}

// Plane at a known depth: z and range of every pixel are exact to 1e-5 relative.
TEST(RasterizerTest, FrontoParallelPlaneExactDepthAndRange) {
  const PinholeCamera cam = PinholeCamera::FromFov(80, 60, glm::radians(70.0));
  TriangleMesh m;
  const float d = 7.25f;
  AddQuad(&m, {-50, -50, d}, {50, -50, d}, {50, 50, d}, {-50, 50, d});
  auto out = Rasterize(m, cam, Rigid3d::Identity(), AllOutputs());
  ASSERT_TRUE(out.ok()) << out.status();
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      ASSERT_NEAR(out->z_depth_m.at(x, y), d, 1e-5 * d) << x << "," << y;
      const double range = cam.RangeFromZDepth({x, y}, d);
      ASSERT_NEAR(out->range_m.at(x, y), range, 1e-5 * range);
      const glm::dvec3 p = cam.Unproject({x, y}, d);
      for (int c = 0; c < 3; ++c) ASSERT_NEAR(out->position_local.at(x, y, c), p[c], 1e-4);
      // Winding (a,b,c) seen from the camera: normal (p1-p0)x(p2-p0) = +z.
      ASSERT_NEAR(out->normal_local.at(x, y, 2), 1.0, 1e-6);
    }
  EXPECT_EQ(out->pixels_covered, size_t(cam.width * cam.height));
}

// A tilted plane n.p = 4 (camera frame): z(u,v) = 4 / (n . ray(u,v)). This needs the
// perspective-correct (1/z-linear) interpolation; screen-linear z would be off by percent.
TEST(RasterizerTest, TiltedPlaneDepthIsPerspectiveCorrect) {
  const PinholeCamera cam = PinholeCamera::FromFov(96, 72, glm::radians(65.0));
  const glm::dvec3 n = glm::normalize(glm::dvec3(0.3, -0.5, 1.0));
  const double dist = 4.0;
  // Build a big quad on the plane from two tangent vectors.
  const glm::dvec3 t1 = glm::normalize(glm::cross(n, glm::dvec3(1, 0, 0)));
  const glm::dvec3 t2 = glm::cross(n, t1);
  const glm::dvec3 o = n * dist;
  auto P = [&](double a, double b) { return glm::vec3(o + a * t1 + b * t2); };
  TriangleMesh m;
  AddQuad(&m, P(-20, -20), P(20, -20), P(20, 20), P(-20, 20));
  RasterOptions opt = AllOutputs();
  auto out = Rasterize(m, cam, Rigid3d::Identity(), opt);
  ASSERT_TRUE(out.ok()) << out.status();
  double max_rel = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const glm::dvec3 ray = cam.RayZ1({x, y});
      const double z = dist / glm::dot(n, ray);
      ASSERT_GT(out->z_depth_m.at(x, y), 0) << x << "," << y;
      max_rel = std::max(max_rel, std::abs(out->z_depth_m.at(x, y) - z) / z);
      const double range = z * glm::length(ray);
      ASSERT_NEAR(out->range_m.at(x, y), range, 1e-5 * range);
      const glm::dvec3 p = ray * z;
      for (int c = 0; c < 3; ++c) ASSERT_NEAR(out->position_local.at(x, y, c), p[c], 2e-4);
    }
  EXPECT_LT(max_rel, 1e-5);
}

// Convex hull area of points (monotone chain), for the analytic silhouette.
double HullAreaAndPerimeter(std::vector<glm::dvec2> pts, double* perimeter) {
  std::sort(pts.begin(), pts.end(),
            [](auto a, auto b) { return a.x < b.x || (a.x == b.x && a.y < b.y); });
  auto cross = [](glm::dvec2 o, glm::dvec2 a, glm::dvec2 b) {
    return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
  };
  std::vector<glm::dvec2> h(2 * pts.size());
  size_t k = 0;
  for (size_t i = 0; i < pts.size(); ++i) {
    while (k >= 2 && cross(h[k - 2], h[k - 1], pts[i]) <= 0) --k;
    h[k++] = pts[i];
  }
  for (size_t i = pts.size() - 1, t = k + 1; i-- > 0;) {
    while (k >= t && cross(h[k - 2], h[k - 1], pts[i]) <= 0) --k;
    h[k++] = pts[i];
  }
  h.resize(k - 1);
  double area = 0;
  *perimeter = 0;
  for (size_t i = 0; i < h.size(); ++i) {
    const glm::dvec2 a = h[i], b = h[(i + 1) % h.size()];
    area += a.x * b.y - a.y * b.x;
    *perimeter += glm::length(b - a);
  }
  return std::abs(area) / 2;
}

TriangleMesh Cube(glm::vec3 c, float half) {
  TriangleMesh m;
  auto v = [&](int sx, int sy, int sz) { return c + half * glm::vec3(sx, sy, sz); };
  AddQuad(&m, v(-1, -1, -1), v(-1, 1, -1), v(1, 1, -1), v(1, -1, -1));  // -z
  AddQuad(&m, v(-1, -1, 1), v(1, -1, 1), v(1, 1, 1), v(-1, 1, 1));      // +z
  AddQuad(&m, v(-1, -1, -1), v(-1, -1, 1), v(-1, 1, 1), v(-1, 1, -1));  // -x
  AddQuad(&m, v(1, -1, -1), v(1, 1, -1), v(1, 1, 1), v(1, -1, 1));      // +x
  AddQuad(&m, v(-1, -1, -1), v(1, -1, -1), v(1, -1, 1), v(-1, -1, 1));  // -y
  AddQuad(&m, v(-1, 1, -1), v(-1, 1, 1), v(1, 1, 1), v(1, 1, -1));      // +y
  return m;
}

// A rotated cube's silhouette: pixel count equals the area of the convex hull of its projected
// corners within the boundary pixels (perimeter).
TEST(RasterizerTest, CubeSilhouetteMatchesProjectedArea) {
  const PinholeCamera cam = PinholeCamera::FromFov(320, 240, glm::radians(60.0));
  const TriangleMesh cube = Cube({0, 0, 0}, 1.0f);
  Rigid3d local_from_cam;
  local_from_cam.rotation = glm::angleAxis(0.5, glm::normalize(glm::dvec3(1, 2, 0.5)));
  local_from_cam.translation = local_from_cam.rotation * glm::dvec3(0.2, -0.1, -6.0);
  RasterOptions opt;
  auto out = Rasterize(cube, cam, local_from_cam, opt);
  ASSERT_TRUE(out.ok()) << out.status();
  const Rigid3d cam_from_local = local_from_cam.Inverse();
  std::vector<glm::dvec2> corners;
  for (int i = 0; i < 8; ++i) {
    glm::dvec2 uv;
    ASSERT_TRUE(cam.Project(cam_from_local * glm::dvec3(i & 1 ? 1 : -1, i & 2 ? 1 : -1,
                                                        i & 4 ? 1 : -1),
                            &uv));
    corners.push_back(uv);
  }
  double perimeter = 0;
  const double area = HullAreaAndPerimeter(corners, &perimeter);
  const int count = CountCovered(out->z_depth_m);
  EXPECT_GT(area, 3000);
  EXPECT_NEAR(count, area, 0.5 * perimeter) << "perimeter " << perimeter;
  // With back-face culling the silhouette is the same (the cube is closed, outward winding).
  opt.cull_backfaces = true;
  auto culled = Rasterize(cube, cam, local_from_cam, opt);
  ASSERT_TRUE(culled.ok());
  EXPECT_EQ(culled->z_depth_m, out->z_depth_m);
}

// Renders each triangle alone and counts per-pixel hits.
std::vector<int> HitCounts(const TriangleMesh& m, const PinholeCamera& cam) {
  std::vector<int> hits(cam.width * cam.height, 0);
  for (size_t t = 0; t < m.num_triangles(); ++t) {
    TriangleMesh one;
    one.positions = m.positions;
    one.indices.assign(m.indices.begin() + 3 * t, m.indices.begin() + 3 * t + 3);
    auto out = Rasterize(one, cam, Rigid3d::Identity(), RasterOptions{});
    EXO_CHECK(out.ok());
    for (int i = 0; i < cam.width * cam.height; ++i) hits[i] += out->z_depth_m.data()[i] > 0;
  }
  return hits;
}

// Watertightness: a quad split along a diagonal through pixel centres (the tie case) is hit
// exactly once per pixel. Guard: the top-left fill rule; with ">= 0" on every edge the diagonal
// pixels are hit twice, with "> 0" they are holes.
TEST(RasterizerTest, SharedEdgeEveryPixelHitExactlyOnce) {
  const PinholeCamera cam = ExactCamera();
  TriangleMesh m;
  // Corners on pixel centres: the outer edges pass through pixel centres too.
  AddQuad(&m, AtPixel(10, 10), AtPixel(40, 10), AtPixel(40, 40), AtPixel(10, 40));
  const std::vector<int> hits = HitCounts(m, cam);
  int total = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const int h = hits[y * cam.width + x];
      ASSERT_LE(h, 1) << x << "," << y;
      total += h;
    }
  // Top-left rule on a square with corners on pixel centres: the top and left edges are in,
  // bottom and right out -> 30 x 30 pixels exactly.
  EXPECT_EQ(total, 30 * 30);
}

// A fan of 8 triangles around a centre on a pixel centre: edges in all 8 directions (vertical,
// horizontal, both diagonals) pass through pixel centres; every pixel of the square is hit once.
TEST(RasterizerTest, FanAroundPixelCentreIsWatertight) {
  const PinholeCamera cam = ExactCamera();
  TriangleMesh m;
  m.positions.push_back(AtPixel(30, 30));
  const double ring[8][2] = {{9.5, 9.5},   {30, 9.5},   {50.5, 9.5}, {50.5, 30},
                             {50.5, 50.5}, {30, 50.5},  {9.5, 50.5}, {9.5, 30}};
  for (auto& r : ring) m.positions.push_back(AtPixel(r[0], r[1]));
  for (uint32_t i = 0; i < 8; ++i) m.indices.insert(m.indices.end(), {0, 1 + i, 1 + (i + 1) % 8});
  const std::vector<int> hits = HitCounts(m, cam);
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const bool inside = x >= 10 && x <= 50 && y >= 10 && y <= 50;
      ASSERT_EQ(hits[y * cam.width + x], inside ? 1 : 0) << x << "," << y;
    }
}

// A ground plane from behind the camera to 50 m ahead crosses the near plane. Guard: near-plane
// clipping; dropping crossing triangles renders nothing, and not clipping projects the vertex
// behind the camera through the centre (mirror image, wrong pixels).
TEST(RasterizerTest, NearPlaneClippingKeepsCrossingTriangles) {
  const PinholeCamera cam = PinholeCamera::FromFov(64, 48, glm::radians(90.0));  // fx = 32
  TriangleMesh m;
  const float h = 1.0f;  // ground 1 m below the camera (y down)
  AddQuad(&m, {-100, h, -10}, {-100, h, 50}, {100, h, 50}, {100, h, -10});
  RasterOptions opt = AllOutputs();
  auto out = Rasterize(m, cam, Rigid3d::Identity(), opt);
  ASSERT_TRUE(out.ok()) << out.status();
  EXPECT_EQ(out->triangles_clipped, 2u);
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const double dv = y - cam.cy;
      const double z = dv > 0 ? cam.fy * h / dv : 0;
      if (dv > 0 && z <= 50 - 1e-6) {
        ASSERT_NEAR(out->z_depth_m.at(x, y), z, 1e-5 * z) << x << "," << y;
        ASSERT_NEAR(out->position_local.at(x, y, 1), h, 1e-5);
      } else if (dv <= 0 || z > 50 + 1e-6) {
        ASSERT_EQ(out->z_depth_m.at(x, y), 0.0f) << x << "," << y;
      }
    }
  // Everything closer than the near plane is cut away.
  TriangleMesh close;
  AddQuad(&close, {-1, -1, 0.005f}, {1, -1, 0.005f}, {1, 1, 0.005f}, {-1, 1, 0.005f});
  auto none = Rasterize(close, cam, Rigid3d::Identity(), opt);
  ASSERT_TRUE(none.ok());
  EXPECT_EQ(none->pixels_covered, 0u);
}

// A wall crossing the near plane at a slant: the part in front is drawn, with correct depth.
TEST(RasterizerTest, SlantedWallThroughNearPlane) {
  const PinholeCamera cam = PinholeCamera::FromFov(64, 48, glm::radians(90.0));
  TriangleMesh m;
  // Plane x = 0.5 - 0.2 z... i.e. n = (1, 0, 0.2)/|.|, passing next to the camera.
  auto P = [](float y, float z) { return glm::vec3(0.5f - 0.2f * z, y, z); };
  AddQuad(&m, P(-5, -3), P(5, -3), P(5, 30), P(-5, 30));
  RasterOptions opt;
  opt.near_m = 0.1;
  auto out = Rasterize(m, cam, Rigid3d::Identity(), opt);
  ASSERT_TRUE(out.ok());
  int checked = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const glm::dvec3 r = cam.RayZ1({x, y});
      // x = 0.5 - 0.2 z with x = r.x z -> z = 0.5 / (r.x + 0.2)
      const double den = r.x + 0.2;
      if (den <= 0) continue;
      const double z = 0.5 / den;
      if (z < 0.1 || z > 30 || std::abs(r.y * z) > 5) continue;
      if (std::abs(r.y * z) > 4.9 || z > 29.5 || z < 0.11) continue;  // away from the borders
      ASSERT_NEAR(out->z_depth_m.at(x, y), z, 1e-5 * z) << x << "," << y;
      ++checked;
    }
  EXPECT_GT(checked, 300);
}

// Cell ids of the ground plane z = 0 seen from 10 m above: each pixel's id is the cell of the
// analytic intersection point (pixels within 1e-4 m of a cell border are skipped).
TEST(RasterizerTest, CellIdsOfAPlane) {
  const PinholeCamera cam = PinholeCamera::FromFov(120, 90, glm::radians(60.0));
  TriangleMesh m;
  AddQuad(&m, {-30, -30, 0}, {30, -30, 0}, {30, 30, 0}, {-30, 30, 0});
  Rigid3d local_from_cam;
  // Looking down: camera z -> local -z; camera y (down in image) -> local -y.
  local_from_cam.rotation = glm::angleAxis(glm::pi<double>(), glm::dvec3(1, 0, 0));
  local_from_cam.translation = {1.3, -2.1, 10.0};
  RasterOptions opt = AllOutputs();
  opt.cell_grid.cell_size_m = 0.5;
  auto out = Rasterize(m, cam, local_from_cam, opt);
  ASSERT_TRUE(out.ok()) << out.status();
  int checked = 0, distinct_changes = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const glm::dvec3 p = local_from_cam * cam.Unproject({x, y}, 10.0);
      ASSERT_NEAR(out->z_depth_m.at(x, y), 10.0, 1e-4);
      ASSERT_NEAR(out->normal_local.at(x, y, 2), 1.0, 1e-6);  // faces up (+z, to the camera)
      auto near_border = [](double v) {
        const double f = v / 0.5 - std::floor(v / 0.5);
        return f < 2e-4 || f > 1 - 2e-4;
      };
      if (near_border(p.x) || near_border(p.y) || near_border(p.z + 1e-3)) continue;
      ASSERT_EQ(out->cell_id.at(x, y), opt.cell_grid.IdOf(p)) << x << "," << y;
      ++checked;
      if (x > 0 && out->cell_id.at(x, y) != out->cell_id.at(x - 1, y)) ++distinct_changes;
    }
  EXPECT_GT(checked, cam.width * cam.height * 9 / 10);
  EXPECT_GT(distinct_changes, 100);  // many cells across the view
}

// Reduced resolution renders through camera.Scaled with consistent intrinsics.
TEST(RasterizerTest, ReducedResolution) {
  const PinholeCamera cam = PinholeCamera::FromFov(160, 120, glm::radians(60.0));
  TriangleMesh m;
  AddQuad(&m, {-0.5f, -0.5f, 3}, {0.5f, -0.5f, 3}, {0.5f, 0.5f, 3}, {-0.5f, 0.5f, 3});
  RasterOptions opt;
  auto full = Rasterize(m, cam, Rigid3d::Identity(), opt);
  opt.width = 40;
  opt.height = 30;
  auto quarter = Rasterize(m, cam, Rigid3d::Identity(), opt);
  ASSERT_TRUE(full.ok() && quarter.ok());
  EXPECT_EQ(quarter->camera.width, 40);
  EXPECT_EQ(quarter->z_depth_m.width(), 40);
  // Analytic area: (fx * 1 / 3)^2 pixels at full res, /16 at quarter res.
  const double area_full = std::pow(cam.fx / 3.0, 2);
  EXPECT_NEAR(CountCovered(full->z_depth_m), area_full, 4 * cam.fx / 3.0);
  EXPECT_NEAR(CountCovered(quarter->z_depth_m), area_full / 16, cam.fx / 3.0);
}

// Depth test + deterministic output for any thread count, on a random triangle soup with
// overlapping and coincident triangles.
TEST(RasterizerTest, DeterministicAcrossThreadCounts) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-3, 3), zd(0.05f, 8);
  TriangleMesh m;
  for (int t = 0; t < 600; ++t) {
    const glm::vec3 c(u(rng), u(rng), zd(rng));
    for (int k = 0; k < 3; ++k) m.positions.push_back(c + 0.5f * glm::vec3(u(rng), u(rng), u(rng)));
    const uint32_t b = 3 * t;
    m.indices.insert(m.indices.end(), {b, b + 1, b + 2});
  }
  // Duplicate the first 50 triangles exactly (depth ties: the lower index must win).
  for (uint32_t t = 0; t < 50; ++t)
    m.indices.insert(m.indices.end(), {3 * t, 3 * t + 1, 3 * t + 2});
  const PinholeCamera cam = PinholeCamera::FromFov(200, 150, glm::radians(80.0));
  RasterOptions opt = AllOutputs();
  opt.num_threads = 1;
  auto a = Rasterize(m, cam, Rigid3d::Identity(), opt);
  ASSERT_TRUE(a.ok());
  for (uint32_t id : a->triangle_id.span()) ASSERT_TRUE(id == kNoTriangle || id < 600);
  for (int threads : {2, 3, 8}) {
    opt.num_threads = threads;
    auto b = Rasterize(m, cam, Rigid3d::Identity(), opt);
    ASSERT_TRUE(b.ok());
    EXPECT_EQ(a->z_depth_m, b->z_depth_m);
    EXPECT_EQ(a->triangle_id, b->triangle_id);
    EXPECT_EQ(a->position_local, b->position_local);
    EXPECT_EQ(a->cell_id, b->cell_id);
  }
  // The depth buffer holds the nearest surface: compare with brute-force ray casting of a few
  // pixels (Moller-Trumbore).
  for (int y = 5; y < cam.height; y += 17)
    for (int x = 3; x < cam.width; x += 13) {
      const glm::dvec3 dir = cam.RayZ1({x, y});
      double best = 0;
      for (size_t t = 0; t < 600; ++t) {
        const glm::dvec3 p0(m.positions[3 * t]), p1(m.positions[3 * t + 1]),
            p2(m.positions[3 * t + 2]);
        const glm::dvec3 e1 = p1 - p0, e2 = p2 - p0, pv = glm::cross(dir, e2);
        const double det = glm::dot(e1, pv);
        if (std::abs(det) < 1e-12) continue;
        const double bu = glm::dot(-p0, pv) / det;
        const glm::dvec3 qv = glm::cross(-p0, e1);
        const double bv = glm::dot(dir, qv) / det, tz = glm::dot(e2, qv) / det;
        if (bu < 1e-6 || bv < 1e-6 || bu + bv > 1 - 1e-6 || tz < opt.near_m) continue;
        if (best == 0 || tz < best) best = tz;
      }
      if (best > 0) {
        EXPECT_NEAR(a->z_depth_m.at(x, y), best, 1e-4 * best) << x << "," << y;
      }
    }
}

// RasterizeParts renders the concatenation without building it: every output identical to
// Rasterize() of the concatenated mesh, with global triangle ids. Random triangles crossing the
// near plane and the image border exercise both the cached-projection fast path and the
// clipper; exact duplicates across parts check that depth ties go to the lower GLOBAL id
// (guards the part offset: with local ids the tie would resolve to the other part's triangle).
TEST(RasterizerTest, PartsEqualConcatenation) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-4, 4), zd(-0.5f, 6);
  std::vector<TriangleMesh> parts(4);
  for (int k = 0; k < 4; ++k)
    for (int t = 0; t < 300; ++t) {
      const glm::vec3 c(u(rng), u(rng), zd(rng));
      for (int j = 0; j < 3; ++j)
        parts[k].positions.push_back(c + 0.6f * glm::vec3(u(rng), u(rng), u(rng)));
      const uint32_t b = 3 * t;
      parts[k].indices.insert(parts[k].indices.end(), {b, b + 1, b + 2});
    }
  parts[3].positions.insert(parts[3].positions.end(), parts[0].positions.begin(),
                            parts[0].positions.begin() + 150);  // 50 exact duplicates of part 0
  for (uint32_t t = 0; t < 50; ++t)
    parts[3].indices.insert(parts[3].indices.end(), {900 + 3 * t, 901 + 3 * t, 902 + 3 * t});
  parts[2] = TriangleMesh{};  // an empty part in between
  TriangleMesh all;
  std::vector<const TriangleMesh*> ptrs;
  for (const TriangleMesh& m : parts) {
    const uint32_t base = static_cast<uint32_t>(all.positions.size());
    all.positions.insert(all.positions.end(), m.positions.begin(), m.positions.end());
    for (uint32_t i : m.indices) all.indices.push_back(base + i);
    ptrs.push_back(&m);
  }
  const PinholeCamera cam = PinholeCamera::FromFov(160, 120, glm::radians(75.0));
  Rigid3d pose;
  pose.rotation = glm::angleAxis(0.2, glm::normalize(glm::dvec3(0.3, 1, 0.1)));
  pose.translation = {0.1, -0.2, -0.3};
  RasterOptions opt = AllOutputs();
  opt.cell_grid.cell_size_m = 0.5;
  for (int threads : {1, 2}) {
    opt.num_threads = threads;
    auto a = Rasterize(all, cam, pose, opt);
    auto b = RasterizeParts(ptrs, cam, pose, opt);
    ASSERT_TRUE(a.ok() && b.ok());
    EXPECT_GT(a->triangles_clipped, 0u);  // the clipper ran
    EXPECT_GT(a->pixels_covered, 2000u);
    EXPECT_EQ(a->triangles_in, b->triangles_in);
    EXPECT_EQ(a->triangles_setup, b->triangles_setup);
    EXPECT_EQ(a->z_depth_m, b->z_depth_m);
    EXPECT_EQ(a->range_m, b->range_m);
    EXPECT_EQ(a->position_local, b->position_local);
    EXPECT_EQ(a->normal_local, b->normal_local);
    EXPECT_EQ(a->triangle_id, b->triangle_id);
    EXPECT_EQ(a->cell_id, b->cell_id);
    // Part 0's triangles win every tie with their duplicates in part 3.
    size_t dup_pixels = 0;
    // Globals: parts 0, 1 = 0..599, part 3 = 600..949, its duplicates = 900..949.
    for (uint32_t id : b->triangle_id.span()) dup_pixels += id != kNoTriangle && id >= 900;
    EXPECT_EQ(dup_pixels, 0u);
    size_t orig_pixels = 0;  // the duplicated originals are visible (the tie is exercised)
    for (uint32_t id : b->triangle_id.span()) orig_pixels += id < 50;
    EXPECT_GT(orig_pixels, 0u);
  }
  std::vector<const TriangleMesh*> with_null = {&all, nullptr};
  EXPECT_FALSE(RasterizeParts(with_null, cam, pose, opt).ok());
  EXPECT_TRUE(RasterizeParts({}, cam, pose, opt).ok());  // nothing to draw: background
}

// ---- Output identity over a stream (speed work must not change a single bit) ----

// Deterministic on every platform: splitmix64 -> float in [a, b) (no <random> distributions,
// no libm calls in the scene or the poses).
struct Lcg {
  uint64_t state;
  uint64_t Next() {
    uint64_t z = (state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
  }
  float Uniform(float a, float b) { return a + (b - a) * float(Next() >> 40) / float(1 << 24); }
};

// A proxy-like scene in 3 parts: a 120 x 120 height field of 0.2 m quads (shared edges, most
// triangles below a pixel of a 160x120 buffer), 4000 small random triangles of both windings,
// 300 slivers (two vertices 1e-4 m apart), 200 exact duplicates (depth ties) and 40 large
// triangles (near-plane and guard-band clipping).
std::vector<TriangleMesh> StreamScene() {
  Lcg rng{2024};
  std::vector<TriangleMesh> parts(3);
  TriangleMesh& field = parts[0];
  const int n = 120;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) {
      const float x = -12 + 0.2f * i, y = -12 + 0.2f * j;
      field.positions.emplace_back(x, y, 0.02f * x * y * 0.1f + rng.Uniform(-0.05f, 0.05f));
    }
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const uint32_t a = j * (n + 1) + i, b = a + 1, c = a + n + 1, d = c + 1;
      field.indices.insert(field.indices.end(), {a, b, d, a, d, c});
    }
  TriangleMesh& soup = parts[1];
  for (int t = 0; t < 4000; ++t) {
    const glm::vec3 c(rng.Uniform(-10, 10), rng.Uniform(-10, 10), rng.Uniform(0, 4));
    const float size = rng.Uniform(0.01f, 0.3f);
    for (int k = 0; k < 3; ++k)
      soup.positions.push_back(c + size * glm::vec3(rng.Uniform(-1, 1), rng.Uniform(-1, 1),
                                                    rng.Uniform(-1, 1)));
    const uint32_t b = 3 * t;
    soup.indices.insert(soup.indices.end(), {b, b + 1, b + 2});
  }
  for (int t = 0; t < 300; ++t) {  // slivers
    const glm::vec3 a(rng.Uniform(-10, 10), rng.Uniform(-10, 10), rng.Uniform(0, 4));
    const glm::vec3 b = a + glm::vec3(rng.Uniform(-2, 2), rng.Uniform(-2, 2), rng.Uniform(-1, 1));
    const uint32_t base = uint32_t(soup.positions.size());
    soup.positions.insert(soup.positions.end(), {a, b, b + glm::vec3(1e-4f, -1e-4f, 0)});
    soup.indices.insert(soup.indices.end(), {base, base + 1, base + 2});
  }
  TriangleMesh& misc = parts[2];
  misc.positions = soup.positions;
  for (uint32_t t = 0; t < 200; ++t)  // exact duplicates of part 1 triangles (ties)
    misc.indices.insert(misc.indices.end(), {3 * t * 7, 3 * t * 7 + 1, 3 * t * 7 + 2});
  for (int t = 0; t < 40; ++t) {  // large triangles
    const uint32_t base = uint32_t(misc.positions.size());
    for (int k = 0; k < 3; ++k)
      misc.positions.emplace_back(rng.Uniform(-15, 15), rng.Uniform(-15, 15), rng.Uniform(-1, 6));
    misc.indices.insert(misc.indices.end(), {base, base + 1, base + 2});
  }
  return parts;
}

// Seen from the identity pose by the test camera scaled to 160x120 (f = 125, c = (79.5, 59.5)),
// a vertex (u - 79.5, v - 59.5, 125) projects exactly to pixel (u, v). Tiny triangles with
// vertices on pixel centres (edges through pixel centres: the fill rule decides), on half
// sub-pixel steps (1/512 px: the rounding of the fixed-point snap decides), both windings,
// overlapping at equal depth (ties).
TriangleMesh ExactPixelTriangles() {
  TriangleMesh m;
  auto vertex = [&](double u, double v) {
    m.positions.emplace_back(float(u - 79.5), float(v - 59.5), 125.0f);
    return uint32_t(m.positions.size() - 1);
  };
  for (int j = 0; j < 28; ++j)
    for (int i = 0; i < 38; ++i) {
      const double u = 2 + 4 * i, v = 2 + 4 * j, d = ((i + 2 * j) % 4) / 512.0;
      const uint32_t a = vertex(u + d, v), b = vertex(u + 2, v - d), c = vertex(u, v + 2 + d),
                     e = vertex(u + 2 - d, v + 2);
      if ((i + j) % 2 == 0) m.indices.insert(m.indices.end(), {a, b, c, b, e, c});
      else m.indices.insert(m.indices.end(), {a, c, b, b, c, e});
      const uint32_t f = vertex(u + 1 + d, v + 1), g = vertex(u + 3, v + 1 + d),
                     h = vertex(u + 1, v + 3);  // overlaps the quad at the same depth
      m.indices.insert(m.indices.end(), {f, g, h});
    }
  return m;
}

// Camera at `eye` looking at `target` (up = +z), without libm calls.
Rigid3d StreamPose(const glm::dvec3& eye, const glm::dvec3& target) {
  const glm::dvec3 z = glm::normalize(target - eye);
  const glm::dvec3 x = glm::normalize(glm::cross(z, glm::dvec3(0, 0, 1)));
  const glm::dvec3 y = glm::cross(z, x);
  Rigid3d r;
  r.rotation = glm::normalize(glm::quat_cast(glm::dmat3(x, y, z)));
  r.translation = eye;
  return r;
}

uint64_t Fnv1a(uint64_t h, const void* data, size_t bytes) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (size_t i = 0; i < bytes; ++i) h = (h ^ p[i]) * 1099511628211ull;
  return h;
}

// FNV-1a of z-depth, triangle id and cell id of 14 renders (6 poses of StreamScene with
// RasterizeParts and ExactPixelTriangles from the identity pose; 160x120, then 320x240). The constant was computed with the rasterizer BEFORE the session-4 speed work
// (commit 8756a9a: no small-box pre-test, per-part vertex buffers, fresh buffers per render,
// std::llround); the speed-ups must reproduce it bit for bit, for 1 and 2 threads, and a render
// must not depend on the one before it (per-thread scratch reuse). Guards every one of them: a
// pre-test that disagrees with the scan's fill rule on one pixel centre, a rounding change in
// Fix(), a stale depth or winner buffer, all change the sum.
TEST(RasterizerTest, StreamChecksumUnchangedBySpeedWork) {
  const std::vector<TriangleMesh> parts = StreamScene();
  const std::vector<const TriangleMesh*> part_ptrs = {&parts[0], &parts[1], &parts[2]};
  const TriangleMesh exact = ExactPixelTriangles();
  PinholeCamera cam;
  cam.fx = cam.fy = 500;
  cam.cx = 319.5;
  cam.cy = 239.5;
  cam.width = 640;
  cam.height = 480;
  const std::vector<Rigid3d> poses = {
      StreamPose({0, -14, 6}, {0, 0, 0}),  StreamPose({-9, -9, 2.5}, {3, 2, 0.5}),
      StreamPose({2, 1, 1.5}, {8, 3, 1}),  StreamPose({0, 0, 20}, {0.5, 0.3, 0}),
      StreamPose({5, 5, 0.3}, {-5, 4, 0.2}), StreamPose({-3, 2, 1.0}, {-3, 9, 1.1})};
  for (int threads : {1, 2}) {
    uint64_t h = 14695981039346656037ull;
    size_t covered = 0;
    for (int size : {160, 320})
      for (size_t k = 0; k <= poses.size(); ++k) {  // the last: exact triangles, identity pose
        const bool exact_view = k == poses.size();
        const Rigid3d pose = exact_view ? Rigid3d::Identity() : poses[k];
        RasterOptions o;
        o.z_depth = o.triangle_id = o.cell_id = true;
        o.cell_grid.cell_size_m = 0.5;
        o.width = size;
        o.height = size * 3 / 4;
        o.num_threads = threads;
        auto r = exact_view ? Rasterize(exact, cam, pose, o)
                            : RasterizeParts(part_ptrs, cam, pose, o);
        ASSERT_TRUE(r.ok()) << r.status();
        h = Fnv1a(h, r->z_depth_m.data(), r->z_depth_m.size() * sizeof(float));
        h = Fnv1a(h, r->triangle_id.data(), r->triangle_id.size() * sizeof(uint32_t));
        h = Fnv1a(h, r->cell_id.data(), r->cell_id.size() * sizeof(uint64_t));
        covered += r->pixels_covered;
      }
    EXPECT_GT(covered, 200000u);  // the renders see the scene (not a sum over background)
    EXPECT_EQ(h, kStreamChecksum) << "threads " << threads << ": got 0x" << std::hex << h;
  }
}

TEST(RasterizerTest, BadInputIsAnError) {
  const PinholeCamera cam = PinholeCamera::FromFov(32, 24, 1.0);
  TriangleMesh m;
  AddQuad(&m, {-1, -1, 2}, {1, -1, 2}, {1, 1, 2}, {-1, 1, 2});
  m.indices.push_back(99);
  m.indices.push_back(0);
  m.indices.push_back(1);
  EXPECT_FALSE(Rasterize(m, cam, Rigid3d::Identity(), RasterOptions{}).ok());
  m.indices.resize(6);
  RasterOptions bad;
  bad.near_m = 0;
  EXPECT_FALSE(Rasterize(m, cam, Rigid3d::Identity(), bad).ok());
  Rigid3d nan_pose;
  nan_pose.translation.x = std::nan("");
  EXPECT_FALSE(Rasterize(m, cam, nan_pose, RasterOptions{}).ok());
  EXPECT_FALSE(Rasterize(m, PinholeCamera{}, Rigid3d::Identity(), RasterOptions{}).ok());
}

}  // namespace
}  // namespace exo
