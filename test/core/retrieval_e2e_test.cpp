// End to end on a small synthetic floor: features -> vocabulary -> BoW -> inverted index.
// A revisited place (a later day, another pose) must retrieve the right database image and
// localize within the protocol's 4.8 mm and 1.5 degrees.
#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/pose.h"
#include "ground_texture_bow/eval/synth/generator.h"
#include "test_scene.h"

namespace gtbow {
namespace {

TEST(RetrievalEndToEnd, RevisitedPlacesFindTheRightDatabaseImage) {
  const synth::Scene scene = testing_util::SmallScene(0.4, 0.3, 30);
  const ImageGeometry geo = scene.options().camera.Geometry();

  RetrievalConfig cfg;  // the paper's high-accuracy configuration, with a small vocabulary
  cfg.vocabulary.num_words = 2000;
  cfg.vocabulary.train_checks = 256;  // training's search effort cut for a unit test's time
  const FeatureExtractor fx(cfg.features);
  std::vector<cv::Mat> train_desc;
  std::vector<uint32_t> image_of;
  std::vector<ImageFeatures> db_feats;
  std::vector<Pose2D> db_poses;
  std::vector<std::pair<Pose2D, ImageFeatures>> queries;
  for (const auto& im : scene.plan().images) {
    const ImageFeatures f = fx.Extract(scene.Render(im));
    if (im.split == "train") {
      train_desc.push_back(f.descriptors);
      image_of.insert(image_of.end(), f.size(), static_cast<uint32_t>(train_desc.size()));
    } else {
      db_feats.push_back(f);
      db_poses.push_back(im.pose);
    }
  }
  // Revisits: every third database place, 30 days later, a few millimetres and degrees off.
  for (size_t d = 0; d < db_poses.size(); d += 3) {
    synth::PlannedImage im;
    im.name = "revisit_" + std::to_string(d);
    im.pose = {db_poses[d].x + 0.004, db_poses[d].y - 0.003, db_poses[d].theta + 0.05};
    im.day = 30;
    im.visit = 100;
    queries.emplace_back(im.pose, fx.Extract(scene.Render(im)));
  }
  cv::Mat desc;
  cv::vconcat(train_desc, desc);
  const auto vocab = TrainVocabulary(cfg.vocabulary, desc, image_of, false);
  const BowEncoder enc(*vocab, cfg.bow);
  BowDatabase db(enc.num_rows(), cfg.bow, vocab->fingerprint());
  for (const auto& f : db_feats) db.Add(enc.Encode(f));

  MapAccess map;
  map.keypoints = [&](uint32_t i) -> const std::vector<Keypoint>& {
    return db_feats.at(i).keypoints;
  };
  map.pose = [&](uint32_t i) { return db_poses.at(i); };
  int right = 0, localized = 0;
  double worst_mm = 0.0, worst_deg = 0.0;
  for (const auto& [pose, f] : queries) {
    size_t best = 0;
    for (size_t d = 1; d < db_poses.size(); ++d) {
      if (Overlap(pose, db_poses[d], geo) > Overlap(pose, db_poses[best], geo)) best = d;
    }
    const auto res = db.Query(enc.Encode(f), 5);
    ASSERT_FALSE(res.empty());
    right += res[0].image == best ? 1 : 0;
    EXPECT_TRUE(IsRelevant(pose, db_poses[res[0].image], geo));
    EXPECT_GT(res[0].matches.size(), 10u);  // pairs for pose estimation
    // Global localization: the protocol's success is 4.8 mm and 1.5 degrees.
    const Localization loc = Localize(db, enc.Encode(f), map, geo, LocalizationOptions{});
    ASSERT_TRUE(loc.success) << loc.reason;
    const double mm = 1000.0 * std::hypot(loc.estimate.floor_from_query.x - pose.x,
                                          loc.estimate.floor_from_query.y - pose.y);
    const double deg =
        std::abs(WrapAngle(loc.estimate.floor_from_query.theta - pose.theta)) * 180.0 / M_PI;
    worst_mm = std::max(worst_mm, mm);
    worst_deg = std::max(worst_deg, deg);
    localized += mm <= 4.8 && deg <= 1.5 ? 1 : 0;
    EXPECT_GT(loc.estimate.covariance[0], 0.0);
    EXPECT_LT(std::sqrt(loc.estimate.covariance[0]), 0.001);  // claimed 1-sigma below 1 mm
  }
  std::printf("localized %d of %zu within 4.8 mm and 1.5 deg; worst %.3f mm, %.3f deg\n", localized,
              queries.size(), worst_mm, worst_deg);
  EXPECT_EQ(localized, static_cast<int>(queries.size()));
  std::printf("top-1 = the revisited database image for %d of %zu day-30 queries\n", right,
              queries.size());
  EXPECT_EQ(right, static_cast<int>(queries.size()));
}

}  // namespace
}  // namespace gtbow
