// Scene completion at a viewer's request (issue 18 item 4, second mode) over real gRPC: a server
// process takes frames of a textured wall seen from a short sideways walk; a viewer synced over
// gRPC flies sideways past what was observed (half its frame shows nothing the server modelled)
// and calls CompleteView. The server publishes an inpainted view (labels = the holes) and a mesh
// chunk of its depth where there was no proxy; the viewer's next sync receives both, and its CPU
// lumigraph render at that pose is covered everywhere while the pixels that were covered before
// stay as they were. Bad requests get INVALID_ARGUMENT and change nothing; a camera that looks at
// nothing modelled gets FAILED_PRECONDITION; completing again says there is nothing to complete;
// the completion view survives a restart (checkpoint), and once frames observe the hole the
// server withdraws or shrinks it (observations preferred).
#include <cmath>
#include <limits>

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include "client/uploader/upload_client.h"
#include "client/viewer/viewer_session.h"
#include "common/lumigraph/cpu_renderer.h"
#include "proto/exoview.grpc.pb.h"
#include "proto/frame_proto.h"
#include "proto/model_proto.h"
#include "server/inpainting/test_scenes.h"
#include "tests/server_fixture.h"

namespace exo {
namespace {

using inpainting::testing::RenderPlanes;
using inpainting::testing::WorldPlane;

PinholeCamera Cam() {
  PinholeCamera c;
  c.width = 160;
  c.height = 120;
  c.fx = c.fy = 144;
  c.cx = 79.5;
  c.cy = 59.5;
  return c;
}

// A textured wall at z = 2 m, camera looking +z.
std::vector<WorldPlane> Wall() { return {{glm::dvec3(0, 0, -1), -2.0, nullptr}}; }

Rigid3d PoseAt(double x) {
  Rigid3d p;
  p.translation = {x, 0.0, 0.0};
  return p;
}

constexpr uint32_t kCompletionBase = 0x60000000u;

class ServiceCompletion : public testing::ServerProcessTest {
 protected:
  void Start(const std::string& log) {
    StartServer({"--checkpoint_path=" + dir_ + "/model.ckpt", "--checkpoint_interval_s=0.2",
                 "--voxel_size_m=0.04", "--mesh_every_n_frames=1",
                 "--completion_refresh_period_s=0.2", "--log_level=debug"},
                log);
    stub_ = v1::Exoview::NewStub(MakeChannel(target_));
  }
  // Frames [first, first + n) of a sideways walk: x = x0 + 0.02 k.
  void Upload(int first, int n, double x0) {
    UploadOptions o;
    auto st = UploadStream(
        MakeChannel(target_), n,
        [&](size_t i) -> absl::StatusOr<v1::Frame> {
          const int k = first + static_cast<int>(i);
          const auto kf = RenderPlanes(Wall(), Cam(), PoseAt(x0 + 0.02 * k));
          Frame f;
          f.sequence = k + 1;
          f.timestamp_s = 0.1 * (k + 1);
          f.color_camera = f.depth_camera = Cam();
          f.color = kf.color;
          f.depth_m = kf.depth_m;
          f.world_from_cam = kf.world_from_cam;
          return FrameToProto(f, {});
        },
        o);
    ASSERT_TRUE(st.ok()) << st.status();
    ASSERT_EQ(st->accepted, static_cast<uint64_t>(n)) << server_->Log();
  }
  v1::Stats WaitProcessed() {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    for (;;) {
      const v1::Stats s = Stats();
      if (s.frames_processed() == s.frames_accepted() && s.async_pending() == 0) return s;
      if (std::chrono::steady_clock::now() > deadline) {
        ADD_FAILURE() << "timed out\n" << server_->Log();
        return s;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }
  grpc::Status Complete(const PinholeCamera& cam, const Rigid3d& local_from_cam,
                        v1::CompleteViewReply* out, uint32_t max_side = 0, bool pose = true) {
    v1::CompleteViewRequest req;
    IntrinsicsToProto(cam, req.mutable_camera());
    if (pose) PoseToProto(local_from_cam, req.mutable_local_from_cam());
    req.set_max_side_px(max_side);
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    return stub_->CompleteView(&ctx, req, out);
  }
  // A fresh viewer's model (snapshot over gRPC).
  std::unique_ptr<ViewerSession> Viewer() {
    auto session = ViewerSession::Open(MakeChannel(target_), "");
    EXO_CHECK(session.ok());
    EXPECT_TRUE((*session)->Sync({}).ok());
    return *std::move(session);
  }
  std::unique_ptr<v1::Exoview::Stub> stub_;
};

CpuRenderOutput RenderAt(const LumigraphModel& model, const Rigid3d& local_from_cam) {
  CpuRenderOptions o;
  o.blend.fill_holes = false;
  auto r = CpuLumigraphRenderer::Create(model, o);
  EXO_CHECK(r.ok());
  auto out = (*r)->Render(Cam(), local_from_cam);
  EXO_CHECK(out.ok());
  return *std::move(out);
}

TEST_F(ServiceCompletion, ViewerCompletesWhatNobodyObservedEveryViewerGetsIt) {
  Start("server1.log");
  ASSERT_NO_FATAL_FAILURE(Upload(0, 8, -0.15));  // x in [-0.15, -0.01]: wall x up to ~1.1 m
  const v1::Stats s0 = WaitProcessed();
  ASSERT_GT(s0.num_chunks(), 0u) << server_->Log();
  ASSERT_GT(s0.num_views(), 0u) << server_->Log();

  auto viewer = Viewer();
  const LumigraphModel& m0 = viewer->store().model();
  // Flown sideways to x = 0.9 m: the right part of the frame looks past the modelled wall.
  const Rigid3d pose = m0.origin.ToLocal(PoseAt(0.9));
  const CpuRenderOutput before = RenderAt(m0, pose);
  const size_t n = size_t(Cam().width) * Cam().height;
  const double coverage_before = double(before.covered_pixels) / n;
  EXPECT_LT(coverage_before, 0.9);
  EXPECT_GT(coverage_before, 0.2);

  // Bad input: INVALID_ARGUMENT, nothing changes.
  const uint64_t version0 = Stats().model_version();
  v1::CompleteViewReply reply;
  PinholeCamera bad = Cam();
  bad.fx = 0;
  EXPECT_EQ(Complete(bad, pose, &reply).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  Rigid3d nan = pose;
  nan.translation.y = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(Complete(Cam(), nan, &reply).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  PinholeCamera huge = Cam();
  huge.width = 100000;
  huge.cx = 50000;
  EXPECT_EQ(Complete(huge, pose, &reply).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(Complete(Cam(), pose, &reply, /*max_side=*/1 << 20).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(Complete(Cam(), pose, &reply, 0, /*pose=*/false).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  // Looking away from everything modelled: no source.
  Rigid3d away = pose;
  away.rotation = glm::angleAxis(3.14159265358979, glm::dvec3(0, 1, 0));
  grpc::Status st = Complete(Cam(), away, &reply);
  EXPECT_EQ(st.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << st.error_message();
  EXPECT_EQ(Stats().model_version(), version0);

  // The completion.
  st = Complete(Cam(), pose, &reply);
  ASSERT_TRUE(st.ok()) << st.error_message() << server_->Log();
  ASSERT_EQ(reply.outcome(), v1::CompleteViewReply::COMPLETED);
  EXPECT_GE(reply.view_id(), kCompletionBase);
  EXPECT_EQ(reply.width(), 160u);
  EXPECT_EQ(reply.hole_px(), n - before.covered_pixels - before.background_pixels);
  EXPECT_GT(reply.void_hole_px(), 0u);
  EXPECT_GT(reply.mesh_triangles(), 0u);
  EXPECT_GT(reply.model_version(), version0);
  EXPECT_GT(reply.total_ms(), 0.0);
  std::cout << "completion: " << reply.ShortDebugString() << "\n";
  // Session 16: the surface holes take the geometry stage's fused vertex colour (the published
  // chunks carry none; the server hands the full-resolution coloured chunks to the completion).
  {
    const v1::Stats s = Stats();
    const double fused = s.counters().at("completion.fused_color_px_total");
    std::cout << "surface hole px " << reply.surface_hole_px() << ", of them with fused colour "
              << fused << "\n";
    if (reply.surface_hole_px() >= 20) {
      EXPECT_GT(fused, 0.5 * reply.surface_hole_px());
    }
    EXPECT_LE(fused, double(reply.surface_hole_px()));
  }

  // Every viewer gets it: a second viewer's snapshot, and the first one resuming.
  auto other = Viewer();
  const LumigraphModel& m1 = other->store().model();
  ASSERT_TRUE(m1.views.count(reply.view_id()));
  const StoredView& cv = m1.views.at(reply.view_id());
  EXPECT_TRUE(cv.inpainted);
  int labels = 0;
  for (size_t i = 0; i < cv.labels.size(); ++i) labels += cv.labels.data()[i] != 0;
  EXPECT_EQ(labels, static_cast<int>(reply.hole_px()));
  EXPECT_TRUE(m1.chunks.count(reply.mesh_chunk_id()));
  ASSERT_TRUE(viewer->Sync({}).ok());
  EXPECT_TRUE(viewer->store().model().views.count(reply.view_id()));

  const CpuRenderOutput after = RenderAt(viewer->store().model(), pose);
  const double coverage_after = double(after.covered_pixels) / n;
  std::cout << "coverage at the pose: before " << coverage_before << ", after " << coverage_after
            << "\n";
  EXPECT_GE(coverage_after, 0.995);
  // Outside the holes the render is unchanged.
  size_t same = 0, compared = 0;
  for (int y = 0; y < Cam().height; ++y)
    for (int x = 0; x < Cam().width; ++x) {
      if (!before.coverage.at(x, y)) continue;
      ++compared;
      bool eq = true;
      for (int k = 0; k < 3; ++k)
        eq &= std::abs(int(after.color.at(x, y, k)) - int(before.color.at(x, y, k))) <= 2;
      same += eq;
    }
  EXPECT_GE(double(same) / compared, 0.99) << same << " of " << compared;

  // Again at the same camera: nothing (left) to complete.
  st = Complete(Cam(), pose, &reply);
  ASSERT_TRUE(st.ok()) << st.error_message();
  EXPECT_EQ(reply.outcome(), v1::CompleteViewReply::NOTHING_TO_COMPLETE)
      << reply.ShortDebugString();
  const uint32_t id = other->store().model().views.rbegin()->first;

  // A restart from the checkpoint keeps the completion view and its mesh.
  std::this_thread::sleep_for(std::chrono::milliseconds(600));  // the periodic checkpoint
  server_->Signal(SIGTERM);
  ASSERT_TRUE(server_->Wait(20).has_value());
  Start("server2.log");
  auto restarted = Viewer();
  ASSERT_TRUE(restarted->store().model().views.count(id)) << server_->Log();
  const v1::Stats s1 = Stats();
  EXPECT_EQ(s1.counters().at("completion.views"), 1.0);

  // Frames that observe the hole: the server withdraws or shrinks the completion view.
  ASSERT_NO_FATAL_FAILURE(Upload(100, 12, 0.9 - 2.0));  // x = 0.9 + 0.02 (k - 100) ... ahead
  WaitProcessed();
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  double changed = 0;
  for (; std::chrono::steady_clock::now() < deadline;) {
    const v1::Stats s = Stats();
    changed = s.counters().at("completion.withdrawn") + s.counters().at("completion.refreshed");
    if (changed > 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  EXPECT_GT(changed, 0.0) << server_->Log();
  auto late = Viewer();
  const auto& lv = late->store().model().views;
  if (lv.count(id)) {
    int left = 0;
    for (size_t i = 0; i < lv.at(id).labels.size(); ++i) left += lv.at(id).labels.data()[i] != 0;
    EXPECT_LT(left, labels);
  }
}

}  // namespace
}  // namespace exo
