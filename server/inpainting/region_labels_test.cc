#include "server/inpainting/region_labels.h"

#include <gtest/gtest.h>

#include <random>

#include <opencv2/imgproc.hpp>

#include "server/inpainting/keyframe_policy.h"
#include "server/inpainting/test_scenes.h"

namespace exo::inpainting {
namespace {

using testing::RenderPlanes;
using testing::SmallCamera;
using testing::WorldPlane;

// A wall at z = 2 m and a box face at z = 1.5 m for x in [-0.3, 0].
std::vector<WorldPlane> BoxScene() {
  return {{glm::dvec3(0, 0, -1), -2.0, nullptr},
          {glm::dvec3(0, 0, -1), -1.5,
           [](const glm::dvec3& p) { return p.x < 0.0 && p.x > -0.3 && std::fabs(p.y) < 0.3; }}};
}

RegionOptions Opts() {
  RegionOptions o;
  o.roi.radius_px = 15;
  o.roi.depth_tol_m = 0.1;
  o.roi.dilate_px = 0;
  o.voxel_m = 0.02;
  return o;
}

Rigid3d Translated(double x, double y, double z) {
  Rigid3d p;
  p.translation = {x, y, z};
  return p;
}

TEST(RegionLabels, VoxelKeysRoundTrip) {
  for (glm::ivec3 v : {glm::ivec3(0, 0, 0), glm::ivec3(-5, 7, -1000000), glm::ivec3(1000000, -1, 3)})
    EXPECT_EQ(UnpackVoxel(PackVoxel(v.x, v.y, v.z)), v);
  EXPECT_NE(PackVoxel(1, 0, 0), PackVoxel(0, 1, 0));
}

TEST(RegionLabels, StrokeOnTheBoxLabelsTheBoxAndReprojectsIntoAMovedFrame) {
  const PinholeCamera cam = SmallCamera();
  const auto planes = BoxScene();
  const RgbdKeyframe f0 = RenderPlanes(planes, cam, Rigid3d::Identity());
  const std::vector<glm::dvec2> stroke = {{60.0, 60.0}, {70.0, 60.0}};
  auto r = RegionFromStroke(stroke, f0.depth_m, cam, Rigid3d::Identity(), Opts());
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_GT(r->labelled_pixels, 300);
  EXPECT_NEAR(r->centroid_local.z, 1.5, 0.01);  // on the box, not the wall
  // A second frame 10 cm to the right: the box moves left in the image; the re-projected ROI is
  // on the box (z = 1.5) and never on the wall.
  const Rigid3d pose1 = Translated(0.1, 0.0, 0.0);
  const RgbdKeyframe f1 = RenderPlanes(planes, cam, pose1);
  const Region3D* regs[] = {&*r};
  RegionLabels labels(regs);
  RegionOptions o = Opts();
  o.reproject_close_px = 0;
  o.reproject_dilate_px = 0;
  const ImageU8 m1 = ProjectRegions(labels, f1.depth_m, cam, pose1, o);
  int box = 0, wall = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x)
      if (m1.at(x, y)) (f1.depth_m.at(x, y) < 1.75f ? box : wall)++;
  EXPECT_EQ(wall, 0);
  EXPECT_GT(box, 250);
}

TEST(RegionLabels, HardCasesGiveClearStatuses) {
  const PinholeCamera cam = SmallCamera();
  const RgbdKeyframe f = RenderPlanes(BoxScene(), cam, Rigid3d::Identity());
  const RegionOptions o = Opts();
  // Empty stroke, stroke outside the image, non-finite point.
  EXPECT_EQ(RegionFromStroke({}, f.depth_m, cam, {}, o).status().code(),
            absl::StatusCode::kInvalidArgument);
  const std::vector<glm::dvec2> outside = {{-100.0, 5.0}, {5.0, 1e6}};
  auto s = RegionFromStroke(outside, f.depth_m, cam, {}, o);
  EXPECT_EQ(s.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.status().message().find("outside"), std::string::npos);
  const std::vector<glm::dvec2> nan = {{std::nan(""), 5.0}};
  EXPECT_EQ(RegionFromStroke(nan, f.depth_m, cam, {}, o).status().code(),
            absl::StatusCode::kInvalidArgument);
  // Sky / void: no depth at all.
  const ImageF void_depth(cam.width, cam.height, 1, 0.f);
  const std::vector<glm::dvec2> in = {{60.0, 60.0}};
  auto sky = RegionFromStroke(in, void_depth, cam, {}, o);
  EXPECT_EQ(sky.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(sky.status().message().find("no surface"), std::string::npos);
  // A region covering the whole frame (huge radius, huge tolerance).
  RegionOptions big = o;
  big.roi.radius_px = 1000;
  big.roi.depth_tol_m = 100;
  auto whole = RegionFromStroke(in, f.depth_m, cam, {}, big);
  EXPECT_EQ(whole.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(whole.status().message().find("% of the frame"), std::string::npos);
  // Mask touching the image border: fine, the stroke is partly outside.
  const std::vector<glm::dvec2> border = {{-3.0, 60.0}, {2.0, 60.0}};
  auto b = RegionFromStroke(border, f.depth_m, cam, {}, o);
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_GT(b->labelled_pixels, 50);
}

TEST(RegionLabels, OverlappingRegionsUnion) {
  const PinholeCamera cam = SmallCamera();
  const RgbdKeyframe f = RenderPlanes(BoxScene(), cam, Rigid3d::Identity());
  const std::vector<glm::dvec2> s1 = {{60.0, 60.0}}, s2 = {{68.0, 60.0}};
  auto a = RegionFromStroke(s1, f.depth_m, cam, {}, Opts());
  auto b = RegionFromStroke(s2, f.depth_m, cam, {}, Opts());
  ASSERT_TRUE(a.ok() && b.ok());
  RegionOptions o = Opts();
  o.reproject_close_px = o.reproject_dilate_px = 0;
  const Region3D* ra[] = {&*a};
  const Region3D* rab[] = {&*a, &*b};
  const int na = CountNonZero(ProjectRegions(RegionLabels(ra), f.depth_m, cam, {}, o));
  const int nab = CountNonZero(ProjectRegions(RegionLabels(rab), f.depth_m, cam, {}, o));
  EXPECT_GT(nab, na);
  EXPECT_GT(na, 0);
  // Nothing labelled: an empty mask, not an error.
  EXPECT_EQ(CountNonZero(ProjectRegions(RegionLabels(), f.depth_m, cam, {}, o)), 0);
}

TEST(KeyframePolicy, PoseDistanceAndUnlabelledRule) {
  EXPECT_NEAR(PoseDistance(Rigid3d::Identity(), Translated(0.3, 0.4, 0.0)), 0.5, 1e-12);
  EXPECT_NEAR(PoseDistance(Translated(1, 2, 3), Translated(1, 2, 3)), 0.0, 1e-12);
  const PinholeCamera cam = SmallCamera();
  ImageU8 roi(cam.width, cam.height, 1, 0);
  for (int y = 40; y < 80; ++y)
    for (int x = 40; x < 80; ++x) roi.at(x, y) = 255;
  const ImageF depth(cam.width, cam.height, 1, 2.f);
  KeyframePolicyOptions o;
  // No keyframe yet: insert.
  EXPECT_TRUE(DecideKeyframe(roi, cam, {}, {}, o).insert);
  // The same pose: fully covered, no new keyframe.
  std::vector<KeyframeView> kfs = {{&roi, &depth, cam, Rigid3d::Identity()}};
  auto d = DecideKeyframe(roi, cam, {}, kfs, o);
  EXPECT_FALSE(d.insert);
  EXPECT_NEAR(d.unlabelled_fraction, 0.0, 1e-9);
  // Moved sideways by 0.6 m: (pose distance 0.6 < 0.7) but the ROI is not covered.
  d = DecideKeyframe(roi, cam, Translated(0.6, 0, 0), kfs, o);
  EXPECT_TRUE(d.insert);
  EXPECT_STREQ(d.reason, "unlabelled");
  // Moved 1 m: the pose rule.
  d = DecideKeyframe(roi, cam, Translated(1.0, 0, 0), kfs, o);
  EXPECT_TRUE(d.insert);
  EXPECT_STREQ(d.reason, "pose");
}

// ProjectRegions' shortcuts (the labels' box in the image and in depth, the voxel bitmap) give the
// mask of the plain rule: every pixel whose depth back-projects into a labelled voxel, closed and
// dilated. Random voxel blobs, random depths around them (many exactly on voxel faces), a
// rotated camera; with and without the bitmap (a box beyond its size uses the hash set).
TEST(RegionLabels, ProjectRegionsEqualsThePerPixelRule) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 6; ++trial) {
    Region3D r;
    r.voxel_m = 0.02;
    std::uniform_int_distribution<int> d(-6, 6);
    for (int i = 0; i < 1500; ++i) r.voxels.push_back(PackVoxel(d(rng), d(rng), 100 + d(rng)));
    Region3D far;  // a second region far away: the box exceeds the bitmap on odd trials
    far.voxel_m = 0.02;
    far.voxels.push_back(PackVoxel(trial % 2 ? 200000 : 20, 0, 100));
    std::sort(r.voxels.begin(), r.voxels.end());
    r.voxels.erase(std::unique(r.voxels.begin(), r.voxels.end()), r.voxels.end());
    const Region3D* both[] = {&r, &far};
    const RegionLabels labels(both);
    PinholeCamera cam;
    cam.width = 96;
    cam.height = 72;
    cam.fx = cam.fy = 200;
    cam.cx = 47.5;
    cam.cy = 35.5;
    Rigid3d pose;  // camera 2 m in front of the blob (z = 100 voxels = 2 m), slightly turned
    pose.rotation = glm::angleAxis(0.05 * trial, glm::normalize(glm::dvec3(0.3, 1, 0.2)));
    pose.translation = {0.01 * trial, -0.02, 0.0};
    ImageF depth(cam.width, cam.height, 1, 0.f);
    std::uniform_real_distribution<double> z(1.86, 2.16);
    for (size_t i = 0; i < depth.size(); ++i)
      depth.data()[i] = i % 3 == 0 ? static_cast<float>(std::round(z(rng) / 0.02) * 0.02)
                                   : static_cast<float>(z(rng));
    ImageU8 want(cam.width, cam.height, 1, 0);
    for (int y = 0; y < cam.height; ++y)
      for (int x = 0; x < cam.width; ++x) {
        const float zz = depth.at(x, y);
        if (zz > 0.f && labels.Contains(pose * cam.Unproject({x, y}, zz))) want.at(x, y) = 255;
      }
    ASSERT_GT(CountNonZero(want), 50) << trial;
    RegionOptions sharp;  // no closing, no dilation: pixel for pixel
    sharp.reproject_close_px = sharp.reproject_dilate_px = 0;
    EXPECT_TRUE(ProjectRegions(labels, depth, cam, pose, sharp) == want) << "trial " << trial;
    RegionOptions o;
    cv::Mat m(cam.height, cam.width, CV_8UC1, want.data());
    cv::morphologyEx(m, m, cv::MORPH_CLOSE,
                     cv::getStructuringElement(cv::MORPH_ELLIPSE,
                                               cv::Size(2 * o.reproject_close_px + 1, 2 * o.reproject_close_px + 1)));
    cv::dilate(m, m, cv::getStructuringElement(cv::MORPH_ELLIPSE,
                                               cv::Size(2 * o.reproject_dilate_px + 1, 2 * o.reproject_dilate_px + 1)));
    EXPECT_TRUE(ProjectRegions(labels, depth, cam, pose, o) == want) << "trial " << trial;
  }
}

}  // namespace
}  // namespace exo::inpainting
