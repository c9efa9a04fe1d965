#include "server/inpainting/inpaint.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <limits>
#include <vector>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "server/inpainting/depth_maps.h"
#include "server/inpainting/layers.h"
#include "server/inpainting/patch_match.h"
#include "server/inpainting/poisson.h"

namespace exo::inpainting {
namespace {

using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}
double CpuMs() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

}  // namespace

FusedGradient FuseGradientSamples(bool has1, float g1, float ref1, bool has2, float g2, float ref2,
                                  const InpaintOptions& options) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  if (!has1 && !has2) return {nan, 1.f};
  if (options.gradient_fusion == GradientFusion::kMean) {
    return {has1 && has2 ? 0.5f * (g1 + g2) : has1 ? g1 : g2, 1.f};
  }
  const float rel = static_cast<float>(options.jump_rel);
  // Jump test relative to the value the sample starts from (scale-invariant, any domain).
  const bool jump1 = has1 && std::fabs(g1) > rel * std::fabs(ref1);
  const bool jump2 = has2 && std::fabs(g2) > rel * std::fabs(ref2);
  float g;
  bool jump;
  if (has1 && has2) {
    if (jump1 != jump2) {
      g = jump1 ? g2 : g1;  // the other sample crossed a discontinuity at its source
      jump = false;
    } else if (std::fabs(g1 - g2) > rel * std::min(std::fabs(ref1), std::fabs(ref2))) {
      const bool first = std::fabs(g1) < std::fabs(g2);  // disagreeing: the smaller one
      g = first ? g1 : g2;
      jump = first ? jump1 : jump2;
    } else {
      g = 0.5f * (g1 + g2);
      jump = jump1 && jump2;
    }
  } else {
    g = has1 ? g1 : g2;
    jump = has1 ? jump1 : jump2;
  }
  return {g, jump ? static_cast<float>(options.jump_weight) : 1.f};
}

float GeometryCost(const float* a, const float* b, int count, float kappa) {
  if (count <= 0) return 1.f;
  float s = 0.f;
  for (int i = 0; i < count; ++i) {
    const float d = a[3 * i] * b[3 * i] + a[3 * i + 1] * b[3 * i + 1] + a[3 * i + 2] * b[3 * i + 2];
    s += 1.f / std::max(kappa, d);  // kappa guard: opposite/zero normals never divide by <= 0
  }
  return s / count;
}

namespace {

// The two borders of the prior's region: Dirichlet = known pixel 4-adjacent to T (also the
// samples of the plane fit), Neumann = T pixel on the frame's edge or next to a pixel that is
// neither in T nor known. Masks are 0 at the border pixels (seeds of the distance transforms).
struct PriorBorders {
  struct Sample {
    double x, y, v;  // x, y in units of 640 px (conditioning), v = known value
  };
  cv::Mat not_dir, not_neu;
  std::vector<Sample> ring;
  bool any_neumann = false;
};

PriorBorders FindPriorBorders(const ImageU8& region, const ImageF& values, int ox, int oy,
                              int frame_w, int frame_h) {
  const int cw = region.width(), ch = region.height();
  PriorBorders b;
  b.not_dir = cv::Mat(ch, cw, CV_8U, cv::Scalar(1));
  b.not_neu = cv::Mat(ch, cw, CV_8U, cv::Scalar(1));
  for (int cy = 0; cy < ch; ++cy) {
    for (int cx = 0; cx < cw; ++cx) {
      const int nx[4] = {cx - 1, cx + 1, cx, cx}, ny[4] = {cy, cy, cy - 1, cy + 1};
      if (region.at(cx, cy)) {
        const int x = ox + cx, y = oy + cy;
        bool neu = x == 0 || y == 0 || x == frame_w - 1 || y == frame_h - 1;
        for (int k = 0; k < 4 && !neu; ++k) {
          if (nx[k] < 0 || ny[k] < 0 || nx[k] >= cw || ny[k] >= ch) continue;
          neu = !region.at(nx[k], ny[k]) && !std::isfinite(values.at(nx[k], ny[k]));
        }
        if (neu) {
          b.not_neu.at<uint8_t>(cy, cx) = 0;
          b.any_neumann = true;
        }
        continue;
      }
      if (!std::isfinite(values.at(cx, cy))) continue;
      bool border = false;
      for (int k = 0; k < 4; ++k)
        border |= nx[k] >= 0 && ny[k] >= 0 && nx[k] < cw && ny[k] < ch && region.at(nx[k], ny[k]);
      if (!border) continue;
      b.not_dir.at<uint8_t>(cy, cx) = 0;
      b.ring.push_back({(ox + cx) / 640.0, (oy + cy) / 640.0, values.at(cx, cy)});
    }
  }
  return b;
}

// Global least-squares plane through the border samples (normal equations averaged per sample)
// and the range of their values; ok = false for a collinear border.
struct GlobalPlane {
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double vlo = std::numeric_limits<double>::infinity(), vhi = -vlo;
  bool ok = false;
};

GlobalPlane FitGlobalPlane(const std::vector<PriorBorders::Sample>& ring) {
  GlobalPlane g;
  for (const PriorBorders::Sample& p : ring) {
    const Eigen::Vector3d a(p.x, p.y, 1.0);
    g.ata += a * a.transpose();
    g.atb += a * p.v;
    g.vlo = std::min(g.vlo, p.v);
    g.vhi = std::max(g.vhi, p.v);
  }
  g.ata /= static_cast<double>(ring.size());
  g.atb /= static_cast<double>(ring.size());
  if (!(std::fabs(g.ata.determinant()) > 1e-14)) return g;  // collinear border: no plane
  g.c = g.ata.ldlt().solve(g.atb);
  g.ok = g.c.allFinite();
  return g;
}

constexpr int kPriorBlock = 8;

// Locally weighted planes: per 8x8 block of the crop holding T pixels, least squares over the
// border samples with Gaussian weights (sigma_px) of their distance to the block centre (cut
// at 3 sigma), plus the global fit's normal equations with the weight of one border sample
// (keeps a collinear local border well-posed). Blocks without T keep the global plane.
std::vector<Eigen::Vector3d> FitBlockPlanes(const ImageU8& region, const PriorBorders& b,
                                            const GlobalPlane& g, int ox, int oy,
                                            double sigma_px) {
  const int cw = region.width(), ch = region.height();
  const int bw = (cw + kPriorBlock - 1) / kPriorBlock, bh = (ch + kPriorBlock - 1) / kPriorBlock;
  std::vector<Eigen::Vector3d> block_plane(static_cast<size_t>(bw) * bh, g.c);
  const double inv2s2 = 1.0 / (2.0 * sigma_px * sigma_px);
  const double cut2 = 9.0 * sigma_px * sigma_px;
  for (int by = 0; by < bh; ++by) {
    for (int bx = 0; bx < bw; ++bx) {
      bool any = false;
      for (int cy = by * kPriorBlock; cy < std::min(ch, (by + 1) * kPriorBlock) && !any; ++cy)
        for (int cx = bx * kPriorBlock; cx < std::min(cw, (bx + 1) * kPriorBlock) && !any; ++cx)
          any = region.at(cx, cy) != 0;
      if (!any) continue;
      const double px = ox + bx * kPriorBlock + 0.5 * kPriorBlock;
      const double py = oy + by * kPriorBlock + 0.5 * kPriorBlock;
      Eigen::Matrix3d ata = g.ata;
      Eigen::Vector3d atb = g.atb;
      for (const PriorBorders::Sample& p : b.ring) {
        const double dx = p.x * 640.0 - px, dy = p.y * 640.0 - py, d2 = dx * dx + dy * dy;
        if (d2 > cut2) continue;
        const double wr = std::exp(-d2 * inv2s2);
        const Eigen::Vector3d a(p.x, p.y, 1.0);
        ata += wr * a * a.transpose();
        atb += wr * a * p.v;
      }
      const Eigen::Vector3d cl = ata.ldlt().solve(atb);
      if (cl.allFinite()) block_plane[static_cast<size_t>(by) * bw + bx] = cl;
    }
  }
  return block_plane;
}

}  // namespace

int BuildSurfacePrior(const ImageU8& region, const ImageF& values, int ox, int oy, int frame_w,
                      int frame_h, const InpaintOptions& o, ImageF* prior, ImageF* prior_weight) {
  if (!(o.neumann_prior_weight > 0.0)) return 0;
  const int cw = region.width(), ch = region.height();
  if (cw == 0 || ch == 0 || values.width() != cw || values.height() != ch) return 0;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const PriorBorders borders = FindPriorBorders(region, values, ox, oy, frame_w, frame_h);
  if (borders.ring.size() < 3) return 0;
  const GlobalPlane global = FitGlobalPlane(borders.ring);
  if (!global.ok) return 0;
  std::vector<Eigen::Vector3d> block_plane;
  if (o.prior_local_px > 0.0)
    block_plane = FitBlockPlanes(region, borders, global, ox, oy, o.prior_local_px);
  const int bw = (cw + kPriorBlock - 1) / kPriorBlock;
  cv::Mat d_dir, d_neu;
  if (borders.any_neumann) {
    cv::distanceTransform(borders.not_dir, d_dir, cv::DIST_L2, cv::DIST_MASK_5);
    cv::distanceTransform(borders.not_neu, d_neu, cv::DIST_L2, cv::DIST_MASK_5);
  }
  *prior = ImageF(cw, ch, 1, nan);
  *prior_weight = ImageF(cw, ch, 1, nan);
  int count = 0;
  for (int cy = 0; cy < ch; ++cy) {
    for (int cx = 0; cx < cw; ++cx) {
      if (!region.at(cx, cy)) continue;
      double wgt = 0.0;
      if (!d_neu.empty()) {
        const double dd = d_dir.at<float>(cy, cx), dn = d_neu.at<float>(cy, cx);
        const double share = dd / std::max(1e-6, dd + dn);  // 0 at the known border, 1 at the free one
        wgt += o.neumann_prior_weight * share * share;
      }
      if (!(wgt > 0.0)) continue;
      const Eigen::Vector3d& c =
          block_plane.empty()
              ? global.c
              : block_plane[static_cast<size_t>(cy / kPriorBlock) * bw + cx / kPriorBlock];
      // Extrapolated beyond the border (regions on the image edge), a plane is clamped to the
      // range of the border values it was fitted to: a tilt never runs off to a surface nearer
      // or farther than anything around T (in inverse depth: never through 0).
      const double v = c[0] * (ox + cx) / 640.0 + c[1] * (oy + cy) / 640.0 + c[2];
      prior->at(cx, cy) = static_cast<float>(std::clamp(v, global.vlo, global.vhi));
      prior_weight->at(cx, cy) = static_cast<float>(wgt);
      ++count;
    }
  }
  if (count == 0) {
    *prior = ImageF();
    *prior_weight = ImageF();
  }
  return count;
}

absl::Status InpaintOptions::Validate() const {
  if (!(w > 0.0 && w <= 1.0)) return absl::InvalidArgumentError("InpaintOptions.w must be in (0, 1]");
  if (!(kappa > 0.0 && kappa <= 1.0)) {
    return absl::InvalidArgumentError("InpaintOptions.kappa must be in (0, 1]");
  }
  if (!(spatial_cap_px2 > 0.0)) return absl::InvalidArgumentError("spatial_cap_px2 must be > 0");
  if (pyramid_levels < 0 || pyramid_levels > 12) {
    return absl::InvalidArgumentError("pyramid_levels must be in [0, 12]");
  }
  if (min_coarse_side < 8) return absl::InvalidArgumentError("min_coarse_side must be >= 8");
  if (coarse_iterations < 1 || fine_iterations < 1 || propagated_iterations < 1) {
    return absl::InvalidArgumentError("iteration counts must be >= 1");
  }
  if (band_rows < 2) return absl::InvalidArgumentError("band_rows must be >= 2");
  if (!(converged_fraction >= 0.0 && converged_fraction < 1.0)) {
    return absl::InvalidArgumentError("converged_fraction must be in [0, 1)");
  }
  if (num_threads < 1 || num_threads > 64) return absl::InvalidArgumentError("num_threads in [1, 64]");
  if (!(max_median_depth_m > 0.0)) return absl::InvalidArgumentError("max_median_depth_m > 0");
  if (!(normal_rel_discontinuity > 0.f)) return absl::InvalidArgumentError("normal_rel_discontinuity > 0");
  if (!(poisson_tolerance > 0.0 && poisson_tolerance < 1.0)) {
    return absl::InvalidArgumentError("poisson_tolerance in (0, 1)");
  }
  if (!(jump_rel > 0.0)) return absl::InvalidArgumentError("jump_rel must be > 0");
  if (!(neumann_prior_weight >= 0.0)) return absl::InvalidArgumentError("neumann_prior_weight >= 0");
  if (!(prior_local_px >= 0.0)) return absl::InvalidArgumentError("prior_local_px must be >= 0");
  if (!(jump_weight > 0.0 && jump_weight <= 1.0)) {
    return absl::InvalidArgumentError("jump_weight must be in (0, 1]");
  }
  if (!(layer_gap_rel > 0.0)) return absl::InvalidArgumentError("layer_gap_rel must be > 0");
  if (!(layer_min_share >= 0.0 && layer_min_share < 1.0)) {
    return absl::InvalidArgumentError("layer_min_share must be in [0, 1)");
  }
  if (max_layers < 1 || max_layers > 3) return absl::InvalidArgumentError("max_layers in [1, 3]");
  if (!(layer_agree_rel >= 0.0)) return absl::InvalidArgumentError("layer_agree_rel must be >= 0");
  if (!(layer_distance_weight >= 0.0) || !(layer_smooth >= 0.0)) {
    return absl::InvalidArgumentError("layer weights must be >= 0");
  }
  if (!(layer_color_sigma > 0.0)) return absl::InvalidArgumentError("layer_color_sigma must be > 0");
  if (layer_label_block < 1 || layer_label_block > 32) {
    return absl::InvalidArgumentError("layer_label_block must be in [1, 32]");
  }
  if (!(layer_jump_factor >= 0.0 && layer_jump_factor <= 1.0)) {
    return absl::InvalidArgumentError("layer_jump_factor must be in [0, 1]");
  }
  return absl::OkStatus();
}


namespace {

// Input checks of InpaintKeyframe; returns the number of T pixels.
absl::StatusOr<int> ValidateInputs(const RgbdKeyframe& frame, const ImageU8& mask,
                                   const InpaintOptions& options, const InpaintResult* previous) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(frame.camera.Validate());
  const int w = frame.color.width(), h = frame.color.height();
  if (frame.color.empty() || frame.color.channels() != 3) {
    return absl::InvalidArgumentError("InpaintKeyframe: colour must be a non-empty RGB8 image");
  }
  if (frame.depth_m.width() != w || frame.depth_m.height() != h || frame.depth_m.channels() != 1) {
    return absl::InvalidArgumentError("InpaintKeyframe: depth must be 1-channel, size of colour");
  }
  if (frame.camera.width != w || frame.camera.height != h) {
    return absl::InvalidArgumentError("InpaintKeyframe: camera size differs from the image size");
  }
  if (mask.width() != w || mask.height() != h || mask.channels() != 1) {
    return absl::InvalidArgumentError("InpaintKeyframe: mask must be 1-channel, size of colour");
  }
  EXO_RETURN_IF_ERROR(CheckDepthUnits(frame.depth_m, options.max_median_depth_m));
  const size_t n = static_cast<size_t>(w) * h;
  int target_count = 0;
  for (size_t i = 0; i < n; ++i) target_count += mask.data()[i] != 0;
  if (target_count == 0) return absl::InvalidArgumentError("InpaintKeyframe: the mask is empty");
  if (target_count == static_cast<int>(n)) {
    return absl::InvalidArgumentError(
        "InpaintKeyframe: the mask covers the whole frame; nothing is left to copy from");
  }
  if (previous) {
    if (previous->source.width() == 0 || previous->mask.width() == 0 ||
        previous->depth_m.width() != previous->camera.width ||
        previous->depth_m.height() != previous->camera.height ||
        previous->mask.width() != previous->depth_m.width() ||
        previous->source.width() != previous->depth_m.width()) {
      return absl::InvalidArgumentError("InpaintKeyframe: previous keyframe result is incomplete");
    }
  }
  return target_count;
}

// Per-pixel masks of the frame.
struct PixelSets {
  std::vector<uint8_t> target;    // T
  std::vector<uint8_t> outside;   // not T
  std::vector<uint8_t> measured;  // outside T with sensor depth
};

PixelSets PixelSetsOf(const RgbdKeyframe& frame, const ImageU8& mask) {
  const size_t n = static_cast<size_t>(frame.color.width()) * frame.color.height();
  PixelSets s;
  s.target.resize(n);
  s.outside.resize(n);
  s.measured.resize(n);
  for (size_t i = 0; i < n; ++i) {
    s.target[i] = mask.data()[i] != 0;
    s.outside[i] = !s.target[i];
    const float z = frame.depth_m.data()[i];
    s.measured[i] = !s.target[i] && std::isfinite(z) && z > 0.f;
  }
  return s;
}

// T's bounding box (inclusive).
struct Box {
  int x0, y0, x1, y1;
};

Box BoundingBox(const std::vector<uint8_t>& target, int w, int h) {
  Box b{w, h, -1, -1};
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (!target[static_cast<size_t>(y) * w + x]) continue;
      b.x0 = std::min(b.x0, x);
      b.x1 = std::max(b.x1, x);
      b.y0 = std::min(b.y0, y);
      b.y1 = y;
    }
  }
  return b;
}

// Level 0 of the search: the frame's colour and normals, T, and where patch data is usable
// (outside T with depth and a normal).
Level BaseLevel(const RgbdKeyframe& frame, const ImageF& depth_m, const ImageF& normals,
                const std::vector<uint8_t>& target) {
  const int w = frame.color.width(), h = frame.color.height();
  const size_t n = static_cast<size_t>(w) * h;
  Level L;
  L.w = w;
  L.h = h;
  L.color.assign(frame.color.data(), frame.color.data() + n * 3);
  L.normal.assign(normals.data(), normals.data() + n * 3);
  L.target = target;
  L.data_ok.assign(n, 0);
  for (size_t i = 0; i < n; ++i) {
    const float* nn = &L.normal[i * 3];
    L.data_ok[i] =
        !target[i] && depth_m.data()[i] > 0.f && (nn[0] != 0.f || nn[1] != 0.f || nn[2] != 0.f);
  }
  FinishLevel(L);
  return L;
}

// Depth (4.13-4.16): the Poisson problem on the mean bidirectional gradients of the copied
// samples, set up on T's bounding box plus one pixel (every pair touching T lies inside it).
// Values are in the depth domain (inverse depth with `inv`); known pixels outside T are
// Dirichlet values (measured or push-pull pre-filled depth).
DepthCrop BuildDepthCrop(const ImageF& depth_m, const Level& L0, const std::vector<uint8_t>& target,
                         const Box& box, bool inv, const InpaintOptions& options) {
  const int w = L0.w, h = L0.h;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  DepthCrop c;
  c.frame_w = w;
  c.frame_h = h;
  c.ox = std::max(0, box.x0 - 1);
  c.oy = std::max(0, box.y0 - 1);
  const int cw = std::min(w - 1, box.x1 + 1) - c.ox + 1, ch = std::min(h - 1, box.y1 + 1) - c.oy + 1;
  // Domain value of a pixel outside T (sources and their 5x5 windows have valid depth).
  auto qv = [&](int x, int y) {
    const float z = depth_m.at(x, y);
    return z > 0.f ? (inv ? 1.f / z : z) : nan;
  };
  c.q = ImageF(cw, ch, 1, nan);
  c.gx = ImageF(cw, ch, 1, nan);
  c.gy = ImageF(cw, ch, 1, nan);
  c.gauge = ImageF(cw, ch, 1, nan);
  c.wx = ImageF(cw, ch, 1, nan);
  c.wy = ImageF(cw, ch, 1, nan);
  c.region = ImageU8(cw, ch, 1, 0);
  for (int cy = 0; cy < ch; ++cy) {
    for (int cx = 0; cx < cw; ++cx) {
      const int x = c.ox + cx, y = c.oy + cy;
      const size_t i = static_cast<size_t>(y) * w + x;
      const bool tp = target[i];
      c.region.at(cx, cy) = tp;
      if (!tp) c.q.at(cx, cy) = qv(x, y);
      if (tp) c.gauge.at(cx, cy) = qv(L0.src[i * 2], L0.src[i * 2 + 1]);
      for (int dir = 0; dir < 2; ++dir) {
        const int dx = dir == 0 ? 1 : 0, dy = dir == 0 ? 0 : 1;
        if (cx + dx >= cw || cy + dy >= ch) continue;
        const size_t j = static_cast<size_t>(y + dy) * w + x + dx;
        const bool tq = target[j];
        if (!tp && !tq) continue;
        // The two copied samples of this pair's gradient and the value they start from.
        float g1 = nan, g2 = nan, ref1 = nan, ref2 = nan;
        if (tp) {  // gradient sampled at u's source: d(f(u)) - d(f(u) + v)
          const int sx = L0.src[i * 2], sy = L0.src[i * 2 + 1];
          ref1 = qv(sx, sy);
          g1 = ref1 - qv(sx + dx, sy + dy);
        }
        if (tq) {  // gradient sampled at (u+v)'s source: d(f(u+v) - v) - d(f(u+v))
          const int sx = L0.src[j * 2], sy = L0.src[j * 2 + 1];
          ref2 = qv(sx, sy);
          g2 = qv(sx - dx, sy - dy) - ref2;
        }
        const FusedGradient fg = FuseGradientSamples(tp, g1, ref1, tq, g2, ref2, options);
        (dir == 0 ? c.gx : c.gy).at(cx, cy) = fg.g;
        if (fg.weight != 1.f) (dir == 0 ? c.wx : c.wy).at(cx, cy) = fg.weight;
      }
    }
  }
  return c;
}

// Writes the solved values of T into depth_m: back to metres, within [1/2, 2] x the range of
// the depths the problem was built from (boundary and copied samples; in inverse depth a
// solution drifting towards 0 would otherwise become an arbitrarily distant surface).
void WriteSolvedDepth(const DepthCrop& c, const ImageF& solved, bool inv, ImageF* depth_m,
                      InpaintStats* stats) {
  const int cw = c.width(), ch = c.height();
  float zlo = std::numeric_limits<float>::infinity(), zhi = 0.f;
  for (int cy = 0; cy < ch; ++cy) {
    for (int cx = 0; cx < cw; ++cx) {
      for (float v : {c.q.at(cx, cy), c.gauge.at(cx, cy)}) {
        if (!std::isfinite(v) || !(v > 0.f)) continue;
        const float z = inv ? 1.f / v : v;
        zlo = std::min(zlo, z);
        zhi = std::max(zhi, z);
      }
    }
  }
  for (int cy = 0; cy < ch; ++cy) {
    for (int cx = 0; cx < cw; ++cx) {
      if (!c.region.at(cx, cy)) continue;
      const float v = solved.at(cx, cy);
      float z = 0.f;
      if (std::isfinite(v) && v > 0.f) z = inv ? 1.f / v : v;
      if (inv && !(v > 0.f) && std::isfinite(v)) z = 2.f * zhi;  // beyond infinity: farthest
      if (z > 0.f && zhi > 0.f) {
        const float zc = std::clamp(z, 0.5f * zlo, 2.f * zhi);
        if (zc != z) ++stats->clamped_depth_pixels;
        z = zc;
      }
      if (!(z > 0.f) || !std::isfinite(z)) {
        z = 0.f;
        ++stats->invalid_depth_pixels;
      }
      depth_m->at(c.ox + cx, c.oy + cy) = z;
    }
  }
}

// Depth of T: the Poisson problem, the layered split (layered_depth) or the single surface's
// prior, the solve, and the solved values written into out->depth_m.
absl::Status SolveDepth(const Level& L0, const PixelSets& px, const Box& box,
                        const InpaintOptions& options, InpaintResult* out) {
  const bool inv = options.depth_domain == DepthDomain::kInverseDepth;
  DepthCrop crop = BuildDepthCrop(out->depth_m, L0, px.target, box, inv, options);
  const int w = L0.w, h = L0.h;
  // Surface prior (screening term): a plane (affine in the depth domain) fitted to the known
  // pixels next to T, weighted per pixel by how weakly the Dirichlet border anchors it (see
  // BuildSurfacePrior); per layer region with the layered solve.
  ImageF prior, prior_w;
  LayerResult layered;
  if (options.layered_depth && inv && options.max_layers > 1)
    layered = SetupLayers(px.measured, out->color, options, &crop);
  out->stats.depth_layers = layered.layers;
  if (layered.layers <= 1) {
    out->stats.prior_pixels =
        BuildSurfacePrior(crop.region, crop.q, crop.ox, crop.oy, w, h, options, &prior, &prior_w);
  } else {
    out->stats.layer_pixels = std::move(layered.layer_pixels);
    out->stats.layer_seed_dist_px = layered.seed_dist_px;
    out->layers = std::move(layered.layer_map);
    prior = std::move(layered.prior);
    prior_w = std::move(layered.prior_weight);
    for (int cy = 0; cy < crop.height(); ++cy)
      for (int cx = 0; cx < crop.width(); ++cx)
        out->stats.prior_pixels += !prior.empty() && std::isfinite(prior_w.at(cx, cy));
  }
  PoissonProblem prob;
  if (!prior.empty()) {
    prob.prior = &prior;
    prob.prior_weight = &prior_w;
  }
  prob.region = &crop.region;
  prob.values = &crop.q;
  prob.gx = &crop.gx;
  prob.gy = &crop.gy;
  prob.gauge = &crop.gauge;
  prob.wx = &crop.wx;
  prob.wy = &crop.wy;
  // No initial guess: the solver's coarse levels give a better one than the previous
  // keyframe's forward-warped depth, whose splatting noise cost more iterations (measured).
  PoissonOptions popt;
  popt.tolerance = options.poisson_tolerance;
  PoissonStats pst;
  EXO_ASSIGN_OR_RETURN(ImageF solved, SolvePoisson(prob, popt, &pst));
  out->stats.poisson_iterations = pst.iterations;
  out->stats.neumann_components = pst.neumann_components;
  WriteSolvedDepth(crop, solved, inv, &out->depth_m, &out->stats);
  return absl::OkStatus();
}

// Normals of the result: unchanged outside T's neighbourhood (the smoothing reaches 2 px, the
// differences 2 px more), recomputed on T's bounding box plus a margin.
void RefreshNormalsAroundTarget(const PinholeCamera& camera, const Box& box,
                                const InpaintOptions& options, InpaintResult* out) {
  const int w = out->depth_m.width(), h = out->depth_m.height();
  const int margin = 8;
  const int x0 = std::max(0, box.x0 - margin), y0 = std::max(0, box.y0 - margin);
  const int x1 = std::min(w - 1, box.x1 + margin), y1 = std::min(h - 1, box.y1 + margin);
  const int nw = x1 - x0 + 1, nh = y1 - y0 + 1;
  ImageF crop(nw, nh, 1);
  for (int y = 0; y < nh; ++y)
    std::copy(out->depth_m.row(y0 + y) + x0, out->depth_m.row(y0 + y) + x0 + nw, crop.row(y));
  PinholeCamera cc = camera;
  cc.cx -= x0;
  cc.cy -= y0;
  cc.width = nw;
  cc.height = nh;
  const ImageF nc =
      NormalsFromDepth(crop, cc, 2, options.normal_rel_discontinuity, options.num_threads);
  const int inner = 4;  // the crop's own border lacks neighbours: keep the full-image values
  for (int y = 0; y < nh; ++y) {
    if ((y0 + y >= inner && y < inner) || (y0 + y < h - inner && y >= nh - inner)) continue;
    for (int x = 0; x < nw; ++x) {
      if ((x0 + x >= inner && x < inner) || (x0 + x < w - inner && x >= nw - inner)) continue;
      for (int k = 0; k < 3; ++k) out->normals.at(x0 + x, y0 + y, k) = nc.at(x, y, k);
    }
  }
}

}  // namespace

absl::StatusOr<InpaintResult> InpaintKeyframe(const RgbdKeyframe& frame, const ImageU8& mask,
                                              const InpaintOptions& options,
                                              const InpaintResult* previous) {
  const auto t_start = Clock::now();
  const double c_start = CpuMs();
  EXO_ASSIGN_OR_RETURN(const int target_count, ValidateInputs(frame, mask, options, previous));
  const int w = frame.color.width(), h = frame.color.height();
  const size_t n = static_cast<size_t>(w) * h;
  const PixelSets px = PixelSetsOf(frame, mask);
  InpaintResult out;
  out.stats.target_pixels = target_count;
  out.camera = frame.camera;
  out.world_from_cam = frame.world_from_cam;
  out.mask = ImageU8(w, h, 1, 0);
  for (size_t i = 0; i < n; ++i) out.mask.data()[i] = px.target[i] ? 255 : 0;

  // Pre-processing: fill sensor holes outside T, normals from the densified depth.
  out.depth_m = frame.depth_m;
  for (size_t i = 0; i < n; ++i) {
    float& z = out.depth_m.data()[i];
    if (!std::isfinite(z) || z < 0.f) z = 0.f;
    if (px.target[i]) z = 0.f;  // T's own depth (the object to remove / a hole) is never used
  }
  out.stats.prefilled_pixels = PrefillDepth(out.depth_m, px.outside, px.outside);
  out.normals = NormalsFromDepth(out.depth_m, frame.camera, 2, options.normal_rel_discontinuity,
                                 options.num_threads);
  std::vector<Level> levels;
  levels.push_back(BaseLevel(frame, out.depth_m, out.normals, px.target));
  out.stats.source_pixels = static_cast<int>(levels[0].src_list.size());
  if (levels[0].src_list.empty()) {
    return absl::FailedPreconditionError(
        "InpaintKeyframe: no valid source patch (a 5x5 window outside the mask with valid depth "
        "and normals); enlarge the visible area or fix the depth");
  }
  const SearchParams params{static_cast<float>(options.w), static_cast<float>(1.0 - options.w),
                            static_cast<float>(options.kappa),
                            static_cast<float>(options.spatial_cap_px2), options.use_geometry,
                            options.peel_measured_normals_only};
  if (previous) out.stats.propagated_pixels = Propagate(*previous, frame, levels[0]);
  out.stats.ms_prepare = MsSince(t_start);
  const double c_search = CpuMs();
  out.stats.cpu_ms_prepare = c_search - c_start;

  // Source map (PatchMatch): from the propagated map when it covers at least half of T.
  const auto t_search = Clock::now();
  if (out.stats.propagated_pixels > 0 && out.stats.propagated_pixels * 2 >= target_count) {
    SearchFromPropagated(levels[0], params, options);
    out.stats.levels = 1;
  } else {
    out.stats.levels = SearchPyramid(&levels, params, options, &out.stats.sweeps);
  }
  out.stats.ms_search = MsSince(t_search);
  out.stats.cpu_ms_search = CpuMs() - c_search;

  // Copy colour (4.11) and the source map.
  const auto t_copy = Clock::now();
  const Level& L0 = levels[0];
  out.color = ImageU8(w, h, 3);
  std::copy(L0.color.begin(), L0.color.end(), out.color.data());
  out.source = ImageI32(w, h, 2, -1);
  for (size_t i = 0; i < n; ++i) {
    if (!px.target[i]) continue;
    out.source.data()[i * 2] = L0.src[i * 2];
    out.source.data()[i * 2 + 1] = L0.src[i * 2 + 1];
  }
  out.stats.ms_copy = MsSince(t_copy);

  // Depth (4.13-4.16).
  const auto t_poisson = Clock::now();
  const double c_poisson = CpuMs();
  const Box box = BoundingBox(px.target, w, h);
  EXO_RETURN_IF_ERROR(SolveDepth(L0, px, box, options, &out));
  out.stats.ms_poisson = MsSince(t_poisson);
  out.stats.cpu_ms_poisson = CpuMs() - c_poisson;
  RefreshNormalsAroundTarget(frame.camera, box, options, &out);
  out.stats.ms_total = MsSince(t_start);
  out.stats.cpu_ms_total = CpuMs() - c_start;
  return out;
}

}  // namespace exo::inpainting
