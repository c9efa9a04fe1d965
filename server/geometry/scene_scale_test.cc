#include "server/geometry/scene_scale.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

namespace exo {
namespace {

SceneScale Of(double diameter, const SceneScaleOptions& o = {}) {
  // A cube with the given diagonal.
  const double side = diameter / std::sqrt(3.0);
  return DeriveSceneScale({1e5, -3, 2}, {1e5 + side, -3 + side, 2 + side}, o);
}

TEST(SceneScale, RuleFollowsDiameterWithinThesisRange) {
  const SceneScale room = Of(4.0);  // 7-Scenes kitchen-sized
  EXPECT_NEAR(room.diameter_m, 4.0, 1e-9);
  EXPECT_DOUBLE_EQ(room.cell_size_m, 0.3);  // 4/16 = 0.25 clamped up to 30 cm
  EXPECT_DOUBLE_EQ(room.d_max_m, 1.0);      // 0.6 clamped up to 1 m
  EXPECT_NEAR(room.sigma_m, 0.8, 1e-9);
  const SceneScale apartment = Of(8.0);
  EXPECT_NEAR(apartment.cell_size_m, 0.5, 1e-9);
  EXPECT_NEAR(apartment.d_max_m, 1.2, 1e-9);
  const SceneScale village = Of(100.0);
  EXPECT_DOUBLE_EQ(village.cell_size_m, 1.0);
  EXPECT_NEAR(village.d_max_m, 15.0, 1e-9);
  EXPECT_NEAR(village.sigma_m, 20.0, 1e-9);  // the thesis' best sigma for the village
}

TEST(SceneScale, OverridesAndDegenerateBounds) {
  SceneScaleOptions o;
  o.cell_size_m = 0.42;
  o.d_max_m = 3.0;
  const SceneScale s = Of(100.0, o);
  EXPECT_DOUBLE_EQ(s.cell_size_m, 0.42);
  EXPECT_DOUBLE_EQ(s.d_max_m, 3.0);
  EXPECT_NEAR(s.sigma_m, 20.0, 1e-9);
  // Empty (inverted) or NaN bounds: diameter 0, lower clamps, never NaN.
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (const SceneScale e : {DeriveSceneScale({1, 1, 1}, {0, 0, 0}), DeriveSceneScale({nan, 0, 0}, {1, 1, 1})}) {
    EXPECT_EQ(e.diameter_m, 0.0);
    EXPECT_DOUBLE_EQ(e.cell_size_m, 0.3);
    EXPECT_DOUBLE_EQ(e.d_max_m, 1.0);
    EXPECT_DOUBLE_EQ(e.sigma_m, 0.5);
  }
}

TEST(SceneScale, ValidateRejectsBadOptions) {
  EXPECT_TRUE(SceneScaleOptions{}.Validate().ok());
  SceneScaleOptions o;
  o.min_cell_m = 2.0;  // > max_cell_m
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.cells_per_diameter = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.cell_size_m = -1;
  EXPECT_FALSE(o.Validate().ok());
  o = {};
  o.sigma_m = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace exo
