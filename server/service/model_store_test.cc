// Versioned model store / publisher: resume with only the missed deltas, snapshot when the log
// was compacted, slow subscriber switched to a snapshot, digest equality.
#include "server/service/model_store.h"

#include <gtest/gtest.h>

namespace exo {
namespace {

v1::ViewAdded View(ViewId id, size_t jpeg_bytes = 100) {
  v1::ViewAdded v;
  v.set_view_id(id);
  v.set_color_jpeg(std::string(jpeg_bytes, static_cast<char>('a' + id % 26)));
  v.mutable_local_from_cam()->mutable_quaternion()->set_w(1.0);
  v.set_exposure(1.0f);
  return v;
}

std::vector<DeltaPtr> Drain(Subscription& s) {
  std::vector<DeltaPtr> all;
  for (;;) {
    auto b = s.Next(0);
    if (b.empty()) break;
    all.insert(all.end(), b.begin(), b.end());
  }
  return all;
}

TEST(ModelStore, ResumeGetsOnlyMissedDeltas) {
  ModelStore store;
  for (ViewId i = 1; i <= 5; ++i) store.AddView(View(i));
  auto sub = store.Subscribe(3, store.EpochAt(3));
  auto d = Drain(*sub);
  ASSERT_EQ(d.size(), 2u);  // versions 4 and 5 only
  EXPECT_EQ(d[0]->version(), 4u);
  EXPECT_EQ(d[1]->view_added().view_id(), 5u);
  EXPECT_EQ(sub->snapshots(), 0u);
}

TEST(ModelStore, CompactedLogGivesSnapshot) {
  ModelStoreOptions o;
  o.max_log_deltas = 3;  // guard under test: the log bound + snapshot fallback
  ModelStore store(o);
  for (ViewId i = 1; i <= 10; ++i) store.AddView(View(i));
  ASSERT_TRUE(store.RemoveView(2).ok());
  auto sub = store.Subscribe(2, store.EpochAt(2));  // versions 3..8 are compacted away
  auto d = Drain(*sub);
  ASSERT_GE(d.size(), 2u);
  EXPECT_TRUE(d.front()->has_snapshot_begin());
  EXPECT_TRUE(d.back()->has_snapshot_end());
  int views = 0;
  for (auto& x : d) views += x->has_view_added();
  EXPECT_EQ(views, 9);
  EXPECT_EQ(d.back()->version(), 11u);
}

TEST(ModelStore, SlowSubscriberIsResyncedAndDoesNotBlockWriters) {
  ModelStoreOptions o;
  o.max_subscriber_lag = 4;
  ModelStore store(o);
  auto slow = store.Subscribe(0, 0);
  for (ViewId i = 1; i <= 20; ++i) store.AddView(View(i));  // never blocks
  auto d = slow->Next(0);
  ASSERT_FALSE(d.empty());
  EXPECT_TRUE(d.front()->has_snapshot_begin());
  EXPECT_EQ(slow->snapshots(), 1u);
  EXPECT_EQ(slow->sent_version(), 20u);
}

TEST(ModelStore, SnapshotWhenCheaperThanDeltas) {
  ModelStore store;
  store.AddView(View(1, 10000));
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(store.UpdateView(1, Rigid3d{}, 1.0f + i).ok());
  // Many large adds that are later removed: replaying costs more than the tiny final model.
  for (ViewId i = 2; i <= 6; ++i) store.AddView(View(i, 20000));
  for (ViewId i = 2; i <= 6; ++i) ASSERT_TRUE(store.RemoveView(i).ok());
  auto sub = store.Subscribe(1, store.EpochAt(1));
  auto d = Drain(*sub);
  ASSERT_FALSE(d.empty());
  EXPECT_TRUE(d.front()->has_snapshot_begin());
}

TEST(ModelStore, DigestChangesWithEveryKindOfMutation) {
  ModelStore store;
  uint64_t last = store.GetSummary().digest;
  auto changed = [&] {
    const uint64_t d = store.GetSummary().digest;
    const bool c = d != last;
    last = d;
    return c;
  };
  store.AddView(View(1));
  EXPECT_TRUE(changed());
  ASSERT_TRUE(store.UpdateView(1, Rigid3d{}, 2.0f).ok());
  EXPECT_TRUE(changed());
  store.SetCellRefs({{PackCell({1, 2, 3}), {1}}});
  EXPECT_TRUE(changed());
  TriangleMesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  m.indices = {0, 1, 2};
  store.UpsertChunk(9, 1, m);
  EXPECT_TRUE(changed());
  ASSERT_TRUE(store.RemoveChunk(9).ok());
  EXPECT_TRUE(changed());
  EXPECT_FALSE(store.RemoveView(42).ok());
}

// Checkpoint round trip (SPEC §12): the restored store has the same version and digest, the
// log tail lets a client behind the checkpoint resume with only its missed deltas (without the
// tail it would need a snapshot), new versions continue after the checkpoint, and a corrupt
// (non-contiguous) tail is refused.
TEST(ModelStore, CheckpointRestoresVersionDigestAndLogTail) {
  ModelStore a;
  LocalOrigin origin;
  origin.origin_in_world = {1.0, 2.0, 3.0};
  a.SetSceneParams(origin, 0.5);
  for (ViewId i = 1; i <= 6; ++i) a.AddView(View(i));
  a.SetCellRefs({{42, {1, 2}}, {43, {3}}});
  TriangleMesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  m.indices = {0, 1, 2};
  a.UpsertChunk(9, 3, m);
  ASSERT_TRUE(a.RemoveView(2).ok());
  const v1::Checkpoint c = a.MakeCheckpoint(size_t{1} << 20);
  ASSERT_EQ(c.version(), a.version());

  ModelStore b;
  ASSERT_TRUE(b.RestoreCheckpoint(c).ok());
  EXPECT_EQ(b.version(), a.version());
  EXPECT_EQ(b.GetSummary().digest, a.GetSummary().digest);
  EXPECT_EQ(b.GetSummary().num_views, 5u);
  auto sub = b.Subscribe(a.version() - 2, a.EpochAt(a.version() - 2));
  auto d = Drain(*sub);
  ASSERT_EQ(d.size(), 2u);
  EXPECT_EQ(sub->snapshots(), 0u);
  EXPECT_TRUE(d.back()->has_view_removed());
  EXPECT_EQ(b.AddView(View(7)), a.version() + 1);  // versions continue
  EXPECT_FALSE(b.RestoreCheckpoint(c).ok());       // only into an empty store

  // A checkpoint without the tail: the same client needs a snapshot.
  ModelStore no_tail;
  ASSERT_TRUE(no_tail.RestoreCheckpoint(a.MakeCheckpoint(0)).ok());
  auto sub2 = no_tail.Subscribe(a.version() - 2, a.EpochAt(a.version() - 2));
  auto d2 = Drain(*sub2);
  ASSERT_FALSE(d2.empty());
  EXPECT_TRUE(d2.front()->has_snapshot_begin());

  v1::Checkpoint bad = c;
  bad.mutable_log()->SwapElements(0, 1);
  ModelStore e;
  EXPECT_FALSE(e.RestoreCheckpoint(bad).ok());
}

// Guard under test: the epoch check in Subscribe. A server restored from a checkpoint older than
// a client produces the client's version numbers again with other content; resuming by version
// alone would apply the new deltas on top of the other history (silently wrong model).
TEST(ModelStore, ClientAheadOfRestoredCheckpointGetsSnapshot) {
  ModelStore a;
  for (ViewId i = 1; i <= 3; ++i) a.AddView(View(i));
  const v1::Checkpoint c = a.MakeCheckpoint(size_t{1} << 20);  // version 3
  a.AddView(View(4));
  a.AddView(View(5));  // a client follows `a` to version 5, then `a` crashes
  const uint64_t client_version = a.version();
  const uint64_t client_epoch = a.EpochAt(client_version);
  EXPECT_EQ(client_epoch, a.epoch());

  ModelStore b;
  ASSERT_TRUE(b.RestoreCheckpoint(c).ok());
  EXPECT_NE(b.epoch(), a.epoch());
  EXPECT_EQ(b.EpochAt(3), a.epoch());  // the checkpoint's history is shared
  for (ViewId i = 14; i <= 16; ++i) b.AddView(View(i));  // versions 4..6, other content
  ASSERT_GT(b.version(), client_version);
  EXPECT_EQ(b.EpochAt(5), b.epoch());

  auto ahead = b.Subscribe(client_version, client_epoch);
  auto d = Drain(*ahead);
  ASSERT_FALSE(d.empty());
  EXPECT_TRUE(d.front()->has_snapshot_begin());
  EXPECT_TRUE(d.back()->has_snapshot_end());
  EXPECT_EQ(d.back()->model_epoch(), b.epoch());
  EXPECT_EQ(ahead->snapshots(), 1u);

  // A client that stopped at the checkpoint's version is on b's history: deltas only, each
  // tagged with b's epoch.
  auto behind = b.Subscribe(3, a.EpochAt(3));
  auto d2 = Drain(*behind);
  ASSERT_EQ(d2.size(), 3u);
  EXPECT_EQ(behind->snapshots(), 0u);
  for (const auto& x : d2) EXPECT_EQ(x->model_epoch(), b.epoch());

  // An unknown epoch with a non-zero version cannot be placed on any history.
  auto unknown = b.Subscribe(3, 0);
  EXPECT_TRUE(Drain(*unknown).front()->has_snapshot_begin());

  // The lineage survives a second restart: b's checkpoint restored into c3.
  ModelStore c3;
  ASSERT_TRUE(c3.RestoreCheckpoint(b.MakeCheckpoint(size_t{1} << 20)).ok());
  EXPECT_EQ(c3.EpochAt(3), a.epoch());
  EXPECT_EQ(c3.EpochAt(5), b.epoch());
  auto again = c3.Subscribe(3, a.epoch());
  EXPECT_EQ(Drain(*again).size(), 3u);
  EXPECT_EQ(again->snapshots(), 0u);

  v1::Checkpoint bad = c;
  bad.mutable_lineage(0)->set_id(0);
  ModelStore e;
  EXPECT_FALSE(e.RestoreCheckpoint(bad).ok());
}

// Issue 20: 500 never-reading subscribers each pinned a copy of the model. Every view is now held
// once, as the snapshot part itself: subscribers at the same or different versions get the same
// objects, and an update replaces the part copy-on-write (a snapshot in flight keeps the old one).
TEST(ModelStore, SnapshotsShareOneCopyOfEachView) {
  ModelStore store;
  for (ViewId i = 1; i <= 4; ++i) store.AddView(View(i, 10000));
  constexpr uint64_t kFuture = 1000;  // a client version from the future: a snapshot
  auto a = store.Subscribe(kFuture, 0);
  auto b = store.Subscribe(kFuture, 0);
  const auto da = a->Next(0), db = b->Next(0);
  ASSERT_EQ(da.size(), db.size());
  ASSERT_TRUE(da.front()->has_snapshot_begin());
  std::vector<const v1::Delta*> parts_a;
  for (size_t i = 0; i < da.size(); ++i) {
    EXPECT_EQ(da[i].get(), db[i].get()) << i;  // the same objects, not copies
    if (da[i]->has_view_added()) parts_a.push_back(da[i].get());
  }
  ASSERT_EQ(parts_a.size(), 4u);
  // A subscriber at a later version: the unchanged views are still the same objects.
  ASSERT_TRUE(store.UpdateView(2, Rigid3d{}, 2.0f).ok());
  auto c = store.Subscribe(kFuture, 0);
  std::vector<const v1::Delta*> parts_c;
  for (const DeltaPtr& d : c->Next(0))
    if (d->has_view_added()) parts_c.push_back(d.get());
  ASSERT_EQ(parts_c.size(), 4u);
  EXPECT_EQ(parts_c[0], parts_a[0]);
  EXPECT_NE(parts_c[1], parts_a[1]);  // view 2 changed: a new part
  EXPECT_EQ(parts_c[1]->view_added().exposure(), 2.0f);
  EXPECT_EQ(parts_a[1]->view_added().exposure(), 1.0f);  // what `a` holds is unchanged
  EXPECT_EQ(parts_c[2], parts_a[2]);
  EXPECT_EQ(store.Views()[0].get(), &parts_a[0]->view_added());  // Views() aliases the parts
}

}  // namespace
}  // namespace exo

namespace exo {
namespace {

TriangleMesh Tri(float z) {
  TriangleMesh m;
  m.positions = {{0, 0, z}, {1, 0, z}, {0, 1, z}};
  m.indices = {0, 1, 2};
  return m;
}

// Every kind of change on a server store, read back through DeltasAfter and replayed into a
// replica (what exoview_relay does with the JetStream stream): same digest, same versions, same
// epochs, so a client resumes on the replica with the server's (version, epoch).
TEST(ModelStoreReplica, ReplayedDeltasGiveTheSameModelVersionsAndEpochs) {
  ModelStore server;
  LocalOrigin o;
  server.SetSceneParams(o, 0.5);
  for (ViewId i = 1; i <= 4; ++i) server.AddView(View(i));
  ASSERT_TRUE(server.UpdateView(2, Rigid3d{}, 0.5f).ok());
  ASSERT_TRUE(server.RemoveView(3).ok());
  server.SetCellRefs({{7, {1, 2}}, {8, {4}}});
  server.SetCellRefs({{8, {}}});
  server.UpsertChunk(11, 1, Tri(0));
  server.UpsertChunk(12, 1, Tri(1));
  ASSERT_TRUE(server.RemoveChunk(12).ok());

  ModelStoreOptions ro;
  ro.replica = true;
  ModelStore replica(ro);
  EXPECT_EQ(replica.epoch(), 0u);
  auto d = server.DeltasAfter(0, 1000, 0);
  ASSERT_TRUE(d.ok());
  ASSERT_EQ(d->size(), server.version());
  for (const DeltaPtr& x : *d) ASSERT_TRUE(replica.ReplayDelta(*x).ok()) << x->DebugString();
  EXPECT_EQ(replica.version(), server.version());
  EXPECT_EQ(replica.GetSummary().digest, server.GetSummary().digest);
  EXPECT_EQ(replica.EpochAt(5), server.epoch());
  // A client of the server at version 5 resumes on the replica with deltas only.
  auto sub = replica.Subscribe(5, server.EpochAt(5));
  EXPECT_EQ(Drain(*sub).size(), server.version() - 5);
  EXPECT_EQ(sub->snapshots(), 0u);
  // The replica's snapshot is the server's model.
  auto snap = replica.Subscribe(0, 0);
  auto parts = Drain(*snap);
  EXPECT_EQ(parts.back()->model_epoch(), server.epoch());

  // Out of order, a snapshot marker or an update of an unknown view: refused, nothing changes.
  EXPECT_EQ(replica.ReplayDelta(*(*d)[3]).code(), absl::StatusCode::kDataLoss);
  v1::Delta marker;
  marker.mutable_snapshot_end();
  marker.set_version(replica.version() + 1);
  marker.set_model_epoch(1);
  EXPECT_EQ(replica.ReplayDelta(marker).code(), absl::StatusCode::kDataLoss);
  v1::Delta unknown;
  unknown.mutable_view_updated()->set_view_id(99);
  unknown.set_version(replica.version() + 1);
  unknown.set_model_epoch(1);
  EXPECT_EQ(replica.ReplayDelta(unknown).code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(replica.version(), server.version());
  EXPECT_EQ(replica.GetSummary().digest, server.GetSummary().digest);
}

// A server restarted from a checkpoint older than its external log replays the log's tail, then
// commits under its own new epoch; a replica started from the checkpoint (replica = keep its
// lineage) and fed the same log agrees on every epoch.
TEST(ModelStoreReplica, RestoredServerReplaysTheLogTailThenCommitsUnderItsOwnEpoch) {
  ModelStore a;
  for (ViewId i = 1; i <= 3; ++i) a.AddView(View(i));
  const v1::Checkpoint c = a.MakeCheckpoint(0);
  a.AddView(View(4));
  a.AddView(View(5));
  auto tail = a.DeltasAfter(3, 100, 0);
  ASSERT_TRUE(tail.ok());
  ASSERT_EQ(tail->size(), 2u);

  ModelStore b;
  ASSERT_TRUE(b.RestoreCheckpoint(c).ok());
  for (const DeltaPtr& x : *tail) ASSERT_TRUE(b.ReplayDelta(*x).ok());
  EXPECT_EQ(b.GetSummary().digest, a.GetSummary().digest);
  EXPECT_EQ(b.EpochAt(5), a.epoch());
  b.AddView(View(6));
  EXPECT_EQ(b.EpochAt(6), b.epoch());
  EXPECT_NE(b.epoch(), a.epoch());
  // Once it has committed its own deltas, a server replays nothing more.
  v1::Delta late = *(*tail)[0];
  late.set_version(b.version() + 1);
  EXPECT_EQ(b.ReplayDelta(late).code(), absl::StatusCode::kFailedPrecondition);

  ModelStoreOptions ro;
  ro.replica = true;
  ModelStore r(ro);
  ASSERT_TRUE(r.RestoreCheckpoint(c).ok());
  auto rest = b.DeltasAfter(3, 100, 0);
  ASSERT_TRUE(rest.ok());
  for (const DeltaPtr& x : *rest) ASSERT_TRUE(r.ReplayDelta(*x).ok());
  EXPECT_EQ(r.GetSummary().digest, b.GetSummary().digest);
  for (uint64_t v = 1; v <= b.version(); ++v) EXPECT_EQ(r.EpochAt(v), b.EpochAt(v)) << v;
}

// Reconciliation with an external log that holds versions the store abandons (delta_log.h):
// the restored server skips past them with no content change; a client holding one of them
// (old epoch) gets a snapshot, a replica that applied them meets a gap, and the server's next
// delta follows the skipped version.
TEST(ModelStoreReplica, SkippedVersionsAreAGapAndClientsOnThemResyncBySnapshot) {
  ModelStore a;
  for (ViewId i = 1; i <= 3; ++i) a.AddView(View(i));
  const v1::Checkpoint c = a.MakeCheckpoint(0);
  a.AddView(View(4));  // versions 4, 5 reach the log, not the checkpoint
  a.AddView(View(5));
  ModelStoreOptions ro;
  ro.replica = true;
  ModelStore replica(ro);
  auto all = a.DeltasAfter(0, 100, 0);
  ASSERT_TRUE(all.ok());
  for (const DeltaPtr& x : *all) ASSERT_TRUE(replica.ReplayDelta(*x).ok());

  ModelStore b;
  ASSERT_TRUE(b.RestoreCheckpoint(c).ok());
  const uint64_t digest3 = b.GetSummary().digest;
  EXPECT_EQ(b.SkipVersionsTo(2).code(), absl::StatusCode::kFailedPrecondition);  // backwards
  ASSERT_TRUE(b.SkipVersionsTo(6).ok());  // the log ended at 5; 6 is never published
  EXPECT_EQ(b.version(), 6u);
  EXPECT_EQ(b.GetSummary().digest, digest3);
  EXPECT_EQ(b.EpochAt(5), b.epoch());
  EXPECT_EQ(b.EpochAt(3), a.EpochAt(3));
  // A client at version 5 of the abandoned history, and one at 3 (the log is empty): snapshots.
  for (uint64_t v : {uint64_t{5}, uint64_t{3}}) {
    auto sub = b.Subscribe(v, a.EpochAt(v));
    auto d = Drain(*sub);
    EXPECT_EQ(sub->snapshots(), 1u) << v;
    ASSERT_FALSE(d.empty());
    EXPECT_EQ(d.back()->version(), 6u);
  }
  b.AddView(View(7));
  EXPECT_EQ(b.version(), 7u);
  auto next = b.DeltasAfter(6, 10, 0);
  ASSERT_TRUE(next.ok());
  ASSERT_EQ(next->size(), 1u);
  // The replica at 5 cannot take 7: a gap (it resyncs from a snapshot).
  EXPECT_EQ(replica.ReplayDelta(*(*next)[0]).code(), absl::StatusCode::kDataLoss);
  // Once it has committed, a server skips no more.
  EXPECT_EQ(b.SkipVersionsTo(10).code(), absl::StatusCode::kFailedPrecondition);
  // The skip survives a checkpoint: a restored store continues at 7.
  ModelStore b2;
  ASSERT_TRUE(b2.RestoreCheckpoint(b.MakeCheckpoint(1 << 20)).ok());
  EXPECT_EQ(b2.version(), 7u);
  EXPECT_EQ(b2.GetSummary().digest, b.GetSummary().digest);
}

TEST(ModelStoreReplica, DeltasAfterReportsACompactedLog) {
  ModelStoreOptions o;
  o.max_log_deltas = 2;
  ModelStore s(o);
  for (ViewId i = 1; i <= 5; ++i) s.AddView(View(i));
  EXPECT_EQ(s.DeltasAfter(1, 10, 0).status().code(), absl::StatusCode::kDataLoss);
  auto ok = s.DeltasAfter(3, 10, 0);
  ASSERT_TRUE(ok.ok());
  EXPECT_EQ(ok->size(), 2u);
  EXPECT_TRUE(s.DeltasAfter(5, 10, 0)->empty());
  // Shutdown: subscribers are woken, but the log shipper still drains what was committed.
  s.CloseAll();
  s.AddView(View(6));
  auto after_close = s.DeltasAfter(5, 10, 1000);
  ASSERT_TRUE(after_close.ok());
  ASSERT_EQ(after_close->size(), 1u);
  EXPECT_EQ(after_close->front()->version(), 6u);
}

}  // namespace
}  // namespace exo

namespace exo {
namespace {

// Per-cell coverage (CellCoverage, issue 17): sent in the CellRefsChanged delta with (or without)
// reference changes, part of the snapshot, the checkpoint and a replica; not of the digest.
TEST(ModelStoreCoverage, CoverageTravelsInDeltasSnapshotsCheckpointsAndReplicas) {
  ModelStore server;
  server.SetSceneParams(LocalOrigin{}, 0.5);
  const uint64_t digest0 = server.GetSummary().digest;
  server.SetCellRefs({{7, {1, 2}}}, {{7, 40}, {9, 0}});
  server.SetCellRefs({}, {{7, 100}});  // τ rose, references unchanged: coverage only
  EXPECT_EQ(server.CellCoverage(), (std::unordered_map<CellId, uint8_t>{{7, 100}, {9, 0}}));
  server.SetCellRefs({}, {{9, 250}});  // clamped to 100 %
  EXPECT_EQ(server.CellCoverage().at(9), 100);
  // The last delta carries only coverage.
  auto d = server.DeltasAfter(server.version() - 1, 10, 0);
  ASSERT_TRUE(d.ok());
  ASSERT_EQ(d->size(), 1u);
  EXPECT_EQ((*d)[0]->cell_refs_changed().cells_size(), 0);
  ASSERT_EQ((*d)[0]->cell_refs_changed().coverage_size(), 1);
  EXPECT_EQ((*d)[0]->cell_refs_changed().coverage(0).tau_percent(), 100u);
  // Not part of the digest (display data): only the references changed it.
  ModelStore refs_only;
  refs_only.SetSceneParams(LocalOrigin{}, 0.5);
  refs_only.SetCellRefs({{7, {1, 2}}});
  EXPECT_EQ(server.GetSummary().digest, refs_only.GetSummary().digest);
  EXPECT_NE(server.GetSummary().digest, digest0);
  // A new subscriber's snapshot has the coverage of every cell.
  auto sub = server.Subscribe(0, 0);
  std::unordered_map<CellId, uint32_t> snap;
  for (const DeltaPtr& p : Drain(*sub))
    if (p->has_cell_refs_changed())
      for (const auto& c : p->cell_refs_changed().coverage()) snap[c.cell_id()] = c.tau_percent();
  EXPECT_EQ(snap, (std::unordered_map<CellId, uint32_t>{{7, 100}, {9, 100}}));
  // A checkpoint restores it; a replica replaying the deltas has it.
  ModelStore restored;
  ASSERT_TRUE(restored.RestoreCheckpoint(server.MakeCheckpoint(1 << 20)).ok());
  EXPECT_EQ(restored.CellCoverage(), server.CellCoverage());
  ModelStoreOptions ro;
  ro.replica = true;
  ModelStore replica(ro);
  auto all = server.DeltasAfter(0, 1000, 0);
  ASSERT_TRUE(all.ok());
  for (const DeltaPtr& x : *all) ASSERT_TRUE(replica.ReplayDelta(*x).ok());
  EXPECT_EQ(replica.CellCoverage(), server.CellCoverage());
}


// A snapshot as the gRPC edges send it (NextForWire): the mesh chunks in zstd batches of at most
// snapshot_chunk_batch_bytes, every other part the same shared object, every chunk back with its
// id, version and mesh; packed once per version for every subscriber; 0 turns it off; log deltas
// pass through.
TEST(ModelStore, WireSnapshotsBatchTheChunksOncePerVersion) {
  ModelStoreOptions o;
  o.snapshot_chunk_batch_bytes = 400;  // a few chunks per batch
  ModelStore store(o);
  store.AddView(View(1, 1000));
  const MeshWireOptions wire{0.02f / 32};
  std::map<uint64_t, std::pair<uint64_t, uint64_t>> want;  // id -> (version, mesh hash)
  for (uint64_t id = 1; id <= 30; ++id) {
    TriangleMesh m = Tri(0.01f * id);
    for (int k = 1; k < 4; ++k) {  // a strip: a few triangles per chunk
      m.positions.push_back({float(k) + 1, 0, 0.01f * id});
      m.indices.insert(m.indices.end(), {uint32_t(k), uint32_t(k + 2), uint32_t(k + 1)});
    }
    store.UpsertChunk(id, 2 * id, m, id % 2 ? wire : MeshWireOptions{});
  }
  for (const auto& c : store.Chunks()) {
    auto m = MeshFromProto(*c);
    ASSERT_TRUE(m.ok());
    want[c->chunk_id()] = {c->chunk_version(), MeshHash(*m)};
  }
  constexpr uint64_t kFuture = 1000;
  auto a = store.Subscribe(kFuture, 0);
  auto b = store.Subscribe(kFuture, 0);
  auto plain_sub = store.Subscribe(kFuture, 0);
  const auto wa = a->NextForWire(0), wb = b->NextForWire(0);
  const auto plain = plain_sub->Next(0);
  ASSERT_EQ(wa.size(), wb.size());
  for (size_t i = 0; i < wa.size(); ++i) EXPECT_EQ(wa[i].get(), wb[i].get()) << i;  // packed once
  ASSERT_TRUE(wa.front()->has_snapshot_begin());
  ASSERT_TRUE(wa.back()->has_snapshot_end());
  EXPECT_EQ(wa.back().get(), plain.back().get());
  std::map<uint64_t, std::pair<uint64_t, uint64_t>> got;
  size_t batches = 0, wire_bytes = 0, plain_bytes = 0, views = 0;
  for (const DeltaPtr& d : plain) plain_bytes += d->ByteSizeLong();
  for (const DeltaPtr& d : wa) {
    wire_bytes += d->ByteSizeLong();
    if (d->has_view_added()) ++views;
    if (d->has_mesh_chunk_upserted()) {
      auto m = MeshFromProto(d->mesh_chunk_upserted());
      ASSERT_TRUE(m.ok());
      got[d->mesh_chunk_upserted().chunk_id()] = {d->mesh_chunk_upserted().chunk_version(),
                                                 MeshHash(*m)};
    }
    if (!d->has_mesh_chunk_batch()) continue;
    ++batches;
    EXPECT_EQ(d->version(), wa.back()->version());
    auto list = UnpackMeshChunks(d->mesh_chunk_batch());
    ASSERT_TRUE(list.ok()) << list.status();
    EXPECT_GE(list->size(), 2u);
    size_t raw = 0;
    for (const auto& c : *list) {
      raw += c.ByteSizeLong();
      auto m = MeshFromProto(c);
      ASSERT_TRUE(m.ok());
      EXPECT_FALSE(got.count(c.chunk_id())) << "chunk " << c.chunk_id() << " sent twice";
      got[c.chunk_id()] = {c.chunk_version(), MeshHash(*m)};
    }
    EXPECT_LE(raw, 400u + 200u);  // the limit, overshot by at most one chunk
  }
  EXPECT_EQ(got, want);
  EXPECT_EQ(views, 1u);
  EXPECT_GE(batches, 3u);
  EXPECT_LT(wire_bytes, plain_bytes);
  // A new version: packed anew (the cached one was for the old version).
  store.AddView(View(2, 1000));
  auto c = store.Subscribe(kFuture, 0);
  const auto wc = c->NextForWire(0);
  EXPECT_EQ(wc.back()->version(), store.version());
  EXPECT_NE(wc.back().get(), wa.back().get());
  // Log deltas pass through unchanged.
  store.AddView(View(3, 10));
  const auto live = c->NextForWire(0);
  ASSERT_EQ(live.size(), 1u);
  EXPECT_TRUE(live[0]->has_view_added());
  // Off: the parts themselves.
  ModelStoreOptions off = o;
  off.snapshot_chunk_batch_bytes = 0;
  ModelStore store0(off);
  store0.UpsertChunk(1, 1, Tri(0));
  store0.UpsertChunk(2, 1, Tri(1));
  auto s0 = store0.Subscribe(kFuture, 0);
  size_t chunks0 = 0;
  for (const DeltaPtr& d : s0->NextForWire(0)) {
    EXPECT_FALSE(d->has_mesh_chunk_batch());
    chunks0 += d->has_mesh_chunk_upserted();
  }
  EXPECT_EQ(chunks0, 2u);
}

}  // namespace
}  // namespace exo
