#include "server/control/occupancy.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_cat.h"
#include "common/cells.h"
#include "common/lumigraph/blend_math.h"  // SrgbToLinear
#include "server/geometry/tsdf_volume.h"

namespace exo::control {

absl::Status OccupancyOptions::Validate() const {
  const glm::dvec3 size = max - min;
  if (!(cell_m > 0) || !std::isfinite(cell_m))
    return absl::InvalidArgumentError("occupancy: cell_m must be > 0");
  if (!(size.x > 0 && size.y > 0 && size.z > 0) || !std::isfinite(size.x + size.y + size.z))
    return absl::InvalidArgumentError(absl::StrCat("occupancy: empty or non-finite bounds (size ",
                                                   size.x, " x ", size.y, " x ", size.z, ")"));
  if (!(drone_radius_m >= 0)) return absl::InvalidArgumentError("occupancy: drone_radius_m < 0");
  const double n =
      std::ceil(size.x / cell_m) * std::ceil(size.y / cell_m) * std::ceil(size.z / cell_m);
  if (n > static_cast<double>(max_cells))
    return absl::InvalidArgumentError(
        absl::StrCat("occupancy: ", n, " cells exceed max_cells ", max_cells, " (raise cell_m)"));
  return absl::OkStatus();
}

absl::StatusOr<OccupancyGrid> OccupancyGrid::Create(const OccupancyOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  return OccupancyGrid(options);
}

OccupancyGrid::OccupancyGrid(const OccupancyOptions& options) : options_(options) {
  const glm::dvec3 size = options.max - options.min;
  dims_ = glm::ivec3(std::max(1, static_cast<int>(std::ceil(size.x / options.cell_m))),
                     std::max(1, static_cast<int>(std::ceil(size.y / options.cell_m))),
                     std::max(1, static_cast<int>(std::ceil(size.z / options.cell_m))));
  cells_.assign(static_cast<size_t>(dims_.x) * dims_.y * dims_.z, 0);
}

glm::ivec3 OccupancyGrid::CellOf(const glm::dvec3& p) const {
  const glm::dvec3 g = (p - options_.min) / options_.cell_m;
  glm::ivec3 c(static_cast<int>(std::floor(g.x)), static_cast<int>(std::floor(g.y)),
               static_cast<int>(std::floor(g.z)));
  // A point on the grid's upper faces belongs to the last cell (zone faces are reachable).
  for (int k = 0; k < 3; ++k)
    if (c[k] == dims_[k] && p[k] <= options_.max[k] + 1e-9) c[k] = dims_[k] - 1;
  return c;
}

glm::dvec3 OccupancyGrid::CentreOf(const glm::ivec3& c) const {
  return options_.min + (glm::dvec3(c) + 0.5) * options_.cell_m;
}

glm::ivec3 OccupancyGrid::CellOfIndex(size_t i) const {
  const int x = static_cast<int>(i % dims_.x);
  const size_t r = i / dims_.x;
  return {x, static_cast<int>(r % dims_.y), static_cast<int>(r / dims_.y)};
}

size_t OccupancyGrid::CountState(Occupancy s) const {
  return static_cast<size_t>(std::count(cells_.begin(), cells_.end(), static_cast<uint8_t>(s)));
}

void OccupancyGrid::MarkSphereFree(const glm::dvec3& p, double radius_m) {
  const glm::ivec3 c = CellOf(p);
  Set(c, Occupancy::kFree);
  const int r = static_cast<int>(std::ceil(radius_m / options_.cell_m));
  for (int dz = -r; dz <= r; ++dz)
    for (int dy = -r; dy <= r; ++dy)
      for (int dx = -r; dx <= r; ++dx) {
        const glm::ivec3 q = c + glm::ivec3(dx, dy, dz);
        if (glm::length(CentreOf(q) - p) <= radius_m) Set(q, Occupancy::kFree);
      }
}

void OccupancyGrid::Set(const glm::ivec3& c, Occupancy s) {
  if (!InGrid(c)) return;
  uint8_t& v = cells_[Index(c)];
  if (v == static_cast<uint8_t>(Occupancy::kOccupied) || v == static_cast<uint8_t>(s)) return;
  if (s == Occupancy::kUnknown) return;  // evidence is never forgotten
  if (v == static_cast<uint8_t>(Occupancy::kUnknown)) ++known_;
  v = static_cast<uint8_t>(s);
  dirty_ = true;
}

void OccupancyGrid::CarveDepth(const ImageF& depth_m, const PinholeCamera& camera,
                               const Rigid3d& frame_from_cam, int stride, double max_range_m,
                               bool no_return_is_free) {
  CarveDepthWhere(depth_m, camera, frame_from_cam, stride, max_range_m,
                  [&](int, int, const glm::dvec3&) { return no_return_is_free; });
}

void OccupancyGrid::CarveDepth(const ImageF& depth_m, const PinholeCamera& camera,
                               const Rigid3d& frame_from_cam, int stride, double max_range_m,
                               const SkyRule& sky) {
  if (depth_m.empty()) return;
  // Per column, the first row with a measurement (the sky lies above it).
  std::vector<int> first_return(depth_m.width(), depth_m.height());
  for (int x = 0; x < depth_m.width(); ++x)
    for (int y = 0; y < depth_m.height(); ++y) {
      const float z = depth_m.at(x, y);
      if (z > 0 && std::isfinite(z)) {
        first_return[x] = y;
        break;
      }
    }
  const glm::dvec3 up = glm::normalize(sky.up);
  const double min_sin = std::sin(sky.min_elevation_rad);
  const bool colour = sky.color && sky.color->width() == depth_m.width() &&
                      sky.color->height() == depth_m.height() && sky.color->channels() >= 3;
  CarveDepthWhere(depth_m, camera, frame_from_cam, stride, max_range_m,
                  [&](int x, int y, const glm::dvec3& dir) {
                    if (y >= first_return[x] || glm::dot(dir, up) < min_sin) return false;
                    if (!colour) return true;
                    const double r = sky.color->at(x, y, 0), g = sky.color->at(x, y, 1),
                                 b = sky.color->at(x, y, 2);
                    return b >= sky.min_blue && b >= r + sky.blue_margin && b >= g;
                  });
}

ImageF OccupancyGrid::SkyColour(const ImageU8& srgb, int width, int height) {
  if (srgb.empty() || srgb.channels() < 3 || width <= 0 || height <= 0) return {};
  ImageF out(width, height, 3);
  for (int y = 0; y < height; ++y) {
    const int sy = std::min(srgb.height() - 1, static_cast<int>((y + 0.5) * srgb.height() / height));
    for (int x = 0; x < width; ++x) {
      const int sx = std::min(srgb.width() - 1, static_cast<int>((x + 0.5) * srgb.width() / width));
      for (int c = 0; c < 3; ++c) out.at(x, y, c) = blend::SrgbToLinear(srgb.at(sx, sy, c) / 255.0f);
    }
  }
  return out;
}

template <typename IsSky>
void OccupancyGrid::CarveDepthWhere(const ImageF& depth_m, const PinholeCamera& camera,
                                    const Rigid3d& frame_from_cam, int stride,
                                    double max_range_m, const IsSky& is_sky) {
  if (depth_m.empty() || camera.width <= 0 || camera.fx <= 0) return;
  stride = std::max(1, stride);
  // The depth image may be a downscaled version of the camera.
  const double sx = static_cast<double>(camera.width) / depth_m.width();
  const double sy = static_cast<double>(camera.height) / depth_m.height();
  const glm::dvec3 eye = frame_from_cam.translation;
  const double step = 0.5 * options_.cell_m;
  for (int y = stride / 2; y < depth_m.height(); y += stride) {
    for (int x = stride / 2; x < depth_m.width(); x += stride) {
      float z = depth_m.at(x, y);
      const bool no_return = !(z > 0) || !std::isfinite(z);
      const glm::dvec2 uv((x + 0.5) * sx - 0.5, (y + 0.5) * sy - 0.5);
      const glm::dvec3 ray = frame_from_cam.rotation * camera.RayZ1(uv);
      const glm::dvec3 dir = glm::normalize(ray);
      if (no_return && !is_sky(x, y, dir)) continue;
      if (no_return) z = std::numeric_limits<float>::infinity();  // free to max_range_m
      const double range = z * glm::length(ray);
      const bool hit = range <= max_range_m;
      const double free_until = std::min(range, max_range_m) - (hit ? step : 0.0);
      for (double t = 0; t < free_until; t += step) Set(CellOf(eye + t * dir), Occupancy::kFree);
      if (hit) Set(CellOf(eye + range * dir), Occupancy::kOccupied);
    }
  }
}

void OccupancyGrid::MarkFromTsdf(const TsdfVolume& volume, const glm::dvec3& offset) {
  const double block_m = volume.block_size_m();
  const double half = 0.5 * options_.cell_m;
  for (uint64_t key : volume.BlockKeys()) {
    const glm::ivec3 b = UnpackCell(key);
    const glm::dvec3 lo = glm::dvec3(b) * block_m + offset;
    const glm::dvec3 hi = lo + block_m;
    const glm::ivec3 c0 = glm::max(CellOf(lo), glm::ivec3(0));
    const glm::ivec3 c1 = glm::min(CellOf(hi), dims_ - 1);
    for (int z = c0.z; z <= c1.z; ++z)
      for (int y = c0.y; y <= c1.y; ++y)
        for (int x = c0.x; x <= c1.x; ++x) {
          const glm::dvec3 p = CentreOf({x, y, z});
          if (p.x < lo.x || p.y < lo.y || p.z < lo.z || p.x >= hi.x || p.y >= hi.y || p.z >= hi.z)
            continue;
          float sdf;
          if (!volume.SdfAt(glm::vec3(p - offset), &sdf)) continue;
          Set({x, y, z}, sdf < half ? Occupancy::kOccupied : Occupancy::kFree);
        }
  }
}

void OccupancyGrid::MarkMeshOccupied(const TriangleMesh& mesh, const glm::dvec3& offset) {
  const double step = 0.5 * options_.cell_m;
  for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
    const glm::dvec3 a = glm::dvec3(mesh.positions[mesh.indices[t]]) + offset;
    const glm::dvec3 b = glm::dvec3(mesh.positions[mesh.indices[t + 1]]) + offset;
    const glm::dvec3 c = glm::dvec3(mesh.positions[mesh.indices[t + 2]]) + offset;
    const double len = std::max({glm::length(b - a), glm::length(c - a), glm::length(c - b)});
    const int n = std::max(1, static_cast<int>(std::ceil(len / step)));
    for (int i = 0; i <= n; ++i)
      for (int j = 0; i + j <= n; ++j) {
        const double u = static_cast<double>(i) / n, v = static_cast<double>(j) / n;
        Set(CellOf(a + u * (b - a) + v * (c - a)), Occupancy::kOccupied);
      }
  }
}

bool OccupancyGrid::IsClear(const glm::ivec3& c) const {
  if (!InGrid(c)) return false;
  return ClearMask()[Index(c)] != 0;
}

const std::vector<uint8_t>& OccupancyGrid::ClearMask() const {
  if (dirty_) Recompute();
  return clear_;
}

void OccupancyGrid::Recompute() const {
  const size_t n = cells_.size();
  // Ball kernel: offsets whose centre distance is within radius + one cell. Half a cell because
  // a surface inside an occupied cell may lie half a cell closer than its centre; the other half
  // because a surface seen only at grazing angles (a door lintel from below) can sit in the
  // neighbouring cell that rays passing under it marked free (measured: the exploration
  // benchmark's drones touched lintels with half a cell).
  const double reach = options_.drone_radius_m + options_.cell_m;
  const int r = static_cast<int>(std::ceil(reach / options_.cell_m));
  std::vector<glm::ivec3> kernel;
  for (int dz = -r; dz <= r; ++dz)
    for (int dy = -r; dy <= r; ++dy)
      for (int dx = -r; dx <= r; ++dx)
        if (glm::length(glm::dvec3(dx, dy, dz)) * options_.cell_m <= reach)
          kernel.push_back({dx, dy, dz});
  std::vector<uint8_t> blocked(n, 0);
  auto bad = [&](uint8_t v) {
    return v == static_cast<uint8_t>(Occupancy::kOccupied) ||
           (options_.inflate_unknown && v == static_cast<uint8_t>(Occupancy::kUnknown));
  };
  static const glm::ivec3 kSix[6] = {{1, 0, 0},  {-1, 0, 0}, {0, 1, 0},
                                     {0, -1, 0}, {0, 0, 1},  {0, 0, -1}};
  for (size_t i = 0; i < n; ++i) {
    if (!bad(cells_[i])) continue;
    blocked[i] = 1;
    const glm::ivec3 c = CellOfIndex(i);
    // Only the boundary of the bad set needs stamping: the dilation of a set by a ball is the
    // set plus the dilation of its boundary.
    bool boundary = false;
    for (const auto& d : kSix) {
      const glm::ivec3 q = c + d;
      if (InGrid(q) && cells_[Index(q)] == static_cast<uint8_t>(Occupancy::kFree)) {
        boundary = true;
        break;
      }
    }
    if (!boundary) continue;
    for (const auto& d : kernel) {
      const glm::ivec3 q = c + d;
      if (InGrid(q)) blocked[Index(q)] = 1;
    }
  }
  clear_.assign(n, 0);
  for (size_t i = 0; i < n; ++i) {
    if (cells_[i] != static_cast<uint8_t>(Occupancy::kFree) || blocked[i]) continue;
    if (options_.inflate_unknown) {
      // Outside the grid is unknown: keep the sphere inside it.
      const glm::ivec3 c = CellOfIndex(i);
      const glm::dvec3 p = CentreOf(c);
      const glm::dvec3 lo = p - options_.min, hi = options_.max - p;
      const double margin = options_.drone_radius_m;
      if (lo.x < margin || lo.y < margin || lo.z < margin || hi.x < margin || hi.y < margin ||
          hi.z < margin)
        continue;
    }
    clear_[i] = 1;
  }
  dirty_ = false;
}

}  // namespace exo::control
