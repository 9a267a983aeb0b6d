// Pose estimation: weighted RANSAC for a 2-D rigid transform, refinement, covariance, and the
// composition with the database image's pose.
#include "ground_texture_bow/core/pose.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace gtbow {
namespace {

const ImageGeometry kGeo{640, 480, 0.00025};

// Matches between a query at `query_pose` and a database image at `db_pose`: `inliers` true
// correspondences with pixel noise `noise`, then `outliers` random pairs of weight
// `outlier_weight`.
std::vector<PointMatch> Plant(const Pose2D& query_pose, const Pose2D& db_pose, int inliers,
                              int outliers, double noise, double outlier_weight, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 639.0), v(0.0, 479.0);
  std::normal_distribution<double> n(0.0, noise);
  std::vector<PointMatch> m;
  while (static_cast<int>(m.size()) < inliers) {
    const Vec2 q{u(rng), v(rng)};
    const Vec2 d = ImageFromFloor(db_pose, kGeo, FloorFromImage(query_pose, kGeo, q));
    if (d.x < 0 || d.x > 639 || d.y < 0 || d.y > 479) continue;  // outside the database image
    m.push_back({q, {d.x + n(rng), d.y + n(rng)}, 1.0});
  }
  for (int i = 0; i < outliers; ++i)
    m.push_back({{u(rng), v(rng)}, {u(rng), v(rng)}, outlier_weight});
  std::shuffle(m.begin(), m.end(), rng);
  return m;
}

TEST(Pose, RecoversAPlantedTransformThroughOutliers) {
  const Pose2D db{1.0, 2.0, 0.3};
  const Pose2D query{1.012, 1.995, 0.3 + 0.4};           // 13 mm and 23 degrees away
  const auto m = Plant(query, db, 60, 90, 0.3, 1.0, 1);  // 60% outliers
  const PoseEstimate e = EstimatePose(m, db, kGeo, PoseOptions{});
  ASSERT_TRUE(e.success) << e.reason;
  EXPECT_NEAR(e.floor_from_query.x, query.x, 0.0001);  // 0.1 mm = 0.4 px
  EXPECT_NEAR(e.floor_from_query.y, query.y, 0.0001);
  EXPECT_NEAR(WrapAngle(e.floor_from_query.theta - query.theta), 0.0, 0.002);
  EXPECT_GE(e.inliers, 58);
  EXPECT_LE(e.inliers, 62);  // a random outlier may fall within 3 px
  EXPECT_LT(e.residual_rms, 0.6);
  EXPECT_GT(e.residual_rms, 0.2);
}

TEST(Pose, WeightedSamplingFindsHeavyInliersAmongManyLightOutliers) {
  const Pose2D db{0.0, 0.0, 0.0};
  const Pose2D query{0.01, 0.0, -0.2};
  // 85% of the matches are outliers, but they carry little weight (a soft-assignment tail).
  const auto m = Plant(query, db, 30, 170, 0.3, 0.02, 2);
  PoseOptions o;
  o.max_iterations = 25;
  int weighted_ok = 0, plain_ok = 0;
  for (uint64_t seed = 1; seed <= 20; ++seed) {
    o.seed = seed;
    o.weighted = true;
    weighted_ok += EstimatePose(m, db, kGeo, o).success ? 1 : 0;
    o.weighted = false;
    plain_ok += EstimatePose(m, db, kGeo, o).success ? 1 : 0;
  }
  std::printf("25 hypotheses, 85%% light outliers: weighted %d/20, plain %d/20\n", weighted_ok,
              plain_ok);
  EXPECT_EQ(weighted_ok, 20);
  EXPECT_LT(plain_ok, weighted_ok);
}

TEST(Pose, CovarianceFollowsTheNoiseAndTheActualSpread) {
  const Pose2D db{0.5, 0.5, 1.0};
  const Pose2D query{0.51, 0.49, 1.1};
  std::vector<double> xs;
  double mean_var = 0.0;
  for (uint32_t seed = 1; seed <= 40; ++seed) {
    const PoseEstimate e =
        EstimatePose(Plant(query, db, 80, 0, 1.0, 1.0, seed), db, kGeo, PoseOptions{});
    ASSERT_TRUE(e.success);
    xs.push_back(e.floor_from_query.x);
    mean_var += e.covariance[0] / 40;
    EXPECT_NEAR(e.covariance[1], e.covariance[3], 1e-15);  // symmetric
    EXPECT_GT(e.covariance[8], 0.0);
  }
  double m = 0.0, v = 0.0;
  for (double x : xs) m += x / xs.size();
  for (double x : xs) v += (x - m) * (x - m) / (xs.size() - 1);
  // The claimed variance matches the spread over trials to within a factor of 2.
  EXPECT_GT(mean_var, v / 2);
  EXPECT_LT(mean_var, v * 2);
  const PoseEstimate quiet =
      EstimatePose(Plant(query, db, 80, 0, 0.1, 1.0, 1), db, kGeo, PoseOptions{});
  EXPECT_LT(quiet.covariance[0], mean_var / 20);  // 10x less noise: ~100x less variance
}

TEST(Pose, NoEstimateWithAReasonInsteadOfAFakePose) {
  const Pose2D db{0, 0, 0};
  PoseEstimate e = EstimatePose({}, db, kGeo, PoseOptions{});
  EXPECT_FALSE(e.success);
  EXPECT_NE(e.reason.find("0 matches"), std::string::npos) << e.reason;
  e = EstimatePose(Plant(db, db, 0, 100, 0.0, 1.0, 3), db, kGeo, PoseOptions{});  // all outliers
  EXPECT_FALSE(e.success);
  EXPECT_FALSE(e.reason.empty());
  EXPECT_LT(e.inliers, PoseOptions{}.min_inliers);
  // All inliers on one pixel: degenerate.
  std::vector<PointMatch> same(20, PointMatch{{100, 100}, {110, 100}, 1.0});
  e = EstimatePose(same, db, kGeo, PoseOptions{});
  EXPECT_FALSE(e.success);
  std::vector<PointMatch> bad(20, PointMatch{{NAN, 1}, {1, 1}, 1.0});
  EXPECT_THROW(EstimatePose(bad, db, kGeo, PoseOptions{}), std::invalid_argument);
  PoseOptions o;
  o.min_inliers = 1;
  EXPECT_THROW(EstimatePose(same, db, kGeo, o), std::invalid_argument);
}

TEST(Pose, MatchesOfMergesPairsRepeatedOverRows) {
  QueryResult r;
  r.matches = {{1, 2, 0.25f}, {0, 0, 0.5f}, {1, 2, 0.5f}};
  std::vector<Keypoint> qk(2), dk(3);
  qk[1].x = 10;
  dk[2].y = 20;
  const auto m = MatchesOf(r, qk, dk);
  ASSERT_EQ(m.size(), 2u);
  EXPECT_DOUBLE_EQ(m[1].weight, 0.75);
  EXPECT_DOUBLE_EQ(m[1].query.x, 10);
  EXPECT_DOUBLE_EQ(m[1].database.y, 20);
  r.matches.push_back({5, 0, 1.0f});
  EXPECT_THROW(MatchesOf(r, qk, dk), std::out_of_range);
}

}  // namespace
}  // namespace gtbow

namespace gtbow {
namespace {

TEST(Localize, AQueryWithoutFeaturesGetsNoEstimateAndAReason) {
  BowOptions o;
  o.size_binning = SizeBinning::kNone;
  o.num_size_bins = 1;
  BowDatabase db(16, o, 1);
  MapAccess map;
  std::vector<Keypoint> none;
  map.keypoints = [&](uint32_t) -> const std::vector<Keypoint>& { return none; };
  map.pose = [](uint32_t) { return Pose2D{}; };
  const BowVector blank;  // what a featureless (blank) floor image encodes to
  const Localization loc = Localize(db, blank, map, kGeo, LocalizationOptions{});
  EXPECT_FALSE(loc.success);
  EXPECT_EQ(loc.reason, "the query image has no features");
  LocalizationOptions bad;
  bad.candidates = 0;
  EXPECT_THROW(Localize(db, blank, map, kGeo, bad), std::invalid_argument);
}

}  // namespace
}  // namespace gtbow
