// Load shedding of the geometry stage (GeometryStageOptions::shed_backlog_fraction): with a
// backlog the stage skips fusing (at most shed_max_run frames in a row), still hands one update
// per frame to planning, and counts what it shed; without a backlog, or with shedding off, every
// frame is fused. Chunk refresh under a budget (republish_extraction_factor, refresh_budget_kbps).
#include "server/service/geometry_stage.h"

#include <gtest/gtest.h>

#include <set>

#include "proto/frame_proto.h"
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
  // The same surface every frame (stream time 0.1 s * seq); `noise_m` > 0 adds per-pixel depth
  // noise (a fixed pseudo-random pattern per frame), so the fused surface moves as it converges.
  // `valid_cols` > 0 keeps only the first columns' depth (the rest invalid): a surface that
  // grows frame by frame changes its chunks' triangle counts (structural changes).
  void Run(uint64_t seq, size_t queued, float noise_m = 0.0f, int valid_cols = 0) {
    PipelineFrame f;
    f.frame = wire_test::SmallFrame(32, 24, seq);
    if (valid_cols > 0)
      for (int y = 0; y < f.frame.depth_m.height(); ++y)
        for (int x = valid_cols; x < f.frame.depth_m.width(); ++x) f.frame.depth_m.at(x, y) = 0.0f;
    if (noise_m > 0.0f) {
      uint32_t state = static_cast<uint32_t>(seq) * 2654435761u + 1u;
      for (int y = 0; y < f.frame.depth_m.height(); ++y)
        for (int x = 0; x < f.frame.depth_m.width(); ++x) {
          state = state * 1664525u + 1013904223u;
          f.frame.depth_m.at(x, y) += noise_m * (static_cast<float>(state >> 8) / 8388608.0f - 1.0f);
        }
    }
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


// Chunk refresh (issue 15): the same surface fused again and again makes every chunk due at
// extraction counts 1, 2, 3, 5, 8, ... (factor 1.5); unlimited, each chunk is re-sent ~log_1.5 n
// times; under a budget the refreshed bytes stay within rate x stream time + burst; off, none.
struct RefreshRun {
  uint64_t first_bytes = 0, refresh_bytes = 0, refreshes = 0, chunks = 0;
  double counter = 0, still = 0;
};
RefreshRun RunRefresh(double factor, double kbps, int frames, double min_move = 0.0,
                      float noise_m = 0.0f) {
  GeometryStageOptions go;
  go.shed_backlog_fraction = 0.0;
  go.republish_extraction_factor = factor;
  go.refresh_budget_kbps = kbps;
  go.refresh_min_move_voxels = min_move;
  go.refresh_burst_s = 1.0;
  Rig rig(go);
  RefreshRun r;
  std::set<uint64_t> seen;
  uint64_t version = rig.store.version();
  for (int s = 1; s <= frames; ++s) {
    rig.Run(static_cast<uint64_t>(s), 0, noise_m);
    auto deltas = rig.store.DeltasAfter(version, 1 << 20, 0);
    EXO_CHECK(deltas.ok());
    for (const auto& d : *deltas) {
      if (!d->has_mesh_chunk_upserted()) continue;
      const uint64_t bytes = d->mesh_chunk_upserted().ByteSizeLong();
      if (seen.insert(d->mesh_chunk_upserted().chunk_id()).second) {
        r.first_bytes += bytes;
      } else {
        r.refresh_bytes += bytes;
        ++r.refreshes;
      }
    }
    version = rig.store.version();
  }
  r.chunks = seen.size();
  r.counter = rig.Counter("geometry.chunks_refreshed");
  r.still = rig.Counter("geometry.refresh_skipped_still");
  return r;
}

TEST(GeometryStage, RefreshFollowsExtractionGrowthWithinTheBudget) {
  const int frames = 60;  // 6 s of stream time
  const RefreshRun off = RunRefresh(0.0, 0.0, frames);
  const RefreshRun all = RunRefresh(1.5, 0.0, frames);
  const RefreshRun budget = RunRefresh(1.5, 4.0, frames);  // 500 bytes per stream second
  ASSERT_GT(off.chunks, 0u);
  EXPECT_EQ(off.refreshes, 0u);
  EXPECT_EQ(off.counter, 0);
  // Extraction counts 1 -> 2, 3, 5, 8, 12, 18, 27, 41 (60 frames): 8 refreshes per chunk at most
  // (a chunk first extracted later has fewer).
  EXPECT_GE(all.refreshes, all.chunks * 5);
  EXPECT_LE(all.refreshes, all.chunks * 8);
  EXPECT_EQ(all.counter, static_cast<double>(all.refreshes));
  EXPECT_EQ(all.first_bytes, off.first_bytes);  // new chunks are never held back
  EXPECT_GT(budget.refreshes, 0u);
  EXPECT_LT(budget.refreshes, all.refreshes);
  // Tokens accrue from the second frame on: 5.9 s x 500 B/s, the estimate errs high (~10 %).
  EXPECT_LE(budget.refresh_bytes, 5.9 * 500 * 1.15);
  EXPECT_EQ(budget.first_bytes, off.first_bytes);
}


// A surface that no longer moves is not re-sent (refresh_min_move_voxels): the same frame fused
// again and again gives the same mesh, so nothing goes out; a noisy surface converging is
// re-sent while it moves, and less often than without the gate.
TEST(GeometryStage, RefreshSkipsSurfacesThatDoNotMove) {
  const int frames = 60;
  const RefreshRun still = RunRefresh(1.5, 0.0, frames, 0.1);
  EXPECT_EQ(still.refreshes, 0u);
  EXPECT_GT(still.still, 0);
  const RefreshRun noisy_all = RunRefresh(1.5, 0.0, frames, 0.0, 0.01f);
  const RefreshRun noisy = RunRefresh(1.5, 0.0, frames, 0.1, 0.01f);
  EXPECT_GT(noisy.refreshes, 0u);
  EXPECT_GT(noisy.still, 0);
  EXPECT_LT(noisy.refreshes, noisy_all.refreshes);
}

// Structural changes (triangle count beyond republish_change_fraction) of chunks the clients
// already have share the refresh bucket when budget_structural is on: the re-published bytes stay
// within rate x stream time + burst + one chunk of debt; off, they go out at once. New chunks are
// never held back, and with an unlimited budget nothing changes.
struct GrowRun {
  uint64_t first_bytes = 0, again_bytes = 0, again = 0, max_chunk = 0;
  double structural_counter = 0;
};
GrowRun RunGrowing(bool budget_structural, double kbps) {
  GeometryStageOptions go;
  go.shed_backlog_fraction = 0.0;
  go.refresh_budget_kbps = kbps;
  go.refresh_burst_s = 0.5;
  go.budget_structural = budget_structural;
  go.publish_lod_error_voxels = 0.0;
  Rig rig(go);
  GrowRun r;
  std::set<uint64_t> seen;
  uint64_t version = rig.store.version();
  for (int s = 1; s <= 32; ++s) {
    rig.Run(static_cast<uint64_t>(s), 0, 0.0f, s);  // 1 ... 32 valid columns
    auto deltas = rig.store.DeltasAfter(version, 1 << 20, 0);
    EXO_CHECK(deltas.ok());
    for (const auto& d : *deltas) {
      if (!d->has_mesh_chunk_upserted()) continue;
      const uint64_t bytes = d->mesh_chunk_upserted().ByteSizeLong();
      r.max_chunk = std::max(r.max_chunk, bytes);
      if (seen.insert(d->mesh_chunk_upserted().chunk_id()).second) {
        r.first_bytes += bytes;
      } else {
        r.again_bytes += bytes;
        ++r.again;
      }
    }
    version = rig.store.version();
  }
  r.structural_counter = rig.Counter("geometry.published_bytes_structural");
  return r;
}

TEST(GeometryStage, StructuralChangesShareTheBudgetWhenAsked) {
  const GrowRun at_once = RunGrowing(false, 2.0);  // 250 bytes per stream second
  const GrowRun budgeted = RunGrowing(true, 2.0);
  const GrowRun unlimited_on = RunGrowing(true, 0.0);
  const GrowRun unlimited_off = RunGrowing(false, 0.0);
  ASSERT_GT(at_once.structural_counter, 0);  // the growing surface makes structural changes
  EXPECT_EQ(budgeted.first_bytes, at_once.first_bytes);  // new chunks are never held back
  EXPECT_LT(budgeted.again_bytes, at_once.again_bytes);
  // 31 frames of 0.1 s after the first: 3.1 s x 250 B/s + 0.5 s burst + one chunk of debt.
  EXPECT_LE(budgeted.again_bytes, 3.1 * 250 + 0.5 * 250 + budgeted.max_chunk);
  // Unlimited: budget_structural has no effect.
  EXPECT_EQ(unlimited_on.first_bytes, unlimited_off.first_bytes);
  EXPECT_EQ(unlimited_on.again_bytes, unlimited_off.again_bytes);
  EXPECT_EQ(unlimited_on.again, unlimited_off.again);
}

TEST(GeometryStage, RefreshOptionsValidated) {
  GeometryStageOptions go;
  go.refresh_budget_kbps = -1;
  EXPECT_FALSE(go.Validate().ok());
  go = {};
  go.refresh_burst_s = 0;
  EXPECT_FALSE(go.Validate().ok());
  go = {};
  go.republish_extraction_factor = 1.0;
  EXPECT_FALSE(go.Validate().ok());
  go = {};
  go.refresh_min_move_voxels = -0.5;
  EXPECT_FALSE(go.Validate().ok());
}

// The clients' proxy LOD (publish_lod_error_voxels): the published chunks carry fewer triangles
// than the full mesh, the counters add up to what went out, and the server's own mesh (what
// planning gets through the hand-off) is the full one.
TEST(GeometryStage, PublishedChunksAreSimplifiedWithinTheLod) {
  auto run = [](double lod_voxels, uint64_t* handed_triangles, double* counter_out) {
    GeometryStageOptions go;
    go.shed_backlog_fraction = 0.0;
    go.republish_extraction_factor = 0.0;
    go.publish_lod_error_voxels = lod_voxels;
    Rig rig(go);
    uint64_t published = 0;
    *handed_triangles = 0;
    for (uint64_t s = 1; s <= 4; ++s) {
      const uint64_t v = rig.store.version();
      rig.Run(s, 0);
      auto deltas = rig.store.DeltasAfter(v, 1 << 20, 0);
      EXO_CHECK(deltas.ok());
      for (const auto& d : *deltas)
        if (d->has_mesh_chunk_upserted()) {
          auto m = MeshFromProto(d->mesh_chunk_upserted());
          EXO_CHECK(m.ok());
          published += m->num_triangles();
        }
      while (auto u = rig.handoff->Pop())
        for (const MeshChunk& c : u->chunks) *handed_triangles += c.mesh.num_triangles();
    }
    *counter_out = rig.Counter("geometry.lod_triangles_out");
    EXPECT_EQ(rig.Counter("geometry.lod_fallbacks") >= 0, true);
    return published;
  };
  uint64_t handed_full = 0, handed_lod = 0;
  double out_full = 0, out_lod = 0;
  const uint64_t full = run(0.0, &handed_full, &out_full);
  const uint64_t lod = run(1.0, &handed_lod, &out_lod);
  ASSERT_GT(full, 0u);
  EXPECT_LT(lod * 2, full) << "the LOD should at least halve a plane's triangles";
  EXPECT_EQ(out_full, 0.0);
  EXPECT_EQ(out_lod, static_cast<double>(lod));
  EXPECT_EQ(handed_lod, handed_full);  // planning sees the full mesh either way
}

// Scene completion's colour guide (session 16): with a coloured map the stage keeps every chunk
// it extracts at full resolution with its fused vertex colours (the published chunks, LOD and
// wire format 3, carry none): as many triangles as planning gets, one colour per vertex.
TEST(GeometryStage, KeepsTheFullResolutionColouredChunksForCompletion) {
  GeometryStageOptions go;
  go.shed_backlog_fraction = 0.0;
  Rig rig(go);
  auto coloured = std::make_shared<ObservedChunks>();
  core::OnlineModelOptions mo;
  auto s = MakeGeometryStage(go, mo, rig.handoff, nullptr, coloured);
  ASSERT_TRUE(s.ok()) << s.status();
  rig.stage = std::move(*s);
  uint64_t handed = 0;
  for (uint64_t q = 1; q <= 3; ++q) {
    rig.Run(q, 0);
    while (auto u = rig.handoff->Pop())
      for (const MeshChunk& c : u->chunks) handed = std::max<uint64_t>(handed, c.mesh.num_triangles());
  }
  const TriangleMesh m = coloured->Merged();
  ASSERT_GT(m.num_triangles(), 0u);
  EXPECT_EQ(m.colors.size(), m.positions.size());
  EXPECT_TRUE(m.normals.empty());
  EXPECT_GE(m.num_triangles(), handed);  // the full mesh (the published one is simplified)
  EXPECT_GT(coloured->size(), 0u);
}

TEST(GeometryStage, LodOptionValidated) {
  GeometryStageOptions go;
  go.publish_lod_error_voxels = -1;
  EXPECT_FALSE(go.Validate().ok());
  go.publish_lod_error_voxels = 11;
  EXPECT_FALSE(go.Validate().ok());
  go.publish_lod_error_voxels = 0.5;
  EXPECT_TRUE(go.Validate().ok());
}

}  // namespace
}  // namespace exo
