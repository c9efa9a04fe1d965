#include "server/inpainting/depth_maps.h"

#include "server/inpainting/parallel_rows.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <thread>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

namespace exo::inpaint {

bool PushPullFill(std::vector<float>& data, int channels, const std::vector<uint8_t>& known,
                  int width, int height) {
  // Level 0 holds the premultiplied sums and weights.
  struct Level {
    int w, h;
    std::vector<float> sum;  // channels per pixel, weighted
    std::vector<float> wt;
  };
  std::vector<Level> levels;
  Level l0{width, height, std::vector<float>(static_cast<size_t>(width) * height * channels),
           std::vector<float>(static_cast<size_t>(width) * height)};
  bool any = false;
  for (size_t i = 0; i < l0.wt.size(); ++i) {
    if (!known[i]) continue;
    any = true;
    l0.wt[i] = 1.f;
    for (int c = 0; c < channels; ++c) l0.sum[i * channels + c] = data[i * channels + c];
  }
  if (!any) return false;
  levels.push_back(std::move(l0));
  // Push: 2x2 sums down to 1x1.
  while (levels.back().w > 1 || levels.back().h > 1) {
    const Level& f = levels.back();
    Level c{(f.w + 1) / 2, (f.h + 1) / 2, {}, {}};
    c.sum.assign(static_cast<size_t>(c.w) * c.h * channels, 0.f);
    c.wt.assign(static_cast<size_t>(c.w) * c.h, 0.f);
    for (int y = 0; y < f.h; ++y) {
      for (int x = 0; x < f.w; ++x) {
        const size_t fi = static_cast<size_t>(y) * f.w + x;
        const size_t ci = static_cast<size_t>(y / 2) * c.w + x / 2;
        c.wt[ci] += f.wt[fi];
        for (int k = 0; k < channels; ++k) c.sum[ci * channels + k] += f.sum[fi * channels + k];
      }
    }
    // Normalise to averages with weight min(1, w) so that sparse data does not dominate.
    for (size_t i = 0; i < c.wt.size(); ++i) {
      if (c.wt[i] > 0.f) {
        const float s = std::min(1.f, c.wt[i]) / c.wt[i];
        for (int k = 0; k < channels; ++k) c.sum[i * channels + k] *= s;
        c.wt[i] = std::min(1.f, c.wt[i]);
      }
    }
    levels.push_back(std::move(c));
  }
  // Pull: every level holds premultiplied values (sum = average * alpha, wt = alpha <= 1);
  // the unknown part (1 - alpha) comes from the coarser level, already complete.
  {
    Level& top = levels.back();
    for (size_t i = 0; i < top.wt.size(); ++i) {
      if (top.wt[i] > 0.f) {
        for (int k = 0; k < channels; ++k) top.sum[i * channels + k] /= top.wt[i];
      }
      top.wt[i] = 1.f;
    }
  }
  for (int li = static_cast<int>(levels.size()) - 2; li >= 0; --li) {
    Level& f = levels[li];
    const Level& c = levels[li + 1];
    for (int y = 0; y < f.h; ++y) {
      for (int x = 0; x < f.w; ++x) {
        const size_t fi = static_cast<size_t>(y) * f.w + x;
        const size_t ci = static_cast<size_t>(y / 2) * c.w + x / 2;
        const float rest = 1.f - std::min(1.f, f.wt[fi]);
        for (int k = 0; k < channels; ++k) {
          f.sum[fi * channels + k] += rest * c.sum[ci * channels + k];
        }
        f.wt[fi] = 1.f;
      }
    }
  }
  const Level& top = levels[0];
  for (size_t i = 0; i < top.wt.size(); ++i) {
    if (known[i]) continue;
    for (int k = 0; k < channels; ++k) data[i * channels + k] = top.sum[i * channels + k];
  }
  return true;
}

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

int FrontFillFarHoles(ImageF& depth_m, const std::vector<uint8_t>& filled,
                      const std::vector<uint8_t>& measured, const std::vector<float>& dist_px,
                      float far_px, float radius_factor) {
  const int w = depth_m.width(), h = depth_m.height();
  const float inf = std::numeric_limits<float>::infinity();
  // Min-pyramid of measured depth: level k holds the minimum over blocks of 2^k x 2^k.
  struct Lv {
    int w, h;
    std::vector<float> v;
  };
  std::vector<Lv> pyr;
  pyr.push_back({w, h, std::vector<float>(static_cast<size_t>(w) * h, inf)});
  for (size_t i = 0; i < pyr[0].v.size(); ++i)
    if (measured[i] && depth_m.data()[i] > 0.f) pyr[0].v[i] = depth_m.data()[i];
  while (pyr.back().w > 1 || pyr.back().h > 1) {
    const Lv& f = pyr.back();
    Lv c{(f.w + 1) / 2, (f.h + 1) / 2, {}};
    c.v.assign(static_cast<size_t>(c.w) * c.h, inf);
    for (int y = 0; y < f.h; ++y)
      for (int x = 0; x < f.w; ++x) {
        float& m = c.v[static_cast<size_t>(y / 2) * c.w + x / 2];
        m = std::min(m, f.v[static_cast<size_t>(y) * f.w + x]);
      }
    pyr.push_back(std::move(c));
  }
  int changed = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      if (!filled[i] || !(dist_px[i] > far_px)) continue;
      const float r = radius_factor * dist_px[i];
      int k = 0;
      while (k + 1 < static_cast<int>(pyr.size()) && static_cast<float>(2 << k) <= r) ++k;
      const Lv& L = pyr[k];
      const int s = 1 << k;
      const int x0 = std::max(0, static_cast<int>(std::floor((x - r) / s)));
      const int x1 = std::min(L.w - 1, static_cast<int>(std::floor((x + r) / s)));
      const int y0 = std::max(0, static_cast<int>(std::floor((y - r) / s)));
      const int y1 = std::min(L.h - 1, static_cast<int>(std::floor((y + r) / s)));
      float m = inf;
      for (int by = y0; by <= y1; ++by)
        for (int bx = x0; bx <= x1; ++bx) m = std::min(m, L.v[static_cast<size_t>(by) * L.w + bx]);
      float& z = depth_m.data()[i];
      if (m < inf && (!(z > 0.f) || m < z)) {
        z = m;
        ++changed;
      }
    }
  }
  return changed;
}
int PlaneFillFarHoles(ImageF& depth_m, const std::vector<uint8_t>& filled,
                      const std::vector<uint8_t>& measured, float far_px, int window_px) {
  const int w = depth_m.width(), h = depth_m.height();
  const size_t n = static_cast<size_t>(w) * h;
  cv::Mat not_measured(h, w, CV_8U), dist, labels;
  for (size_t i = 0; i < n; ++i) not_measured.data[i] = measured[i] && depth_m.data()[i] > 0.f ? 0 : 1;
  cv::distanceTransform(not_measured, dist, labels, cv::DIST_L2, cv::DIST_MASK_5, cv::DIST_LABEL_PIXEL);
  // Label -> pixel of the measured seed.
  std::vector<int> seed_of_label;
  for (size_t i = 0; i < n; ++i) {
    if (not_measured.data[i]) continue;
    const int lab = labels.ptr<int>(0)[i];
    if (lab >= static_cast<int>(seed_of_label.size())) seed_of_label.resize(lab + 1, -1);
    seed_of_label[lab] = static_cast<int>(i);
  }
  // Per seed: plane of inverse depth over the same-surface measured pixels in its window.
  std::vector<Eigen::Vector3f> plane(seed_of_label.size());
  std::vector<uint8_t> done(seed_of_label.size(), 0);
  int changed = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      if (!filled[i] || !(dist.at<float>(y, x) > far_px)) continue;
      const int lab = labels.at<int>(y, x);
      if (lab < 0 || lab >= static_cast<int>(seed_of_label.size()) || seed_of_label[lab] < 0) continue;
      const int si = seed_of_label[lab], sx = si % w, sy = si / w;
      const float zs = depth_m.data()[si];
      if (!done[lab]) {
        done[lab] = 1;
        Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
        Eigen::Vector3d atb = Eigen::Vector3d::Zero();
        for (int yy = std::max(0, sy - window_px); yy <= std::min(h - 1, sy + window_px); ++yy)
          for (int xx = std::max(0, sx - window_px); xx <= std::min(w - 1, sx + window_px); ++xx) {
            const size_t j = static_cast<size_t>(yy) * w + xx;
            const float z = depth_m.data()[j];
            if (not_measured.data[j] || std::fabs(z - zs) > 0.05f * zs) continue;
            const Eigen::Vector3d a((xx - sx) / 16.0, (yy - sy) / 16.0, 1.0);
            ata += a * a.transpose();
            atb += a * (1.0 / z);
          }
        ata += 1e-3 * Eigen::Matrix3d::Identity() * ata(2, 2);  // collinear support: flat
        const Eigen::Vector3d c = ata.ldlt().solve(atb);
        plane[lab] = c.allFinite() ? c.cast<float>() : Eigen::Vector3f(0.f, 0.f, 1.f / zs);
      }
      const Eigen::Vector3f& c = plane[lab];
      const float v = c[0] * (x - sx) / 16.f + c[1] * (y - sy) / 16.f + c[2];
      const float z = v > 0.f ? std::clamp(1.f / v, zs / 1.5f, zs * 1.5f) : zs * 1.5f;
      depth_m.data()[i] = z;
      ++changed;
    }
  }
  return changed;
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

}  // namespace exo::inpaint
