// Integration of the client store with the server model store (in process, no gRPC): the
// client's local store reaches the server model's digest through deltas, through a snapshot,
// and through a resume from its last version.
#include "client/store/local_store.h"

#include <gtest/gtest.h>

#include "server/service/model_store.h"

namespace exo {
namespace {

v1::ViewAdded MakeView(ViewId id) {
  StoredView v;
  v.id = id;
  v.camera = PinholeCamera::FromFov(32, 24, 1.0);
  v.local_from_cam.translation = {0.1 * id, 0.0, 0.0};
  v.color = ImageU8(32, 24, 3, static_cast<uint8_t>(10 * id));
  v.depth_m = ImageF(32, 24, 1, 1.0f + 0.1f * id);
  auto m = ViewToProto(v, {});
  EXO_CHECK(m.ok());
  return *m;
}

void Mutate(ModelStore& s, ViewId first, ViewId last) {
  for (ViewId i = first; i <= last; ++i) {
    s.AddView(MakeView(i));
    s.SetCellRefs({{PackCell({static_cast<int>(i), 0, 0}), {i}}});
  }
  TriangleMesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, static_cast<float>(last)}};
  m.indices = {0, 1, 2};
  s.UpsertChunk(1, last, m);
}

absl::Status Pump(Subscription& sub, LocalStore& local) {
  for (;;) {
    auto batch = sub.Next(0);
    if (batch.empty()) return absl::OkStatus();
    for (const auto& d : batch) EXO_RETURN_IF_ERROR(local.Apply(*d));
  }
}

TEST(LocalStore, DeltasSnapshotAndResumeReachTheServerDigest) {
  ModelStore server;
  server.SetSceneParams(LocalOrigin{{10.0, 0.0, 0.0}}, 0.5);
  Mutate(server, 1, 4);
  LocalStore a;
  auto sub = server.Subscribe(a.version(), a.epoch());
  ASSERT_TRUE(Pump(*sub, a).ok());
  EXPECT_EQ(a.version(), server.version());
  EXPECT_EQ(a.Digest(), server.GetSummary().digest);
  EXPECT_EQ(a.model().views.size(), 4u);
  EXPECT_EQ(a.model().views.at(3).color.at(0, 0, 0), 30);  // decoded JPEG (flat colour)
  EXPECT_EQ(a.model().origin.origin_in_world.x, 10.0);

  // Disconnect, the server moves on (including a removal and a refinement update), resume.
  sub.reset();
  Mutate(server, 5, 6);
  ASSERT_TRUE(server.RemoveView(2).ok());
  ASSERT_TRUE(server.UpdateView(3, Rigid3d{{1, 0, 0, 0}, {5, 5, 5}}, 1.5f).ok());
  const uint64_t before = a.version();
  const uint64_t snapshots_before = a.snapshots_applied(), deltas_before = a.deltas_applied();
  auto sub2 = server.Subscribe(a.version(), a.epoch());
  ASSERT_TRUE(Pump(*sub2, a).ok());
  EXPECT_EQ(a.snapshots_applied(), snapshots_before);  // resumed with deltas only
  EXPECT_EQ(a.deltas_applied() - deltas_before, server.version() - before);
  EXPECT_GT(a.version(), before);
  EXPECT_EQ(a.Digest(), server.GetSummary().digest);
  EXPECT_EQ(a.model().views.count(2), 0u);
  EXPECT_EQ(a.model().views.at(3).exposure, 1.5f);
  EXPECT_EQ(a.epoch(), server.epoch());  // what the client sends on its next Subscribe

  // A fresh client from a compacted server gets a snapshot and the same digest.
  ModelStoreOptions small;
  small.max_log_deltas = 2;
  ModelStore compact(small);
  Mutate(compact, 1, 5);
  LocalStore b;
  auto sub3 = compact.Subscribe(0, 0);
  ASSERT_TRUE(Pump(*sub3, b).ok());
  EXPECT_EQ(b.snapshots_applied(), 1u);
  EXPECT_EQ(b.Digest(), compact.GetSummary().digest);
  EXPECT_EQ(b.version(), compact.version());
}

TEST(LocalStore, GapOrReplayedVersionIsAnError) {
  ModelStore server;
  Mutate(server, 1, 2);
  LocalStore a;
  auto sub = server.Subscribe(0, 0);
  auto batch = sub->Next(0);
  ASSERT_GE(batch.size(), 3u);
  ASSERT_TRUE(a.Apply(*batch[0]).ok());
  EXPECT_FALSE(a.Apply(*batch[0]).ok());  // replay of version 1
  EXPECT_FALSE(a.Apply(*batch[2]).ok());  // gap: version 3 after 1
  // Digest differs while the store is behind (the comparison can fail).
  EXPECT_NE(a.Digest(), server.GetSummary().digest);
}

}  // namespace
}  // namespace exo

namespace exo {
namespace {

// An inpainted keyframe (SPEC §7) reaches the client with its flag and label mask, and the
// digests (which cover the labels) agree.
TEST(LocalStore, InpaintedViewArrivesWithItsLabels) {
  ModelStore server;
  server.SetSceneParams(LocalOrigin{{0.0, 0.0, 0.0}}, 0.5);
  StoredView v;
  v.id = 0x40000000u;
  v.camera = PinholeCamera::FromFov(32, 24, 1.0);
  v.color = ImageU8(32, 24, 3, 90);
  v.depth_m = ImageF(32, 24, 1, 2.0f);
  v.inpainted = true;
  v.labels = ImageU8(32, 24, 1, 0);
  for (int x = 5; x < 20; ++x) v.labels.at(x, 10) = 255;
  auto msg = ViewToProto(v, {});
  ASSERT_TRUE(msg.ok()) << msg.status();
  server.AddView(*msg);
  LocalStore a;
  auto sub = server.Subscribe(0, 0);
  ASSERT_TRUE(Pump(*sub, a).ok());
  EXPECT_EQ(a.Digest(), server.GetSummary().digest);
  const StoredView& got = a.model().views.at(v.id);
  EXPECT_TRUE(got.inpainted);
  ASSERT_EQ(got.labels.width(), 32);
  EXPECT_EQ(got.labels.at(5, 10), 255);
  EXPECT_EQ(got.labels.at(4, 10), 0);
  // Other labels: another digest.
  v.labels.at(4, 10) = 255;
  ModelStore other;
  other.SetSceneParams(LocalOrigin{{0.0, 0.0, 0.0}}, 0.5);
  other.AddView(*ViewToProto(v, {}));
  EXPECT_NE(other.GetSummary().digest, server.GetSummary().digest);
  // An inpainted view without labels is refused.
  v.labels = ImageU8();
  EXPECT_FALSE(ViewToProto(v, {}).ok());
}

}  // namespace
}  // namespace exo
