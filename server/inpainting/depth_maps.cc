#include "server/inpainting/depth_maps.h"

#include "server/inpainting/parallel_rows.h"

#include <algorithm>
#include <cmath>
#include <thread>

namespace exo::inpainting {

int PrefillDepth(ImageF& depth_m, const std::vector<uint8_t>& fill_here,
                 const std::vector<uint8_t>& use_as_data) {
  const int w = depth_m.width(), h = depth_m.height();
  const size_t n = static_cast<size_t>(w) * h;
  std::vector<float> data(n, 0.f);
  std::vector<uint8_t> known(n, 0);
  bool need = false;
  for (size_t i = 0; i < n; ++i) {
    const float z = depth_m.data()[i];
    const bool valid = std::isfinite(z) && z > 0.f;
    if (valid && use_as_data[i]) {
      known[i] = 1;
      data[i] = z;
    }
    if (!valid && fill_here[i]) need = true;
  }
  if (!need) return 0;
  if (!PushPullFill(data, 1, known, w, h)) return 0;
  int filled = 0;
  for (size_t i = 0; i < n; ++i) {
    float& z = depth_m.data()[i];
    if (fill_here[i] && !(std::isfinite(z) && z > 0.f) && data[i] > 0.f) {
      z = data[i];
      ++filled;
    }
  }
  return filled;
}


ImageF NormalsFromDepth(const ImageF& depth_m, const PinholeCamera& camera, int step,
                        float rel_discontinuity, int num_threads) {
  const int w = depth_m.width(), h = depth_m.height();
  auto valid = [](float z) { return std::isfinite(z) && z > 0.f; };
  // 5x5 smoothing that only averages neighbours on the same surface (relative test). The depth
  // is sanitised first (invalid -> 0), so the relative test alone rejects invalid neighbours
  // (|0 - zc| > tol for tol < zc) and the interior loop runs without branches.
  const float rel = std::min(rel_discontinuity, 0.999f);
  ImageF clean(w, h, 1, 0.f);
  for (size_t i = 0; i < depth_m.size(); ++i) {
    const float z = depth_m.data()[i];
    clean.data()[i] = valid(z) ? z : 0.f;
  }
  ImageF smooth(w, h, 1, 0.f);
  ParallelRows(h, num_threads, [&](int y) {
    const int y0 = std::max(0, y - 2), y1 = std::min(h - 1, y + 2);
    const float* crow = clean.row(y);
    float* srow = smooth.row(y);
    for (int x = 0; x < w; ++x) {
      const float zc = crow[x];
      if (!(zc > 0.f)) continue;
      const float tol = rel * zc;
      const int x0 = std::max(0, x - 2), x1 = std::min(w - 1, x + 2);
      float s = 0.f, cnt = 0.f;
      for (int yy = y0; yy <= y1; ++yy) {
        const float* row = clean.row(yy);
        for (int xx = x0; xx <= x1; ++xx) {
          const float z = row[xx];
          const float in = std::fabs(z - zc) <= tol ? 1.f : 0.f;
          s += in * z;
          cnt += in;
        }
      }
      srow[x] = s / cnt;
    }
  });
  ImageF normals(w, h, 3, 0.f);
  const double ifx = 1.0 / camera.fx, ify = 1.0 / camera.fy;
  auto point = [&](int x, int y) {
    const double z = smooth.at(x, y);
    return glm::dvec3((x - camera.cx) * ifx * z, (y - camera.cy) * ify * z, z);
  };
  auto usable = [&](int x, int y, float zc) {
    if (x < 0 || y < 0 || x >= w || y >= h) return false;
    const float z = smooth.at(x, y);
    return valid(z) && std::fabs(z - zc) <= rel_discontinuity * zc * step;
  };
  ParallelRows(h, num_threads, [&](int y) {
    for (int x = 0; x < w; ++x) {
      const float zc = smooth.at(x, y);
      if (!valid(zc)) continue;
      const glm::dvec3 pc = point(x, y);
      glm::dvec3 dx(0.0), dy(0.0);
      const bool xp = usable(x + step, y, zc), xm = usable(x - step, y, zc);
      const bool yp = usable(x, y + step, zc), ym = usable(x, y - step, zc);
      if (xp && xm) dx = point(x + step, y) - point(x - step, y);
      else if (xp) dx = point(x + step, y) - pc;
      else if (xm) dx = pc - point(x - step, y);
      else continue;
      if (yp && ym) dy = point(x, y + step) - point(x, y - step);
      else if (yp) dy = point(x, y + step) - pc;
      else if (ym) dy = pc - point(x, y - step);
      else continue;
      glm::dvec3 n = glm::cross(dy, dx);
      const double len = glm::length(n);
      if (!(len > 0.0) || !std::isfinite(len)) continue;
      n /= len;
      if (glm::dot(n, pc) > 0.0) n = -n;  // face the camera
      normals.at(x, y, 0) = static_cast<float>(n.x);
      normals.at(x, y, 1) = static_cast<float>(n.y);
      normals.at(x, y, 2) = static_cast<float>(n.z);
    }
  });
  return normals;
}

absl::Status CheckDepthUnits(const ImageF& depth_m, double max_median_depth_m) {
  std::vector<float> v;
  v.reserve(depth_m.size());
  for (float z : depth_m.span()) {
    if (z < 0.f) return absl::InvalidArgumentError("depth has negative values; 0 marks invalid");
    if (std::isfinite(z) && z > 0.f) v.push_back(z);
  }
  if (v.empty()) return absl::OkStatus();
  auto mid = v.begin() + v.size() / 2;
  std::nth_element(v.begin(), mid, v.end());
  if (*mid > max_median_depth_m) {
    return absl::InvalidArgumentError(absl::StrCat(
        "median depth is ", *mid, " but depth must be in metres (limit ", max_median_depth_m,
        " m); is it in millimetres? divide by the sensor's depth scale first"));
  }
  return absl::OkStatus();
}

}  // namespace exo::inpainting
