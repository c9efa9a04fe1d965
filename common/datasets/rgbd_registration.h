// Depth-to-colour registration of RGB-D sensors whose colour and depth cameras are separate
// (Kinect v1, 7-Scenes): the calibration (colour intrinsics + depth->colour extrinsic), the
// forward warp of a depth image into the colour camera, a registered Frame, and a
// self-calibration that estimates the calibration from the data (posed RGB-D frames) with Ceres.
//
// Conventions (exact):
// - A RAW frame, as SevenScenesReader::Open(dir) delivers it, holds depth in `depth_camera`,
//   colour in a camera of unknown intrinsics (its `color_camera` is a placeholder), and its
//   `world_from_cam` is the pose of the DEPTH camera (7-Scenes poses are KinectFusion's, which
//   tracks depth). Its `color_from_depth` must be identity (the raw reader's placeholder).
// - DepthColorCalibration::color_from_depth maps a point in depth-camera coordinates to
//   colour-camera coordinates: p_in_color = color_from_depth * p_in_depth.
// - A REGISTERED frame (RegisterFrame) has color_camera = depth_camera = calib.color_camera,
//   color_from_depth = identity, depth z-depth in the colour camera, and
//   world_from_cam = world_from_depth * inverse(color_from_depth) = pose of the colour camera.
#pragma once

#include <string>
#include <vector>

#include "common/camera.h"
#include "common/frame.h"
#include "common/image.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo {

struct DepthColorCalibration {
  PinholeCamera color_camera;                       // intrinsics + size of the colour image
  Rigid3d color_from_depth = Rigid3d::Identity();   // depth-camera -> colour-camera
  // Valid intrinsics, finite unit-quaternion rotation, |translation| < 1 m.
  absl::Status Validate() const;
};

// The committed estimate (see SevenScenesKinectV1Calibration below for provenance).
inline constexpr double kSevenScenesColorFx = 522.5236, kSevenScenesColorFy = 519.634;
inline constexpr double kSevenScenesColorCx = 324.6322, kSevenScenesColorCy = 232.2712;
// color_from_depth rotation (w, x, y, z; 0.7801 deg) and translation (m).
inline constexpr double kSevenScenesQw = 0.99997683, kSevenScenesQx = 0.0001522,
                        kSevenScenesQy = -0.00661029, kSevenScenesQz = 0.00162133;
inline constexpr double kSevenScenesTx = -0.014155, kSevenScenesTy = 0.019636,
                        kSevenScenesTz = -0.007657;

// Estimated on 7-Scenes redkitchen (frames 0-299, Kinect v1, 640x480) by
//   build-reg/common/datasets/exoview_calibrate_7scenes --dir /work/shared/data/7scenes-redkitchen
//       --first 0 --step 10 --count 30          (30 frames, 3 pyramid levels, default options)
// (see docs/registration.md for the run, its residuals and the method). Depth camera: K of the
// data (fx = fy = 585, cx = 320, cy = 240).
DepthColorCalibration SevenScenesKinectV1Calibration();

// Forward-projects every valid depth pixel (z-depth in `depth_camera`) into the colour camera,
// keeps the nearest surface per colour pixel (z-buffer), and closes 1-px splat cracks: an
// invalid pixel whose two opposite neighbours (left/right, up/down or diagonal) are valid and
// agree within
// `kCrackRelativeTolerance` of their depth gets their mean; a pixel that sees through a 1-px
// crack of a nearer surface (both opposite neighbours nearer than it by more than the tolerance
// and agreeing with each other) is replaced the same way. Nothing else is filled, so no depth is
// invented across a discontinuity. Output: z-depth in the colour camera (its size), 0 = invalid.
// Errors: invalid camera/calibration, depth size != depth_camera size, NaN/Inf/negative depth.
inline constexpr double kCrackRelativeTolerance = 0.03;
absl::StatusOr<ImageF> RegisterDepthToColor(const ImageF& depth_m,
                                            const PinholeCamera& depth_camera,
                                            const DepthColorCalibration& calib);

// A registered copy of a RAW frame (conventions above). Errors: invalid frame or calibration,
// colour image size != calib.color_camera size, raw frame with a non-identity color_from_depth.
absl::StatusOr<Frame> RegisterFrame(const Frame& raw, const DepthColorCalibration& calib);

// ---- Self-calibration ------------------------------------------------------------------------
//
// Unknowns: colour fx, fy, cx, cy and color_from_depth (rotation on the unit-quaternion
// manifold, translation). Two terms, coarse-to-fine over an image pyramid:
//  1. multi-view photometric consistency: 3-D points from depth frame i (world via the depth
//     pose) are projected through the candidate calibration into the colour images of i and of
//     neighbouring frames j; residual = difference of the bicubically sampled grey intensities
//     (sRGB, [0, 1], blurred) / photometric_sigma, Huber loss. (Normalising each image by its
//     own mean/std was tried and is wrong: views of different content get different scales.) Points not visible
//     in depth frame j (occluded, outside) are dropped (test on the known depth + pose of j).
//  2. edge alignment: depth-discontinuity pixels (near side of a jump) of frame i are projected
//     into colour image i; residual = distance (px, full resolution) to the nearest colour edge
//     (Canny + distance transform, truncated) / edge_sigma_px, Cauchy loss.
//  Gauge / weak directions: translation along the optical axis is weakly observable, so a prior
//  t_z ~ N(initial t_z, tz_prior_sigma_m) is added (stated in the report). The focal length is
//  initialised by a 1-D search of the coarsest-level cost over focal scales (the optimiser's
//  basin at 10 % scale error is too narrow otherwise).
struct CalibrationOptions {
  // Start point; default (color_camera.fx == 0): colour camera = depth camera (at the colour
  // image size), color_from_depth = identity.
  DepthColorCalibration initial;
  int pyramid_levels = 3;               // coarsest level = pyramid_levels - 1 (half size each)
  int max_iterations_per_level = 25;
  bool same_focal = false;              // estimate one f (fx = fy)
  // Initial focal search: f = scale * initial fx for scales in [min, max] step `step`
  // (focal_search_step = 0 disables it).
  double focal_search_min = 0.80, focal_search_max = 1.10, focal_search_step = 0.01;
  // Photometric term.
  double photometric_weight = 1.0;
  double photometric_sigma = 0.025;     // grey units ([0, 1])
  int photometric_samples_per_frame = 2500;
  int neighbours_per_frame = 3;
  double min_pair_rotation_deg = 3.0;   // a pair needs this rotation OR min baseline (parallax)
  double min_pair_baseline_m = 0.10;
  double max_pair_rotation_deg = 35.0;
  double max_pair_baseline_m = 1.5;
  // Edge term.
  double edge_weight = 1.0;
  double edge_sigma_px = 1.5;           // full-resolution px
  double edge_truncation_px = 12.0;     // full-resolution px (per level it is /2^level, >= 3)
  int edge_samples_per_frame = 1500;
  double depth_jump_relative = 0.06;    // a discontinuity: neighbour farther by > rel*z
  double depth_jump_min_m = 0.08;       //   and by more than this
  // Prior on the translation along the optical axis (0 = no prior).
  double tz_prior_sigma_m = 0.02;
  // Prior on the rotation (towards the initial one), degrees (0 = none). A colour-camera
  // rotation about x (y) and a shift of cy (cx) move the image almost alike (they differ only by
  // the projective term ~ u^2/f), so without it the pair drifts along that valley on real data.
  double rotation_prior_sigma_deg = 0.5;
  bool estimate_rotation = true;        // false: keep the initial rotation
  int num_threads = 2;
  absl::Status Validate() const;
};

struct CalibrationTermStats {
  size_t residuals = 0;
  double cost_before = 0, cost_after = 0;           // robustified, weighted (Ceres cost)
  double median_abs_before = 0, median_abs_after = 0;  // raw residual (photo: grey units; edge: px)
};

struct CalibrationReport {
  DepthColorCalibration initial;        // after the focal search
  DepthColorCalibration calibration;    // the estimate
  double focal_search_best_scale = 1.0;
  double initial_cost = 0, final_cost = 0;  // finest level, all terms
  CalibrationTermStats photometric, edge;   // finest level
  size_t frames_used = 0, frames_dropped_duplicate_color = 0, pairs_used = 0;
  int iterations = 0;
  double seconds = 0;
  std::string ToJson() const;
};

// Estimates the calibration from RAW frames (conventions above) that share one depth camera and
// one colour image size. Errors: empty list, invalid options/frames, frames whose sizes differ,
// no usable samples (all-invalid depth), a solver failure.
absl::StatusOr<CalibrationReport> EstimateDepthColorCalibration(
    const std::vector<Frame>& raw_frames, const PinholeCamera& depth_camera,
    const CalibrationOptions& options);

// Calibration-independent alignment measures of a calibration on RAW frames, at full
// resolution, no robust loss: the median absolute multi-view photometric difference (grey in
// [0, 1], same sampling as the estimator) and the median distance (px) from projected
// depth-discontinuity pixels to the nearest colour edge (untruncated distance transform).
struct AlignmentMeasures {
  double photometric_median_abs = 0;
  size_t photometric_samples = 0;
  double edge_median_px = 0;
  double edge_p90_px = 0;  // 90th percentile (large offsets at occluding contours)
  size_t edge_samples = 0;
};
absl::StatusOr<AlignmentMeasures> MeasureDepthColorAlignment(
    const std::vector<Frame>& raw_frames, const PinholeCamera& depth_camera,
    const DepthColorCalibration& calib, const CalibrationOptions& options);

}  // namespace exo
