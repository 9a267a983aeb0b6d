#include "ground_texture_bow/core/maintenance.h"

#include <stdexcept>

#include <gtest/gtest.h>

namespace gtbow {
namespace {

// 320 x 240 at 0.5 mm per pixel: a place is within 0.25 * 240 * 0.5 mm = 30 mm.
ImageGeometry Geometry() { return {320, 240, 0.0005}; }

Localization Fix(uint32_t image, double x, double y, int inliers) {
  Localization f;
  f.success = true;
  f.image = image;
  f.estimate.success = true;
  f.estimate.inliers = inliers;
  f.estimate.floor_from_query = {x, y, 0.3};
  return f;
}

TEST(MapMaintainer, OnlyAChangedPlaceWithATrustedFixGetsAKeyframe) {
  MaintenanceOptions o;  // refresh below 40 inliers, place it from 12 and 0.15 degrees
  MapMaintainer m(o, Geometry());
  EXPECT_DOUBLE_EQ(m.place_radius(), 0.03);
  m.Track(0, {0.0, 0.0, 0.0}, 0, false);
  Localization none;
  none.reason = "no candidate verified";
  EXPECT_FALSE(m.Observe(none, 10).add);
  EXPECT_FALSE(m.Observe(Fix(0, 0.001, 0, 80), 10).add) << "the floor as mapped";
  EXPECT_FALSE(m.Observe(Fix(0, 0.001, 0, 11), 10).add) << "too weak to place a keyframe";
  Localization loose = Fix(0, 0.001, 0, 20);
  loose.estimate.theta_sigma = 0.004;
  EXPECT_FALSE(m.Observe(loose, 10).add) << "its rotation too uncertain";
  const MaintenanceStep step = m.Observe(Fix(0, 0.001, 0, 20), 10);
  EXPECT_TRUE(step.add) << step.reason;
  EXPECT_TRUE(step.retire.empty()) << "the place holds no view yet";
}

TEST(MapMaintainer, AFullPlaceRetiresTheViewMatchedLongestAgoNeverAMappedKeyframe) {
  MaintenanceOptions o;
  o.max_views_per_place = 3;
  MapMaintainer m(o, Geometry());
  m.Track(0, {0.000, 0.0, 0.0}, 0, false);   // the map's: never retired
  m.Track(1, {0.005, 0.0, 0.0}, 100, true);  // a view, matched on day 50 below
  m.Track(2, {0.010, 0.0, 0.0}, 200, true);  // made later, never matched
  m.Track(3, {0.020, 0.0, 0.0}, 300, true);  // gives the fix below
  m.Track(4, {0.200, 0.0, 0.0}, 50, true);   // another place: never retired for this one
  EXPECT_EQ(m.PlaceOf({0.0, 0.0, 0.0}), (std::vector<uint32_t>{0, 1, 2, 3}));
  EXPECT_EQ(m.PlaceOf({0.0, 0.0, 0.0}, true), (std::vector<uint32_t>{1, 2, 3}));
  EXPECT_FALSE(m.Observe(Fix(1, 0.0, 0.0, 90), 500).add);  // view 1 matched at 500
  const MaintenanceStep step = m.Observe(Fix(3, 0.012, 0.0, 20), 600);
  ASSERT_TRUE(step.add);
  // Room for the new view: 2 of 3 stay. View 2 was never matched (last: its stamp 200), view 1
  // was at 500, view 3 just now; keyframe 0 is the map's.
  EXPECT_EQ(step.retire, (std::vector<uint32_t>{2}));
  EXPECT_EQ(m.tracked(), 4u);
  m.Track(5, {0.012, 0.0, 0.3}, 600, true);
  // The place is full again: the next changed view retires view 1 (matched at 500), and the
  // map's keyframe 0, matched longest ago of all, stays.
  const MaintenanceStep next = m.Observe(Fix(5, 0.011, 0.0, 15), 700);
  EXPECT_EQ(next.retire, (std::vector<uint32_t>{1}));
  EXPECT_EQ(m.PlaceOf({0.0, 0.0, 0.0}), (std::vector<uint32_t>{0, 3, 5}));
  EXPECT_EQ(m.PlaceOf({0.2, 0.0, 0.0}), (std::vector<uint32_t>{4}));
}

TEST(MapMaintainer, KeyframesThatCannotBePlacedAreNotTrackedAndBadOptionsAreNamed) {
  MapMaintainer m(MaintenanceOptions{}, Geometry());
  m.Track(0, {NAN, 0.0, 0.0}, 0, false);
  m.Track(1, {1e9, 0.0, 0.0}, 0, true);
  EXPECT_EQ(m.tracked(), 0u);
  m.Track(2, {-0.5, -0.5, 0.0}, 0, true);  // negative coordinates hash like any others
  EXPECT_EQ(m.PlaceOf({-0.49, -0.5, 0.0}), (std::vector<uint32_t>{2}));
  m.Forget(2);
  EXPECT_TRUE(m.PlaceOf({-0.49, -0.5, 0.0}).empty());
  MaintenanceOptions bad;
  bad.refresh_below_inliers = bad.min_inliers;
  try {
    MapMaintainer(bad, Geometry());
    FAIL() << "accepted refresh_below_inliers == min_inliers";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("refresh_below_inliers"), std::string::npos) << e.what();
  }
  bad = MaintenanceOptions{};
  bad.max_views_per_place = 0;
  EXPECT_THROW(MapMaintainer(bad, Geometry()), std::invalid_argument);
  bad = MaintenanceOptions{};
  bad.max_theta_sigma = 0;
  EXPECT_THROW(MapMaintainer(bad, Geometry()), std::invalid_argument);
  EXPECT_THROW(MapMaintainer(MaintenanceOptions{}, ImageGeometry{320, 240, 0.0}),
               std::invalid_argument);
}

}  // namespace
}  // namespace gtbow
