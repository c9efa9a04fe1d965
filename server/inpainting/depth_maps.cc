#include "server/inpainting/depth_maps.h"

#include "server/inpainting/parallel_rows.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
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


namespace {

// Four float lanes (SSE2 on x86-64; GCC/Clang vector extensions, elementwise IEEE operations).
typedef float V4 __attribute__((vector_size(16)));
typedef int32_t V4i __attribute__((vector_size(16)));
inline V4 LoadV4(const float* p) {
  V4 v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}
inline V4 AbsV4(V4 v) {  // std::fabs per lane: the sign bit cleared
  V4i i;
  std::memcpy(&i, &v, sizeof(i));
  i &= V4i{0x7fffffff, 0x7fffffff, 0x7fffffff, 0x7fffffff};
  std::memcpy(&v, &i, sizeof(v));
  return v;
}
inline V4 Select(V4i mask, V4 v) {  // v where mask (-1), else +0
  V4i i;
  std::memcpy(&i, &v, sizeof(i));
  i &= mask;
  std::memcpy(&v, &i, sizeof(v));
  return v;
}
inline V4 OneWhere(V4i mask) { return Select(mask, V4{1.f, 1.f, 1.f, 1.f}); }

}  // namespace

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
    auto scalar = [&](int x) {
      const float zc = crow[x];
      if (!(zc > 0.f)) return;
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
    };
    // Interior columns four at a time (SSE2 lanes, GCC/Clang vector extensions): every lane runs
    // the scalar loop's operations in its order (IEEE, no contraction), so the result is the
    // same bit for bit; a lane whose centre has no depth keeps 0 (its sum is 0 / cnt >= 1).
    int x = 0;
    for (; x < std::min(w, 2); ++x) scalar(x);
    for (; x + 4 <= w - 2; x += 4) {
      const V4 zc = LoadV4(crow + x);
      const V4 tol = V4{rel, rel, rel, rel} * zc;
      V4 s = {0.f, 0.f, 0.f, 0.f}, cnt = s;
      for (int yy = y0; yy <= y1; ++yy) {
        const float* row = clean.row(yy) + x;
        for (int dx = -2; dx <= 2; ++dx) {
          const V4 z = LoadV4(row + dx);
          const V4 in = OneWhere(AbsV4(z - zc) <= tol);
          s += in * z;
          cnt += in;
        }
      }
      const V4 out = Select(zc > V4{0.f, 0.f, 0.f, 0.f}, s / cnt);
      std::memcpy(srow + x, &out, sizeof(out));
    }
    for (; x < w; ++x) scalar(x);
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
  // The median v[n/2] of the n valid depths (sorted) exceeds the limit exactly when at least
  // n - n/2 of them do: one counting pass instead of copying and partially sorting the frame
  // (nth_element over 300k values was ~3 ms of every keyframe); the median itself is computed
  // only for the error message.
  size_t n = 0, above = 0;
  for (float z : depth_m.span()) {
    if (z < 0.f) return absl::InvalidArgumentError("depth has negative values; 0 marks invalid");
    if (std::isfinite(z) && z > 0.f) {
      ++n;
      above += static_cast<double>(z) > max_median_depth_m;
    }
  }
  if (n == 0 || above < n - n / 2) return absl::OkStatus();
  std::vector<float> v;
  v.reserve(n);
  for (float z : depth_m.span())
    if (std::isfinite(z) && z > 0.f) v.push_back(z);
  auto mid = v.begin() + v.size() / 2;
  std::nth_element(v.begin(), mid, v.end());
  return absl::InvalidArgumentError(absl::StrCat(
      "median depth is ", *mid, " but depth must be in metres (limit ", max_median_depth_m,
      " m); is it in millimetres? divide by the sensor's depth scale first"));
}

PixelRect SourcePixelsOnto(const ImageF& src_depth, const PinholeCamera& src_cam,
                           const PinholeCamera& cam, const Rigid3d& cam_from_kf,
                           const PixelRect& box) {
  const PixelRect whole{0, 0, src_cam.width, src_cam.height};
  if (box.x1 <= box.x0) return PixelRect{};
  const int bx0 = box.x0, by0 = box.y0, bx1 = box.x1 - 1, by1 = box.y1 - 1;
  float zmin = std::numeric_limits<float>::max(), zmax = 0.f;
  for (size_t i = 0; i < src_depth.size(); ++i) {
    const float z = src_depth.data()[i];
    if (z > 0.f && std::isfinite(z)) {
      zmin = std::min(zmin, z);
      zmax = std::max(zmax, z);
    }
  }
  if (!(zmax > 0.f)) return PixelRect{};
  const Rigid3d kf_from_cam = cam_from_kf.Inverse();
  const glm::dvec3 c = kf_from_cam * glm::dvec3(0.0);  // the destination's centre, source coords
  double u0 = 1e30, v0 = 1e30, u1 = -1e30, v1 = -1e30;
  for (int k = 0; k < 4; ++k) {
    const glm::dvec2 px(k & 1 ? bx1 + 1.5 : bx0 - 1.5, k & 2 ? by1 + 1.5 : by0 - 1.5);
    const glm::dvec3 d = kf_from_cam * cam.Unproject(px, 1.0) - c;
    if (std::abs(d.z) < 1e-9) return whole;
    double ta = (zmin - c.z) / d.z, tb = (zmax - c.z) / d.z;
    if (ta > tb) std::swap(ta, tb);
    ta = std::max(ta, 0.0);
    // A ray that never meets the depth range: the frustum holds a direction parallel to the
    // range's planes, so the cut body is unbounded (its projection is not bounded by the rays').
    if (tb <= ta) return whole;
    for (double t : {ta, tb}) {
      glm::dvec2 uv;
      if (!src_cam.Project(c + t * d, &uv)) return whole;
      u0 = std::min(u0, uv.x);
      v0 = std::min(v0, uv.y);
      u1 = std::max(u1, uv.x);
      v1 = std::max(v1, uv.y);
    }
  }
  if (!(std::isfinite(u0) && std::isfinite(v0) && std::isfinite(u1) && std::isfinite(v1)))
    return whole;
  PixelRect r;
  r.x0 = static_cast<int>(std::clamp(std::floor(u0) - 2.0, 0.0, double(src_cam.width)));
  r.y0 = static_cast<int>(std::clamp(std::floor(v0) - 2.0, 0.0, double(src_cam.height)));
  r.x1 = static_cast<int>(std::clamp(std::ceil(u1) + 3.0, 0.0, double(src_cam.width)));
  r.y1 = static_cast<int>(std::clamp(std::ceil(v1) + 3.0, 0.0, double(src_cam.height)));
  return r;
}


}  // namespace exo::inpainting
