#include "server/inpainting/dr_view.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <span>

#include "common/image_fill.h"
#include "common/image_fill_impl.h"
#include "server/inpainting/depth_maps.h"
#include "server/inpainting/poisson.h"

namespace exo::inpainting {

namespace {

// The bounding box of `mask`'s non-zero pixels, [x0, x1) x [y0, y1); empty (x1 = 0) when none.
PixelRect MaskBox(const ImageU8& mask) {
  int bx0 = mask.width(), by0 = mask.height(), bx1 = -1, by1 = -1;
  for (int y = 0; y < mask.height(); ++y) {
    const uint8_t* r = mask.row(y);
    int first = -1, last = -1;
    for (int x = 0; x < mask.width(); ++x)
      if (r[x]) {
        if (first < 0) first = x;
        last = x;
      }
    if (first < 0) continue;
    bx0 = std::min(bx0, first);
    bx1 = std::max(bx1, last);
    by0 = std::min(by0, y);
    by1 = y;
  }
  if (bx1 < 0) return PixelRect{};
  return PixelRect{bx0, by0, bx1 + 1, by1 + 1};
}

}  // namespace

// Background depth of the frame's ROI: the keyframe's depth (observed + inpainted) forward-warped
// into the ROI pixels (each point to its nearest pixel, nearest point wins; a 2x2 splat biases
// the depth by half a pixel, which adds up on a floor seen at a grazing angle), the frame's own
// depth outside the ROI, the gaps push-pull filled (bilinear).
ImageF WarpBackgroundDepth(const DrView& kf, const PinholeCamera& cam, const Rigid3d& pose,
                           const ImageU8& roi, const ImageF& frame_depth) {
  const int w = cam.width, h = cam.height;
  ImageF d(w, h, 1, 0.f);
  for (size_t i = 0; i < d.size(); ++i) d.data()[i] = roi.data()[i] ? 0.f : frame_depth.data()[i];
  const Rigid3d cam_from_kf = pose.Inverse() * kf.world_from_cam;
  const PixelRect box = MaskBox(roi);
  const PixelRect rect = SourcePixelsOnto(kf.depth, kf.cam, cam, cam_from_kf, box);
  // The z-buffer covers only the ROI's box (a splat lands only on ROI pixels).
  const int zw = box.x1 - box.x0;
  std::vector<float> zbuf(static_cast<size_t>(std::max(0, zw)) * std::max(0, box.y1 - box.y0),
                          1e30f);
  for (int y = rect.y0; y < rect.y1; ++y)
    for (int x = rect.x0; x < rect.x1; ++x) {
      const float z = kf.depth.at(x, y);
      if (!(z > 0.f)) continue;
      const glm::dvec3 p = cam_from_kf * kf.cam.Unproject({x, y}, z);
      glm::dvec2 uv;
      if (!cam.Project(p, &uv)) continue;
      const int u = static_cast<int>(RoundHalfAway(uv.x)), v = static_cast<int>(RoundHalfAway(uv.y));
      if (!d.Contains(u, v) || !roi.at(u, v)) continue;
      float& zb = zbuf[static_cast<size_t>(v - box.y0) * zw + (u - box.x0)];
      if (p.z >= zb) continue;
      zb = static_cast<float>(p.z);
      d.at(u, v) = static_cast<float>(p.z);
    }
  // Push-pull (bilinear) of the pixels without depth. With few of them (the usual frame: the
  // splat's gaps in the ROI) the sparse evaluation computes only the pyramid cells they read,
  // bit-identical to the dense pass over the whole frame (image_fill_impl.h), whose full pyramid
  // was most of this function's time.
  std::vector<uint8_t> known(d.size());
  std::vector<size_t> unknown;
  for (size_t i = 0; i < d.size(); ++i) {
    known[i] = d.data()[i] > 0.f;
    if (!known[i]) unknown.push_back(i);
  }
  if (unknown.size() <= d.size() / 16) {
    if (!unknown.empty() && unknown.size() < d.size()) {
      float* dd = d.data();
      const uint8_t* kn = known.data();
      image_fill_internal::PushPullSparseBilinear<1>(
          w, h, 1, [kn](size_t i) { return kn[i] != 0; }, [dd](size_t i, int) { return dd[i]; },
          [dd](size_t i, int, float v) { dd[i] = v; }, unknown);
    }
  } else {
    PushPullFill(std::span<float>(d.data(), d.size()), 1, known, w, h, PullFilter::kBilinear);
  }
  // Two fixed-point steps: each pixel's point is looked up in the keyframe (bilinear depth there)
  // and re-projected, which removes the nearest-pixel staircase of the splat.
  const Rigid3d kf_from_cam = cam_from_kf.Inverse();
  // Each pixel's step reads only its own depth, so the steps update `d` in place; only the ROI's
  // box holds ROI pixels.
  for (int it = 0; it < 2; ++it) {
    ImageF& next = d;
    for (int y = box.y0; y < box.y1; ++y)
      for (int x = box.x0; x < box.x1; ++x) {
        if (!roi.at(x, y) || !(d.at(x, y) > 0.f)) continue;
        glm::dvec2 uv;
        if (!kf.cam.Project(kf_from_cam * cam.Unproject({x, y}, d.at(x, y)), &uv) ||
            !kf.cam.InImage(uv, 1.0))
          continue;
        const int x0 = static_cast<int>(uv.x), y0 = static_cast<int>(uv.y);
        const float z00 = kf.depth.at(x0, y0), z10 = kf.depth.at(x0 + 1, y0),
                    z01 = kf.depth.at(x0, y0 + 1), z11 = kf.depth.at(x0 + 1, y0 + 1);
        if (!(z00 > 0.f && z10 > 0.f && z01 > 0.f && z11 > 0.f)) continue;
        const float zmin = std::min({z00, z10, z01, z11}), zmax = std::max({z00, z10, z01, z11});
        if (zmax - zmin > 0.05f * zmin) continue;  // a depth edge: keep the splat's value
        const double ax = uv.x - x0, ay = uv.y - y0;
        const double z = (1 - ay) * ((1 - ax) * z00 + ax * z10) + ay * ((1 - ax) * z01 + ax * z11);
        const glm::dvec3 q = cam_from_kf * kf.cam.Unproject(uv, z);
        // The re-projected point lands near (x, y); its depth along this pixel's ray, to first
        // order, is its z.
        if (q.z > 0) next.at(x, y) = static_cast<float>(q.z);
      }
  }
  return d;
}

// Colour of `region`'s pixels (frame `cam`/`pose`, background depth `depth`) looked up in the
// views (nearest pose first): the first view that observed the point (visible there: depth
// within 2 % + 1 cm, not inpainted) gives it (bilinear); failing that, the nearest view holding
// an inpainted sample of it. `observed` = 255 where an observation gave the colour, `filled` =
// 255 where anything did.
void LookUpInViews(const std::vector<const DrView*>& views, const PinholeCamera& cam,
                   const Rigid3d& pose, const ImageU8& region, const ImageF& depth, ImageU8* color,
                   ImageU8* observed, ImageU8* filled, bool bicubic) {
  // Catmull-Rom bicubic (sharper than bilinear: a resampled wooden floor keeps its grain),
  // bilinear within a pixel of the border.
  auto bilinear = [bicubic](const DrView& v, const glm::dvec2& uv, int c) {
    const double x = std::clamp(uv.x, 0.0, v.cam.width - 1.001),
                 y = std::clamp(uv.y, 0.0, v.cam.height - 1.001);
    const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
    const double ax = x - x0, ay = y - y0;
    if (bicubic && x0 >= 1 && y0 >= 1 && x0 + 2 < v.cam.width && y0 + 2 < v.cam.height) {
      auto w = [](double t, double* k) {
        const double t2 = t * t, t3 = t2 * t;
        k[0] = 0.5 * (-t3 + 2 * t2 - t);
        k[1] = 0.5 * (3 * t3 - 5 * t2 + 2);
        k[2] = 0.5 * (-3 * t3 + 4 * t2 + t);
        k[3] = 0.5 * (t3 - t2);
      };
      double kx[4], ky[4];
      w(ax, kx);
      w(ay, ky);
      double sum = 0;
      for (int j = 0; j < 4; ++j)
        for (int i = 0; i < 4; ++i) sum += kx[i] * ky[j] * v.color.at(x0 - 1 + i, y0 - 1 + j, c);
      return std::clamp(sum, 0.0, 255.0);
    }
    return (1 - ay) * ((1 - ax) * v.color.at(x0, y0, c) + ax * v.color.at(x0 + 1, y0, c)) +
           ay * ((1 - ax) * v.color.at(x0, y0 + 1, c) + ax * v.color.at(x0 + 1, y0 + 1, c));
  };
  std::fill(observed->data(), observed->data() + observed->size(), uint8_t{0});
  std::fill(filled->data(), filled->data() + filled->size(), uint8_t{0});
  const PixelRect box = MaskBox(region);  // only the region's box is looked at
  for (int y = box.y0; y < box.y1; ++y)
    for (int x = box.x0; x < box.x1; ++x) {
      if (!region.at(x, y) || !(depth.at(x, y) > 0.f)) continue;
      const glm::dvec3 X = pose * cam.Unproject({x, y}, depth.at(x, y));
      const DrView* fallback = nullptr;
      glm::dvec2 fallback_uv;
      const DrView* hit = nullptr;
      glm::dvec2 hit_uv;
      for (const DrView* v : views) {
        const glm::dvec3 q = v->cam_from_world * X;
        glm::dvec2 uv;
        if (!v->cam.Project(q, &uv) || !v->cam.InImage(uv)) continue;
        const int u = std::clamp(static_cast<int>(RoundHalfAway(uv.x)), 0, v->cam.width - 1),
                  w = std::clamp(static_cast<int>(RoundHalfAway(uv.y)), 0, v->cam.height - 1);
        const float z = v->depth.at(u, w);
        if (!(z > 0.f) || std::fabs(z - q.z) > 0.02 * q.z + 0.01) continue;
        if (!v->hallucinated.empty() && v->hallucinated.at(u, w)) {
          if (!fallback) {
            fallback = v;
            fallback_uv = uv;
          }
          continue;
        }
        hit = v;
        hit_uv = uv;
        break;
      }
      if (!hit) {
        hit = fallback;
        hit_uv = fallback_uv;
      } else {
        observed->at(x, y) = 255;
      }
      if (!hit) continue;
      filled->at(x, y) = 255;
      for (int c = 0; c < 3; ++c)
        color->at(x, y, c) = static_cast<uint8_t>(RoundHalfAway(bilinear(*hit, hit_uv, c)));
    }
}

// Gradient-domain blend: inside `roi` the result has the gradients of `guide` (defined on roi
// dilated by one pixel) and meets `frame` at the ROI's border (Dirichlet).
absl::Status PoissonBlendColor(const ImageU8& guide, const ImageU8& roi, ImageU8* frame) {
  if (guide.width() != roi.width() || guide.height() != roi.height() || guide.channels() != 3 ||
      frame->width() != roi.width() || frame->height() != roi.height() || frame->channels() != 3)
    return absl::InvalidArgumentError("PoissonBlendColor: guide, roi and frame sizes differ");
  const int w = roi.width(), h = roi.height();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int c = 0; c < 3; ++c) {
    ImageF values(w, h, 1, nan), gx(w, h, 1, nan), gy(w, h, 1, nan);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        if (!roi.at(x, y)) values.at(x, y) = frame->at(x, y, c);
        if (x + 1 < w && (roi.at(x, y) || roi.at(x + 1, y)))
          gx.at(x, y) = float(guide.at(x, y, c)) - float(guide.at(x + 1, y, c));
        if (y + 1 < h && (roi.at(x, y) || roi.at(x, y + 1)))
          gy.at(x, y) = float(guide.at(x, y, c)) - float(guide.at(x, y + 1, c));
      }
    PoissonProblem pb;
    pb.region = &roi;
    pb.values = &values;
    pb.gx = &gx;
    pb.gy = &gy;
    PoissonOptions po;
    po.tolerance = 1e-6;
    auto r = SolvePoisson(pb, po);
    if (!r.ok()) return r.status();
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        if (roi.at(x, y))
          frame->at(x, y, c) = static_cast<uint8_t>(std::clamp(std::lround(r->at(x, y)), 0L, 255L));
  }
  return absl::OkStatus();
}

}  // namespace exo::inpainting
