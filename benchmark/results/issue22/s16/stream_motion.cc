#include <cstdio>
#include <cmath>
#include <vector>
#include <algorithm>
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
using namespace exo;
static double Angle(const glm::dquat& a, const glm::dquat& b) {
  double d = std::abs(glm::dot(a, b)); d = std::min(1.0, d); return 2 * std::acos(d);
}
int main(int argc, char** argv) {
  for (const char* sc : {"apartment", "village"})
    for (const char* tr : {"drone", "handheld"})
      for (int seed = 1; seed <= 3; ++seed) {
        synth::SceneOptions so; so.seed = seed;
        auto kind = synth::ParseSceneKind(sc); auto scene = synth::MakeScene(*kind, so);
        synth::TrajectoryOptions to; to.num_frames = 5000; to.seed = seed;
        auto tk = synth::ParseTrajectoryKind(tr);
        auto traj = synth::MakeTrajectory(*scene, *tk, to);
        double st = 0, sr = 0, sa = 0; std::vector<double> ratios;
        for (size_t i = 1; i < traj->size(); ++i) {
          const auto& a = (*traj)[i - 1].local_from_cam; const auto& b = (*traj)[i].local_from_cam;
          st += glm::length(a.translation - b.translation); sr += Angle(a.rotation, b.rotation);
          const glm::dvec3 za = a.rotation * glm::dvec3(0,0,1), zb = b.rotation * glm::dvec3(0,0,1);
          sa += 2 * std::asin(std::min(1.0, 0.5 * glm::length(za - zb)));
        }
        std::printf("%s %s seed %d: path %.1f m, turn %.1f rad, axis turn %.1f rad (%.2f), ratio %.3f m/rad, extent %.1f\n", sc, tr, seed, st, sr, sa, sa / sr, st / sr, scene->ExtentM());
      }
}
