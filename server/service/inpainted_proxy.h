// The link between the inpainting stage and the geometry stage for InpaintFusion's labelled proxy
// (SPEC §7, geometry/inpainted_surface.h): the inpainting stage hands over the depth of every
// inpainted keyframe it publishes (its ROI pixels), the geometry stage, which owns the observed
// TSDF and publishes the mesh chunks, fuses them into the inpainted field (L_IP voxels only),
// carves the marked regions (the registry's L_ROI labels) and republishes the chunks whose
// clients' mesh changed. The planner keeps getting the observed update (GeometryHandoff), so
// it never sees the inpainted surface. Kick() applies waiting keyframes at once (they arrive
// asynchronously, also after the last frame); otherwise the next frame does. Thread-safe.
#pragma once

#include <deque>
#include <functional>
#include <memory>
#include <mutex>

#include "common/camera.h"
#include "common/image.h"
#include "common/rigid3.h"
#include "server/service/observed_chunks.h"
#include "server/service/regions.h"

namespace exo {

struct InpaintedDepth {
  ImageF depth;    // the keyframe's depth (inpainted in the ROI)
  ImageU8 mask;    // 1 channel, != 0 = ROI pixel (its L_IP labels)
  ImageU8 color;   // RGB8 of the same camera (may be empty)
  PinholeCamera camera;
  Rigid3d local_from_cam;
};

class InpaintedProxyLink {
 public:
  // At most this many keyframes wait (beyond: the oldest waiting one is dropped and counted;
  // the stage publishes at most one keyframe at a time, so this only fills without frames).
  static constexpr size_t kMaxWaiting = 32;

  // `observed` (may be null): where the geometry stage keeps the observed mesh of every chunk
  // it publishes labelled (the drone's map, observed_chunks.h).
  explicit InpaintedProxyLink(std::shared_ptr<RegionRegistry> regions,
                              std::shared_ptr<ObservedChunks> observed = nullptr)
      : regions_(std::move(regions)), observed_(std::move(observed)) {}

  const std::shared_ptr<RegionRegistry>& regions() const { return regions_; }
  ObservedChunks* observed() const { return observed_.get(); }

  // Inpainting stage: a published keyframe's depth; every inpainted view withdrawn.
  void Add(InpaintedDepth d) {
    std::lock_guard lock(mu_);
    if (waiting_.size() >= kMaxWaiting) {
      waiting_.pop_front();
      ++dropped_;
    }
    waiting_.push_back(std::move(d));
  }
  void Reset() {
    std::lock_guard lock(mu_);
    waiting_.clear();
    reset_ = true;
  }
  // Runs the geometry stage's applier now (no-op before it registered).
  void Kick() {
    std::lock_guard lock(applier_mu_);
    if (applier_) applier_();
  }

  // Geometry stage.
  struct Pending {
    bool reset = false;
    std::deque<InpaintedDepth> items;
  };
  Pending Take() {
    std::lock_guard lock(mu_);
    Pending p;
    p.reset = reset_;
    p.items.swap(waiting_);
    reset_ = false;
    return p;
  }
  void SetApplier(std::function<void()> fn) {
    std::lock_guard lock(applier_mu_);
    applier_ = std::move(fn);
  }
  uint64_t dropped() const {
    std::lock_guard lock(mu_);
    return dropped_;
  }

 private:
  std::shared_ptr<RegionRegistry> regions_;
  std::shared_ptr<ObservedChunks> observed_;
  // Lock order: applier_mu_ -> (the geometry stage's locks) -> mu_; never mu_ then applier_mu_.
  std::mutex applier_mu_;
  std::function<void()> applier_;
  mutable std::mutex mu_;
  std::deque<InpaintedDepth> waiting_;
  bool reset_ = false;
  uint64_t dropped_ = 0;
};

}  // namespace exo
