#include "ground_texture_bow/core/geometry.h"

#include <cmath>

#include <gtest/gtest.h>

namespace gtbow {
namespace {

const ImageGeometry kGeo{640, 480, 0.00025};  // 16 x 12 cm footprint

TEST(Geometry, CentrePixelMapsToPose) {
  const Pose2D p{1.5, -2.0, 0.7};
  const Vec2 c = FloorFromImage(p, kGeo, {319.5, 239.5});
  EXPECT_NEAR(c.x, 1.5, 1e-12);
  EXPECT_NEAR(c.y, -2.0, 1e-12);
}

TEST(Geometry, AxesFollowTheta) {
  // theta = 90 deg: the image u axis points along floor +y, v along floor -x.
  const Pose2D p{0.0, 0.0, M_PI / 2};
  const Vec2 right = FloorFromImage(p, kGeo, {319.5 + 100, 239.5});
  EXPECT_NEAR(right.x, 0.0, 1e-12);
  EXPECT_NEAR(right.y, 0.025, 1e-12);
  const Vec2 down = FloorFromImage(p, kGeo, {319.5, 239.5 + 100});
  EXPECT_NEAR(down.x, -0.025, 1e-12);
  EXPECT_NEAR(down.y, 0.0, 1e-12);
}

TEST(Geometry, ImageFromFloorInvertsFloorFromImage) {
  const Pose2D p{0.3, 0.1, -2.2};
  for (Vec2 px : {Vec2{0, 0}, Vec2{639, 479}, Vec2{12.25, 400.5}}) {
    const Vec2 back = ImageFromFloor(p, kGeo, FloorFromImage(p, kGeo, px));
    EXPECT_NEAR(back.x, px.x, 1e-9);
    EXPECT_NEAR(back.y, px.y, 1e-9);
  }
}

TEST(Geometry, FootprintAreaAndCorners) {
  const auto fp = Footprint({0, 0, 0}, kGeo);
  EXPECT_NEAR(fp[0].x, -0.08, 1e-12);
  EXPECT_NEAR(fp[0].y, -0.06, 1e-12);
  EXPECT_NEAR(fp[2].x, 0.08, 1e-12);
  EXPECT_NEAR(fp[2].y, 0.06, 1e-12);
  const auto rot = Footprint({1, 2, 1.1}, kGeo);
  EXPECT_NEAR(PolygonArea({rot.begin(), rot.end()}), 0.16 * 0.12, 1e-12);
}

// Hand-computed overlaps of 16 x 12 cm footprints.
TEST(Geometry, OverlapHandCases) {
  const Pose2D q{0, 0, 0};
  EXPECT_NEAR(Overlap(q, q, kGeo), 1.0, 1e-12);
  EXPECT_NEAR(Overlap(q, {0.08, 0, 0}, kGeo), 0.5, 1e-12);       // half the width
  EXPECT_NEAR(Overlap(q, {0.08, 0.06, 0}, kGeo), 0.25, 1e-12);   // a quarter
  EXPECT_NEAR(Overlap(q, {0.04, 0, M_PI}, kGeo), 0.75, 1e-12);   // rotation by pi is symmetric
  EXPECT_NEAR(Overlap(q, {0, 0, M_PI / 2}, kGeo), 0.75, 1e-12);  // 12 x 12 of 16 x 12
  EXPECT_NEAR(Overlap(q, {0.16, 0, 0}, kGeo), 0.0, 1e-12);       // touching edges
  EXPECT_NEAR(Overlap(q, {0.5, 0.5, 0.3}, kGeo), 0.0, 1e-12);    // far apart
  // A square rotated by 45 degrees over itself: a regular octagon of area (2 sqrt2 - 2) a^2.
  const ImageGeometry square{100, 100, 0.01};
  EXPECT_NEAR(Overlap({0, 0, 0}, {0, 0, M_PI / 4}, square), 2 * std::sqrt(2.0) - 2, 1e-12);
}

TEST(Geometry, OverlapIsRelativeToTheQuery) {
  // Different sizes cannot happen within a dataset, but the ratio is area-of-query based:
  // a query shifted by a quarter width overlaps 75%.
  EXPECT_NEAR(Overlap({0, 0, 0}, {0.04, 0, 0}, kGeo), 0.75, 1e-12);
  EXPECT_NEAR(Overlap({0.04, 0, 0}, {0, 0, 0}, kGeo), 0.75, 1e-12);
}

TEST(Geometry, RelevanceThreshold) {
  EXPECT_TRUE(IsRelevant({0, 0, 0}, {0.08, 0.06, 0}, kGeo));       // exactly 0.25
  EXPECT_FALSE(IsRelevant({0, 0, 0}, {0.0801, 0.0601, 0}, kGeo));  // just below
  EXPECT_TRUE(IsRelevant({0, 0, 0}, {0.0, 0.0, 3.0}, kGeo));
}

TEST(Geometry, WrapAngle) {
  EXPECT_NEAR(WrapAngle(3 * M_PI), M_PI, 1e-12);
  EXPECT_NEAR(WrapAngle(-M_PI), M_PI, 1e-12);
  EXPECT_NEAR(WrapAngle(2 * M_PI + 0.1), 0.1, 1e-12);
  EXPECT_NEAR(WrapAngle(-0.5), -0.5, 1e-12);
}

TEST(Geometry, ComposeAndInverse) {
  // A quarter turn, then one metre along the new x axis: one metre along the old y axis.
  const Pose2D turn{2.0, 3.0, M_PI / 2};
  const Pose2D step{1.0, 0.0, 0.25};
  const Pose2D c = Compose(turn, step);
  EXPECT_NEAR(c.x, 2.0, 1e-12);
  EXPECT_NEAR(c.y, 4.0, 1e-12);
  EXPECT_NEAR(c.theta, M_PI / 2 + 0.25, 1e-12);
  // The composed pose maps points like the two poses one after the other.
  const ImageGeometry g{640, 480, 0.001};
  const Vec2 px{100.0, 50.0};
  const Vec2 through_step = FloorFromImage(step, g, px);
  const Vec2 a = FloorFromImage(turn, ImageGeometry{1, 1, 1.0}, through_step);
  const Vec2 b = FloorFromImage(c, g, px);
  EXPECT_NEAR(a.x, b.x, 1e-12);
  EXPECT_NEAR(a.y, b.y, 1e-12);
  for (const Pose2D& p : {turn, step, c, Pose2D{-0.3, 7.0, -2.9}}) {
    const Pose2D i = Compose(p, Inverse(p)), j = Compose(Inverse(p), p);
    for (const Pose2D& q : {i, j}) {
      EXPECT_NEAR(q.x, 0.0, 1e-12);
      EXPECT_NEAR(q.y, 0.0, 1e-12);
      EXPECT_NEAR(WrapAngle(q.theta), 0.0, 1e-12);
    }
  }
}

}  // namespace
}  // namespace gtbow
