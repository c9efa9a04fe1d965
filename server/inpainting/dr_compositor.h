// Diminished reality through 3D, per frame (issue 18, SPEC §7; docs/inpainting.md "Session 10"
// and "Session 11"): the orchestration of the per-pixel pieces of dr_view.h into a stream of
// frames with the ROI removed. Pure library (no threads, no gRPC): dr_bench runs it
// synchronously, the server's inpainting stage runs its keyframes on a worker thread.
//
// Per frame with an ROI (its pixels to remove):
//  1. Keyframe rule (0.7 / 10 %, keyframe_policy.h) against the keyframes so far.
//  2. A new keyframe takes the colour of every ROI pixel that some view OBSERVED (the keyframes'
//     observed pixels and the kept observation frames; depth agreeing), at the background depth
//     warped from the nearest keyframe, and the library (InpaintKeyframe, propagated from the
//     nearest keyframe) inpaints only the rest, with the observed pixels as its context
//     (observations preferred). The first keyframe is inpainted whole.
//  3. Between keyframes every ROI pixel is looked up through 3D: background depth warped from the
//     nearest keyframe, colour from the nearest view that observed the point, else the nearest
//     keyframe's inpainted colour; the few pixels no view reaches are Telea-filled.
//  4. Gradient-domain blend with the frame's border, the output depth re-anchored on the frame's
//     depth around the ROI (Poisson), and exponential smoothing along the camera motion.
//  5. Every obs_stride-th frame is kept as an observation view (its ROI unusable).
//
// For asynchronous keyframes (the live server) the keyframe step is split: Decide, MakeJob (a
// self-contained snapshot of the views: shared, immutable), ComputeKeyframe (static: heavy, any
// thread), AddKeyframe. Not thread-safe itself: callers serialise the non-static calls.
#pragma once

#include <deque>
#include <memory>
#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/rigid3.h"
#include "common/status.h"
#include "server/inpainting/dr_view.h"
#include "server/inpainting/inpaint.h"
#include "server/inpainting/keyframe_policy.h"

namespace exo::inpainting {

enum class DrBlend { kPaste, kPoisson, kPoissonHallucinated };
// The blend's guide on the one-pixel ring around the ROI: kObserved = looked up where another
// view observed it, else the frame; kLookUp = looked up (hallucinated too); kFrame = the frame.
enum class DrRing { kObserved, kLookUp, kFrame };

struct DrOptions {
  InpaintOptions inpaint = [] {
    InpaintOptions o;
    o.num_threads = 1;
    return o;
  }();
  KeyframePolicyOptions policy;
  int obs_stride = 10;  // keep every Nth frame (by the caller's index) as an observation view
  int obs_views = 24;   // observation views kept (0 = keyframes only)
  size_t max_keyframes = 0;  // oldest keyframe forgotten beyond this; 0 = unbounded
  DrBlend blend = DrBlend::kPoisson;
  DrRing ring = DrRing::kLookUp;
  double ring_sigma = 0.0;  // blend only the ring mismatch smoothed by this Gaussian (px); 0 = all
  double temporal = 0.8;    // weight of the previous output in the smoothing, 0 = none
  bool temporal_hallucinated_only = false;
  bool depth_poisson = true;    // between keyframes: warped depth's gradients anchored on the frame
  bool kf_context = true;       // a keyframe takes observed colour first (see 2. above)
  bool prefer_observed = true;  // look up in every view (false: only the nearest keyframe)
  bool bicubic = false;
  // A keyframe's PatchMatch + Poisson run on a crop of the frame around its ROI: the ROI's
  // bounding box grown by max(kf_crop_margin_px, kf_crop_margin_rel x its larger side) on each
  // side (clamped to the frame); the sources are the crop's pixels. 0 / 0 = the whole frame.
  int kf_crop_margin_px = 0;
  double kf_crop_margin_rel = 0.0;
  absl::Status Validate() const;
};

// Everything a keyframe needs, self-contained (views are shared and never modified once made).
struct DrKeyframeJob {
  RgbdKeyframe frame;  // colour, registered depth, camera, pose (one consistent world frame)
  ImageU8 roi;
  std::shared_ptr<const DrView> nearest;          // the rule's nearest keyframe (null: first)
  std::shared_ptr<const InpaintResult> previous;  // nearest keyframe with a result (propagation)
  std::vector<std::shared_ptr<const DrView>> views;  // keyframes + observations, nearest first
};

struct DrKeyframe {
  std::shared_ptr<DrView> view;  // colour/depth: observed outside the ROI, filled inside
  // The look-up state of the frame (the synchronous path composites the keyframe's frame from it).
  ImageU8 guide, observed, filled;
  ImageF depth;
  bool inpainted = false;  // the library ran (some ROI pixel was observed by no view)
  bool propagated = false;  // ... initialised from a previous keyframe (4.3-4.6)
  int observed_px = 0, hallucinated_px = 0;
  InpaintStats stats;  // of the library run
  double ms = 0;       // wall of the library run
};

struct DrFrameResult {
  ImageU8 color;  // the frame with its ROI removed
  ImageF depth;
  bool keyframe = false;
  int roi_px = 0, observed_px = 0;
};

struct DrStats {
  int keyframes_inpainted = 0, keyframes_propagated = 0;
  double first_keyframe_ms = 0, propagated_keyframe_ms = 0;  // wall, sum over propagated
};

// The live DR view (issue 18: the camera's stream with the ROI removed at the camera's frame
// rate, keyframes computed elsewhere, asynchronously). Per frame: the background depth of the
// ROI warped from the nearest keyframe (pose distance), the colour looked up in the `max_views`
// nearest views (observed first, else inpainted), pixels no view reaches and the mismatch on the
// one-pixel ring spread over the ROI by push-pull (a cheap membrane instead of the three Poisson
// solves of ProcessFrame), and the exponential smoothing along the camera motion. Never computes
// a keyframe and never keeps the frame: O(ROI + one splat of the keyframe).
struct DrLiveOptions {
  int max_views = 4;      // look-up views, nearest pose first (bounds the per-pixel cost)
  double temporal = 0.8;  // weight of the previous output (DrOptions::temporal), 0 = none
  bool blend = true;      // spread the ring mismatch over the ROI (false: paste)
  absl::Status Validate() const;
};
// What one live frame reads (shared, immutable views): take it under the caller's lock, compose
// outside it.
struct DrLiveSnapshot {
  std::shared_ptr<const DrView> nearest;  // background depth; null = no keyframe yet
  std::vector<std::shared_ptr<const DrView>> views;  // look-up, nearest pose first
};
// Smoothing state of one live stream (the previous output and its pose).
struct DrLiveState {
  ImageU8 prev_color;
  Rigid3d prev_pose;
  void Reset() { prev_color = ImageU8(); }
};
// The frame with its ROI removed. Without a keyframe (`snap.nearest` null) the frame comes back
// unchanged with `composited` false. Errors: sizes (InvalidArgument).
struct DrLiveResult {
  ImageU8 color;
  ImageF depth;
  bool composited = false;
  int roi_px = 0, observed_px = 0, unreached_px = 0;
};
absl::StatusOr<DrLiveResult> ComposeLiveFrame(const RgbdKeyframe& frame, const ImageU8& roi,
                                              const DrLiveSnapshot& snap,
                                              const DrLiveOptions& options, DrLiveState* state);

class DiminishedReality {
 public:
  explicit DiminishedReality(const DrOptions& options) : options_(options) {}

  // Synchronous: one frame (its registered depth) and its ROI in, the frame with the ROI removed
  // out; a keyframe the rule asks for is computed here. `index` counts frames (observation
  // stride). An empty ROI returns the frame unchanged (and keeps nothing).
  absl::StatusOr<DrFrameResult> ProcessFrame(const RgbdKeyframe& frame, const ImageU8& roi,
                                             int64_t index);

  // --- asynchronous keyframes ---
  KeyframeDecision Decide(const ImageU8& roi, const PinholeCamera& camera,
                          const Rigid3d& pose) const;
  DrKeyframeJob MakeJob(RgbdKeyframe frame, ImageU8 roi, const KeyframeDecision& d) const;
  // Heavy (the library's PatchMatch + Poisson); any thread. Errors: the library's (e.g. no valid
  // source patch), wrong sizes.
  static absl::StatusOr<DrKeyframe> ComputeKeyframe(const DrKeyframeJob& job,
                                                    const DrOptions& options);
  void AddKeyframe(std::shared_ptr<const DrView> view, const DrKeyframe* computed = nullptr);
  // Keeps the frame as an observation view when index % obs_stride == 0 (its ROI's depth zeroed).
  void AddObservation(const RgbdKeyframe& frame, const ImageU8& roi, int64_t index);
  // Forgets keyframes, observations and the smoothing state (the regions changed).
  void Clear();

  // --- observations preferred after the fact (SPEC §7: a hole that is later observed is
  // replaced by the observation) ---
  // Every keyframe and observation view except `kf`, nearest to `kf`'s pose first.
  std::vector<std::shared_ptr<const DrView>> ViewsAround(const DrView& kf) const;
  // The keyframe's hallucinated pixels that one of `views` OBSERVED (visible there at the
  // keyframe's depth: within 2 % + 1 cm, not inpainted there) take that colour and stop being
  // hallucinated. Pure, any thread; `kf` is not changed. `view` is null when nothing was replaced.
  struct Refresh {
    std::shared_ptr<DrView> view;
    int replaced = 0, hallucinated_before = 0;
  };
  static Refresh RefreshKeyframe(const DrView& kf,
                                 const std::vector<std::shared_ptr<const DrView>>& views);
  // Swaps a keyframe for its refreshed copy; false when `old` is no longer a keyframe.
  bool ReplaceKeyframe(const DrView* old, std::shared_ptr<const DrView> now);

  // The views a live frame at `pose` reads (ComposeLiveFrame): the nearest keyframe and the
  // `max_views` nearest keyframes and observation views.
  DrLiveSnapshot LiveSnapshot(const Rigid3d& pose, int max_views) const;

  const std::vector<std::shared_ptr<const DrView>>& keyframes() const { return keyframes_; }
  size_t observations() const { return obs_.size(); }
  const DrStats& stats() const { return stats_; }
  const DrOptions& options() const { return options_; }

 private:
  std::vector<std::shared_ptr<const DrView>> ViewsNearest(const Rigid3d& pose, int nearest) const;

  DrOptions options_;
  std::vector<std::shared_ptr<const DrView>> keyframes_;
  std::deque<std::shared_ptr<const DrView>> obs_;
  ImageU8 prev_color_;
  Rigid3d prev_pose_;
  DrStats stats_;
};

// A DrView of a keyframe result (the stage's restored views): colour/depth, its ROI, the
// hallucinated part (`hallucinated` empty = the whole ROI).
std::shared_ptr<DrView> MakeKeyframeView(const RgbdKeyframe& frame, const ImageU8& roi,
                                         const ImageU8& hallucinated);

}  // namespace exo::inpainting
