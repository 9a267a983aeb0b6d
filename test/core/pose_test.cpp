// Pose estimation: weighted RANSAC for a 2-D rigid transform, refinement, covariance, and the
// composition with the database image's pose.
#include "ground_texture_bow/core/pose.h"

#include <gtest/gtest.h>

#include <cmath>
#include <optional>
#include <random>

#include <opencv2/core.hpp>

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

// Issue 15: the checks a pose must pass besides min_inliers.
TEST(PoseChecks, ClusteredInliersLeaveTheRotationUncertainAndAreRefused) {
  const Pose2D db{0.0, 0.0, 0.0};
  const Pose2D query{0.004, 0.002, 0.1};
  // 12 true matches within a 12-pixel patch, 1 px noise: the translation is pinned, the
  // rotation is not.
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(300.0, 312.0);
  std::normal_distribution<double> n(0.0, 1.0);
  std::vector<PointMatch> clustered;
  for (int i = 0; i < 12; ++i) {
    const Vec2 q{u(rng), u(rng) - 60.0};
    const Vec2 d = ImageFromFloor(db, kGeo, FloorFromImage(query, kGeo, q));
    clustered.push_back({q, {d.x + n(rng), d.y + n(rng)}, 1.0});
  }
  PoseOptions o;
  const PoseEstimate loose = EstimatePose(clustered, db, kGeo, o);
  ASSERT_TRUE(loose.success) << loose.reason;
  EXPECT_LT(loose.spread, 6.0);
  EXPECT_GT(loose.theta_sigma, 0.5 * M_PI / 180.0);  // the covariance says what it does not know
  o.max_theta_sigma = 0.5 * M_PI / 180.0;
  const PoseEstimate strict = EstimatePose(clustered, db, kGeo, o);
  EXPECT_FALSE(strict.success);
  EXPECT_NE(strict.reason.find("rotation uncertain"), std::string::npos) << strict.reason;
  o.max_theta_sigma = 0.0;
  o.min_spread = 20.0;
  const PoseEstimate clumped = EstimatePose(clustered, db, kGeo, o);
  EXPECT_FALSE(clumped.success);
  EXPECT_NE(clumped.reason.find("min_spread"), std::string::npos) << clumped.reason;
  // The same number of matches spread over the image passes both checks.
  o.max_theta_sigma = 0.5 * M_PI / 180.0;
  const auto spread = Plant(query, db, 12, 0, 1.0, 1.0, 4);
  const PoseEstimate good = EstimatePose(spread, db, kGeo, o);
  ASSERT_TRUE(good.success) << good.reason;
  EXPECT_LT(good.theta_sigma, 0.5 * M_PI / 180.0);
  EXPECT_GT(good.spread, 50.0);
}

TEST(PoseChecks, OrientationsAndASecondHypothesisExposeARepeatedPattern) {
  const Pose2D db{0.0, 0.0, 0.0};
  const Pose2D truth{0.003, -0.002, 0.5};
  const Pose2D alias{-0.01, 0.006, 0.2};  // another transform the matches also support
  auto with_rotation = [](std::vector<PointMatch> m, double rotation) {
    for (PointMatch& x : m) x.rotation = rotation;
    return m;
  };
  // 20 true matches whose keypoints turn by the true rotation; 26 that fit another transform
  // but whose keypoint orientations turn by something else entirely.
  std::vector<PointMatch> m = with_rotation(Plant(truth, db, 20, 0, 0.3, 1.0, 5), 0.5);
  for (const PointMatch& x : with_rotation(Plant(alias, db, 26, 0, 0.3, 1.0, 6), -1.9))
    m.push_back(x);
  PoseOptions o;
  const PoseEstimate plain = EstimatePose(m, db, kGeo, o);
  ASSERT_TRUE(plain.success);
  EXPECT_NEAR(plain.floor_from_query.theta, alias.theta, 0.01);  // the larger set wins
  EXPECT_LT(plain.angle_agreement, 0.1);
  o.angle_tolerance = 15.0 * M_PI / 180.0;
  const PoseEstimate oriented = EstimatePose(m, db, kGeo, o);
  ASSERT_TRUE(oriented.success) << oriented.reason;
  EXPECT_NEAR(oriented.floor_from_query.theta, truth.theta, 0.01);
  EXPECT_NEAR(oriented.floor_from_query.x, truth.x, 0.0002);
  EXPECT_EQ(oriented.angle_agreement, 1.0);
  // Without orientations the two transforms are equally plausible: a second hypothesis with
  // over half the best's inliers refuses the pose.
  o.angle_tolerance = 0.0;
  o.max_second_ratio = 0.5;
  const PoseEstimate ambiguous = EstimatePose(m, db, kGeo, o);
  EXPECT_FALSE(ambiguous.success);
  EXPECT_GE(ambiguous.second_inliers, 18);
  EXPECT_NE(ambiguous.reason.find("ambiguous"), std::string::npos) << ambiguous.reason;
  // One pattern alone is not ambiguous.
  const PoseEstimate single =
      EstimatePose(with_rotation(Plant(truth, db, 20, 30, 0.3, 1.0, 7), 0.5), db, kGeo, o);
  EXPECT_TRUE(single.success) << single.reason;
  EXPECT_LT(single.second_inliers, 5);
}

TEST(PoseChecks, ConsensusRefusesDisagreeingCandidatesOrTheWholePlace) {
  auto est = [](int inliers) {
    PoseEstimate e;
    e.success = true;
    e.inliers = inliers;
    return e;
  };
  const Pose2D p{1.0, 2.0, 0.3};
  const std::vector<std::optional<Pose2D>> poses = {
      Pose2D{1.003, 2.0, 0.31},  // agrees with the best (within 10 mm and 3 degrees)
      p,                         // the best: 30 inliers
      Pose2D{1.32, 2.0, 0.3},    // 320 mm away: the floor repeats itself
      std::nullopt};             // no pose to compare: left alone
  const std::vector<PoseEstimate> base = {est(25), est(30), est(12), est(8)};
  LocalizationOptions o;
  auto run = [&](double ratio) {
    o.max_conflict_ratio = ratio;
    std::vector<PoseEstimate> e = base;
    ResolveConflicts(poses, &e, o);
    return e;
  };
  auto e = run(0.0);  // off
  for (const PoseEstimate& x : e) EXPECT_TRUE(x.success);
  e = run(0.5);  // the disagreeing pose has 12 < 15 inliers: only it is refused
  EXPECT_TRUE(e[0].success);
  EXPECT_TRUE(e[1].success);
  EXPECT_FALSE(e[2].success);
  EXPECT_NE(e[2].reason.find("disagrees with candidate 2"), std::string::npos) << e[2].reason;
  EXPECT_TRUE(e[3].success);
  e = run(0.4);  // 12 >= 0.4 x 30: ambiguous, every comparable pose refused
  EXPECT_FALSE(e[0].success);
  EXPECT_FALSE(e[1].success);
  EXPECT_FALSE(e[2].success);
  EXPECT_NE(e[1].reason.find("ambiguous place"), std::string::npos) << e[1].reason;
  EXPECT_TRUE(e[3].success);
}

TEST(PoseChecks, DescriptorMatchesAreMutualNearestNeighboursPassingTheRatioTest) {
  std::mt19937 rng(8);
  const int n = 40;
  cv::Mat q(n, 32, CV_8U), d(n + 10, 32, CV_8U);
  cv::randu(q, 0, 256);
  cv::randu(d, 0, 256);
  std::vector<Keypoint> qk(n), dk(n + 10);
  for (int i = 0; i < n; ++i) {
    qk[i].x = static_cast<float>(i);
    qk[i].angle = 0.1f;
  }
  for (int j = 0; j < n + 10; ++j) {
    dk[j].x = static_cast<float>(100 + j);
    dk[j].angle = 0.4f;
  }
  // Database row 2i + 1 (i < 20) is query row i with 10 bits flipped; query rows 20.. have no
  // partner (random rows are ~128 bits from everything).
  for (int i = 0; i < 20; ++i) {
    q.row(i).copyTo(d.row(2 * i + 1));
    for (int b = 0; b < 10; ++b) d.at<uint8_t>(2 * i + 1, (b * 3 + i) % 32) ^= 1u << (b % 8);
  }
  const auto m = DescriptorMatches(qk, q, dk, d, 0.8);
  ASSERT_EQ(m.size(), 20u);
  for (const PointMatch& x : m) {
    const int i = static_cast<int>(x.query.x);
    EXPECT_EQ(x.database.x, 100 + 2 * i + 1);
    EXPECT_NEAR(x.rotation, 0.3, 1e-6);
    EXPECT_EQ(x.weight, 1.0);
  }
  // A second database row as close to query row 0 (10 other bits flipped): the ratio test
  // refuses the ambiguous match.
  q.row(0).copyTo(d.row(0));
  for (int b = 0; b < 10; ++b) d.at<uint8_t>(0, (b * 3 + 1) % 32) ^= 1u << ((b + 4) % 8);
  EXPECT_EQ(DescriptorMatches(qk, q, dk, d, 0.8).size(), 19u);
  std::vector<Keypoint> short_keypoints(3);
  EXPECT_THROW(DescriptorMatches(short_keypoints, q, dk, d, 0.8), std::invalid_argument);
}

// Guided matching (issue 28): a faint floor's lasting keypoints whose descriptors have twins
// elsewhere in the image fail the ratio test; matched near where a 5-inlier hypothesis puts
// them, they give the pose. Off by default. With the repeat check, not from a keyframe that
// verifies elsewhere in its own map.
TEST(PoseChecks, GuidedMatchingRecoversMatchesTheRatioTestDrops) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(60.0, 580.0), v(60.0, 420.0);
  const Rigid2D h{0.2, {30.0, -20.0}};  // database - c = R(h.theta) (query - c) + h.t
  const Vec2 c{319.5, 239.5};
  auto to_db = [&](double x, double y) {
    const double dx = x - c.x, dy = y - c.y;
    return Vec2{std::cos(h.theta) * dx - std::sin(h.theta) * dy + h.t.x + c.x,
                std::sin(h.theta) * dx + std::cos(h.theta) * dy + h.t.y + c.y};
  };
  const int clean = 5, twinned = 30;
  std::vector<Keypoint> qk, dk;
  cv::Mat qd(0, 32, CV_8U), dd(0, 32, CV_8U);
  auto flip = [](cv::Mat row, int bits, int salt) {
    for (int b = 0; b < bits; ++b)
      row.at<uint8_t>(0, (b * 7 + salt) % 32) ^= 1u << ((b + salt) % 8);
  };
  while (static_cast<int>(qk.size()) < clean + twinned) {
    const double x = u(rng), y = v(rng);
    const Vec2 d = to_db(x, y);
    if (d.x < 20 || d.x > 620 || d.y < 20 || d.y > 460) continue;
    cv::Mat row(1, 32, CV_8U);
    cv::randu(row, 0, 256);
    Keypoint a;
    a.x = static_cast<float>(x);
    a.y = static_cast<float>(y);
    qk.push_back(a);
    qd.push_back(row);
    Keypoint b;
    b.x = static_cast<float>(d.x);
    b.y = static_cast<float>(d.y);
    b.angle = static_cast<float>(h.theta);
    cv::Mat aged = row.clone();
    flip(aged, 20, static_cast<int>(qk.size()));  // 20 bits changed since
    dk.push_back(b);
    dd.push_back(aged);
    if (static_cast<int>(qk.size()) > clean) {  // a twin as close, far from the true place
      Keypoint t = b;
      t.x = static_cast<float>(std::fmod(d.x + 300.0, 600.0) + 20.0);
      cv::Mat twin = row.clone();
      flip(twin, 20, static_cast<int>(qk.size()) + 3);
      dk.push_back(t);
      dd.push_back(twin);
    }
  }
  // And 3 unique matches at places that do not fit (the ratio test keeps them: outliers).
  for (int i = 0; i < 3; ++i) {
    cv::Mat row(1, 32, CV_8U);
    cv::randu(row, 0, 256);
    Keypoint a, b;
    a.x = static_cast<float>(100 + 200 * i);
    a.y = 100.0f;
    b.x = static_cast<float>(500 - 150 * i);
    b.y = 400.0f;
    qk.push_back(a);
    qd.push_back(row);
    dk.push_back(b);
    cv::Mat aged = row.clone();
    flip(aged, 20, 50 + i);
    dd.push_back(aged);
  }
  const ImageGeometry geo{640, 480, 0.0005};
  // The ratio test keeps the 5 clean ones and the 3 outliers.
  EXPECT_EQ(DescriptorMatches(qk, qd, dk, dd, 0.8).size(), static_cast<size_t>(clean + 3));
  // Guided through the true transform: every lasting keypoint, none of the twins.
  std::vector<PointMatch> g = GuidedMatches(qk, qd, dk, dd, h, geo, 8.0, 80.0);
  ASSERT_EQ(g.size(), static_cast<size_t>(clean + twinned));
  for (const PointMatch& m : g) {
    const Vec2 want = to_db(m.query.x, m.query.y);
    EXPECT_NEAR(m.database.x, want.x, 1e-3);
    EXPECT_NEAR(m.database.y, want.y, 1e-3);
  }
  // Nothing beyond the distance or the radius (a hypothesis 20 px off).
  EXPECT_TRUE(GuidedMatches(qk, qd, dk, dd, h, geo, 8.0, 10.0).empty());
  EXPECT_TRUE(
      GuidedMatches(qk, qd, dk, dd, {h.theta, {h.t.x + 20.0, h.t.y}}, geo, 8.0, 80.0).empty());

  // Through VerifyCandidates: 5 inliers, short of 8; guided, the pose.
  BowVector query;
  query.source = qk;
  query.source_descriptors = qd;
  MapAccess map;
  map.keypoints = [&](uint32_t) { return dk; };
  map.descriptors = [&](uint32_t) { return dd; };
  map.pose = [](uint32_t) { return Pose2D{1.0, 2.0, 0.0}; };
  QueryResult r;
  r.image = 3;
  LocalizationOptions o;
  o.candidates = 1;
  o.matches = MatchSource::kDescriptors;
  o.pose.min_inliers = 8;
  for (const double conflict : {0.0, 0.5}) {  // first-verified and consensus procedures
    o.max_conflict_ratio = conflict;
    o.guided_radius = 0.0;
    const Localization plain = VerifyCandidates({r}, query, map, geo, o);
    EXPECT_FALSE(plain.success);
    EXPECT_NE(plain.reason.find("5 inliers"), std::string::npos) << plain.reason;
    o.guided_radius = 8.0;
    const Localization guided = VerifyCandidates({r}, query, map, geo, o);
    ASSERT_TRUE(guided.success) << guided.reason;
    EXPECT_EQ(guided.estimate.inliers, clean + twinned);
    EXPECT_NEAR(guided.estimate.database_from_query.theta, h.theta, 1e-3);
    EXPECT_NEAR(guided.estimate.database_from_query.t.x, h.t.x, 0.05);
    EXPECT_NEAR(guided.estimate.database_from_query.t.y, h.t.y, 0.05);
    // A seed needs guided_seed_inliers: with 6 the 5-inlier hypothesis seeds nothing.
    o.guided_seed_inliers = 6;
    EXPECT_FALSE(VerifyCandidates({r}, query, map, geo, o).success);
    o.guided_seed_inliers = 4;
  }

  // The repeat check: map image 3 has an exact copy, image 7, placed elsewhere (a floor that
  // repeats); image 3 queried against its map verifies with 7 far from its own pose, so the
  // guided pose is refused. With 7 where 3 is (an overlapping neighbour) it is kept.
  Pose2D copy_pose{1.2, 2.0, M_PI / 2};
  map.pose = [&](uint32_t i) { return i == 7 ? copy_pose : Pose2D{1.0, 2.0, 0.0}; };
  int requeried = 0;
  map.query_of = [&](uint32_t i) {
    EXPECT_EQ(i, 3u);
    ++requeried;
    BowVector v;
    v.source = dk;
    v.source_descriptors = dd;
    return v;
  };
  map.retrieve = [&](const BowVector&, uint32_t self, size_t k) {
    EXPECT_EQ(self, 3u);
    EXPECT_EQ(k, 5u);
    QueryResult copy;
    copy.image = 7;
    return std::vector<QueryResult>{copy};
  };
  o.guided_repeat_check = true;
  o.guided_repeat_candidates = 5;
  // Localizes once: no pose, and the reason says `why`.
  auto refused_for = [&](const std::string& why) {
    const Localization l = VerifyCandidates({r}, query, map, geo, o);
    EXPECT_FALSE(l.success);
    EXPECT_NE(l.reason.find(why), std::string::npos) << l.reason;
    return l;
  };
  for (const double conflict : {0.0, 0.5}) {
    o.max_conflict_ratio = conflict;
    copy_pose = {1.2, 2.0, M_PI / 2};
    const Localization refused =
        refused_for("keyframe 3 repeats elsewhere: it verifies with keyframe 7");
    EXPECT_NE(refused.reason.find("200.0 mm and 90.0 degrees"), std::string::npos)
        << refused.reason;
    copy_pose = {1.0, 2.0, 0.0};
    const Localization kept = VerifyCandidates({r}, query, map, geo, o);
    ASSERT_TRUE(kept.success) << kept.reason;
    EXPECT_EQ(kept.estimate.inliers, clean + twinned);
  }
  EXPECT_EQ(requeried, 4);
  // guided_repeat_ratio: the query matched at the copy too. An exact copy holds as many of the
  // query's inliers: refused. A copy of a part (the first 12 keypoints): the keyframe's place.
  o.guided_repeat_ratio = 0.5;
  copy_pose = {1.2, 2.0, M_PI / 2};
  refused_for("the query holds 35 inliers at the copy against 35");
  const std::vector<Keypoint> part(dk.begin(), dk.begin() + 12);
  const cv::Mat part_d = dd.rowRange(0, 12).clone();
  map.keypoints = [&](uint32_t i) { return i == 7 ? part : dk; };
  map.descriptors = [&](uint32_t i) { return i == 7 ? part_d : dd; };
  const Localization partial = VerifyCandidates({r}, query, map, geo, o);
  ASSERT_TRUE(partial.success) << partial.reason;
  EXPECT_EQ(partial.estimate.inliers, clean + twinned);
  o.guided_repeat_ratio = 0.0;  // without the contest, the part copy refuses it too
  refused_for("repeats elsewhere");
  o.guided_repeat_ratio = -1.0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o.guided_repeat_ratio = 0.0;
  map.query_of = nullptr;  // a map that cannot query its own images
  EXPECT_THROW(VerifyCandidates({r}, query, map, geo, o), std::invalid_argument);
  o.guided_repeat_candidates = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o.guided_repeat_candidates = 5;
  o.guided_radius = 0.0;  // the check belongs to guided matching
  EXPECT_THROW(o.Check(), std::invalid_argument);

  // The repeat check of plain poses (plain_repeat_below): with 5 inliers enough, the 5 clean
  // matches give a plain pose. An exact copy elsewhere holds as many of the query's guided
  // inliers as the keyframe does (35 each): refused, in both procedures and in a first pass
  // (no guided matching of the query). Not checked at or above the threshold; a copy of a part,
  // or a copy at the keyframe's own place, leaves the pose standing.
  map.keypoints = [&](uint32_t) { return dk; };
  map.descriptors = [&](uint32_t) { return dd; };
  map.query_of = [&](uint32_t) {
    BowVector v;
    v.source = dk;
    v.source_descriptors = dd;
    return v;
  };
  o.guided_radius = 8.0;
  o.guided_repeat_check = true;
  o.guided_repeat_ratio = 0.5;
  o.pose.min_inliers = 5;
  for (const double conflict : {0.0, 0.5}) {
    o.max_conflict_ratio = conflict;
    copy_pose = {1.2, 2.0, M_PI / 2};
    o.plain_repeat_below = 0;
    const Localization plain = VerifyCandidates({r}, query, map, geo, o);
    ASSERT_TRUE(plain.success) << plain.reason;
    EXPECT_EQ(plain.estimate.inliers, clean);
    o.plain_repeat_below = clean + 1;
    refused_for("keyframe 3 repeats elsewhere: it verifies with keyframe 7");
    refused_for("the query holds 35 inliers at the copy against 35 (plain_repeat_ratio 1)");
    const Localization first = VerifyCandidates({r}, query, map, geo, FirstPassOptions(o));
    EXPECT_FALSE(first.success);
    EXPECT_NE(first.reason.find("repeat: keyframe 3"), std::string::npos) << first.reason;
    std::vector<PoseEstimate> each = VerifyEach({r}, query, map, geo, o);
    ASSERT_EQ(each.size(), 1u);
    EXPECT_FALSE(each[0].success);
    EXPECT_NE(each[0].reason.find("repeat: keyframe 3"), std::string::npos) << each[0].reason;
    o.plain_repeat_below = clean;  // 5 inliers are not below 5: not checked
    EXPECT_TRUE(VerifyCandidates({r}, query, map, geo, o).success);
    o.plain_repeat_below = clean + 1;
    map.keypoints = [&](uint32_t i) { return i == 7 ? part : dk; };
    map.descriptors = [&](uint32_t i) { return i == 7 ? part_d : dd; };
    const Localization partial_plain = VerifyCandidates({r}, query, map, geo, o);
    ASSERT_TRUE(partial_plain.success) << partial_plain.reason;
    EXPECT_EQ(partial_plain.estimate.inliers, clean);
    o.plain_repeat_ratio = 0.0;  // without the contest, the part copy refuses it too
    refused_for("keyframe 3 repeats elsewhere: it verifies with keyframe 7");
    o.plain_repeat_ratio = 1.0;
    map.keypoints = [&](uint32_t) { return dk; };
    map.descriptors = [&](uint32_t) { return dd; };
    copy_pose = {1.0, 2.0, 0.0};  // the "copy" is the keyframe's own place: no repeat
    EXPECT_TRUE(VerifyCandidates({r}, query, map, geo, o).success);
  }
  // A map's RepeatCache keeps each keyframe's copies between queries: keyframe 3 is queried
  // against its map once, and again after the cache is cleared (the map changed).
  RepeatCache cache;
  map.repeats = &cache;
  int asked = 0;
  map.query_of = [&](uint32_t) {
    ++asked;
    BowVector v;
    v.source = dk;
    v.source_descriptors = dd;
    return v;
  };
  copy_pose = {1.2, 2.0, M_PI / 2};
  refused_for("the query holds 35 inliers at the copy against 35 (plain_repeat_ratio 1)");
  refused_for("the query holds 35 inliers at the copy against 35 (plain_repeat_ratio 1)");
  EXPECT_EQ(asked, 1);
  EXPECT_EQ(cache.size(), 1u);
  cache.Clear();
  refused_for("repeats elsewhere");
  EXPECT_EQ(asked, 2);
  map.repeats = nullptr;
  o.plain_repeat_ratio = -1.0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o.plain_repeat_ratio = 1.0;
  o.plain_repeat_below = -1;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o.plain_repeat_below = clean + 1;
  o.guided_repeat_check = false;  // the plain check extends the guided one
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o.plain_repeat_below = 0;
  o.pose.min_inliers = 8;
  o.guided_repeat_ratio = 0.0;
  EXPECT_FALSE(LocalizationOptions{}.guided_repeat_check);
  EXPECT_EQ(LocalizationOptions{}.plain_repeat_below, 0);

  o.guided_radius = -1.0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o.guided_radius = 8.0;
  o.matches = MatchSource::kWords;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o.matches = MatchSource::kDescriptors;
  o.guided_seed_inliers = 8;  // a seed must be short of min_inliers (8)
  EXPECT_THROW(o.Check(), std::invalid_argument);
  EXPECT_EQ(LocalizationOptions{}.guided_radius, 0.0);  // off unless a preset sets it
}

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
