// Load shedding of the geometry stage (GeometryStageOptions::shed_backlog_fraction): with a
// backlog the stage skips fusing (at most shed_max_run frames in a row), still hands one update
// per frame to planning, and counts what it shed; without a backlog, or with shedding off, every
// frame is fused.
#include "server/service/geometry_stage.h"

#include <gtest/gtest.h>

#include "proto/test_frames.h"
#include "server/service/model_store.h"

namespace exo {
namespace {

struct Rig {
  ModelStore store;
  SceneContext ctx;
  std::shared_ptr<GeometryHandoff> handoff = std::make_shared<GeometryHandoff>();
  std::unique_ptr<PipelineStage> stage;
  explicit Rig(const GeometryStageOptions& go) {
    core::OnlineModelOptions mo;
    const Frame first = wire_test::SmallFrame(32, 24, 1);
    auto setup = core::ChooseSceneSetup(first, mo, std::nullopt, 0.0);
    EXO_CHECK(setup.ok());
    ctx.setup = *setup;
    ctx.origin = setup->origin;
    ctx.cell_size_m = setup->cell_m;
    ctx.store = &store;
    auto s = MakeGeometryStage(go, mo, handoff);
    EXO_CHECK(s.ok());
    stage = std::move(*s);
  }
  void Run(uint64_t seq, size_t queued) {
    PipelineFrame f;
    f.frame = wire_test::SmallFrame(32, 24, seq);
    stage->SetBacklog(queued, 8);
    ASSERT_TRUE(stage->Process(f, ctx).ok());
  }
  double Counter(const std::string& k) {
    std::map<std::string, double> m;
    stage->AddCounters(&m);
    return m.count(k) ? m[k] : -1.0;
  }
  size_t Handed() {
    size_t n = 0;
    while (handoff->Pop()) ++n;
    return n;
  }
};

TEST(GeometryStage, ShedsUnderBacklogAtMostMaxRunInARow) {
  GeometryStageOptions go;  // defaults: shed at half the queue, at most 2 in a row
  Rig rig(go);
  rig.Run(1, 7);  // the first frame is always fused (it creates the volume)
  for (uint64_t s = 2; s <= 10; ++s) rig.Run(s, 7);  // a full backlog: fuse, shed, shed, ...
  EXPECT_EQ(rig.Counter("geometry.fused"), 4);  // frames 1, 4, 7, 10
  EXPECT_EQ(rig.Counter("geometry.shed"), 6);
  EXPECT_EQ(rig.Handed(), 10u);  // one hand-off per frame, shed or not
  for (uint64_t s = 11; s <= 14; ++s) rig.Run(s, 3);  // below half: everything fused
  EXPECT_EQ(rig.Counter("geometry.fused"), 8);
  EXPECT_EQ(rig.Counter("geometry.shed"), 6);
}

TEST(GeometryStage, NoSheddingWhenOff) {
  GeometryStageOptions go;
  go.shed_backlog_fraction = 0.0;
  Rig rig(go);
  for (uint64_t s = 1; s <= 6; ++s) rig.Run(s, 8);
  EXPECT_EQ(rig.Counter("geometry.fused"), 6);
  EXPECT_EQ(rig.Counter("geometry.shed"), 0);
  EXPECT_EQ(rig.Handed(), 6u);
}

TEST(GeometryStage, OptionsValidated) {
  GeometryStageOptions go;
  go.shed_backlog_fraction = 1.5;
  EXPECT_FALSE(go.Validate().ok());
  go = {};
  go.shed_max_run = 0;
  EXPECT_FALSE(go.Validate().ok());
}

}  // namespace
}  // namespace exo
