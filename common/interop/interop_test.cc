#include "common/interop/interop.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <random>

#include "common/interop/readback_for_tests.h"

namespace exo::interop {
namespace {

namespace fs = std::filesystem;
using testing::QuatToMatrix;

class InteropTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/exoview_interop_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string dir_;
};

// A unit cube's 12 triangles (outward), one zero-area triangle and one vertex nobody uses.
TriangleMesh CubeWithJunk() {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i) m.positions.push_back(glm::vec3(i & 1, (i >> 1) & 1, (i >> 2) & 1));
  const uint32_t f[] = {0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4,
                        2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6, 1, 3, 5, 3, 7, 5};
  m.indices.assign(std::begin(f), std::end(f));
  m.positions.push_back(glm::vec3(5, 5, 5));     // 8: unused
  m.positions.push_back(glm::vec3(0, 0, 0));     // 9: duplicate of 0
  m.indices.insert(m.indices.end(), {0, 9, 1});  // zero area
  return m;
}

TEST_F(InteropTest, PlyReadsBackWithCountsAndUnitOutwardNormals) {
  auto nm = PrepareMesh(CubeWithJunk(), glm::dvec3(100.0, -5.0, 0.5));
  ASSERT_TRUE(nm.ok()) << nm.status();
  EXPECT_EQ(nm->dropped_triangles, 1u);
  EXPECT_EQ(nm->dropped_vertices, 2u);
  ASSERT_TRUE(WritePly(dir_ + "/m.ply", *nm, {"hello", "frame world"}).ok());

  const auto ply = testing::ReadBinaryPly(dir_ + "/m.ply");
  ASSERT_EQ(ply.error, "");
  EXPECT_EQ(ply.comments, (std::vector<std::string>{"hello", "frame world"}));
  ASSERT_EQ(ply.vertex.at("x").size(), 8u);
  ASSERT_EQ(ply.faces.size(), 12u);
  const glm::dvec3 centre(100.5, -4.5, 1.0);
  for (size_t i = 0; i < 8; ++i) {
    const glm::dvec3 p(ply.vertex.at("x")[i], ply.vertex.at("y")[i], ply.vertex.at("z")[i]);
    const glm::dvec3 n(ply.vertex.at("nx")[i], ply.vertex.at("ny")[i], ply.vertex.at("nz")[i]);
    EXPECT_NEAR(glm::length(n), 1.0, 1e-6);
    // A cube corner's area-weighted normal points away from the centre.
    EXPECT_GT(glm::dot(n, glm::normalize(p - centre)), 0.5) << i;
    EXPECT_NEAR(std::abs(p.x - 100.5), 0.5, 1e-5);
  }
  for (const auto& f : ply.faces) {
    ASSERT_EQ(f.size(), 3u);
    for (int64_t v : f) EXPECT_LT(v, 8);
  }
}

TEST_F(InteropTest, PrepareMeshRefusesOutOfRangeIndices) {
  TriangleMesh m = CubeWithJunk();
  m.indices.push_back(0);
  EXPECT_FALSE(PrepareMesh(m, {}).ok());  // not a multiple of 3
  m.indices.insert(m.indices.end(), {1, 42});
  EXPECT_FALSE(PrepareMesh(m, {}).ok());  // 42 out of range
}

std::vector<PosedView> RandomViews(int n) {
  std::mt19937 rng(3);
  std::normal_distribution<double> g;
  std::vector<PosedView> v;
  for (int i = 0; i < n; ++i) {
    PosedView p;
    p.id = 10 + 3 * i;
    p.camera = {500 + (i % 2) * 20.0, 505, 319.5, 239.5, 640, 480};
    p.world_from_cam.rotation = glm::normalize(glm::dquat(g(rng), g(rng), g(rng), g(rng)));
    p.world_from_cam.translation = {1e5 + g(rng), g(rng), 3 * g(rng)};
    v.push_back(p);
  }
  return v;
}

void ExpectMatNear(const glm::dmat3& a, const glm::dmat3& b, double tol) {
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) EXPECT_NEAR(a[c][r], b[c][r], tol) << c << "," << r;
}

TEST_F(InteropTest, TumLinesRoundTripCameraToWorld) {
  const auto views = RandomViews(7);
  ASSERT_TRUE(WriteTumTrajectory(dir_ + "/t.tum", views).ok());
  const auto lines = testing::ReadTum(dir_ + "/t.tum");
  ASSERT_EQ(lines.size(), views.size());
  for (size_t i = 0; i < views.size(); ++i) {
    EXPECT_EQ(lines[i].id, views[i].id);
    EXPECT_GE(lines[i].q.w, 0.0);
    ExpectMatNear(QuatToMatrix(lines[i].q), views[i].world_from_cam.RotationMatrix(), 1e-12);
    EXPECT_NEAR(glm::length(lines[i].t - views[i].world_from_cam.translation), 0.0, 1e-9);
  }
}

TEST_F(InteropTest, ColmapImagesAreWorldToCameraAndCamerasArePinholeShifted) {
  const auto views = RandomViews(5);
  std::vector<std::string> names;
  for (const auto& v : views) names.push_back("view_" + std::to_string(v.id) + ".jpg");
  ASSERT_TRUE(WriteColmapText(dir_ + "/c", views, names).ok());
  std::vector<std::string> points;
  const auto imgs = testing::ReadColmapImages(dir_ + "/c/images.txt", &points);
  const auto cams = testing::ReadColmapCameras(dir_ + "/c/cameras.txt");
  ASSERT_EQ(imgs.size(), views.size());
  ASSERT_EQ(cams.size(), 2u);  // two distinct focal lengths
  for (size_t i = 0; i < views.size(); ++i) {
    EXPECT_EQ(imgs[i].id, views[i].id);
    EXPECT_EQ(imgs[i].name, names[i]);
    EXPECT_EQ(points[i], "");
    // x_cam = R x_world + t must send the camera centre to 0 and the optical axis to +z.
    const glm::dmat3 r = QuatToMatrix(imgs[i].q);
    const glm::dvec3 centre = views[i].world_from_cam.translation;
    EXPECT_NEAR(glm::length(r * centre + imgs[i].t), 0.0, 1e-6);
    const glm::dvec3 ahead = views[i].world_from_cam * glm::dvec3(0, 0, 2);
    const glm::dvec3 in_cam = r * ahead + imgs[i].t;
    EXPECT_NEAR(in_cam.x, 0.0, 1e-6);
    EXPECT_NEAR(in_cam.y, 0.0, 1e-6);
    EXPECT_NEAR(in_cam.z, 2.0, 1e-6);
    ExpectMatNear(glm::transpose(r), views[i].world_from_cam.RotationMatrix(), 1e-12);
    const auto& c = cams.at(imgs[i].camera_id);
    EXPECT_EQ(c.model, "PINHOLE");
    EXPECT_EQ(c.width, 640);
    ASSERT_EQ(c.params.size(), 4u);
    EXPECT_DOUBLE_EQ(c.params[0], views[i].camera.fx);
    EXPECT_DOUBLE_EQ(c.params[2], 320.0);  // 319.5 + 0.5
    EXPECT_DOUBLE_EQ(c.params[3], 240.0);
  }
  std::ifstream p(dir_ + "/c/points3D.txt");
  std::string line;
  int data = 0;
  while (std::getline(p, line))
    if (!line.empty() && line[0] != '#') ++data;
  EXPECT_EQ(data, 0);
}

TEST_F(InteropTest, ColmapRefusesNamesWithSpaces) {
  const auto views = RandomViews(1);
  EXPECT_FALSE(WriteColmapText(dir_ + "/c", views, {"a b.jpg"}).ok());
  EXPECT_FALSE(WriteColmapText(dir_ + "/c", views, {}).ok());
}

TEST_F(InteropTest, ExportModelWritesEveryFileInTheWorldFrame) {
  LumigraphModel model;
  model.origin.origin_in_world = {1000, 2000, 3};
  MeshChunk c1, c2;
  const TriangleMesh cube = CubeWithJunk();
  c1.mesh = cube;
  c2.mesh = cube;
  for (auto& p : c2.mesh.positions) p += glm::vec3(2, 0, 0);
  model.chunks[1] = c1;
  model.chunks[2] = c2;
  for (const PosedView& v : RandomViews(3)) {
    StoredView s;
    s.id = v.id;
    s.camera = {50, 50, 15.5, 11.5, 32, 24};
    s.local_from_cam = v.world_from_cam;
    s.color = ImageU8(32, 24, 3, 128);
    model.views[s.id] = s;
  }
  auto sum = ExportModel(model, dir_ + "/out");
  ASSERT_TRUE(sum.ok()) << sum.status();
  EXPECT_EQ(sum->views, 3u);
  EXPECT_EQ(sum->mesh_vertices, 16u);
  EXPECT_EQ(sum->mesh_triangles, 24u);
  EXPECT_EQ(sum->colmap_cameras, 1u);
  EXPECT_EQ(sum->files.size(), 5u + 3u);
  for (const auto& f : sum->files) EXPECT_TRUE(fs::exists(dir_ + "/out/" + f)) << f;
  const auto ply = testing::ReadBinaryPly(dir_ + "/out/mesh.ply");
  ASSERT_EQ(ply.error, "");
  EXPECT_EQ(ply.faces.size(), 24u);
  EXPECT_NEAR(ply.vertex.at("x")[0], 1000.0, 1e-3);  // world frame
  const auto tum = testing::ReadTum(dir_ + "/out/trajectory.tum");
  ASSERT_EQ(tum.size(), 3u);
  const auto& first = model.views.begin()->second;
  EXPECT_NEAR(tum[0].t.x, first.local_from_cam.translation.x + 1000, 1e-6);

  ExportOptions local;
  local.frame = ExportFrame::kLocal;
  local.write_images = false;
  auto sum2 = ExportModel(model, dir_ + "/local", local);
  ASSERT_TRUE(sum2.ok());
  EXPECT_EQ(sum2->files.size(), 5u);
  EXPECT_EQ(sum2->frame, "local");
  EXPECT_NEAR(testing::ReadTum(dir_ + "/local/trajectory.tum")[0].t.x,
              first.local_from_cam.translation.x, 1e-9);
}

}  // namespace
}  // namespace exo::interop
