// The diminished-reality scene of the live-system test and bench (issue 18, session 11): the
// synthetic apartment with its removable chair (common/synth), rendered with and without it,
// on dr_bench's arc around the chair (radius 1.7 m, eye 1.5 m, 90 degrees from the north side of
// the room), and the operator's mark: stroke points painted over the chair's pixels.
#pragma once

#include <cmath>
#include <memory>

#include "common/lumigraph/model.h"
#include "common/status.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "proto/exoview.pb.h"
#include "proto/frame_proto.h"

namespace exo::testing {

struct ChairScene {
  std::shared_ptr<synth::SynthScene> with, without;
  synth::RenderOptions ro;
  glm::dvec3 centre{0.0};
  synth::Box3 bounds;  // the chair's box (world = the scene's frame)
  // t in [0, 1] along the arc.
  Rigid3d Pose(double t) const {
    const double a = (90.0 + (-0.5 + t) * 90.0) * M_PI / 180.0;
    return synth::LookAt({centre.x + 1.7 * std::cos(a), centre.y + 1.7 * std::sin(a), 1.5}, centre);
  }
};

inline ChairScene MakeChairScene(int w, int h) {
  ChairScene c;
  synth::SceneOptions so;
  so.removable_objects = true;
  auto s = synth::MakeScene(synth::SceneKind::kApartment, so);
  EXO_CHECK(s.ok());
  auto wo = synth::RemoveObjects(*s, {"chair"});
  EXO_CHECK(wo.ok());
  c.with = std::make_shared<synth::SynthScene>(*std::move(s));
  c.without = std::make_shared<synth::SynthScene>(*std::move(wo));
  c.ro.width = w;
  c.ro.height = h;
  c.ro.num_threads = 1;
  for (const auto& o : c.with->removable)
    if (o.name == "chair") {
      c.centre = o.bounds.Centre();
      c.bounds = o.bounds;
    }
  return c;
}

// Vertices of a viewer's proxy (its mesh chunks) on the chair: inside the chair's box, above the
// lowest 5 cm (the floor under its legs is surface of the scene without it too).
inline size_t ChairProxyVertices(const LumigraphModel& model, const ChairScene& scene) {
  synth::Box3 b = scene.bounds;
  b.min.z += 0.05;
  size_t n = 0;
  for (const auto& [id, c] : model.chunks)
    for (const glm::vec3& p : c.mesh.positions) n += b.Contains(model.origin.ToWorld(p));
  return n;
}

// The chair's pixels (depth with it nearer than without), dilated by `dilate` px.
inline ImageU8 ChairPixels(const synth::RenderedFrame& with, const synth::RenderedFrame& without,
                           int dilate) {
  const ImageF& a = with.frame.depth_m;
  const ImageF& b = without.frame.depth_m;
  ImageU8 m(a.width(), a.height(), 1, 0), out(a.width(), a.height(), 1, 0);
  for (size_t i = 0; i < m.size(); ++i)
    m.data()[i] = (a.data()[i] > 0.f && (a.data()[i] + 1e-3f < b.data()[i] || !(b.data()[i] > 0.f)))
                      ? 255 : 0;
  for (int y = 0; y < m.height(); ++y)
    for (int x = 0; x < m.width(); ++x)
      for (int dy = -dilate; dy <= dilate && !out.at(x, y); ++dy)
        for (int dx = -dilate; dx <= dilate; ++dx)
          if (m.Contains(x + dx, y + dy) && m.at(x + dx, y + dy)) {
            out.at(x, y) = 255;
            break;
          }
  return out;
}

// The operator paints over the chair seen from `pose`: stroke points every 3 px (scaled with the
// width from 320 px) on its pixels away from its outline, r_ROI 4 px (scaled), d_ROI 10 cm.
inline v1::MarkRegionRequest ChairMarkRequest(const ChairScene& scene, const Rigid3d& pose) {
  auto a = synth::RenderFrame(*scene.with, pose, scene.ro);
  auto b = synth::RenderFrame(*scene.without, pose, scene.ro);
  EXO_CHECK(a.ok() && b.ok());
  const ImageU8 chair = ChairPixels(*a, *b, 0);
  const int step = std::max(3, 3 * scene.ro.width / 320), edge = std::max(2, 2 * scene.ro.width / 320);
  v1::MarkRegionRequest req;
  IntrinsicsToProto(scene.ro.Camera(), req.mutable_camera());
  PoseToProto(pose, req.mutable_world_from_cam());
  for (int y = edge; y + edge < chair.height(); y += step)
    for (int x = edge; x + edge < chair.width(); x += step) {
      bool inside = true;
      for (int d = -edge; d <= edge && inside; ++d) inside = chair.at(x + d, y) && chair.at(x, y + d);
      if (!inside) continue;
      auto* p = req.add_stroke();
      p->set_x(x);
      p->set_y(y);
    }
  req.set_radius_px(4.0 * scene.ro.width / 320);
  req.set_depth_tolerance_m(0.1);
  req.set_label("chair");
  return req;
}

}  // namespace exo::testing
