// End-to-end on loopback with real processes (SPEC §1, §12): exoview_server + exoview_uploader
// (built-in synthetic scene) + two exoview_viewer processes + a third viewer killed mid-stream
// and restarted from its journal. At the end every viewer's local store equals the server's
// model (digest and version), the restarted viewer caught up with deltas only, and frames the
// viewer process rendered equal the same frames rendered in-process from the server's model.
#include <sys/stat.h>

#include <filesystem>

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include "client/uploader/upload_client.h"
#include "client/viewer/viewer_session.h"
#include "common/io/image_file.h"
#include "common/lumigraph/cpu_renderer.h"
#include "common/synth/render.h"
#include "common/synth/scene.h"
#include "common/synth/trajectory.h"
#include "proto/exoview.grpc.pb.h"
#include "tests/server_fixture.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using testing::JsonNumber;
using testing::JsonU64;
using testing::ReadAll;
using testing::Subprocess;
using testing::WaitForFile;

constexpr int kFrames = 40;

class ServiceE2E : public testing::ServerProcessTest {};

TEST_F(ServiceE2E, ViewersEqualServerModelAndRestartedViewerCatchesUpExactly) {
  // A log that holds the whole run and no snapshot shortcut, so the restarted viewer must resume
  // with exactly the deltas it missed (the snapshot paths are covered in model_store_test).
  StartServer({"--max_log_deltas=1000000", "--max_log_bytes=1000000000",
               "--max_subscriber_lag=1000000", "--snapshot_when_cheaper=false",
               "--voxel_size_m=0.08", "--mesh_every_n_frames=5", "--fuse_depth_downscale=2"});
  const std::string until = "--until_frames=" + std::to_string(kFrames);
  Subprocess a(EXOVIEW_VIEWER_BIN, {"--server=" + target_, until, "--state_json=" + dir_ + "/a.json"},
               dir_ + "/a.log");
  Subprocess b(EXOVIEW_VIEWER_BIN,
               {"--server=" + target_, until, "--state_json=" + dir_ + "/b.json", "--render_frames=3",
                "--width=96", "--height=72", "--renderer=cpu", "--out=" + dir_ + "/b",
                "--path=synthetic:apartment:walk"},
               dir_ + "/b.log");
  auto c = std::make_unique<Subprocess>(
      EXOVIEW_VIEWER_BIN, std::vector<std::string>{"--server=" + target_, "--follow", "--journal=" + dir_ + "/c.journal"},
      dir_ + "/c1.log");
  Subprocess up(EXOVIEW_UPLOADER_BIN,
                {"--server=" + target_, "--synthetic=apartment", "--trajectory=walk",
                 "--frames=" + std::to_string(kFrames), "--width=160", "--height=120",
                 "--rate_hz=20", "--stats_json=" + dir_ + "/up.json"},
                dir_ + "/up.log");

  // Kill viewer C (SIGKILL: no chance to clean up) once it has journalled some deltas and while
  // the upload is still going.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  for (;;) {
    std::error_code ec;
    const auto sz = std::filesystem::file_size(dir_ + "/c.journal", ec);
    const v1::Stats s = Stats();
    if (!ec && sz > 0 && s.frames_received() >= kFrames / 4) break;
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << c->Log();
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  c->Signal(SIGKILL);
  ASSERT_TRUE(c->Wait(10).has_value());
  const uint64_t received_at_kill = Stats().frames_received();
  EXPECT_LT(received_at_kill, static_cast<uint64_t>(kFrames)) << "the kill was not mid-stream";

  ASSERT_EQ(up.Wait(60), 0) << up.Log();
  const std::string upj = ReadAll(dir_ + "/up.json");
  EXPECT_EQ(JsonNumber(upj, "sent"), kFrames);
  EXPECT_EQ(JsonNumber(upj, "rejected"), 0) << upj;
  EXPECT_EQ(JsonNumber(upj, "accepted") + JsonNumber(upj, "dropped"), kFrames);

  // Restart C from its journal.
  c = std::make_unique<Subprocess>(
      EXOVIEW_VIEWER_BIN,
      std::vector<std::string>{"--server=" + target_, until, "--journal=" + dir_ + "/c.journal",
                               "--state_json=" + dir_ + "/c.json"},
      dir_ + "/c2.log");
  ASSERT_EQ(a.Wait(90), 0) << a.Log();
  ASSERT_EQ(b.Wait(90), 0) << b.Log();
  ASSERT_EQ(c->Wait(90), 0) << c->Log();

  const v1::Stats s = Stats();
  EXPECT_EQ(s.frames_processed(), s.frames_accepted());
  EXPECT_GT(s.num_views(), 0u);
  EXPECT_GT(s.num_chunks(), 0u);
  EXPECT_GT(s.num_cells(), 0u);
  for (const char* name : {"a", "b", "c"}) {
    const std::string j = ReadAll(dir_ + "/" + name + ".json");
    SCOPED_TRACE(std::string(name) + ": " + j);
    EXPECT_EQ(JsonU64(j, "version"), s.model_version());
    EXPECT_EQ(JsonU64(j, "digest"), s.model_digest());
    EXPECT_EQ(JsonU64(j, "views"), s.num_views());
  }
  const std::string cj = ReadAll(dir_ + "/c.json");
  EXPECT_GT(JsonU64(cj, "replayed"), 0u) << cj;
  EXPECT_GT(JsonU64(cj, "resumed_from"), 0u) << cj;           // resumed, not from scratch
  EXPECT_EQ(JsonU64(cj, "resumed_from"), JsonU64(cj, "replayed"));  // journal = versions 1..n
  EXPECT_EQ(JsonU64(cj, "snapshots"), 0u) << cj;              // only the missed deltas
  EXPECT_EQ(JsonU64(cj, "resumed_from") + JsonU64(cj, "deltas"), s.model_version()) << cj;

  // Frames rendered by viewer B == the same frames rendered here from the server's model.
  auto session = ViewerSession::Open(MakeChannel(target_), "");
  ASSERT_TRUE(session.ok());
  ASSERT_TRUE((*session)->Sync({}).ok());
  ASSERT_EQ((*session)->store().Digest(), s.model_digest());
  auto scene = synth::MakeScene(synth::SceneKind::kApartment, {});
  ASSERT_TRUE(scene.ok());
  synth::TrajectoryOptions to;
  to.num_frames = 3;
  auto poses = synth::MakeTrajectory(*scene, synth::TrajectoryKind::kWalk, to);
  ASSERT_TRUE(poses.ok());
  synth::RenderOptions ro;
  ro.width = 96;
  ro.height = 72;
  const LumigraphModel& model = (*session)->store().model();
  auto renderer = CpuLumigraphRenderer::Create(model, {});
  ASSERT_TRUE(renderer.ok());
  size_t covered = 0;
  for (int i = 0; i < 3; ++i) {
    auto mine = (*renderer)->Render(ro.Camera(), model.origin.ToLocal((*poses)[i].local_from_cam));
    ASSERT_TRUE(mine.ok());
    covered += mine->covered_pixels;
    char name[64];
    std::snprintf(name, sizeof(name), "/b/frame_%04d.png", i);
    auto theirs = ReadColorImage(dir_ + name);
    ASSERT_TRUE(theirs.ok()) << theirs.status();
    EXPECT_TRUE(*theirs == mine->color) << "frame " << i << " differs";
  }
  EXPECT_GT(covered, 0u);  // the comparison is not between two empty images

  // Graceful shutdown on SIGTERM.
  server_->Signal(SIGTERM);
  EXPECT_EQ(server_->Wait(15), 0) << server_->Log();
  server_.reset();
}

// SPEC §4 on the server: with planning_id_from_proxy=1 the planning stage renders its cell-id
// buffers from the geometry stage's re-meshed chunks (planning::CellIdRenderer fed through
// the geometry stage's per-frame GeometryHandoff) instead of back-projecting the frame's depth. Every candidate
// after the first meshed chunks takes that path, no chunk update fails, and views are planned.
TEST_F(ServiceE2E, PlanningRendersCellIdsFromTheProxyChunks) {
  StartServer({"--planning_id_from_proxy=1", "--refinement=0"});
  constexpr int kProxyFrames = 30;
  Subprocess up(EXOVIEW_UPLOADER_BIN,
                {"--server=" + target_, "--synthetic=apartment", "--trajectory=walk",
                 "--frames=" + std::to_string(kProxyFrames), "--width=160", "--height=120",
                 "--rate_hz=20"},
                dir_ + "/up.log");
  ASSERT_EQ(up.Wait(60), 0) << up.Log();
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  v1::Stats s = Stats();
  while (s.frames_processed() < s.frames_accepted() || s.frames_accepted() == 0) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << server_->Log();
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    s = Stats();
  }
  const auto& c = s.counters();
  ASSERT_TRUE(c.contains("planning.ids_from_proxy")) << server_->Log();
  // Of the candidates that reached the planner (a loaded machine may drop some with "overload"),
  // most used the proxy: only the first frames, before any chunk is meshed, use their depth.
  ASSERT_TRUE(c.contains("planning.candidates")) << server_->Log();
  EXPECT_GT(c.at("planning.candidates"), 0.0);
  EXPECT_GT(c.at("planning.ids_from_proxy"), c.at("planning.candidates") / 2) << server_->Log();
  EXPECT_EQ(c.at("planning.cellid_update_errors"), 0.0);
  EXPECT_GT(s.num_chunks(), 0u);
  EXPECT_GT(s.num_views(), 0u);
  EXPECT_GT(s.num_cells(), 0u);
}

}  // namespace
}  // namespace exo
