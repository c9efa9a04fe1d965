// Keyframe insertion of InpaintFusion (SPEC §7, thesis 4.2): a frame whose ROI is visible becomes
// a new inpainting keyframe when its pose is farther than `max_pose_distance` (0.7) from the
// nearest keyframe, ||I - M_i^-1 M_k||_F on the 4x4 rigid matrices (metres), or when more than
// `max_unlabelled_fraction` (10 %) of its ROI is not covered by that keyframe's inpainted surface
// (the keyframe's ROI pixels, lifted with their inpainted depth and projected into the frame).
// Pure library.
#pragma once

#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo::inpainting {

struct KeyframePolicyOptions {
  double max_pose_distance = 0.7;
  double max_unlabelled_fraction = 0.10;
  int splat_px = 1;  // each lifted keyframe pixel covers (2 splat_px + 1)^2 frame pixels
  absl::Status Validate() const;
};

// ||I - a^-1 b||_F of the 4x4 matrices.
double PoseDistance(const Rigid3d& a, const Rigid3d& b);

// What the policy needs of an existing keyframe (poses in one frame, e.g. scene-local).
struct KeyframeView {
  const ImageU8* mask = nullptr;   // its ROI (!= 0)
  const ImageF* depth_m = nullptr; // its inpainted depth
  PinholeCamera camera;
  Rigid3d local_from_cam;
};

// Fraction of `roi`'s pixels (frame `camera` at `local_from_cam`) that `kf`'s ROI pixels do not
// reach. 0 for an empty ROI.
double UnlabelledFraction(const ImageU8& roi, const PinholeCamera& camera,
                          const Rigid3d& local_from_cam, const KeyframeView& kf,
                          const KeyframePolicyOptions& options);

struct KeyframeDecision {
  bool insert = false;
  int nearest = -1;               // index into the keyframes, -1 when there is none
  double pose_distance = 0.0;     // to the nearest
  double unlabelled_fraction = 1.0;
  const char* reason = "";        // "first", "pose", "unlabelled", ""
};

KeyframeDecision DecideKeyframe(const ImageU8& roi, const PinholeCamera& camera,
                                const Rigid3d& local_from_cam,
                                const std::vector<KeyframeView>& keyframes,
                                const KeyframePolicyOptions& options);

}  // namespace exo::inpainting
