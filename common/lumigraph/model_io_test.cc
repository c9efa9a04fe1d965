#include "common/lumigraph/model_io.h"

#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

namespace exo {
namespace {

LumigraphModel SmallModel() {
  LumigraphModel m;
  m.origin.origin_in_world = {1e5, -2.5, 3.25};
  m.grid.cell_size_m = 0.37;
  m.version = 42;
  for (ViewId id : {3u, 9u}) {
    StoredView v;
    v.id = id;
    v.camera = PinholeCamera::FromFov(32, 24, 1.1);
    v.local_from_cam.translation = {0.5 * id, -1.0, 2.0};
    v.local_from_cam.rotation = glm::normalize(glm::dquat(0.9, 0.1 * id, -0.2, 0.3));
    v.exposure = 0.8f + 0.1f * id;
    v.color = ImageU8(32, 24, 3);
    v.depth_m = ImageF(32, 24, 1, 0.0f);
    for (int y = 0; y < 24; ++y)
      for (int x = 0; x < 32; ++x) {
        for (int c = 0; c < 3; ++c) v.color.at(x, y, c) = uint8_t((x * 7 + y * 3 + c * 50 + id) % 256);
        v.depth_m.at(x, y) = (x + y) % 5 == 0 ? 0.0f : 0.5f + 0.01f * x + 0.1f * y;
      }
    v.depth_m.at(0, 1) = std::nanf("");     // invalid values are stored as 0
    v.depth_m.at(1, 1) = -3.0f;
    m.views[id] = v;
  }
  m.cell_refs[PackCell({1, 2, 3})] = {3, 9};
  m.cell_refs[PackCell({-4, 0, 7})] = {9};
  m.cell_coverage[PackCell({1, 2, 3})] = 100;
  m.cell_coverage[PackCell({-4, 0, 7})] = 37;
  MeshChunk c;
  c.id = 17;
  c.version = 5;
  c.mesh.positions = {{0, 0, 1}, {1, 0, 1}, {0, 1, 1.5f}};
  c.mesh.indices = {0, 1, 2};
  m.chunks[17] = c;
  return m;
}

TEST(ModelIoTest, RoundTripIsExactForRawColourAndQuantisedDepth) {
  const LumigraphModel m = SmallModel();
  auto bytes = SerializeModel(m);
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  auto back = DeserializeModel(*bytes);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->origin.origin_in_world, m.origin.origin_in_world);
  EXPECT_EQ(back->grid.cell_size_m, m.grid.cell_size_m);
  EXPECT_EQ(back->version, 42u);
  EXPECT_EQ(back->cell_refs, m.cell_refs);
  EXPECT_EQ(back->cell_coverage, m.cell_coverage);
  ASSERT_EQ(back->chunks.size(), 1u);
  EXPECT_EQ(back->chunks.at(17).version, 5u);
  EXPECT_EQ(back->chunks.at(17).mesh.positions, m.chunks.at(17).mesh.positions);
  EXPECT_EQ(back->chunks.at(17).mesh.indices, m.chunks.at(17).mesh.indices);
  ASSERT_EQ(back->views.size(), 2u);
  for (const auto& [id, v] : m.views) {
    const StoredView& b = back->views.at(id);
    EXPECT_EQ(b.camera.fx, v.camera.fx);
    EXPECT_EQ(b.camera.width, v.camera.width);
    EXPECT_EQ(b.local_from_cam.translation, v.local_from_cam.translation);
    EXPECT_EQ(b.local_from_cam.rotation, v.local_from_cam.rotation);
    EXPECT_EQ(b.exposure, v.exposure);
    EXPECT_EQ(0, std::memcmp(b.color.data(), v.color.data(), v.color.size()));
    for (int y = 0; y < 24; ++y)
      for (int x = 0; x < 32; ++x) {
        const float z = v.depth_m.at(x, y);
        if (std::isfinite(z) && z > 0.0f) {
          EXPECT_NEAR(b.depth_m.at(x, y), z, 0.0005) << x << "," << y;  // min step 0.5 mm
        } else {
          EXPECT_EQ(b.depth_m.at(x, y), 0.0f) << x << "," << y;
        }
      }
  }
}

TEST(ModelIoTest, JpegColourIsClose) {
  ModelIoOptions o;
  o.color_jpeg_quality = 95;
  const LumigraphModel m = SmallModel();
  auto bytes = SerializeModel(m, o);
  ASSERT_TRUE(bytes.ok()) << bytes.status();
  auto back = DeserializeModel(*bytes);
  ASSERT_TRUE(back.ok()) << back.status();
  double err = 0;
  const auto& a = m.views.at(3).color;
  const auto& b = back->views.at(3).color;
  for (size_t i = 0; i < a.size(); ++i) err += std::abs(int(a.data()[i]) - int(b.data()[i]));
  EXPECT_LT(err / a.size(), 20.0);  // lossy but the same picture
}

TEST(ModelIoTest, TruncatedFilesAreClearErrors) {
  // Guard: every length is checked against the remaining bytes (no read past the end).
  auto bytes = SerializeModel(SmallModel());
  ASSERT_TRUE(bytes.ok());
  for (size_t n : {size_t(0), size_t(7), size_t(15), size_t(40), bytes->size() / 2, bytes->size() - 1}) {
    auto r = DeserializeModel(std::span<const uint8_t>(bytes->data(), n));
    ASSERT_FALSE(r.ok()) << "prefix of " << n << " bytes accepted";
    EXPECT_EQ(r.status().code(), absl::StatusCode::kDataLoss) << r.status();
  }
}

TEST(ModelIoTest, CorruptBytesAreDetected) {
  // Guard: the per-section checksum (a flipped bit inside a payload is not silently accepted).
  auto bytes = SerializeModel(SmallModel());
  ASSERT_TRUE(bytes.ok());
  for (size_t at : {size_t(40), bytes->size() / 3, bytes->size() / 2, bytes->size() - 20}) {
    std::vector<uint8_t> bad = *bytes;
    bad[at] ^= 0x10;
    auto r = DeserializeModel(bad);
    EXPECT_FALSE(r.ok()) << "flip at " << at << " accepted";
  }
  std::vector<uint8_t> bad_magic = *bytes;
  bad_magic[0] = 'X';
  auto r = DeserializeModel(bad_magic);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("magic"), std::string::npos);
  std::vector<uint8_t> future = *bytes;
  future[8] = 99;  // format version
  r = DeserializeModel(future);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("version"), std::string::npos);
}

TEST(ModelIoTest, SaveLoadAndMissingFile) {
  const std::string path = ::testing::TempDir() + "/model_io_test.exomodel";
  ASSERT_TRUE(SaveModel(path, SmallModel()).ok());
  auto m = LoadModel(path);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->views.size(), 2u);
  std::remove(path.c_str());
  auto missing = LoadModel(path);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
}

TEST(ModelIoTest, RejectsInconsistentViews) {
  LumigraphModel m = SmallModel();
  m.views.at(3).color = ImageU8(8, 8, 3);
  EXPECT_FALSE(SerializeModel(m).ok());
  ModelIoOptions o;
  o.color_jpeg_quality = 101;
  EXPECT_FALSE(SerializeModel(SmallModel(), o).ok());
}

}  // namespace
}  // namespace exo
