// Durable acknowledgements (issue 20 item 3, SPEC §14): a real exoview_server process with a
// checkpoint and its frame journal on loopback is killed with SIGKILL at 20 random moments while
// an uploader (uploader id, reconnect + resend) streams. After each restart every frame that was
// acked durable before the kill is in the recovered model's applied-frame ledger, the ledger is
// contiguous (no frame lost in between) and no frame came twice; at the end every frame was acked
// durable exactly once, the final checkpoint holds each frame once, and no two stored views share
// a pose (a frame applied twice would add its view again under a new id). Then the same frames go
// through a server that is never interrupted: the stored views (ids, poses, exposures) and the
// geometry, planning and model digests must be equal (the checkpoint carries the pipeline's
// state, the journal replays through the same stages; refinement, asynchronous and
// timing-driven, is off in both runs: docs/security.md §4).
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <thread>

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include "client/uploader/synth_source.h"
#include "client/uploader/upload_client.h"
#include "proto/exoview.grpc.pb.h"
#include "tests/durable_upload.h"
#include "tests/server_fixture.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using testing::ReadAll;
using testing::Subprocess;
using testing::WaitForFile;

using testing::FreeLoopbackPort;

constexpr char kUploader[] = "crash-test";

class ServiceDurable : public testing::ServerProcessTest {
 protected:
  // The same fixed port every time, so the uploader's channel reconnects to the new process.
  void Start(int port, int life, const std::string& sub = "") {
    const std::string dir = dir_ + sub;
    std::filesystem::create_directories(dir);
    const std::string port_file = dir + "/port";
    std::filesystem::remove(port_file);
    std::vector<std::string> args{"--listen=127.0.0.1:" + std::to_string(port),
                                  "--port_file=" + port_file,
                                  "--checkpoint_path=" + dir + "/model.ckpt",
                                  "--checkpoint_interval_s=0.3", "--admission_block=true",
                                  "--voxel_size_m=0.08", "--mesh_every_n_frames=5",
                                  "--fuse_depth_downscale=2",
                                  // Refinement is asynchronous and skips views under load (its
                                  // output depends on timing, not only on the frames): off, so
                                  // the killed and the uninterrupted runs can be compared.
                                  "--refinement=false"};
    for (const std::string& f : ExtraFlags()) args.push_back(f);
    server_ = std::make_unique<Subprocess>(EXOVIEW_SERVER_BIN, args,
                                           dir + "/server" + std::to_string(life) + ".log");
    ASSERT_TRUE(WaitForFile(port_file, 30)) << server_->Log();
    target_ = "127.0.0.1:" + std::to_string(port);
  }
  // Measurement hook: EXO_DURABLE_FLAGS="--a=1 --b=2" adds server flags to every run.
  static std::vector<std::string> ExtraFlags() {
    std::vector<std::string> out;
    if (const char* e = getenv("EXO_DURABLE_FLAGS")) {
      std::istringstream in(e);
      for (std::string f; in >> f;) out.push_back(f);
    }
    return out;
  }
  // What the comparison with an uninterrupted run looks at, per component.
  struct Fingerprint {
    uint64_t store_digest = 0;
    double geometry_digest = 0, planning_digest = 0;
    uint32_t views = 0, chunks = 0, cells = 0;
    std::map<uint32_t, std::string> view_poses;  // id -> pose bytes + exposure (final checkpoint)
    std::string ToString() const {
      std::ostringstream o;
      o << "store digest " << store_digest << ", geometry digest "
        << static_cast<uint64_t>(geometry_digest) << ", planning digest "
        << static_cast<uint64_t>(planning_digest) << ", " << views << " views, " << chunks
        << " chunks, " << cells << " cells";
      return o.str();
    }
  };
  // Waits until every frame went through every stage and no async work is pending, reads the
  // digests, stops the server gracefully and reads the stored views from its final checkpoint.
  void Settle(int frames, const std::string& sub, Fingerprint* fp) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    v1::Stats st;
    for (uint64_t last_version = ~uint64_t{0};;) {
      auto p = Progress(&st);
      if (p && p->applied_max_sequence() == static_cast<uint64_t>(frames) &&
          st.async_pending() == 0 && st.model_version() == last_version)
        break;
      last_version = st.model_version();
      ASSERT_LT(std::chrono::steady_clock::now(), deadline) << server_->Log();
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    fp->store_digest = st.model_digest();
    fp->geometry_digest = st.counters().count("geometry.digest") ? st.counters().at("geometry.digest") : 0;
    fp->planning_digest = st.counters().count("planning.digest") ? st.counters().at("planning.digest") : 0;
    fp->views = st.num_views();
    fp->chunks = st.num_chunks();
    fp->cells = st.num_cells();
    server_->Signal(SIGTERM);
    ASSERT_EQ(server_->Wait(30), 0) << server_->Log();
    server_.reset();
    v1::Checkpoint c;
    std::ifstream in(dir_ + sub + "/model.ckpt", std::ios::binary);
    ASSERT_TRUE(c.ParseFromIstream(&in));
    for (const auto& d : c.model())
      if (d.has_view_added()) {
        const auto& v = d.view_added();
        fp->view_poses[v.view_id()] =
            v.local_from_cam().SerializeAsString() + "/" + std::to_string(v.exposure());
      }
  }
  static void ExpectSameModel(const Fingerprint& got, const Fingerprint& want) {
    EXPECT_EQ(got.ToString(), want.ToString());
    std::vector<uint32_t> only_got, only_want, moved;
    for (const auto& [id, pose] : got.view_poses) {
      auto it = want.view_poses.find(id);
      if (it == want.view_poses.end()) only_got.push_back(id);
      else if (it->second != pose) moved.push_back(id);
    }
    for (const auto& [id, pose] : want.view_poses)
      if (!got.view_poses.count(id)) only_want.push_back(id);
    auto list = [](const std::vector<uint32_t>& v) {
      std::string s;
      for (uint32_t id : v) s += " " + std::to_string(id);
      return s;
    };
    EXPECT_TRUE(only_got.empty() && only_want.empty() && moved.empty())
        << got.view_poses.size() << " vs " << want.view_poses.size()
        << " views; only after the kills:" << list(only_got)
        << "; only uninterrupted:" << list(only_want) << "; other pose/exposure:" << list(moved);
  }
  static absl::StatusOr<v1::Frame> LoadFrame(SynthFrameSource* source, size_t i) {
    EXO_ASSIGN_OR_RETURN(Frame f, source->Load(i));
    return FrameToProto(f, UploadOptions{}.encode);
  }
  static std::unique_ptr<SynthFrameSource> MakeSource(int frames) {
    SynthSourceOptions so;
    so.scene = "apartment";
    so.trajectory = "walk";
    so.num_frames = frames;
    so.width = 160;
    so.height = 120;
    auto source = SynthFrameSource::Create(so);
    EXPECT_TRUE(source.ok()) << source.status();
    return source.ok() ? *std::move(source) : nullptr;
  }
  // The same frames through a server that is never interrupted (its own directory).
  void RunUninterrupted(int frames, Fingerprint* fp) {
    const int port = FreeLoopbackPort();
    ASSERT_NO_FATAL_FAILURE(Start(port, 0, "/uninterrupted"));
    auto source = MakeSource(frames);
    ASSERT_TRUE(source);
    testing::DurableUploadThread uploader(
        target_, kUploader, frames, [&](size_t i) { return LoadFrame(source.get(), i); });
    const absl::StatusOr<UploadAckStats>& result = uploader.Join();
    ASSERT_TRUE(result.ok()) << result.status();
    ASSERT_EQ(result->durable, static_cast<uint64_t>(frames));
    ASSERT_NO_FATAL_FAILURE(Settle(frames, "/uninterrupted", fp));
  }

  std::optional<v1::UploaderProgress> Progress(v1::Stats* stats) {
    *stats = Stats();
    for (const auto& u : stats->uploaders())
      if (u.uploader() == kUploader) return u;
    return std::nullopt;
  }
};

TEST_F(ServiceDurable, KillNineAtTwentyRandomMomentsLosesNoDurableFrameAndAppliesNoneTwice) {
  constexpr int kFrames = 600, kKills = 20;
  const int port = FreeLoopbackPort();
  ASSERT_NO_FATAL_FAILURE(Start(port, 0));

  SynthSourceOptions so;
  so.scene = "apartment";
  so.trajectory = "walk";
  so.num_frames = kFrames;
  so.width = 160;
  so.height = 120;
  auto source = SynthFrameSource::Create(so);
  ASSERT_TRUE(source.ok()) << source.status();

  testing::DurableUploadThread uploader(target_, kUploader, kFrames,
                                        [&](size_t i) -> absl::StatusOr<v1::Frame> {
                                          EXO_ASSIGN_OR_RETURN(Frame f, (*source)->Load(i));
                                          return FrameToProto(f, UploadOptions{}.encode);
                                        });
  std::mt19937 rng(20);
  std::uniform_real_distribution<double> wait_s(0.05, 0.7);
  double replayed_total = 0;
  int kills = 0;
  for (; kills < kKills && !uploader.done(); ++kills) {
    std::this_thread::sleep_for(std::chrono::duration<double>(wait_s(rng)));
    server_->Signal(SIGKILL);
    ASSERT_TRUE(server_->Wait(10).has_value());
    const uint64_t acked = uploader.max_durable_acked();
    ASSERT_NO_FATAL_FAILURE(Start(port, kills + 1));
    // The restarted server's ledger: checkpoint + journal replay through the pipeline.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    v1::Stats st;
    std::optional<v1::UploaderProgress> p;
    for (;;) {
      p = Progress(&st);
      if (acked == 0 || (p && p->applied_max_sequence() >= acked)) break;
      ASSERT_LT(std::chrono::steady_clock::now(), deadline)
          << "kill " << kills + 1 << ": frames up to " << acked << " were acked durable, the "
          << "restarted server applied up to " << (p ? p->applied_max_sequence() : 0) << "\n"
          << server_->Log();
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    replayed_total += st.counters().at("journal.replayed");
    if (!p) continue;
    SCOPED_TRACE(::testing::Message() << "after kill " << kills + 1 << ": " << p->DebugString());
    EXPECT_EQ(p->applied_frames(), p->applied_max_sequence());  // 1..max, none missing
    EXPECT_EQ(p->double_applied(), 0u);
    EXPECT_EQ(st.counters().at("journal.not_durable"), 0.0);
  }
  const absl::StatusOr<UploadAckStats>& result = uploader.Join();
  const std::multiset<uint64_t> durable_acked = uploader.durable_acked();  // repeats included
  ASSERT_TRUE(result.ok()) << result.status();
  EXPECT_EQ(kills, kKills) << "the upload ended before the 20th kill";
  EXPECT_GT(replayed_total, 0.0) << "no restart replayed the journal: the test missed its point";

  // Every frame acked once, durable; nothing rejected or dropped.
  EXPECT_EQ(result->accepted, static_cast<uint64_t>(kFrames)) << result->ToJson();
  EXPECT_EQ(result->durable, static_cast<uint64_t>(kFrames));
  EXPECT_EQ(result->rejected + result->dropped, 0u);
  // (A kill during a restart, before the uploader came back, costs no reconnect of its own.)
  EXPECT_GE(result->reconnects, static_cast<uint64_t>(kKills / 2));
  EXPECT_EQ(durable_acked.size(), static_cast<size_t>(kFrames));
  EXPECT_EQ(std::set<uint64_t>(durable_acked.begin(), durable_acked.end()).size(),
            static_cast<size_t>(kFrames));
  std::printf("{\"kills\": %d, \"frames\": %d, \"replayed\": %.0f, \"resent\": %llu, "
              "\"duplicates\": %llu, \"reconnects\": %llu}\n",
              kills, kFrames, replayed_total, static_cast<unsigned long long>(result->resent),
              static_cast<unsigned long long>(result->duplicates),
              static_cast<unsigned long long>(result->reconnects));

  // Wait for the pipeline to settle (digests), stop gracefully, read the final checkpoint.
  Fingerprint after_kills;
  ASSERT_NO_FATAL_FAILURE(Settle(kFrames, "", &after_kills));
  v1::Checkpoint c;
  std::ifstream in(dir_ + "/model.ckpt", std::ios::binary);
  ASSERT_TRUE(c.ParseFromIstream(&in));
  ASSERT_EQ(c.uploaders_size(), 1);
  EXPECT_FALSE(c.pipeline_state().empty()) << "the final checkpoint carries no pipeline state";
  std::printf("{\"checkpoint_bytes\": %zu, \"pipeline_state_bytes\": %zu}\n", c.ByteSizeLong(),
              c.pipeline_state().size());
  EXPECT_EQ(c.uploaders(0).applied_frames(), static_cast<uint64_t>(kFrames));
  EXPECT_EQ(c.uploaders(0).applied_max_sequence(), static_cast<uint64_t>(kFrames));
  EXPECT_EQ(c.uploaders(0).double_applied(), 0u);
  std::set<std::string> poses;
  int views = 0;
  for (const auto& d : c.model())
    if (d.has_view_added()) {
      ++views;
      EXPECT_TRUE(poses.insert(d.view_added().local_from_cam().SerializeAsString()).second)
          << "view " << d.view_added().view_id() << " has the pose of another view";
    }
  EXPECT_GT(views, 0);
  // Truncation: 21 server lives each opened a segment; what the checkpoints covered is gone. The
  // journal keeps what the previous checkpoint generation (model.ckpt.prev, the fallback) does
  // not cover: every closed segment left must hold a record above its applied lsn. A segment's
  // last lsn is below the next segment's first (the file name), so a segment i with
  // first(i + 1) - 1 <= prev.applied_lsn is one that should have been dropped. (How many are left
  // depends on how many short lives passed without a checkpoint of their own: 4-5 here.)
  v1::Checkpoint prev;
  {
    std::ifstream pin(dir_ + "/model.ckpt.prev", std::ios::binary);
    ASSERT_TRUE(prev.ParseFromIstream(&pin));
  }
  std::vector<uint64_t> firsts;
  for (const auto& e : std::filesystem::directory_iterator(dir_ + "/model.ckpt.journal"))
    if (e.path().extension() == ".wal")
      firsts.push_back(std::stoull(e.path().stem().string().substr(4)));  // seg-<lsn>.wal
  std::sort(firsts.begin(), firsts.end());
  EXPECT_LT(firsts.size(), 21u) << "no journal segment was ever dropped";
  for (size_t i = 0; i + 1 < firsts.size(); ++i)
    EXPECT_GT(firsts[i + 1] - 1, prev.applied_lsn())
        << "segment seg-" << firsts[i] << " is covered by the previous checkpoint generation "
        << "(applied lsn " << prev.applied_lsn() << ") but was not dropped";

  // The model is a function of the durable frames alone: the same frames through a server that
  // was never interrupted give the same stored views (ids, poses, exposures), the same geometry
  // and planner digests and the same model digest (what every viewer computes).
  Fingerprint uninterrupted;
  ASSERT_NO_FATAL_FAILURE(RunUninterrupted(kFrames, &uninterrupted));
  std::printf("after %d kills: %s\nuninterrupted: %s\n", kills, after_kills.ToString().c_str(),
              uninterrupted.ToString().c_str());
  ExpectSameModel(after_kills, uninterrupted);
}

// Measurement (not run in CI): uninterrupted twice, or one kill -9 once frame EXO_KILL_AT was
// acked durable, against an uninterrupted run; prints each run's fingerprint.
TEST_F(ServiceDurable, DISABLED_OneKillAgainstUninterrupted) {
  const int frames = getenv("EXO_FRAMES") ? atoi(getenv("EXO_FRAMES")) : 300;
  const uint64_t kill_at = getenv("EXO_KILL_AT") ? atoll(getenv("EXO_KILL_AT")) : 0;
  Fingerprint want, got;
  ASSERT_NO_FATAL_FAILURE(RunUninterrupted(frames, &want));
  std::printf("uninterrupted: %s\n", want.ToString().c_str());
  const int port = FreeLoopbackPort();
  ASSERT_NO_FATAL_FAILURE(Start(port, 0, "/killed"));
  auto source = MakeSource(frames);
  testing::DurableUploadThread uploader(target_, kUploader, frames,
                                        [&](size_t i) { return LoadFrame(source.get(), i); });
  if (kill_at > 0) {
    while (uploader.max_durable_acked() < kill_at)
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    server_->Signal(SIGKILL);
    ASSERT_TRUE(server_->Wait(10).has_value());
    ASSERT_NO_FATAL_FAILURE(Start(port, 1, "/killed"));
  }
  ASSERT_TRUE(uploader.Join().ok());
  ASSERT_NO_FATAL_FAILURE(Settle(frames, "/killed", &got));
  std::printf("killed at %llu: %s\n", static_cast<unsigned long long>(kill_at),
              got.ToString().c_str());
  ExpectSameModel(got, want);
}

}  // namespace
}  // namespace exo
