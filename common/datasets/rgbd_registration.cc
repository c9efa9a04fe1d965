// Calibration validation, the depth -> colour forward warp and RegisterFrame. The Ceres
// self-calibration is in rgbd_registration_estimate.cc.
#include "common/datasets/rgbd_registration.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_cat.h"

namespace exo {

absl::Status DepthColorCalibration::Validate() const {
  if (auto s = color_camera.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("calibration colour camera: ", s.message()));
  const glm::dquat& q = color_from_depth.rotation;
  if (auto s = ValidateQuaternion(q); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("calibration rotation: ", s.message()));
  const glm::dvec3& t = color_from_depth.translation;
  if (!std::isfinite(t.x) || !std::isfinite(t.y) || !std::isfinite(t.z))
    return absl::InvalidArgumentError("calibration translation has NaN or Inf");
  if (glm::length(t) >= 1.0)
    return absl::InvalidArgumentError(absl::StrCat(
        "calibration translation |t| = ", glm::length(t), " m; expected < 1 m (metres?)"));
  return absl::OkStatus();
}

DepthColorCalibration SevenScenesKinectV1Calibration() {
  DepthColorCalibration c;
  // Values: see the header comment for the command that produced them.
  c.color_camera = PinholeCamera{kSevenScenesColorFx, kSevenScenesColorFy, kSevenScenesColorCx,
                                 kSevenScenesColorCy, 640, 480};
  c.color_from_depth.rotation =
      glm::normalize(glm::dquat(kSevenScenesQw, kSevenScenesQx, kSevenScenesQy, kSevenScenesQz));
  c.color_from_depth.translation = {kSevenScenesTx, kSevenScenesTy, kSevenScenesTz};
  return c;
}

absl::StatusOr<ImageF> RegisterDepthToColor(const ImageF& depth_m,
                                            const PinholeCamera& depth_camera,
                                            const DepthColorCalibration& calib) {
  if (auto s = depth_camera.Validate(); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("depth camera: ", s.message()));
  EXO_RETURN_IF_ERROR(calib.Validate());
  if (depth_m.channels() != 1 || depth_m.width() != depth_camera.width ||
      depth_m.height() != depth_camera.height)
    return absl::InvalidArgumentError(absl::StrCat(
        "depth image is ", depth_m.width(), "x", depth_m.height(), "x", depth_m.channels(),
        ", depth camera is ", depth_camera.width, "x", depth_camera.height, "x1"));
  for (float z : depth_m.span())
    if (!std::isfinite(z) || z < 0.0f)
      return absl::InvalidArgumentError(
          absl::StrCat("depth has a NaN/Inf/negative value (", z, "); 0 marks invalid"));

  const PinholeCamera& cc = calib.color_camera;
  const int W = cc.width, H = cc.height;
  constexpr float kEmpty = std::numeric_limits<float>::infinity();
  ImageF z_buffer(W, H, 1, kEmpty);
  const glm::dmat3 R = calib.color_from_depth.RotationMatrix();
  const glm::dvec3 t = calib.color_from_depth.translation;
  // p_in_color = z * (R * ray(u, v)) + t with ray = (a_u, b_v, 1): R*ray = a_u*R0 + b_v*R1 + R2.
  for (int v = 0; v < depth_m.height(); ++v) {
    const float* row = depth_m.row(v);
    const double b = (v - depth_camera.cy) / depth_camera.fy;
    const glm::dvec3 rb = b * R[1] + R[2];
    for (int u = 0; u < depth_m.width(); ++u) {
      const double z = row[u];
      if (z <= 0.0) continue;
      const double a = (u - depth_camera.cx) / depth_camera.fx;
      const glm::dvec3 p = z * (a * R[0] + rb) + t;
      if (!(p.z > 1e-6)) continue;
      const double inv_z = 1.0 / p.z;
      const double x = cc.fx * p.x * inv_z + cc.cx + 0.5, y = cc.fy * p.y * inv_z + cc.cy + 0.5;
      if (!(x >= 0.0 && y >= 0.0 && x < W && y < H)) continue;  // nearest pixel in the image
      const int xi = static_cast<int>(x), yi = static_cast<int>(y);  // floor (x, y >= 0)
      float& dst = z_buffer.at(xi, yi);
      dst = std::min(dst, static_cast<float>(p.z));
    }
  }
  // 1-px cracks, judged on the z-buffer before filling (so fills never chain into a hole).
  ImageF out(W, H, 1, 0.0f);
  const float tol = static_cast<float>(kCrackRelativeTolerance);
  for (int y = 0; y < H; ++y) {
    const float* zb = z_buffer.row(y);
    float* dst = out.row(y);
    const bool interior_row = y > 0 && y + 1 < H;
    for (int x = 0; x < W; ++x) {
      const float c = zb[x];
      dst[x] = c < kEmpty ? c : 0.0f;
      if (!interior_row || x == 0 || x + 1 == W) continue;
      const float* up = zb - W;
      const float* dn = zb + W;
      // A pair (a, b) of opposite neighbours fills c when both are valid, agree within tol, and
      // c is empty or farther than both by more than tol (see-through). Empty = +inf.
      const float thr = c * (1.0f - tol);  // +inf when c is empty
      const float pairs[4][2] = {{zb[x - 1], zb[x + 1]}, {up[x], dn[x]},
                                 {up[x - 1], dn[x + 1]}, {up[x + 1], dn[x - 1]}};
      float best = kEmpty;
      for (const auto& pr : pairs) {
        const float a = pr[0], b = pr[1];
        if (!(a < thr && b < thr)) continue;  // also rejects empty neighbours (+inf)
        if (std::abs(a - b) > tol * std::min(a, b)) continue;
        best = std::min(best, 0.5f * (a + b));
      }
      if (best < kEmpty) dst[x] = best;
    }
  }
  return out;
}

absl::StatusOr<Frame> RegisterFrame(const Frame& raw, const DepthColorCalibration& calib) {
  EXO_RETURN_IF_ERROR(raw.Validate());
  EXO_RETURN_IF_ERROR(calib.Validate());
  if (raw.color.width() != calib.color_camera.width ||
      raw.color.height() != calib.color_camera.height)
    return absl::InvalidArgumentError(absl::StrCat(
        "colour image is ", raw.color.width(), "x", raw.color.height(),
        ", calibration colour camera is ", calib.color_camera.width, "x",
        calib.color_camera.height));
  const Rigid3d& e = raw.color_from_depth;
  if (RotationAngleRad(e.rotation, glm::dquat(1, 0, 0, 0)) > 1e-12 ||
      glm::length(e.translation) > 1e-12)
    return absl::InvalidArgumentError(
        "RegisterFrame expects a raw frame (color_from_depth = identity, world_from_cam = depth "
        "pose); this frame already carries an extrinsic");
  Frame out;
  out.sequence = raw.sequence;
  out.timestamp_s = raw.timestamp_s;
  out.exposure = raw.exposure;
  out.color_camera = calib.color_camera;
  out.depth_camera = calib.color_camera;
  out.color_from_depth = Rigid3d::Identity();
  // world_from_color = world_from_depth * depth_from_color.
  out.world_from_cam = raw.world_from_cam * calib.color_from_depth.Inverse();
  out.color = raw.color;
  EXO_ASSIGN_OR_RETURN(out.depth_m,
                       RegisterDepthToColor(raw.depth_m, raw.depth_camera, calib));
  EXO_RETURN_IF_ERROR(out.Validate());
  return out;
}

}  // namespace exo
