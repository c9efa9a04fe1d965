#include "client/navigation/scene_overlay.h"

#include <algorithm>
#include <cmath>

#include "common/drone/drone_types.h"

namespace exo::nav {

uint32_t CoverageColor(int tau_percent, int alpha) {
  const double f = std::clamp(tau_percent, 0, 100) / 100.0;
  // Red -> yellow over the first half, yellow -> green over the second.
  const int r = f < 0.5 ? 255 : int(std::lround(255 * (1 - f) * 2));
  const int g = f < 0.5 ? int(std::lround(255 * f * 2)) : 255;
  return Rgba(r, g, 40, alpha);
}

uint32_t RefCountColor(size_t refs, size_t max_refs, int alpha) {
  const double f = std::clamp(double(refs) / double(std::max<size_t>(1, max_refs)), 0.0, 1.0);
  return Rgba(int(255 * (1 - f)), int(255 * f), 40, alpha);
}

const char* OverlayKindName(OverlayKind k) {
  switch (k) {
    case OverlayKind::kDrone: return "drone";
    case OverlayKind::kFrustum: return "frustum";
    case OverlayKind::kTarget: return "target";
    case OverlayKind::kRoute: return "route";
    case OverlayKind::kZone: return "zone";
  }
  return "?";
}

glm::dmat3 DroneCameraAxes(const glm::dvec3& up_in, double yaw, double pitch) {
  auto frame = control::SceneFrame::FromUp(up_in);
  const control::SceneFrame f = frame.ok() ? *frame : control::SceneFrame::ZUp();
  const glm::dvec3 heading = f.Heading(yaw);
  const glm::dvec3 forward = std::cos(pitch) * heading + std::sin(pitch) * f.up;
  const glm::dvec3 right = glm::normalize(glm::cross(heading, f.up));
  const glm::dvec3 down = glm::cross(forward, right);
  return glm::dmat3(right, down, forward);
}

namespace {

// Colours (RGBA): the drone orange, its frustum red-orange, the target magenta, the route
// yellow (flown part dim), zones translucent green.
constexpr uint32_t kDroneColor = Rgba(255, 140, 0);
constexpr uint32_t kFrustumColor = Rgba(255, 80, 40);
constexpr uint32_t kTargetColor = Rgba(255, 40, 255);
constexpr uint32_t kRouteColor = Rgba(255, 255, 0);
constexpr uint32_t kRouteFlownColor = Rgba(160, 160, 60, 140);
constexpr uint32_t kZoneColor = Rgba(60, 255, 120, 150);

}  // namespace

std::vector<OverlayLine> DroneOverlayLines(const ControlView& c, const LocalOrigin& origin,
                                           const DroneOverlayOptions& o) {
  std::vector<OverlayLine> out;
  auto frame = control::SceneFrame::FromUp(c.up);
  const control::SceneFrame f = frame.ok() ? *frame : control::SceneFrame::ZUp();
  auto local = [&](const glm::dvec3& w) { return w - origin.origin_in_world; };
  auto add = [&](const glm::dvec3& a, const glm::dvec3& b, uint32_t col, float w, OverlayKind k) {
    out.push_back({a, b, col, w, k});
  };
  // Zones: a box's 12 edges, or a prism's polygon at floor and ceiling and its vertical edges.
  for (const ZoneView& z : c.zones) {
    if (z.prism_axis >= 0 && z.prism_axis <= 2 && z.polygon.size() >= 3) {
      const int v = z.prism_axis, a = (v + 1) % 3, b = (v + 2) % 3;
      auto corner = [&](const glm::dvec2& uv, double h) {
        glm::dvec3 p(0.0);
        p[a] = uv.x;
        p[b] = uv.y;
        p[v] = h;
        return local(p);
      };
      for (size_t i = 0; i < z.polygon.size(); ++i) {
        const glm::dvec2& p = z.polygon[i];
        const glm::dvec2& q = z.polygon[(i + 1) % z.polygon.size()];
        add(corner(p, z.min[v]), corner(q, z.min[v]), kZoneColor, 1.5f, OverlayKind::kZone);
        add(corner(p, z.max[v]), corner(q, z.max[v]), kZoneColor, 1.5f, OverlayKind::kZone);
        add(corner(p, z.min[v]), corner(p, z.max[v]), kZoneColor, 1.5f, OverlayKind::kZone);
      }
    } else {
      const glm::dvec3 lo = local(z.min), hi = local(z.max);
      auto pt = [&](int i) {
        return glm::dvec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
      };
      for (int i = 0; i < 8; ++i)
        for (int bit : {1, 2, 4})
          if (!(i & bit)) add(pt(i), pt(i | bit), kZoneColor, 1.5f, OverlayKind::kZone);
    }
  }
  if (!c.drone_known) return out;
  const glm::dvec3 p = local(c.drone);
  // Route: the drone -> the waypoint being flown -> the rest (flown ones dim).
  if (c.has_command && !c.waypoints.empty()) {
    const size_t k = std::min<size_t>(c.waypoint_index, c.waypoints.size() - 1);
    for (size_t i = 0; i + 1 <= k; ++i)
      if (i + 1 < c.waypoints.size())
        add(local(c.waypoints[i]), local(c.waypoints[i + 1]), kRouteFlownColor, 1.5f,
            OverlayKind::kRoute);
    add(p, local(c.waypoints[k]), kRouteColor, 2.5f, OverlayKind::kRoute);
    for (size_t i = k; i + 1 < c.waypoints.size(); ++i)
      add(local(c.waypoints[i]), local(c.waypoints[i + 1]), kRouteColor, 2.5f,
          OverlayKind::kRoute);
  }
  // Target: a cross along the scene axes and its heading.
  if (c.has_command) {
    const glm::dvec3 t = local(c.target);
    const double s = o.target_m;
    add(t - s * f.e1, t + s * f.e1, kTargetColor, 2.5f, OverlayKind::kTarget);
    add(t - s * f.e2, t + s * f.e2, kTargetColor, 2.5f, OverlayKind::kTarget);
    add(t - s * f.up, t + s * f.up, kTargetColor, 2.5f, OverlayKind::kTarget);
    const glm::dmat3 ax = DroneCameraAxes(f.up, c.target_yaw, c.target_pitch);
    add(t, t + 2.5 * s * ax[2], kTargetColor, 2.5f, OverlayKind::kTarget);
  }
  // Body: an X of arms 45° off the heading with a rotor ring at each end, and a nose.
  const glm::dvec3 h = f.Heading(c.yaw), side = f.Heading(c.yaw + control::kPi / 2);
  for (int k = 0; k < 4; ++k) {
    const double a = c.yaw + control::kPi / 4 + k * control::kPi / 2;
    const glm::dvec3 arm = f.Heading(a);
    const glm::dvec3 end = p + o.arm_m * arm;
    add(p, end, kDroneColor, 3.f, OverlayKind::kDrone);
    constexpr int kRing = 10;
    for (int i = 0; i < kRing; ++i) {
      const double t0 = 2 * control::kPi * i / kRing, t1 = 2 * control::kPi * (i + 1) / kRing;
      add(end + o.rotor_m * (std::cos(t0) * h + std::sin(t0) * side),
          end + o.rotor_m * (std::cos(t1) * h + std::sin(t1) * side), kDroneColor, 2.f,
          OverlayKind::kDrone);
    }
  }
  add(p, p + 0.6 * o.arm_m * h, kDroneColor, 3.f, OverlayKind::kDrone);
  // Camera frustum: apex at the drone, the image rectangle at frustum_m along its optical axis.
  const glm::dmat3 ax = DroneCameraAxes(f.up, c.yaw, c.camera_pitch);
  const double tx = std::tan(0.5 * o.hfov_rad), ty = tx / std::max(1e-3, o.aspect);
  glm::dvec3 q[4];
  const double sx[4] = {-1, 1, 1, -1}, sy[4] = {-1, -1, 1, 1};
  for (int i = 0; i < 4; ++i)
    q[i] = p + o.frustum_m * (ax[2] + sx[i] * tx * ax[0] + sy[i] * ty * ax[1]);
  for (int i = 0; i < 4; ++i) {
    add(p, q[i], kFrustumColor, 1.5f, OverlayKind::kFrustum);
    add(q[i], q[(i + 1) % 4], kFrustumColor, 1.5f, OverlayKind::kFrustum);
  }
  // The image's top edge marked (which way is up in the drone's picture).
  add(0.5 * (q[0] + q[1]), 0.5 * (q[0] + q[1]) - 0.15 * o.frustum_m * ax[1], kFrustumColor, 1.5f,
      OverlayKind::kFrustum);
  return out;
}

std::optional<Segment2> ProjectSegment(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                       const glm::dvec3& a_local, const glm::dvec3& b_local,
                                       double near_m) {
  const Rigid3d cam_from_local = local_from_cam.Inverse();
  glm::dvec3 a = cam_from_local * a_local, b = cam_from_local * b_local;
  if (a.z < near_m && b.z < near_m) return std::nullopt;
  if (a.z < near_m) a = a + (b - a) * ((near_m - a.z) / (b.z - a.z));
  if (b.z < near_m) b = b + (a - b) * ((near_m - b.z) / (a.z - b.z));
  Segment2 s;
  if (!camera.Project(a, &s.a) || !camera.Project(b, &s.b)) return std::nullopt;
  return s;
}

}  // namespace exo::nav
