// The client's local store on its own (no server): deltas applied in version order, replays and
// gaps refused, snapshots applied atomically at SnapshotEnd, and the digest computed from exactly
// what was received. The test against the server's model store is tests/store_sync_test.cc.
#include "client/store/local_store.h"

#include <gtest/gtest.h>

#include "proto/frame_proto.h"

namespace exo {
namespace {

v1::Delta ViewDelta(uint64_t version, ViewId id) {
  StoredView v;
  v.id = id;
  v.camera = PinholeCamera::FromFov(32, 24, 1.0);
  v.local_from_cam.translation = {0.1 * id, 0.0, 0.0};
  v.color = ImageU8(32, 24, 3, static_cast<uint8_t>(10 * id));
  v.depth_m = ImageF(32, 24, 1, 1.0f + 0.1f * id);
  auto m = ViewToProto(v, {});
  EXO_CHECK(m.ok());
  v1::Delta d;
  d.set_version(version);
  *d.mutable_view_added() = *m;
  return d;
}

v1::Delta SceneDelta(uint64_t version, double origin_x) {
  v1::Delta d;
  d.set_version(version);
  d.mutable_scene_params()->mutable_origin_in_world()->set_x(origin_x);
  d.mutable_scene_params()->set_cell_size_m(0.5);
  return d;
}

v1::Delta CellsDelta(uint64_t version, CellId cell, std::vector<ViewId> views) {
  v1::Delta d;
  d.set_version(version);
  auto* c = d.mutable_cell_refs_changed()->add_cells();
  c->set_cell_id(cell);
  for (ViewId v : views) c->add_view_ids(v);
  return d;
}

v1::Delta ChunkDelta(uint64_t version, uint64_t chunk, const TriangleMesh& mesh) {
  v1::Delta d;
  d.set_version(version);
  MeshToProto(mesh, d.mutable_mesh_chunk_upserted());
  d.mutable_mesh_chunk_upserted()->set_chunk_id(chunk);
  d.mutable_mesh_chunk_upserted()->set_chunk_version(version);
  return d;
}

TriangleMesh Triangle(float z) {
  TriangleMesh m;
  m.positions = {{0, 0, z}, {1, 0, z}, {0, 1, z}};
  m.indices = {0, 1, 2};
  return m;
}

TEST(LocalStore, AppliesDeltasInOrderAndDigestsWhatItReceived) {
  LocalStore s;
  const v1::Delta view = ViewDelta(2, 7);
  const CellId cell = PackCell({3, 0, 0});
  for (const v1::Delta& d :
       {SceneDelta(1, 10.0), view, CellsDelta(3, cell, {7}), ChunkDelta(4, 1, Triangle(2.0f))})
    ASSERT_TRUE(s.Apply(d).ok()) << d.version();
  EXPECT_EQ(s.version(), 4u);
  EXPECT_EQ(s.deltas_applied(), 4u);
  EXPECT_EQ(s.model().origin.origin_in_world.x, 10.0);
  ASSERT_EQ(s.model().views.size(), 1u);
  EXPECT_EQ(s.model().views.at(7).color.at(0, 0, 0), 70);  // decoded JPEG (flat colour)
  EXPECT_EQ(s.model().views.at(7).depth_m.width(), 32);    // depth back at colour size
  EXPECT_EQ(s.model().cell_refs.at(cell), std::vector<ViewId>{7});
  ASSERT_EQ(s.model().chunks.size(), 1u);
  // The digest is the wire library's ModelDigest of exactly the received records.
  std::map<ViewId, ViewDigestRecord> views{{7, DigestRecordFromProto(view.view_added())}};
  // (the mesh as decoded from the wire: the compact encoding quantizes positions)
  const auto received = MeshFromProto(ChunkDelta(4, 1, Triangle(2.0f)).mesh_chunk_upserted());
  ASSERT_TRUE(received.ok());
  std::map<uint64_t, ChunkDigestRecord> chunks{{1, {4, MeshHash(*received)}}};
  EXPECT_EQ(s.Digest(), ModelDigest(views, s.model().cell_refs, chunks));
  // Any change of content changes it.
  const uint64_t before = s.Digest();
  ASSERT_TRUE(s.Apply(ChunkDelta(5, 1, Triangle(2.5f))).ok());
  EXPECT_NE(s.Digest(), before);
}

TEST(LocalStore, ReplayGapAndUnknownIdsAreErrors) {
  LocalStore s;
  ASSERT_TRUE(s.Apply(SceneDelta(1, 0.0)).ok());
  ASSERT_TRUE(s.Apply(ViewDelta(2, 1)).ok());
  const auto replay = s.Apply(ViewDelta(2, 1));
  EXPECT_EQ(replay.code(), absl::StatusCode::kFailedPrecondition);
  const auto gap = s.Apply(ViewDelta(4, 2));
  EXPECT_EQ(gap.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(gap.message().find("delta version 4 does not follow the local version 2"),
            std::string::npos)
      << gap;
  v1::Delta remove;
  remove.set_version(3);
  remove.mutable_view_removed()->set_view_id(99);
  EXPECT_EQ(s.Apply(remove).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(s.version(), 2u);  // nothing refused moved the version
  EXPECT_EQ(s.model().views.size(), 1u);
}

TEST(LocalStore, SnapshotReplacesTheModelOnlyWhenComplete) {
  LocalStore s;
  ASSERT_TRUE(s.Apply(SceneDelta(1, 0.0)).ok());
  ASSERT_TRUE(s.Apply(ViewDelta(2, 1)).ok());
  const uint64_t digest_v2 = s.Digest();
  v1::Delta begin, end;
  begin.mutable_snapshot_begin();
  end.set_version(40);
  end.set_model_epoch(1234);
  end.mutable_snapshot_end();
  ASSERT_TRUE(s.Apply(begin).ok());
  ASSERT_TRUE(s.Apply(SceneDelta(0, 5.0)).ok());
  ASSERT_TRUE(s.Apply(ViewDelta(0, 3)).ok());
  ASSERT_TRUE(s.Apply(ViewDelta(0, 4)).ok());
  // Mid-snapshot: still the previous consistent model (a client cut here resumes from v2).
  EXPECT_TRUE(s.in_snapshot());
  EXPECT_EQ(s.version(), 2u);
  EXPECT_EQ(s.Digest(), digest_v2);
  ASSERT_TRUE(s.model().views.count(1));
  ASSERT_TRUE(s.Apply(end).ok());
  EXPECT_FALSE(s.in_snapshot());
  EXPECT_EQ(s.version(), 40u);
  EXPECT_EQ(s.epoch(), 1234u);
  EXPECT_EQ(s.snapshots_applied(), 1u);
  EXPECT_EQ(s.model().origin.origin_in_world.x, 5.0);
  EXPECT_EQ(s.model().views.size(), 2u);
  EXPECT_FALSE(s.model().views.count(1));  // replaced, not merged
  EXPECT_NE(s.Digest(), digest_v2);
  ASSERT_TRUE(s.Apply(CellsDelta(41, PackCell({0, 0, 0}), {3, 4})).ok());  // deltas go on
  v1::Delta stray_end;
  stray_end.mutable_snapshot_end();
  EXPECT_EQ(s.Apply(stray_end).code(), absl::StatusCode::kFailedPrecondition);
}

// Issue 20: one view with an exposure that is inf as a float made exoview_viewer exit 1. The
// viewer now renders from WithoutUnusableViews: the view is skipped and reported.
TEST(LocalStore, UnusableViewsAreSkippedAndReported) {
  LocalStore s;
  ASSERT_TRUE(s.Apply(SceneDelta(1, 0.0)).ok());
  ASSERT_TRUE(s.Apply(ViewDelta(2, 7)).ok());
  v1::Delta bad = ViewDelta(3, 16);
  bad.mutable_view_added()->set_exposure(std::numeric_limits<float>::infinity());
  ASSERT_TRUE(s.Apply(bad).ok());
  ASSERT_TRUE(s.Apply(CellsDelta(4, 42, {7, 16})).ok());
  std::vector<std::string> skipped;
  std::vector<std::string> none;
  EXPECT_FALSE(WithoutUnusableViews(LumigraphModel{}, &none).has_value());
  EXPECT_TRUE(none.empty());
  const std::optional<LumigraphModel> filtered = WithoutUnusableViews(s.model(), &skipped);
  ASSERT_TRUE(filtered.has_value());
  const LumigraphModel& usable = *filtered;
  ASSERT_EQ(skipped.size(), 1u);
  EXPECT_EQ(skipped[0], "view 16: exposure must be finite and > 0, got inf");
  EXPECT_EQ(usable.views.size(), 1u);
  EXPECT_EQ(usable.views.count(7), 1u);
  EXPECT_EQ(usable.cell_refs.at(42), std::vector<ViewId>{7});
  EXPECT_EQ(s.model().views.size(), 2u);  // the store itself keeps what the server sent
}

TEST(LocalStore, CellCoverageIsKeptPerCellAndOutOfRangeIsAnError) {
  LocalStore s;
  ASSERT_TRUE(s.Apply(SceneDelta(1, 0.0)).ok());
  v1::Delta d = CellsDelta(2, 7, {1});
  auto* c = d.mutable_cell_refs_changed()->add_coverage();
  c->set_cell_id(7);
  c->set_tau_percent(35);
  ASSERT_TRUE(s.Apply(d).ok());
  v1::Delta only;  // coverage without a reference change
  only.set_version(3);
  auto* c2 = only.mutable_cell_refs_changed()->add_coverage();
  c2->set_cell_id(7);
  c2->set_tau_percent(100);
  ASSERT_TRUE(s.Apply(only).ok());
  EXPECT_EQ(s.model().cell_coverage.at(7), 100);
  EXPECT_EQ(s.model().cell_refs.at(7), std::vector<ViewId>{1});
  const uint64_t digest = s.Digest();
  c2->set_tau_percent(101);
  only.set_version(4);
  const absl::Status st = s.Apply(only);
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(st.message().find("above 100"), std::string::npos) << st;
  EXPECT_EQ(s.version(), 3u);  // nothing applied
  EXPECT_EQ(s.Digest(), digest);
}

TEST(LocalStore, PackedCellRefsApplyLikeThePlainOnesAndCorruptOnesChangeNothing) {
  // The server packs CellRefsChanged with zstd (proto/frame_proto.h PackCellRefs).
  v1::Delta plain;
  plain.set_version(2);
  auto* refs = plain.mutable_cell_refs_changed();
  for (CellId cell = 100; cell < 400; ++cell) {
    auto* e = refs->add_cells();
    e->set_cell_id(cell);
    for (ViewId v = 1; v <= 40; ++v) e->add_view_ids(v);
    auto* t = refs->add_coverage();
    t->set_cell_id(cell);
    t->set_tau_percent(static_cast<uint32_t>(cell % 100));
  }
  v1::Delta packed = plain;
  PackCellRefs(packed.mutable_cell_refs_changed());
  ASSERT_FALSE(packed.cell_refs_changed().packed().empty());
  LocalStore a, b;
  for (LocalStore* s : {&a, &b}) ASSERT_TRUE(s->Apply(SceneDelta(1, 0.0)).ok());
  ASSERT_TRUE(a.Apply(plain).ok());
  ASSERT_TRUE(b.Apply(packed).ok());
  EXPECT_EQ(a.Digest(), b.Digest());
  EXPECT_EQ(a.model().cell_refs, b.model().cell_refs);
  EXPECT_EQ(a.model().cell_coverage, b.model().cell_coverage);
  // A corrupt packed delta is an error and leaves the store as it was.
  v1::Delta bad = packed;
  bad.set_version(3);
  std::string p = bad.cell_refs_changed().packed();
  p.resize(p.size() - 3);
  bad.mutable_cell_refs_changed()->set_packed(p);
  const uint64_t digest = b.Digest();
  EXPECT_EQ(b.Apply(bad).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(b.version(), 2u);
  EXPECT_EQ(b.Digest(), digest);
}


TEST(LocalStore, SnapshotChunkBatchesApplyLikeTheChunksAndAreRefusedOutsideASnapshot) {
  // The server's gRPC edge sends a snapshot's chunks as MeshChunkBatch (proto/frame_proto.h
  // PackMeshChunks): the same model and digest as the chunks one by one.
  std::vector<v1::MeshChunkUpserted> chunks;
  for (uint64_t id = 1; id <= 12; ++id) {
    TriangleMesh m;
    const float z = 0.1f * id;
    m.positions = {{0, 0, z}, {1, 0, z}, {0, 1, z}, {1, 1, z}};
    m.indices = {0, 1, 2, 1, 3, 2};
    v1::MeshChunkUpserted c;
    MeshToProto(m, &c, false, {id % 2 ? 0.02f / 32 : 0.0f});
    c.set_chunk_id(id);
    c.set_chunk_version(3 * id);
    chunks.push_back(std::move(c));
  }
  auto snapshot = [&](bool batched, bool corrupt) {
    std::vector<v1::Delta> out;
    v1::Delta begin;
    begin.set_version(9);
    begin.mutable_snapshot_begin();
    out.push_back(begin);
    out.push_back(SceneDelta(9, 0.0));
    out.push_back(ViewDelta(9, 4));
    if (batched) {
      std::vector<const v1::MeshChunkUpserted*> p;
      for (const auto& c : chunks) p.push_back(&c);
      auto b = PackMeshChunks(p);
      EXO_CHECK(b.ok());
      v1::Delta d;
      d.set_version(9);
      *d.mutable_mesh_chunk_batch() = *b;
      if (corrupt) {
        std::string bytes = d.mesh_chunk_batch().packed();
        bytes.resize(bytes.size() - 3);
        d.mutable_mesh_chunk_batch()->set_packed(bytes);
      }
      out.push_back(d);
    } else {
      for (const auto& c : chunks) {
        v1::Delta d;
        d.set_version(9);
        *d.mutable_mesh_chunk_upserted() = c;
        out.push_back(d);
      }
    }
    v1::Delta end;
    end.set_version(9);
    end.set_model_epoch(77);
    end.mutable_snapshot_end();
    out.push_back(end);
    return out;
  };
  LocalStore a, b;
  for (const v1::Delta& d : snapshot(false, false)) ASSERT_TRUE(a.Apply(d).ok());
  for (const v1::Delta& d : snapshot(true, false)) ASSERT_TRUE(b.Apply(d).ok());
  EXPECT_EQ(a.version(), 9u);
  EXPECT_EQ(b.version(), 9u);
  EXPECT_EQ(b.model().chunks.size(), chunks.size());
  EXPECT_EQ(a.Digest(), b.Digest());
  for (const auto& [id, c] : a.model().chunks) {
    ASSERT_TRUE(b.model().chunks.count(id));
    EXPECT_EQ(b.model().chunks.at(id).version, c.version);
    EXPECT_EQ(b.model().chunks.at(id).mesh.positions, c.mesh.positions);
  }
  // Outside a snapshot a batch is refused (it has no place in the version order).
  v1::Delta live = snapshot(true, false)[3];
  ASSERT_TRUE(live.has_mesh_chunk_batch());
  live.set_version(10);
  EXPECT_EQ(b.Apply(live).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(b.version(), 9u);
  // A corrupt batch inside a snapshot is an error; the model held before stays.
  const uint64_t digest = b.Digest();
  const auto bad = snapshot(true, true);
  absl::Status st;
  for (const v1::Delta& d : bad)
    if (st = b.Apply(d); !st.ok()) break;
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument) << st;
  EXPECT_EQ(b.version(), 9u);
  EXPECT_EQ(b.Digest(), digest);
}

}  // namespace
}  // namespace exo
