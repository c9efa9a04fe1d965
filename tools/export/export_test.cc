// exoview_export on models produced the real way: a server (store of 6 views, checkpoint at
// shutdown) takes 24 synthetic frames from exoview_uploader while exoview_viewer syncs and saves
// its store (and renders a few views on and off the path); exoview_export writes both the
// viewer's model file and the server's checkpoint.
// The exports are read back by a minimal binary-PLY/TUM/COLMAP parser written from the format
// specifications (readback_for_tests.h) and compared with the model itself and with each other,
// and by independent Python readers (read_exports.py: numpy + struct, and Open3D).
#include <gtest/gtest.h>

#include <csignal>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <set>

#include "common/interop/readback_for_tests.h"
#include "common/lumigraph/model_io.h"
#include "exoview_source_dir.h"
#include "tests/server_fixture.h"
#include "tests/subprocess.h"

namespace exo {
namespace {

using testing::ReadAll;
using testing::Subprocess;
namespace rb = interop::testing;

class ExportTest : public testing::ServerProcessTest {};

void ExpectMatNear(const glm::dmat3& a, const glm::dmat3& b, double tol) {
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) EXPECT_NEAR(a[c][r], b[c][r], tol) << c << "," << r;
}

TEST_F(ExportTest, ViewerStoreAndCheckpointExportAndReadBack) {
  constexpr int kFrames = 24, kStore = 6;
  StartServer({"--checkpoint_path=" + dir_ + "/model.ckpt", "--checkpoint_interval_s=0",
               "--max_views=" + std::to_string(kStore)});
  Subprocess viewer(EXOVIEW_VIEWER_BIN,
                    {"--server=" + target_, "--until_frames=" + std::to_string(kFrames),
                     "--save_model=" + dir_ + "/viewer.model", "--state_json=" + dir_ + "/v.json",
                     // and the novel views of the demo, small: on the path and off it
                     "--render_frames=2", "--test_views=2", "--test_sets=near,scene", "--gt_png",
                     "--width=64", "--height=48", "--renderer=cpu", "--out=" + dir_ + "/views"},
                    dir_ + "/viewer.log");
  Subprocess up(
      EXOVIEW_UPLOADER_BIN,
      {"--server=" + target_, "--synthetic=apartment", "--trajectory=walk",
       "--frames=" + std::to_string(kFrames), "--width=160", "--height=120", "--rate_hz=30"},
      dir_ + "/up.log");
  ASSERT_EQ(up.Wait(90), 0) << up.Log();
  ASSERT_EQ(viewer.Wait(90), 0) << viewer.Log();
  server_->Signal(SIGTERM);  // graceful: writes the checkpoint
  ASSERT_EQ(server_->Wait(30), 0) << server_->Log();
  server_.reset();

  // The viewer's report: MSSIM per set, one record per view with its PNGs.
  const auto report = nlohmann::json::parse(ReadAll(dir_ + "/views/viewer_report.json"));
  for (const char* set : {"path", "near", "scene"}) {
    ASSERT_TRUE(report["sets"].contains(set)) << report.dump();
    EXPECT_EQ(report["sets"][set]["views"], 2);
    const double mssim = report["sets"][set]["mssim"];
    EXPECT_GT(mssim, 0.0);
    EXPECT_LE(mssim, 1.0);
  }
  ASSERT_EQ(report["per_frame"].size(), 6u);
  for (const auto& r : report["per_frame"]) {
    EXPECT_TRUE(std::filesystem::exists(dir_ + "/views/" + r["png"].get<std::string>())) << r;
    EXPECT_TRUE(std::filesystem::exists(dir_ + "/views/" + r["gt_png"].get<std::string>())) << r;
  }
  EXPECT_EQ(report["store"]["views"], kStore);

  auto model = LoadModel(dir_ + "/viewer.model");
  ASSERT_TRUE(model.ok()) << model.status();
  ASSERT_EQ(model->views.size(), size_t{kStore});  // 24 frames into a store of 6: it chose
  ASSERT_FALSE(model->chunks.empty());

  for (const char* input : {"--model", "--checkpoint"}) {
    const std::string out = dir_ + (std::string(input) == "--model" ? "/exp_model" : "/exp_ckpt");
    const std::string file = std::string(input) == "--model" ? "/viewer.model" : "/model.ckpt";
    Subprocess ex(EXOVIEW_EXPORT_BIN, {input, dir_ + file, "--out", out}, out + ".log");
    ASSERT_EQ(ex.Wait(60), 0) << ex.Log();
  }

  // The mesh: counts computed here from the model (triangles of non-zero area, the vertices
  // they use), unit normals, positions in the world frame.
  size_t triangles = 0;
  std::set<std::pair<uint64_t, uint32_t>> used;
  glm::dvec3 lo(1e30), hi(-1e30);
  for (const auto& [id, c] : model->chunks)
    for (size_t t = 0; t < c.mesh.indices.size(); t += 3) {
      const glm::dvec3 a(c.mesh.positions[c.mesh.indices[t]]),
          b(c.mesh.positions[c.mesh.indices[t + 1]]), d(c.mesh.positions[c.mesh.indices[t + 2]]);
      if (!(glm::length(glm::cross(b - a, d - a)) > 0)) continue;
      ++triangles;
      for (int k = 0; k < 3; ++k) {
        used.insert({id, c.mesh.indices[t + k]});
        const glm::dvec3 p =
            glm::dvec3(c.mesh.positions[c.mesh.indices[t + k]]) + model->origin.origin_in_world;
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
      }
    }
  const auto ply = rb::ReadBinaryPly(dir_ + "/exp_model/mesh.ply");
  ASSERT_EQ(ply.error, "");
  ASSERT_EQ(ply.faces.size(), triangles);
  ASSERT_EQ(ply.vertex.at("x").size(), used.size());
  for (size_t i = 0; i < used.size(); ++i) {
    const glm::dvec3 n(ply.vertex.at("nx")[i], ply.vertex.at("ny")[i], ply.vertex.at("nz")[i]);
    ASSERT_NEAR(glm::length(n), 1.0, 1e-5) << i;
    const glm::dvec3 p(ply.vertex.at("x")[i], ply.vertex.at("y")[i], ply.vertex.at("z")[i]);
    ASSERT_TRUE(glm::all(glm::greaterThanEqual(p, lo - 1e-4)) &&
                glm::all(glm::lessThanEqual(p, hi + 1e-4)));
  }
  for (const auto& f : ply.faces) {
    ASSERT_EQ(f.size(), 3u);
    for (int64_t v : f) ASSERT_LT(v, static_cast<int64_t>(used.size()));
  }

  // TUM: one line per stored view, camera-to-world, the quaternion gives the stored rotation.
  const auto tum = rb::ReadTum(dir_ + "/exp_model/trajectory.tum");
  ASSERT_EQ(tum.size(), model->views.size());
  for (const auto& line : tum) {
    ASSERT_TRUE(model->views.count(line.id)) << line.id;
    const StoredView& v = model->views.at(line.id);
    ExpectMatNear(rb::QuatToMatrix(line.q), v.local_from_cam.RotationMatrix(), 1e-12);
    EXPECT_NEAR(
        glm::length(line.t - (v.local_from_cam.translation + model->origin.origin_in_world)), 0.0,
        1e-9);
  }
  // COLMAP: world-to-camera, the stored view's centre maps to the camera origin.
  std::vector<std::string> points;
  const auto imgs = rb::ReadColmapImages(dir_ + "/exp_model/colmap/images.txt", &points);
  const auto cams = rb::ReadColmapCameras(dir_ + "/exp_model/colmap/cameras.txt");
  ASSERT_EQ(imgs.size(), model->views.size());
  for (const auto& im : imgs) {
    const StoredView& v = model->views.at(im.id);
    const glm::dmat3 r = rb::QuatToMatrix(im.q);
    ExpectMatNear(glm::transpose(r), v.local_from_cam.RotationMatrix(), 1e-12);
    const glm::dvec3 centre = v.local_from_cam.translation + model->origin.origin_in_world;
    EXPECT_NEAR(glm::length(r * centre + im.t), 0.0, 1e-9);
    const auto& cam = cams.at(im.camera_id);
    EXPECT_EQ(cam.model, "PINHOLE");
    EXPECT_EQ(cam.width, v.camera.width);
    EXPECT_DOUBLE_EQ(cam.params[0], v.camera.fx);
    EXPECT_DOUBLE_EQ(cam.params[2], v.camera.cx + 0.5);
    EXPECT_TRUE(std::filesystem::exists(dir_ + "/exp_model/colmap/images/" + im.name)) << im.name;
  }
  for (const auto& p : points) EXPECT_EQ(p, "");

  // The checkpoint holds the same model as the synced viewer: the same exports.
  EXPECT_EQ(ReadAll(dir_ + "/exp_ckpt/trajectory.tum"),
            ReadAll(dir_ + "/exp_model/trajectory.tum"));
  EXPECT_EQ(ReadAll(dir_ + "/exp_ckpt/colmap/images.txt"),
            ReadAll(dir_ + "/exp_model/colmap/images.txt"));
  // Same vertices and triangles; the normals differ in origin: the checkpoint's chunks carry the
  // TSDF's normals, the model file none (computed from the triangles): both unit length, and
  // they agree in orientation almost everywhere.
  const auto ck = rb::ReadBinaryPly(dir_ + "/exp_ckpt/mesh.ply");
  ASSERT_EQ(ck.error, "");
  ASSERT_TRUE(ck.faces == ply.faces);
  for (const char* k : {"x", "y", "z"}) ASSERT_TRUE(ck.vertex.at(k) == ply.vertex.at(k)) << k;
  size_t agree = 0;
  for (size_t i = 0; i < used.size(); ++i) {
    const glm::dvec3 a(ply.vertex.at("nx")[i], ply.vertex.at("ny")[i], ply.vertex.at("nz")[i]);
    const glm::dvec3 b(ck.vertex.at("nx")[i], ck.vertex.at("ny")[i], ck.vertex.at("nz")[i]);
    ASSERT_NEAR(glm::length(b), 1.0, 1e-5) << i;
    agree += glm::dot(a, b) > 0;
  }
  EXPECT_GT(static_cast<double>(agree) / used.size(), 0.99);

  // The independent Python reader agrees on both.
  for (const char* d : {"/exp_model", "/exp_ckpt"}) {
    Subprocess py("/usr/bin/python3",
                  {std::string(EXOVIEW_SOURCE_DIR) + "/tools/export/read_exports.py", dir_ + d,
                   "--views", std::to_string(kStore), "--require_open3d"},
                  dir_ + d + "_py.log");
    EXPECT_EQ(py.Wait(60), 0) << py.Log();
  }
}

TEST_F(ExportTest, BadInputIsAClearError) {
  std::ofstream(dir_ + "/junk.model") << "not a model";
  Subprocess a(EXOVIEW_EXPORT_BIN, {"--model", dir_ + "/junk.model", "--out", dir_ + "/o"},
               dir_ + "/a.log");
  EXPECT_EQ(a.Wait(30), 1);
  Subprocess b(EXOVIEW_EXPORT_BIN, {"--checkpoint", dir_ + "/junk.model", "--out", dir_ + "/o"},
               dir_ + "/b.log");
  EXPECT_EQ(b.Wait(30), 1);
  EXPECT_NE(b.Log().find("checkpoint"), std::string::npos) << b.Log();
  Subprocess c(EXOVIEW_EXPORT_BIN, {"--out", dir_ + "/o"}, dir_ + "/c.log");
  EXPECT_EQ(c.Wait(30), 2);
  Subprocess d(
      EXOVIEW_EXPORT_BIN,
      {"--model", dir_ + "/junk.model", "--checkpoint", dir_ + "/junk.model", "--out", "o"},
      dir_ + "/d.log");
  EXPECT_EQ(d.Wait(30), 2);
}

}  // namespace
}  // namespace exo
