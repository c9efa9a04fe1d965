#include "common/synth/scene.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace exo::synth {
namespace {

// Where the apartment's removable chair stands (living room, local frame).
constexpr double kApartmentChairX = 4.3, kApartmentChairY = 2.4;

// Builds a mesh of subdivided quads/boxes with one material per triangle.
class MeshBuilder {
 public:
  explicit MeshBuilder(double max_edge_m) : max_edge_(max_edge_m) {}

  // Parallelogram o + s*a + t*b, s,t in [0,1]; front side (normal a x b) is the visible one.
  void Quad(const glm::dvec3& o, const glm::dvec3& a, const glm::dvec3& b, Material m) {
    const int nu = Divisions(glm::length(a)), nv = Divisions(glm::length(b));
    const uint32_t base = static_cast<uint32_t>(mesh_.positions.size());
    for (int j = 0; j <= nv; ++j)
      for (int i = 0; i <= nu; ++i)
        mesh_.positions.push_back(glm::vec3(o + a * (double(i) / nu) + b * (double(j) / nv)));
    for (int j = 0; j < nv; ++j)
      for (int i = 0; i < nu; ++i) {
        const uint32_t v00 = base + j * (nu + 1) + i, v10 = v00 + 1, v01 = v00 + nu + 1,
                       v11 = v01 + 1;
        Tri(v00, v10, v11, m);
        Tri(v00, v11, v01, m);
      }
  }
  void Triangle(const glm::dvec3& p0, const glm::dvec3& p1, const glm::dvec3& p2, Material m) {
    const uint32_t base = static_cast<uint32_t>(mesh_.positions.size());
    mesh_.positions.insert(mesh_.positions.end(), {glm::vec3(p0), glm::vec3(p1), glm::vec3(p2)});
    Tri(base, base + 1, base + 2, m);
  }
  // Axis-aligned box with outward faces. `top`/`bottom` materials; bottom skipped if !bottom.
  void Box(const glm::dvec3& lo, const glm::dvec3& hi, Material sides, Material top,
           bool bottom = false) {
    const glm::dvec3 d = hi - lo;
    const glm::dvec3 X(d.x, 0, 0), Y(0, d.y, 0), Z(0, 0, d.z);
    Quad(lo, Z, Y, sides);                                   // -x: normal Z x Y = -x
    Quad(glm::dvec3(hi.x, lo.y, lo.z), Y, Z, sides);         // +x
    Quad(lo, X, Z, sides);                                   // -y: X x Z = -y
    Quad(glm::dvec3(lo.x, hi.y, lo.z), Z, X, sides);         // +y
    Quad(glm::dvec3(lo.x, lo.y, hi.z), X, Y, top);           // +z
    if (bottom) Quad(lo, Y, X, top);                         // -z
  }
  TriangleMesh Take() { return std::move(mesh_); }
  uint32_t NumTriangles() const { return static_cast<uint32_t>(mesh_.material.size()); }

 private:
  int Divisions(double len) const {
    if (max_edge_ <= 0) return 1;
    return std::max(1, static_cast<int>(std::ceil(len / max_edge_ - 1e-9)));
  }
  void Tri(uint32_t a, uint32_t b, uint32_t c, Material m) {
    mesh_.indices.insert(mesh_.indices.end(), {a, b, c});
    mesh_.material.push_back(static_cast<uint32_t>(m));
  }
  double max_edge_;
  TriangleMesh mesh_;
};

// Appends the boxes of one removable object (after everything else in the scene).
void AddRemovable(MeshBuilder* mb, SynthScene* s, const std::string& name,
                  const std::vector<std::pair<Box3, std::pair<Material, Material>>>& boxes) {
  RemovableObject o;
  o.name = name;
  o.first_triangle = mb->NumTriangles();
  o.bounds = {glm::dvec3(1e300), glm::dvec3(-1e300)};
  for (const auto& [b, m] : boxes) {
    mb->Box(b.min, b.max, m.first, m.second, b.min.z > 0);
    o.bounds.min = glm::min(o.bounds.min, b.min);
    o.bounds.max = glm::max(o.bounds.max, b.max);
  }
  o.num_triangles = mb->NumTriangles() - o.first_triangle;
  s->solids.push_back(o.bounds);
  s->removable.push_back(std::move(o));
}

Box3 MeshBounds(const TriangleMesh& mesh) {
  Box3 b{glm::dvec3(1e300), glm::dvec3(-1e300)};
  for (const glm::vec3& p : mesh.positions) {
    b.min = glm::min(b.min, glm::dvec3(p));
    b.max = glm::max(b.max, glm::dvec3(p));
  }
  return b;
}

// Gabled roof over [lo,hi] footprint at height z0, ridge along the longer horizontal axis.
void GableRoof(MeshBuilder* mb, glm::dvec2 lo, glm::dvec2 hi, double z0, double rise,
               double overhang) {
  lo -= overhang;
  hi += overhang;
  const bool ridge_x = (hi.x - lo.x) >= (hi.y - lo.y);
  if (ridge_x) {
    const double ym = 0.5 * (lo.y + hi.y);
    const glm::dvec3 a(lo.x, lo.y, z0), b(hi.x, lo.y, z0), c(hi.x, hi.y, z0), d(lo.x, hi.y, z0);
    const glm::dvec3 r0(lo.x, ym, z0 + rise), r1(hi.x, ym, z0 + rise);
    mb->Quad(a, b - a, r0 - a, Material::kRoofTiles);   // south slope, normal (0,-,+)
    mb->Quad(c, d - c, r1 - c, Material::kRoofTiles);   // north slope
    mb->Triangle(a, r0, d, Material::kPlaster);          // west gable (normal -x)
    mb->Triangle(b, c, r1, Material::kPlaster);          // east gable
    mb->Quad(a, d - a, b - a, Material::kPlaster);       // soffit (underside, normal -z)
  } else {
    const double xm = 0.5 * (lo.x + hi.x);
    const glm::dvec3 a(lo.x, lo.y, z0), b(hi.x, lo.y, z0), c(hi.x, hi.y, z0), d(lo.x, hi.y, z0);
    const glm::dvec3 r0(xm, lo.y, z0 + rise), r1(xm, hi.y, z0 + rise);
    mb->Quad(d, a - d, r1 - d, Material::kRoofTiles);   // west slope
    mb->Quad(b, c - b, r0 - b, Material::kRoofTiles);   // east slope
    mb->Triangle(a, b, r0, Material::kPlaster);          // south gable
    mb->Triangle(c, d, r1, Material::kPlaster);          // north gable
    mb->Quad(a, d - a, b - a, Material::kPlaster);
  }
}

}  // namespace

const char* MaterialName(Material m) {
  static const char* kNames[] = {"grass",  "asphalt", "pavement",  "brick",  "plaster",
                                 "roof",   "wood",    "floor_tiles", "wallpaper", "ceiling",
                                 "fabric", "bark",    "leaves",    "metal",  "marble"};
  const auto i = static_cast<uint32_t>(m);
  return i < static_cast<uint32_t>(Material::kCount) ? kNames[i] : "unknown";
}

const char* SceneKindName(SceneKind k) {
  return k == SceneKind::kVillage ? "village" : "apartment";
}

absl::StatusOr<SceneKind> ParseSceneKind(const std::string& name) {
  if (name == "village") return SceneKind::kVillage;
  if (name == "apartment") return SceneKind::kApartment;
  return absl::InvalidArgumentError(
      absl::StrCat("unknown scene '", name, "' (expected village or apartment)"));
}

absl::Status SceneOptions::Validate() const {
  if (!(max_edge_m >= 0) || !std::isfinite(max_edge_m))
    return absl::InvalidArgumentError("scene max_edge_m must be >= 0");
  if (max_edge_m > 0 && max_edge_m < 0.05)
    return absl::InvalidArgumentError("scene max_edge_m below 5 cm would explode the mesh");
  for (int i = 0; i < 3; ++i)
    if (!std::isfinite(origin_in_world[i]))
      return absl::InvalidArgumentError("scene origin_in_world has NaN or Inf");
  return absl::OkStatus();
}

bool SynthScene::IsFree(const glm::dvec3& p, double clearance_m) const {
  if (!navigable.Contains(p)) return false;
  for (const Box3& s : solids)
    if (s.Contains(p, clearance_m)) return false;
  return true;
}

absl::StatusOr<SynthScene> MakeScene(SceneKind kind, const SceneOptions& options) {
  return kind == SceneKind::kVillage ? MakeVillage(options) : MakeApartment(options);
}

absl::StatusOr<SynthScene> MakeVillage(const SceneOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  std::mt19937_64 rng(options.seed * 0x9E3779B97F4A7C15ull + 11);
  auto uni = [&](double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); };
  SynthScene s;
  s.name = "village";
  s.kind = SceneKind::kVillage;
  s.origin.origin_in_world = options.origin_in_world;
  s.texture_seed = static_cast<uint32_t>(options.seed * 2654435761u + 1);
  s.sun_dir = glm::normalize(glm::dvec3(0.45, -0.3, 0.84));
  s.ambient = 0.38;
  s.flyover_altitude_m = 22.0;
  s.street_x = {-14.0, 10.0};
  s.street_y = {-14.0, 10.0};
  s.street_half_width_m = 3.0;
  const double half = 32.0;  // 64 x 64 m
  MeshBuilder mb(options.max_edge_m);

  // Ground: 1 m tiles, each with the material of its centre (no overlapping surfaces).
  auto dist_to_street = [&](double x, double y) {
    double d = 1e9;
    for (double c : s.street_x) d = std::min(d, std::abs(x - c));
    for (double c : s.street_y) d = std::min(d, std::abs(y - c));
    return d;
  };
  // A plaza (pavement) around the crossing (10,10)... and a park with trees in one block.
  for (int j = -32; j < 32; ++j)
    for (int i = -32; i < 32; ++i) {
      const double cx = i + 0.5, cy = j + 0.5;
      const double d = dist_to_street(cx, cy);
      Material m = Material::kGrass;
      if (d < s.street_half_width_m) m = Material::kAsphalt;
      else if (d < s.street_half_width_m + 2.0) m = Material::kPavement;
      else if (cx > -9 && cx < 5 && cy > -9 && cy < 5 && !(cx > -6 && cx < 2 && cy > -6 && cy < 2))
        m = Material::kPavement;  // plaza ring around the central lawn
      mb.Quad({double(i), double(j), 0.0}, {1, 0, 0}, {0, 1, 0}, m);
    }

  // Blocks between streets (with sidewalks): x and y intervals.
  const double sw = s.street_half_width_m + 2.0;
  const std::vector<std::pair<double, double>> spans = {
      {-half + 1, -14 - sw}, {-14 + sw, 10 - sw}, {10 + sw, half - 1}};
  int building = 0;
  for (int by = 0; by < 3; ++by)
    for (int bx = 0; bx < 3; ++bx) {
      const glm::dvec2 lo(spans[bx].first, spans[by].first), hi(spans[bx].second, spans[by].second);
      if (bx == 1 && by == 1) {
        // Central block: plaza with trees on the lawn and a fountain-like low wall square.
        for (int t = 0; t < 5; ++t) {
          const double tx = uni(-5, 1), ty = uni(-5, 1);
          const double h = uni(2.0, 3.0), c = uni(1.0, 1.6);
          mb.Box({tx - 0.2, ty - 0.2, 0}, {tx + 0.2, ty + 0.2, h}, Material::kBark, Material::kBark);
          mb.Box({tx - c, ty - c, h}, {tx + c, ty + c, h + 2 * c}, Material::kLeaves,
                 Material::kLeaves, true);
          s.solids.push_back({{tx - c, ty - c, 0}, {tx + c, ty + c, h + 2 * c}});
        }
        continue;
      }
      // Split the block into 1-2 lots along its longer side; one building per lot.
      const glm::dvec2 size = hi - lo;
      const int lots = size.x > 12 || size.y > 12 ? 2 : 1;
      for (int l = 0; l < lots; ++l) {
        glm::dvec2 llo = lo, lhi = hi;
        if (lots == 2) {
          if (size.x >= size.y) {
            llo.x = lo.x + size.x * l / 2;
            lhi.x = lo.x + size.x * (l + 1) / 2;
          } else {
            llo.y = lo.y + size.y * l / 2;
            lhi.y = lo.y + size.y * (l + 1) / 2;
          }
        }
        const glm::dvec2 lsize = lhi - llo;
        const double w = std::clamp(uni(0.55, 0.85) * lsize.x, 4.0, 14.0);
        const double d = std::clamp(uni(0.55, 0.85) * lsize.y, 4.0, 14.0);
        const double ox = llo.x + uni(0.5, std::max(0.6, lsize.x - w - 0.5));
        const double oy = llo.y + uni(0.5, std::max(0.6, lsize.y - d - 0.5));
        const int floors = 1 + static_cast<int>(rng() % 4);
        const double h = 3.0 * floors + 0.4;
        const Material wall = (building++ % 3 == 1) ? Material::kPlaster : Material::kBrick;
        mb.Box({ox, oy, 0}, {ox + w, oy + d, h}, wall, Material::kPlaster);
        double top = h;
        if (rng() % 4 != 0) {
          const double rise = uni(1.5, 3.0);
          GableRoof(&mb, {ox, oy}, {ox + w, oy + d}, h, rise, 0.3);
          top += rise;
        }
        s.solids.push_back({{ox - 0.3, oy - 0.3, 0}, {ox + w + 0.3, oy + d + 0.3, top}});
        // A low garden wall on the lot's edge facing away from the building, sometimes.
        if (rng() % 2 == 0 && lsize.x > w + 2.5) {
          const double wx = (ox - llo.x > lhi.x - ox - w) ? llo.x + 0.3 : lhi.x - 0.6;
          mb.Box({wx, llo.y + 0.5, 0}, {wx + 0.3, lhi.y - 0.5, 1.1}, Material::kBrick,
                 Material::kPavement);
          s.solids.push_back({{wx, llo.y + 0.5, 0}, {wx + 0.3, lhi.y - 0.5, 1.1}});
        }
        // A tree in the yard if there is room.
        if (lsize.y > d + 4.5) {
          const double tx = 0.5 * (llo.x + lhi.x);
          const double ty = (oy - llo.y > lhi.y - oy - d) ? llo.y + 1.8 : lhi.y - 1.8;
          const double th = uni(2.0, 3.0), c = uni(1.0, 1.5);
          mb.Box({tx - 0.2, ty - 0.2, 0}, {tx + 0.2, ty + 0.2, th}, Material::kBark,
                 Material::kBark);
          mb.Box({tx - c, ty - c, th}, {tx + c, ty + c, th + 2 * c}, Material::kLeaves,
                 Material::kLeaves, true);
          s.solids.push_back({{tx - c, ty - c, 0}, {tx + c, ty + c, th + 2 * c}});
        }
      }
    }
  // Parked cars along the street edges (painted metal: the specular material).
  for (double cx : s.street_x)
    for (int k = 0; k < 3; ++k) {
      const double y = uni(-28, 26);
      if (dist_to_street(cx + 2.1, y) < 0.5 && std::abs(y - cx) < 6) continue;
      bool near_crossing = false;
      for (double sy : s.street_y) near_crossing |= std::abs(y + 2 - sy) < 6;
      if (near_crossing) continue;
      const double x0 = cx + 1.3;  // parked on the right lane edge
      mb.Box({x0, y, 0.25}, {x0 + 1.7, y + 4.0, 1.0}, Material::kMetal, Material::kMetal, true);
      mb.Box({x0 + 0.15, y + 1.0, 1.0}, {x0 + 1.55, y + 3.0, 1.45}, Material::kMetal,
             Material::kMetal);
      s.solids.push_back({{x0, y, 0}, {x0 + 1.7, y + 4.0, 1.45}});
    }
  // Lamp posts at street corners.
  for (double cx : s.street_x)
    for (double cy : s.street_y)
      for (int sx : {-1, 1}) {
        const double x = cx + sx * (s.street_half_width_m + 0.6), y = cy - sx * 4.5;
        mb.Box({x - 0.08, y - 0.08, 0}, {x + 0.08, y + 0.08, 4.0}, Material::kMetal,
               Material::kMetal);
        mb.Box({x - 0.25, y - 0.25, 4.0}, {x + 0.25, y + 0.25, 4.3}, Material::kMetal,
               Material::kMetal, true);
        s.solids.push_back({{x - 0.25, y - 0.25, 0}, {x + 0.25, y + 0.25, 4.3}});
      }

  if (options.removable_objects) {
    // A hand cart at the west kerb of the street x = -14 (wooden bed on a metal frame, wheels
    // as blocks, a handle bar).
    const glm::dvec2 c(-16.4, -21.0);
    const auto W = std::make_pair(Material::kWood, Material::kWood);
    const auto M = std::make_pair(Material::kMetal, Material::kMetal);
    AddRemovable(&mb, &s, "cart",
                 {{{{c.x - 0.45, c.y - 0.7, 0.35}, {c.x + 0.45, c.y + 0.7, 0.75}}, W},
                  {{{c.x - 0.55, c.y - 0.35, 0.0}, {c.x - 0.45, c.y + 0.35, 0.45}}, M},
                  {{{c.x + 0.45, c.y - 0.35, 0.0}, {c.x + 0.55, c.y + 0.35, 0.45}}, M},
                  {{{c.x - 0.3, c.y + 0.7, 0.7}, {c.x - 0.25, c.y + 1.3, 0.78}}, M},
                  {{{c.x + 0.25, c.y + 0.7, 0.7}, {c.x + 0.3, c.y + 1.3, 0.78}}, M},
                  {{{c.x - 0.3, c.y + 1.25, 0.7}, {c.x + 0.3, c.y + 1.3, 0.8}}, M}});
  }

  s.mesh = mb.Take();
  s.bounds = MeshBounds(s.mesh);
  s.navigable = {{-half + 2, -half + 2, 0.5}, {half - 2, half - 2, s.flyover_altitude_m + 4}};
  // Walk: a loop along the streets (right of the centre line) and across the plaza.
  const double e = s.eye_height_m;
  s.walk_waypoints = {{-15, -27, e}, {-15, -20, e}, {-15, -15, e}, {-6, -15, e}, {3, -15, e},
                      {9, -15, e},   {9, -6, e},    {9, 3, e},     {9, 9, e},   {0, 9, e},
                      {-8, 9, e},    {-15, 9, e},   {-15, 18, e},  {-15, 27, e}};
  return s;
}

absl::StatusOr<SynthScene> MakeApartment(const SceneOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  std::mt19937_64 rng(options.seed * 0xD1B54A32D192ED03ull + 5);
  auto uni = [&](double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); };
  SynthScene s;
  s.name = "apartment";
  s.kind = SceneKind::kApartment;
  s.indoor = true;
  s.origin.origin_in_world = options.origin_in_world;
  s.texture_seed = static_cast<uint32_t>(options.seed * 2246822519u + 3);
  s.sun_dir = glm::normalize(glm::dvec3(0.35, 0.5, 0.79));
  s.ambient = 0.5;
  const double W = 12.0, D = 9.0, H = 2.7, t = 0.15;  // outer size, height, wall thickness
  MeshBuilder mb(options.max_edge_m);

  // Floors per room (wood in living/bedroom, tiles in kitchen/study) and the ceiling.
  mb.Quad({0, 0, 0}, {7, 0, 0}, {0, 9, 0}, Material::kWood);
  mb.Quad({7, 0, 0}, {5, 0, 0}, {0, 9, 0}, Material::kFloorTiles);
  mb.Quad({0, 0, H}, {0, D, 0}, {W, 0, 0}, Material::kCeiling);  // faces down

  // Walls as boxes; a wall along x (or y) from a to b with door openings [d0, d1].
  auto wall = [&](bool along_x, double c, double a, double b, std::vector<glm::dvec2> doors,
                  Material m) {
    std::sort(doors.begin(), doors.end(), [](auto p, auto q) { return p.x < q.x; });
    double start = a;
    auto seg = [&](double s0, double s1, double z0, double z1) {
      if (s1 - s0 < 1e-6) return;
      glm::dvec3 lo, hi;
      if (along_x) {
        lo = {s0, c - t / 2, z0};
        hi = {s1, c + t / 2, z1};
      } else {
        lo = {c - t / 2, s0, z0};
        hi = {c + t / 2, s1, z1};
      }
      mb.Box(lo, hi, m, Material::kPlaster, z0 > 0);
      s.solids.push_back({lo, hi});
    };
    for (const glm::dvec2& d : doors) {
      seg(start, d.x, 0, H);
      seg(d.x, d.y, 2.05, H);  // lintel
      start = d.y;
    }
    seg(start, b, 0, H);
  };
  // Outer walls (slightly outside the rooms) and inner walls with doors.
  wall(true, -t / 2, -t, W + t, {}, Material::kPlaster);
  wall(true, D + t / 2, -t, W + t, {}, Material::kWallpaper);
  wall(false, -t / 2, 0, D, {}, Material::kWallpaper);
  wall(false, W + t / 2, 0, D, {}, Material::kPlaster);
  wall(false, 7.0, 0, D, {{1.5, 2.5}, {6.0, 7.0}}, Material::kWallpaper);
  wall(true, 5.0, 0, 7.0 - t / 2, {{3.0, 4.0}}, Material::kPlaster);
  wall(true, 4.5, 7.0 + t / 2, W, {{9.0, 10.0}}, Material::kWallpaper);

  auto solid_box = [&](glm::dvec3 lo, glm::dvec3 hi, Material side, Material top) {
    mb.Box(lo, hi, side, top);
    s.solids.push_back({lo, hi});
  };
  auto table = [&](double x, double y, double w, double d, double h, Material top) {
    solid_box({x, y, h - 0.05}, {x + w, y + d, h}, top, top);
    for (int i = 0; i < 4; ++i) {
      const double lx = (i & 1) ? x + w - 0.08 : x + 0.03, ly = (i & 2) ? y + d - 0.08 : y + 0.03;
      mb.Box({lx, ly, 0}, {lx + 0.05, ly + 0.05, h - 0.05}, Material::kWood, Material::kWood);
    }
    s.solids.push_back({{x, y, 0}, {x + w, y + d, h}});
  };
  // Living room [0,7]x[0,5]: sofa on the west wall, coffee table, bookshelf on the south wall.
  const double sofa_y = uni(1.2, 2.4);
  solid_box({0.05, sofa_y, 0}, {0.95, sofa_y + 2.2, 0.45}, Material::kFabric, Material::kFabric);
  solid_box({0.05, sofa_y, 0.45}, {0.3, sofa_y + 2.2, 0.9}, Material::kFabric, Material::kFabric);
  table(1.3, sofa_y + 0.5, 0.6, 1.2, 0.42, Material::kWood);
  const double shelf_x = uni(2.5, 4.0);
  solid_box({shelf_x, 0.05, 0}, {shelf_x + 1.8, 0.45, 2.0}, Material::kWood, Material::kWood);
  solid_box({5.8, 3.9, 0}, {6.85, 4.85, 0.75}, Material::kWood, Material::kMarble);  // sideboard
  // Bedroom [0,7]x[5,9]: bed on the west wall, wardrobe on the north wall, desk.
  solid_box({0.05, 6.6, 0}, {2.1, 8.2, 0.5}, Material::kFabric, Material::kFabric);
  solid_box({0.05, 6.6, 0.5}, {0.2, 8.2, 1.1}, Material::kWood, Material::kWood);
  const double ward_x = uni(3.0, 4.6);
  solid_box({ward_x, 8.3, 0}, {ward_x + 1.6, 8.95, 2.2}, Material::kWood, Material::kWood);
  table(5.4, 8.1, 1.2, 0.8, 0.75, Material::kWood);
  // Kitchen [7,12]x[0,4.5]: counter along the south and east walls (marble top), table.
  solid_box({8.0, 0.05, 0}, {11.95, 0.65, 0.9}, Material::kWood, Material::kMarble);
  solid_box({11.35, 0.65, 0}, {11.95, 2.6, 0.9}, Material::kWood, Material::kMarble);
  solid_box({8.2, 0.05, 1.5}, {11.95, 0.4, 2.2}, Material::kWood, Material::kWood);  // cabinets
  solid_box({11.3, 3.1, 0}, {11.95, 3.8, 1.9}, Material::kMetal, Material::kMetal);  // fridge
  table(8.4, uni(2.2, 2.6), 1.0, 0.8, 0.75, Material::kWood);
  // Study [7,12]x[4.5,9]: desk, shelf, armchair.
  table(10.6, 7.3, 1.3, 1.6, 0.75, Material::kWood);
  solid_box({7.6, 8.5, 0}, {9.4, 8.95, 1.8}, Material::kWood, Material::kWood);
  solid_box({11.0, 5.0, 0}, {11.9, 5.9, 0.8}, Material::kFabric, Material::kFabric);

  if (options.removable_objects) {
    // A chair in the middle of the living room (fabric seat, wooden legs and backrest).
    const glm::dvec2 c(kApartmentChairX, kApartmentChairY);
    const double h = 0.22, seat = 0.45;
    const auto F = std::make_pair(Material::kFabric, Material::kFabric);
    const auto Wd = std::make_pair(Material::kWood, Material::kWood);
    std::vector<std::pair<Box3, std::pair<Material, Material>>> boxes;
    boxes.push_back({{{c.x - h, c.y - h, seat - 0.06}, {c.x + h, c.y + h, seat}}, F});
    for (int i = 0; i < 4; ++i) {
      const double lx = (i & 1) ? c.x + h - 0.045 : c.x - h, ly = (i & 2) ? c.y + h - 0.045 : c.y - h;
      boxes.push_back({{{lx, ly, 0.0}, {lx + 0.045, ly + 0.045, seat - 0.06}}, Wd});
    }
    boxes.push_back({{{c.x - h, c.y - h, seat}, {c.x + h, c.y - h + 0.05, seat + 0.5}}, Wd});
    AddRemovable(&mb, &s, "chair", boxes);
  }

  s.mesh = mb.Take();
  s.bounds = MeshBounds(s.mesh);
  s.navigable = {{0.2, 0.2, 0.3}, {W - 0.2, D - 0.2, H - 0.3}};
  const double e = s.eye_height_m;
  // Living room -> kitchen (door x=7, y 1.5..2.5) -> study (door y=4.5, x 9..10) -> bedroom
  // (door x=7, y 6..7) -> living room (door y=5, x 3..4). Waypoints before/after each door keep
  // the spline perpendicular to the opening.
  s.walk_waypoints = {{3.5, 3.0, e}, {5.2, 2.0, e}, {6.3, 2.0, e}, {7.7, 2.0, e}, {9.5, 2.0, e},
                      {9.5, 3.6, e}, {9.5, 5.4, e}, {9.2, 6.5, e}, {7.8, 6.5, e}, {6.2, 6.5, e},
                      {4.5, 6.8, e}, {3.5, 5.9, e}, {3.5, 4.1, e}, {3.0, 3.0, e}};
  return s;
}

absl::StatusOr<SynthScene> RemoveObjects(const SynthScene& scene,
                                         const std::vector<std::string>& names) {
  for (const std::string& n : names) {
    bool found = false;
    for (const RemovableObject& o : scene.removable) found |= o.name == n;
    if (!found)
      return absl::NotFoundError(
          absl::StrCat("scene '", scene.name, "' has no removable object '", n, "'"));
  }
  std::vector<char> drop(scene.mesh.material.size(), 0);
  SynthScene out = scene;
  out.removable.clear();
  std::vector<Box3> dropped;
  for (const RemovableObject& o : scene.removable) {
    if (!names.empty() && std::find(names.begin(), names.end(), o.name) == names.end()) {
      out.removable.push_back(o);
      continue;
    }
    for (uint32_t t = 0; t < o.num_triangles; ++t) drop[o.first_triangle + t] = 1;
    dropped.push_back(o.bounds);
  }
  out.mesh.indices.clear();
  out.mesh.material.clear();
  std::vector<uint32_t> new_index(drop.size(), 0);
  uint32_t kept = 0;
  for (size_t t = 0; t < drop.size(); ++t) {
    new_index[t] = kept;
    if (drop[t]) continue;
    ++kept;
    for (int k = 0; k < 3; ++k) out.mesh.indices.push_back(scene.mesh.indices[3 * t + k]);
    out.mesh.material.push_back(scene.mesh.material[t]);
  }
  for (RemovableObject& o : out.removable) o.first_triangle = new_index[o.first_triangle];
  std::erase_if(out.solids, [&](const Box3& b) {
    for (const Box3& d : dropped)
      if (b.min == d.min && b.max == d.max) return true;
    return false;
  });
  return out;
}

}  // namespace exo::synth
