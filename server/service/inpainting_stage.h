// Pipeline stage "inpainting" (InpaintFusion, SPEC §7): diminished reality for the marked
// regions. For every frame the stage re-projects the L_ROI labels (RegionRegistry) into the frame
// (its registered depth and pose) and applies the keyframe rule (pose distance > 0.7 from the
// nearest keyframe, or > 10 % of the ROI not covered by it; keyframe_policy.h). The keyframes
// are those of the library's DiminishedReality (server/inpainting/dr_compositor.h, method "dr",
// the default): every 10th frame with the ROI visible is kept as an observation view (its ROI
// unusable), and a new keyframe takes the colour of each ROI pixel that an earlier view OBSERVED
// (at the background depth warped from the nearest keyframe); PatchMatch colour + Poisson depth
// (server/inpainting/inpaint.h), propagated from the nearest keyframe (4.3-4.6), fill only the
// rest. Method "keyframe" is session 9's: the whole ROI inpainted, no observations. A keyframe
// is computed on the stage's own worker thread and published as a ViewAdded with `inpainted`
// set and its label mask. The slot for waiting work is bounded (one job in flight, none queued):
// while a keyframe is computed, frames are only counted (every obs_stride-th is still kept as an
// observation), so the stage never slows ingest down. When the worker is idle and a new
// observation view was kept, the worker refreshes one keyframe: its hallucinated pixels that an
// observation now shows take the observed colour (observations preferred, SPEC §7), and the
// keyframe is republished under the same view id. The frames themselves are never
// changed, so planning, refinement and tracking never see inpainted pixels; inpainted views are
// never referenced by cells. Clearing a region withdraws every inpainted view (Withdraw) and a
// keyframe still in flight for the old regions is discarded (generation check under the publish
// lock).
#pragma once

#include <memory>

#include "proto/model_proto.h"
#include "server/inpainting/dr_compositor.h"
#include "server/inpainting/inpaint.h"
#include "server/inpainting/keyframe_policy.h"
#include "server/service/inpainted_proxy.h"
#include "server/service/pipeline.h"
#include "server/service/regions.h"

namespace exo {

// Inpainted keyframes get view ids from this base up (planner ids count from 1).
inline constexpr ViewId kInpaintedViewIdBase = 0x40000000u;

struct InpaintingStageOptions {
  inpainting::InpaintOptions inpaint = [] {
    inpainting::InpaintOptions o;
    o.num_threads = 1;  // one worker thread: ingest and the other stages keep the other core
    return o;
  }();
  inpainting::KeyframePolicyOptions policy;
  inpainting::RegionOptions region;  // re-projection margins (the registry's options)
  size_t max_keyframes = 16;  // oldest inpainted keyframe withdrawn beyond this
  // "dr": the session-11 keyframes (observed colour first, observation views); "keyframe": the
  // session-9 keyframes (the whole ROI inpainted).
  std::string method = "dr";
  int observation_views = 24;   // "dr": observation views kept (memory: ~2 MB each at 640x480)
  int observation_stride = 10;  // "dr": every Nth frame (of all frames) with the ROI visible is one
  // The stage looks at every Nth frame only (re-projection, rule, observation): 1 = every frame.
  int frame_stride = 1;
  // "dr": when the worker is idle, a keyframe's hallucinated pixels that a newer observation view
  // saw are replaced by the observation and the keyframe is republished (same view id), once at
  // least this many pixels changed (0 = never).
  int refresh_min_px = 16;
  // The live DR view (the camera's stream with the ROI removed; WatchDrView): composited per
  // frame from the keyframes so far (inpainting::ComposeLiveFrame) while someone watches, or
  // always with live_always (benchmarks).
  int live_views = 4;
  bool live_always = false;
  // The stage's two threads (frames, keyframes) run this much nicer than the server: the DR
  // work yields the CPU to ingest and the modelling stages (0 = the server's priority).
  int nice = 10;
  // The frame thread's own niceness (the live DR view's rate) while the pipeline keeps up;
  // -1 = `nice`. Its work is bounded (only the newest frame, the live view only while watched).
  // Default -1: at 0 (with keyframe_nice 0) the live view ran at 12-21 fps instead of 10-11 on a
  // quiet machine, but the geometry stage shed 45-55 of 150 frames instead of 7-8 and one run
  // dropped 6 of 142 at admission (docs/inpainting.md, Session 14).
  int frame_nice = -1;
  // The keyframe thread's niceness (keyframe latency) while the pipeline keeps up; -1 = `nice`.
  int keyframe_nice = -1;
  // Both threads back off to `nice` while frames reach this stage more than this many ms
  // after their admission (the modelling stages are behind: ingest comes first; at 30 Hz the
  // admission queue of 8 is full at ~270 ms), and returns to
  // `frame_nice` / `keyframe_nice` once they arrive within half of it again. 0 = never back off.
  double frame_backoff_ms = 250.0;
  // "dr": a keyframe inpaints a crop around its ROI (DrOptions::kf_crop_margin_*; 0 / 0 = whole).
  int kf_crop_margin_px = 0;
  double kf_crop_margin_rel = 0.0;
  ViewEncodeOptions publish;
  absl::Status Validate() const;
};

class InpaintingStage;

// Created by the server (so that the ClearRegion RPC can reach Withdraw) and handed to the
// pipeline as a stage.
std::unique_ptr<InpaintingStage> MakeInpaintingStage(const InpaintingStageOptions& options,
                                                     std::shared_ptr<RegionRegistry> regions,
                                                     ModelStore* store,
                                                     std::shared_ptr<InpaintedProxyLink> link = nullptr);

// One frame of the live DR view.
struct DrLiveFrame {
  uint64_t index = 0;  // counts the live frames of this server (WaitLiveFrame's `after`)
  uint64_t sequence = 0;
  double timestamp_s = 0;
  Rigid3d world_from_cam;
  ImageU8 color;            // RGB8, the ROI removed (unchanged when !composited)
  bool composited = false;  // false: no keyframe yet or the ROI is not in view
  int roi_px = 0;
  double compose_ms = 0, compose_cpu_ms = 0;
  double latency_ms = 0;  // from the frame's admission to this output
};

class InpaintingStage : public PipelineStage {
 public:
  // The live DR view: the newest frame with index > `after`, waiting up to `timeout_s`; null
  // when none came. Frames are composited only while at least one watcher is registered.
  virtual std::shared_ptr<const DrLiveFrame> WaitLiveFrame(uint64_t after, double timeout_s) = 0;
  virtual void AddLiveWatcher(int delta) = 0;
  // Removes every inpainted view from the model and forgets the keyframes (after the regions
  // changed); returns how many views were removed. Thread-safe.
  virtual uint32_t Withdraw() = 0;
  // Blocks until no keyframe is in flight (tests, shutdown); false on timeout.
  virtual bool WaitIdle(double timeout_s) = 0;
  // The outcome of the last keyframe: "" (none yet), "ok", or why it failed (e.g. "no valid
  // source patch ..." when the ROI leaves nothing to copy from).
  virtual std::string status() const = 0;
};

}  // namespace exo
