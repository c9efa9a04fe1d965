#include "server/inpainting/roi.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "server/inpainting/depth_maps.h"

namespace exo::inpainting {

absl::Status RoiOptions::Validate() const {
  if (!(radius_px > 0.0) || !std::isfinite(radius_px)) {
    return absl::InvalidArgumentError("RoiOptions.radius_px must be > 0");
  }
  if (!(depth_tol_m > 0.0) || !std::isfinite(depth_tol_m)) {
    return absl::InvalidArgumentError("RoiOptions.depth_tol_m must be > 0");
  }
  if (dilate_px < 0 || dilate_px > 256) return absl::InvalidArgumentError("RoiOptions.dilate_px in [0, 256]");
  return absl::OkStatus();
}

absl::StatusOr<ImageU8> RoiFromStroke(std::span<const glm::dvec2> stroke_px, const ImageF& depth_m,
                                      const PinholeCamera& camera, const RoiOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(camera.Validate());
  const int w = depth_m.width(), h = depth_m.height();
  if (depth_m.channels() != 1 || w != camera.width || h != camera.height) {
    return absl::InvalidArgumentError("RoiFromStroke: depth must be 1-channel, size of the camera");
  }
  if (stroke_px.empty()) return absl::InvalidArgumentError("RoiFromStroke: empty stroke");
  auto valid = [](float z) { return std::isfinite(z) && z > 0.f; };
  const ImageF normals = NormalsFromDepth(depth_m, camera);
  ImageU8 roi(w, h, 1, 0);
  const double r = options.radius_px, r2 = r * r;
  bool any_inside = false;
  for (const glm::dvec2& s : stroke_px) {
    if (!std::isfinite(s.x) || !std::isfinite(s.y) || !camera.InImage(s)) continue;
    any_inside = true;
    const int sx = static_cast<int>(std::lround(s.x)), sy = static_cast<int>(std::lround(s.y));
    // V(u_user): the stroke point's depth, or the nearest valid depth within 5 px.
    double zs = depth_m.at(sx, sy);
    if (!valid(static_cast<float>(zs))) {
      zs = 0.0;
      double best = 1e30;
      for (int dy = -5; dy <= 5; ++dy) {
        for (int dx = -5; dx <= 5; ++dx) {
          const int x = sx + dx, y = sy + dy;
          if (!depth_m.Contains(x, y) || !valid(depth_m.at(x, y))) continue;
          if (dx * dx + dy * dy < best) {
            best = dx * dx + dy * dy;
            zs = depth_m.at(x, y);
          }
        }
      }
    }
    const bool have_vs = zs > 0.0;
    const glm::dvec3 vs = camera.Unproject(s, zs);
    const int x0 = std::max(0, static_cast<int>(std::floor(s.x - r))),
              x1 = std::min(w - 1, static_cast<int>(std::ceil(s.x + r)));
    const int y0 = std::max(0, static_cast<int>(std::floor(s.y - r))),
              y1 = std::min(h - 1, static_cast<int>(std::ceil(s.y + r)));
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        const double ddx = x - s.x, ddy = y - s.y;
        if (ddx * ddx + ddy * ddy >= r2) continue;
        uint8_t& m = roi.at(x, y);
        if (m) continue;
        const float z = depth_m.at(x, y);
        const glm::dvec3 n(normals.at(x, y, 0), normals.at(x, y, 1), normals.at(x, y, 2));
        if (!valid(z) || glm::dot(n, n) == 0.0) {
          if (options.include_invalid_depth) m = 255;
          continue;
        }
        if (!have_vs) {  // no depth at the stroke: screen-space disc only
          m = 255;
          continue;
        }
        const glm::dvec3 vu = camera.Unproject({x, y}, z);
        if (std::fabs(glm::dot(vs - vu, n)) < options.depth_tol_m) m = 255;
      }
    }
  }
  if (!any_inside) return absl::InvalidArgumentError("RoiFromStroke: the stroke lies outside the image");
  if (options.dilate_px > 0) {
    cv::Mat m(h, w, CV_8UC1, roi.data());
    const int k = 2 * options.dilate_px + 1;
    cv::dilate(m, m, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(k, k)));
  }
  return roi;
}

}  // namespace exo::inpainting
