// Tests of view refinement on an analytic ray-cast room with known pose and exposure.
#include "server/refinement/view_refiner.h"

#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "server/refinement/testing/room_scene.h"

namespace exo {
namespace {

using refinement_testing::LookAt;
using refinement_testing::Perturb;
using refinement_testing::RenderRoom;
using refinement_testing::RoomScene;

struct RoomSetup {
  RoomScene scene;
  PinholeCamera cam;
  std::vector<StoredView> refs;
  Rigid3d cand_true;
  std::vector<const StoredView*> RefPtrs() const {
    std::vector<const StoredView*> p;
    for (const auto& r : refs) p.push_back(&r);
    return p;
  }
};

RoomSetup MakeSetup(int num_refs, int w = 160, int h = 120, RoomScene scene = {}) {
  RoomSetup s;
  s.scene = scene;
  s.cam = PinholeCamera::FromFov(w, h, 65.0 * M_PI / 180.0);
  const glm::dvec3 target{0.3, 0.3, 2.5};
  s.cand_true = LookAt({0.0, -0.1, -1.4}, target);
  const glm::dvec3 eyes[4] = {{-0.35, -0.2, -1.6}, {0.4, 0.0, -1.5}, {0.1, -0.35, -1.2},
                              {-0.2, 0.15, -1.8}};
  for (int i = 0; i < num_refs; ++i) {
    StoredView v = RenderRoom(s.scene, s.cam, LookAt(eyes[i], target + glm::dvec3(0.1 * i, 0, 0)), 1.0);
    v.id = i + 1;
    s.refs.push_back(std::move(v));
  }
  return s;
}

double RotErrDeg(const Rigid3d& a, const Rigid3d& b) {
  return RotationAngleRad(a.rotation, b.rotation) * 180.0 / M_PI;
}
double TransErrM(const Rigid3d& a, const Rigid3d& b) {
  return glm::length(a.translation - b.translation);
}

TEST(ViewRefinerTest, Explore) {
  const RoomSetup s = MakeSetup(4);
  const auto refs = s.RefPtrs();
  RefinementOptions o;
  for (int trial = 0; trial < 10; ++trial) {
    StoredView cand = RenderRoom(s.scene, s.cam, s.cand_true, 0.7, 1.0, trial);
    cand.local_from_cam = Perturb(s.cand_true, 2.0, 0.02, trial);
    auto r = RefineView(cand, refs, o);
    ASSERT_TRUE(r.ok()) << r.status();
    std::printf("trial %d E=%.4f (1/0.7=%.4f) rot %.3f->%.3f deg trans %.4f->%.4f m  it=%d "
                "ns=%d nv=%d cost %.4f->%.4f rel=%.4f lmin=%.3g cond=%.3g refused=%d outl=%d rev=%d %.1f ms\n",
                trial, r->exposure, 1 / 0.7, RotErrDeg(cand.local_from_cam, s.cand_true),
                RotErrDeg(r->local_from_cam, s.cand_true), TransErrM(cand.local_from_cam, s.cand_true),
                TransErrM(r->local_from_cam, s.cand_true), r->iterations, r->num_samples,
                r->num_valid_final, r->cost_before, r->cost_after, r->relative_residual,
                r->pose_min_eigenvalue, r->pose_condition, r->pose_refused_rank_deficient,
                r->rejected_outlier, r->step_reverted, r->ms);
  }
}

}  // namespace
}  // namespace exo
