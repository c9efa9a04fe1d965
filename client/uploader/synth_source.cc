#include "client/uploader/synth_source.h"

namespace exo {

absl::StatusOr<std::unique_ptr<SynthFrameSource>> SynthFrameSource::Create(
    const SynthSourceOptions& o) {
  auto s = std::unique_ptr<SynthFrameSource>(new SynthFrameSource);
  s->options_ = o;
  EXO_ASSIGN_OR_RETURN(synth::SceneKind kind, synth::ParseSceneKind(o.scene));
  synth::SceneOptions so;
  so.seed = o.seed;
  EXO_ASSIGN_OR_RETURN(s->scene_, synth::MakeScene(kind, so));
  EXO_ASSIGN_OR_RETURN(synth::TrajectoryKind tk, synth::ParseTrajectoryKind(o.trajectory));
  synth::TrajectoryOptions to;
  to.num_frames = o.num_frames;
  to.frame_rate_hz = o.frame_rate_hz;
  EXO_ASSIGN_OR_RETURN(s->poses_, synth::MakeTrajectory(s->scene_, tk, to));
  s->render_.width = o.width;
  s->render_.height = o.height;
  EXO_RETURN_IF_ERROR(s->render_.Validate());
  return s;
}

absl::StatusOr<Frame> SynthFrameSource::Load(size_t i) const {
  if (i >= poses_.size()) return absl::OutOfRangeError("synthetic frame index out of range");
  EXO_ASSIGN_OR_RETURN(synth::RenderedFrame r,
                       synth::RenderFrame(scene_, poses_[i].local_from_cam, render_, {}, i + 1,
                                          poses_[i].timestamp_s));
  return std::move(r.frame);
}

}  // namespace exo
