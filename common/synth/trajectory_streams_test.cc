// Issue 22 streams (drone, handheld): deterministic from the seed and a prefix of any longer
// stream; long (5 400 frames = 3 min at 30 Hz); every frame in free space; hovers really still
// and several seconds long; pans fast; revisits really come back to an earlier place after going
// away; variable speed.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <vector>

#include <gtest/gtest.h>

#include "common/synth/scene.h"
#include "common/synth/trajectory.h"

namespace exo::synth {
namespace {

constexpr int kLong = 5400;

std::vector<TimedPose> Make(SceneKind sk, TrajectoryKind tk, int n, uint64_t seed) {
  auto scene = MakeScene(sk, {});
  EXPECT_TRUE(scene.ok());
  TrajectoryOptions to;
  to.num_frames = n;
  to.seed = seed;
  auto t = MakeTrajectory(*scene, tk, to);
  EXPECT_TRUE(t.ok()) << t.status();
  return t.ok() ? *t : std::vector<TimedPose>{};
}

struct Case {
  SceneKind scene;
  TrajectoryKind traj;
};
const Case kCases[] = {{SceneKind::kVillage, TrajectoryKind::kDrone},
                       {SceneKind::kApartment, TrajectoryKind::kDrone},
                       {SceneKind::kVillage, TrajectoryKind::kHandheld},
                       {SceneKind::kApartment, TrajectoryKind::kHandheld}};
std::string Name(const Case& c) {
  return std::string(SceneKindName(c.scene)) + "/" + TrajectoryKindName(c.traj);
}

bool SamePose(const TimedPose& a, const TimedPose& b) {
  return a.local_from_cam.translation == b.local_from_cam.translation &&
         a.local_from_cam.rotation == b.local_from_cam.rotation && a.motion == b.motion &&
         a.place == b.place && a.timestamp_s == b.timestamp_s;
}

TEST(TrajectoryStreamsTest, DeterministicPrefixOfLongerStreamAndSeeded) {
  for (const Case& c : kCases) {
    const auto a = Make(c.scene, c.traj, 1500, 3);
    const auto b = Make(c.scene, c.traj, 1500, 3);
    const auto longer = Make(c.scene, c.traj, 4000, 3);
    const auto other = Make(c.scene, c.traj, 1500, 4);
    ASSERT_EQ(a.size(), 1500u);
    ASSERT_EQ(longer.size(), 4000u);
    size_t differ = 0;
    for (size_t i = 0; i < a.size(); ++i) {
      EXPECT_TRUE(SamePose(a[i], b[i])) << Name(c) << " frame " << i;
      EXPECT_TRUE(SamePose(a[i], longer[i])) << Name(c) << " frame " << i;
      if (glm::length(a[i].local_from_cam.translation - other[i].local_from_cam.translation) > 0.1)
        ++differ;
    }
    EXPECT_GT(differ, 1000u) << Name(c) << ": another seed gives another stream";
  }
}

TEST(TrajectoryStreamsTest, LongFreeSmoothStillHoversFastPansRevisitsVariableSpeed) {
  for (const Case& c : kCases) {
    auto scene = MakeScene(c.scene, {});
    ASSERT_TRUE(scene.ok());
    const auto t = Make(c.scene, c.traj, kLong, 1);
    ASSERT_EQ(t.size(), size_t(kLong)) << Name(c);
    const bool drone = c.traj == TrajectoryKind::kDrone;
    const double hz = 30;
    double max_step = 0, max_turn_deg = 0;
    std::vector<double> move_speed;
    std::map<Motion, int> count;
    for (size_t i = 0; i < t.size(); ++i) {
      const Rigid3d& p = t[i].local_from_cam;
      ++count[t[i].motion];
      EXPECT_NEAR(t[i].timestamp_s, i / hz, 1e-9);
      ASSERT_TRUE(scene->IsFree(p.translation, 0.2))
          << Name(c) << " frame " << i << " at " << p.translation.x << "," << p.translation.y
          << "," << p.translation.z;
      EXPECT_EQ(t[i].place < 0, t[i].motion == Motion::kMove) << Name(c) << " frame " << i;
      if (i == 0) continue;
      const Rigid3d& q = t[i - 1].local_from_cam;
      const double step = glm::length(p.translation - q.translation);
      const double turn = glm::degrees(RotationAngleRad(p.rotation, q.rotation));
      max_step = std::max(max_step, step);
      max_turn_deg = std::max(max_turn_deg, turn);
      if (t[i].motion == Motion::kMove && t[i - 1].motion == Motion::kMove)
        move_speed.push_back(step * hz);
    }
    // Drone: at most 8 m/s outdoors; handheld 1.4 m/s plus shake and bob. Turns at most 180
    // deg/s (the fastest pan) plus the shake.
    EXPECT_LT(max_step, (drone ? 8.0 : 1.6) / hz) << Name(c);
    EXPECT_LT(max_turn_deg, 180.0 / hz + 0.5) << Name(c);

    // Still segments: every complete hover is >= 3 s and exactly still; every handheld stop
    // (hand shake only, 1 cm per axis) moves < 4 cm and is >= 1.5 s.
    const Motion hold = drone ? Motion::kHover : Motion::kStop;
    int holds = 0;
    for (size_t i = 0; i < t.size();) {
      if (t[i].motion != hold) {
        ++i;
        continue;
      }
      size_t j = i;
      double spread = 0, spin = 0;
      while (j < t.size() && t[j].motion == hold) {
        spread = std::max(spread, glm::length(t[j].local_from_cam.translation -
                                              t[i].local_from_cam.translation));
        spin = std::max(spin, glm::degrees(RotationAngleRad(t[j].local_from_cam.rotation,
                                                            t[i].local_from_cam.rotation)));
        ++j;
      }
      if (j < t.size()) {  // complete (not cut by the end of the stream)
        ++holds;
        EXPECT_GE(double(j - i) / hz, drone ? 3.0 - 1e-9 : 1.5 - 1e-9) << Name(c) << " at " << i;
      }
      if (drone) {
        EXPECT_EQ(spread, 0.0) << Name(c) << " hover at " << i;
        EXPECT_LT(spin, 1e-6) << Name(c) << " hover at " << i;
      } else {
        EXPECT_LT(spread, 0.04) << Name(c) << " stop at " << i;
        EXPECT_LT(spin, 2.0) << Name(c) << " stop at " << i;
      }
      i = j;
    }
    EXPECT_GE(holds, 8) << Name(c);
    EXPECT_GT(count[hold], kLong / 20) << Name(c) << ": at least 5 % of the stream held still";

    // Pans / look-arounds: on the spot, fast (drone >= 90 deg/s, handheld >= 40 deg/s).
    const Motion turn = drone ? Motion::kPan : Motion::kLookAround;
    EXPECT_GT(count[turn], kLong / 50) << Name(c);
    double turn_sum = 0;
    int turn_frames = 0;
    for (size_t i = 1; i < t.size(); ++i) {
      if (t[i].motion != turn || t[i - 1].motion != turn || t[i].place != t[i - 1].place) continue;
      const double d = glm::length(t[i].local_from_cam.translation -
                                   t[i - 1].local_from_cam.translation);
      EXPECT_LT(d, drone ? 1e-12 : 0.01) << Name(c) << " pan frame " << i;
      turn_sum += glm::degrees(RotationAngleRad(t[i].local_from_cam.rotation,
                                                t[i - 1].local_from_cam.rotation));
      ++turn_frames;
    }
    // Mean rate over turning frames (pauses between the legs of a look-around included).
    EXPECT_GT(turn_sum / turn_frames * hz, drone ? 80.0 : 25.0) << Name(c);

    // Revisits: a place whose visits are separated by a stretch away from it (> 2 m on foot or
    // indoors, > 10 m for the outdoor drone), coming back to the first visit's position (within
    // the hand shake on foot).
    std::map<int, std::vector<size_t>> visit_start;  // place -> frames where a visit begins
    for (size_t i = 0; i < t.size(); ++i)
      if (t[i].place >= 0 && (i == 0 || t[i - 1].place != t[i].place))
        visit_start[t[i].place].push_back(i);
    const double away = drone && !scene->indoor ? 10.0 : 2.0;
    int revisits = 0;
    for (const auto& [place, starts] : visit_start)
      for (size_t k = 1; k < starts.size(); ++k) {
        const glm::dvec3 p0 = t[starts[0]].local_from_cam.translation;
        const glm::dvec3 pk = t[starts[k]].local_from_cam.translation;
        EXPECT_LT(glm::length(pk - p0), drone ? 1e-9 : 0.05) << Name(c) << " place " << place;
        double farthest = 0;
        for (size_t i = starts[k - 1]; i < starts[k]; ++i)
          farthest = std::max(farthest, glm::length(t[i].local_from_cam.translation - p0));
        EXPECT_GT(farthest, away) << Name(c) << " place " << place;
        ++revisits;
      }
    EXPECT_GE(revisits, 2) << Name(c);

    // Variable speed: the travelling frames' speeds spread (p90 / p50 > 1.15 and cruise speeds
    // of several legs).
    std::sort(move_speed.begin(), move_speed.end());
    const double p50 = move_speed[move_speed.size() / 2];
    const double p90 = move_speed[move_speed.size() * 9 / 10];
    EXPECT_GT(p90 / p50, 1.15) << Name(c);
    std::printf("%s: %d frames, move %d hold %d turn %d, %d holds, %d revisits, speed p50 %.2f p90 "
                "%.2f m/s, max step %.3f m, max turn %.2f deg/frame\n",
                Name(c).c_str(), kLong, count[Motion::kMove], count[hold], count[turn], holds,
                revisits, p50, p90, max_step, max_turn_deg);
  }
}

TEST(TrajectoryStreamsTest, NamesParseAndBadOptionsFail) {
  for (TrajectoryKind k : {TrajectoryKind::kDrone, TrajectoryKind::kHandheld}) {
    auto p = ParseTrajectoryKind(TrajectoryKindName(k));
    ASSERT_TRUE(p.ok());
    EXPECT_EQ(*p, k);
  }
  auto scene = MakeScene(SceneKind::kApartment, {});
  ASSERT_TRUE(scene.ok());
  TrajectoryOptions to;
  to.num_frames = 0;
  EXPECT_FALSE(MakeTrajectory(*scene, TrajectoryKind::kDrone, to).ok());
  to.num_frames = 10;
  to.frame_rate_hz = 0;
  EXPECT_FALSE(MakeTrajectory(*scene, TrajectoryKind::kHandheld, to).ok());
}

}  // namespace
}  // namespace exo::synth
