// The built-in synthetic scene as a FrameSource: frames rendered on demand from common/synth
// along a trajectory (fly-over or walk), with world poses (scene origin applied). Used by the
// uploader (--synthetic), the end-to-end tests and the service benchmark.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "common/datasets/frame_source.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace exo {

struct SynthSourceOptions {
  std::string scene = "village";          // village | apartment
  std::string trajectory = "flyover";     // flyover | walk
  int num_frames = 120;
  int width = 640, height = 480;
  uint64_t seed = 1;
  double frame_rate_hz = 30.0;
};

class SynthFrameSource : public FrameSource {
 public:
  static absl::StatusOr<std::unique_ptr<SynthFrameSource>> Create(const SynthSourceOptions& o);
  size_t size() const override { return poses_.size(); }
  absl::StatusOr<Frame> Load(size_t i) const override;
  std::string name() const override { return "synthetic:" + options_.scene; }
  const synth::SynthScene& scene() const { return scene_; }
  const synth::RenderOptions& render_options() const { return render_; }
  const std::vector<synth::TimedPose>& poses() const { return poses_; }

 private:
  SynthSourceOptions options_;
  synth::SynthScene scene_;
  synth::RenderOptions render_;
  std::vector<synth::TimedPose> poses_;
};

}  // namespace exo
