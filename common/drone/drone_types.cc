#include "common/drone/drone_types.h"

namespace exo::control {
namespace {

bool Finite(const glm::dvec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

}  // namespace

const char* InteractionName(InteractionKind k) {
  switch (k) {
    case InteractionKind::kNone:
      return "none";
    case InteractionKind::kPickAndPlace:
      return "pick_and_place";
    case InteractionKind::kGazeToSee:
      return "gaze_to_see";
    case InteractionKind::kJoypad:
      return "joypad";
    case InteractionKind::kGoToView:
      return "go_to_view";
    case InteractionKind::kHold:
      return "hold";
    case InteractionKind::kExplore:
      return "explore";
  }
  return "unknown";
}

absl::StatusOr<SceneFrame> SceneFrame::FromUp(const glm::dvec3& up) {
  const double n = glm::length(up);
  if (!Finite(up) || !(n > 1e-9))
    return absl::InvalidArgumentError("scene frame: the up axis must be a non-zero finite vector");
  SceneFrame f;
  f.up = up / n;
  glm::dvec3 ref(1, 0, 0);
  if (std::abs(glm::dot(ref, f.up)) > 0.9) ref = glm::dvec3(0, 1, 0);
  f.e1 = glm::normalize(ref - glm::dot(ref, f.up) * f.up);
  f.e2 = glm::cross(f.up, f.e1);
  return f;
}

}  // namespace exo::control
