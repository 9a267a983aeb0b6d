// The online map behind the ROS node, on a small synthetic floor whose ground truth is known:
// keyframes in, loop-closure candidates with relative poses and global fixes out, and a map
// file that survives a round trip and refuses damage.
#include "ground_texture_bow/core/localizer.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <sstream>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "../fuzz/fuzz_util.h"
#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/maintenance.h"
#include "ground_texture_bow/eval/synth/generator.h"
#include "map_v1.h"
#include "test_scene.h"
#include "test_util.h"

namespace gtbow {
namespace {

struct Scene {
  synth::SynthOptions so;
  std::shared_ptr<Vocabulary> vocabulary;
  std::vector<cv::Mat> db_images;
  std::vector<Pose2D> db_poses;
  std::vector<cv::Mat> revisits;  // every third database place, 30 days later, a bit off
  std::vector<Pose2D> revisit_poses;
  // Sequence queries: for the first three revisits, the two images the robot took just before
  // (2 and 4 cm along the image's x axis, turning a little), on the same day.
  std::vector<std::array<cv::Mat, 2>> trails;
  std::vector<std::array<Pose2D, 2>> trail_poses;
};

const Scene& TheScene() {
  static const Scene scene = [] {
    Scene s;
    const synth::Scene floor = testing_util::SmallScene(0.4, 0.3, 30);
    s.so = floor.options();
    RetrievalConfig cfg;
    cfg.vocabulary.num_words = 2000;
    cfg.vocabulary.train_checks = 256;  // training's search effort cut for a unit test's time
    const FeatureExtractor fx(cfg.features);
    std::vector<cv::Mat> train;
    std::vector<uint32_t> image_of;
    for (const auto& im : floor.plan().images) {
      cv::Mat img = floor.Render(im);
      if (im.split == "train") {
        const ImageFeatures f = fx.Extract(img);
        train.push_back(f.descriptors);
        image_of.insert(image_of.end(), f.size(), static_cast<uint32_t>(train.size()));
      } else {
        s.db_images.push_back(img);
        s.db_poses.push_back(im.pose);
      }
    }
    for (size_t d = 0; d < s.db_poses.size(); d += 3) {
      synth::PlannedImage im;
      im.name = "revisit_" + std::to_string(d);
      im.pose = {s.db_poses[d].x + 0.004, s.db_poses[d].y - 0.003, s.db_poses[d].theta + 0.05};
      im.day = 30;
      im.visit = 100;
      s.revisits.push_back(floor.Render(im));
      s.revisit_poses.push_back(im.pose);
      if (s.trails.size() < 3) {
        std::array<cv::Mat, 2> views;
        std::array<Pose2D, 2> poses;
        for (int j = 0; j < 2; ++j) {
          synth::PlannedImage t = im;
          t.name += "_trail" + std::to_string(j);
          t.pose = Compose(im.pose, {0.02 * (j + 1), 0.001 * j, 0.02 * (j + 1)});
          views[j] = floor.Render(t);
          poses[j] = t.pose;
        }
        s.trails.push_back(views);
        s.trail_poses.push_back(poses);
      }
    }
    cv::Mat desc;
    cv::vconcat(train, desc);
    s.vocabulary = TrainVocabulary(cfg.vocabulary, desc, image_of, false);
    s.vocabulary->set_extractor(FormatFeatureOptions(cfg.features));  // as gtbow train-vocab does
    return s;
  }();
  return scene;
}

LocalizerOptions Options() {
  LocalizerOptions o;
  o.retrieval.vocabulary.num_words = 2000;
  o.meters_per_pixel = TheScene().so.camera.meters_per_pixel;
  return o;
}

// A localizer holding every database image as a keyframe (with its pose when `posed`).
std::unique_ptr<Localizer> Mapped(bool posed) {
  const Scene& s = TheScene();
  auto loc = std::make_unique<Localizer>(s.vocabulary, "test.gtvoc", Options());
  for (size_t i = 0; i < s.db_images.size(); ++i) {
    const uint32_t id = loc->Add(loc->Process(s.db_images[i]), 1000 + static_cast<int64_t>(i),
                                 posed ? std::optional<Pose2D>(s.db_poses[i]) : std::nullopt);
    EXPECT_EQ(id, i);
  }
  return loc;
}

// match_from_query from two ground-truth poses.
Pose2D Relative(const Pose2D& match, const Pose2D& query) {
  const double c = std::cos(match.theta), s = std::sin(match.theta);
  const double dx = query.x - match.x, dy = query.y - match.y;
  return {c * dx + s * dy, -s * dx + c * dy, std::remainder(query.theta - match.theta, 2 * M_PI)};
}

TEST(Localizer, GlobalFixesOfRevisitsAreWithinTheProtocolsTolerance) {
  const Scene& s = TheScene();
  const auto loc = Mapped(true);
  ASSERT_EQ(loc->size(), s.db_images.size());
  for (size_t q = 0; q < s.revisits.size(); ++q) {
    const Localization fix = loc->Localize(loc->Process(s.revisits[q]));
    ASSERT_TRUE(fix.success) << fix.reason;
    const Pose2D& t = s.revisit_poses[q];
    const Pose2D& p = fix.estimate.floor_from_query;
    EXPECT_LT(1000 * std::hypot(p.x - t.x, p.y - t.y), 4.8);
    EXPECT_LT(std::abs(std::remainder(p.theta - t.theta, 2 * M_PI)) * 180 / M_PI, 1.5);
    EXPECT_GT(fix.estimate.covariance[0], 0.0);
    EXPECT_GE(fix.estimate.inliers, 6);
    EXPECT_EQ(fix.inlier_pixels.size(), static_cast<size_t>(fix.estimate.inliers));
  }
}

// Issue 15: the presets' verification (descriptor matches, rotation sigma, consensus) through
// the Localizer, as the node runs it.
TEST(Localizer, TrustedVerificationLocalizesRevisitsAndRefusesARepeatedFloor) {
  const Scene& s = TheScene();
  LocalizerOptions o = Options();
  o.retrieval.verification =
      LoadRetrievalConfig(GTBOW_CONFIG_DIR "/high_accuracy.yaml").verification;
  ASSERT_EQ(o.retrieval.verification.matches, MatchSource::kDescriptors);
  Localizer loc(s.vocabulary, "test.gtvoc", o);
  for (size_t i = 0; i < s.db_images.size(); ++i)
    loc.Add(loc.Process(s.db_images[i]), 1000 + static_cast<int64_t>(i), s.db_poses[i]);
  for (size_t q = 0; q < s.revisits.size(); ++q) {
    const Localization fix = loc.Localize(loc.Process(s.revisits[q]));
    ASSERT_TRUE(fix.success) << fix.reason;
    const Pose2D& t = s.revisit_poses[q];
    const Pose2D& p = fix.estimate.floor_from_query;
    EXPECT_LT(1000 * std::hypot(p.x - t.x, p.y - t.y), 4.8);
    EXPECT_LT(std::abs(std::remainder(p.theta - t.theta, 2 * M_PI)) * 180 / M_PI, 1.5);
    EXPECT_LT(fix.estimate.theta_sigma, 0.4 * M_PI / 180);
  }
  // The same floor twice, 0.3 m apart (a copied patch, as in some of the real photographs):
  // both copies verify equally well, so the place is ambiguous and no pose is given.
  const size_t d = 3;  // revisit 1 is database place 3
  loc.Add(loc.Process(s.db_images[d]), 5000,
          Pose2D{s.db_poses[d].x + 0.3, s.db_poses[d].y, s.db_poses[d].theta});
  const ProcessedImage img = loc.Process(s.revisits[1]);
  const Localization fix = loc.Localize(img);
  EXPECT_FALSE(fix.success);
  EXPECT_NE(fix.reason.find("ambiguous place"), std::string::npos) << fix.reason;
  // Loop-closure candidates keep both copies (their keyframes' poses may be drifting odometry,
  // which cannot arbitrate): the one with the most inliers is the closure.
  const auto cands = loc.Query(img, 5, true);
  const int closure = LoopClosureCandidate(cands, o.retrieval.verification);
  ASSERT_GE(closure, 0);
  for (const Candidate& c : cands) {
    if (c.verified) {
      EXPECT_LE(c.relative.inliers, cands[closure].relative.inliers);
    }
  }
  // The paper's verification takes the first candidate that verifies, whichever copy it is.
  o.retrieval.verification = LocalizationOptions{};
  Localizer paper(s.vocabulary, "test.gtvoc", o);
  for (size_t i = 0; i < s.db_images.size(); ++i)
    paper.Add(paper.Process(s.db_images[i]), 1000 + static_cast<int64_t>(i), s.db_poses[i]);
  paper.Add(paper.Process(s.db_images[d]), 5000,
            Pose2D{s.db_poses[d].x + 0.3, s.db_poses[d].y, s.db_poses[d].theta});
  EXPECT_TRUE(paper.Localize(img).success);
}

// The scene's database as a map, and with `copy` >= 0 that database place again 0.3 m away (a
// floor that repeats a place).
std::unique_ptr<Localizer> SceneMap(const LocalizerOptions& opt, int copy) {
  const Scene& s = TheScene();
  auto loc = std::make_unique<Localizer>(s.vocabulary, "test.gtvoc", opt);
  for (size_t i = 0; i < s.db_images.size(); ++i)
    loc->Add(loc->Process(s.db_images[i]), 1000 + static_cast<int64_t>(i), s.db_poses[i]);
  if (copy >= 0) {
    const size_t d = static_cast<size_t>(copy);
    loc->Add(loc->Process(s.db_images[d]), 5000,
             Pose2D{s.db_poses[d].x + 0.3, s.db_poses[d].y, s.db_poses[d].theta});
  }
  return loc;
}

// Guided matching's repeat check through the Localizer (the node's map): a keyframe whose image
// the map also holds elsewhere (a copy 0.3 m away) gives no guided pose, since queried against
// its own map it verifies with the copy; without the copy the guided pose stands.
TEST(Localizer, TheRepeatCheckRefusesGuidedPosesFromAKeyframeWithACopy) {
  const Scene& s = TheScene();
  LocalizerOptions o = Options();
  o.retrieval.verification =
      LoadRetrievalConfig(GTBOW_CONFIG_DIR "/ablation/changing/guided_repeat_check.yaml")
          .verification;
  ASSERT_TRUE(o.retrieval.verification.guided_repeat_check);
  o.retrieval.verification.max_conflict_ratio = 0.0;  // first verified: the copy is not compared
  const size_t d = 3;                                 // revisit 1 is database place 3
  auto map = [&](const LocalizerOptions& opt, bool copy) {
    return SceneMap(opt, copy ? static_cast<int>(d) : -1);
  };
  // Every candidate's ratio-test matches one inlier short: only guided matching gives a pose.
  const auto plain = map(o, false);
  const ProcessedImage img = plain->Process(s.revisits[1]);
  int most = 0;
  for (const Candidate& c : plain->Query(img, 5, true)) most = std::max(most, c.relative.inliers);
  ASSERT_GT(most, 0);
  o.retrieval.verification.pose.min_inliers = most + 1;
  const Localization kept = map(o, false)->Localize(img);
  ASSERT_TRUE(kept.success) << kept.reason;
  const Pose2D& t = s.revisit_poses[1];
  EXPECT_LT(1000 * std::hypot(kept.estimate.floor_from_query.x - t.x,
                              kept.estimate.floor_from_query.y - t.y),
            4.8);
  // The same features as a sequence query's combined view are verified without guided matching
  // (CombinedViewOptions) unless guided_combined.
  ProcessedImage view = img;
  view.combined = true;
  const Localization unguided = map(o, false)->Localize(view);
  EXPECT_FALSE(unguided.success);
  EXPECT_EQ(unguided.reason.find("guided"), std::string::npos) << unguided.reason;
  o.retrieval.verification.guided_combined = true;
  EXPECT_TRUE(map(o, false)->Localize(view).success);
  o.retrieval.verification.guided_combined = false;
  const Localization refused = map(o, true)->Localize(img);
  EXPECT_FALSE(refused.success);
  EXPECT_NE(refused.reason.find("repeats elsewhere"), std::string::npos) << refused.reason;
  o.retrieval.verification.guided_repeat_check = false;  // without it, a guided pose
  EXPECT_TRUE(map(o, true)->Localize(img).success);
}

// The repeat check of plain poses through the Localizer (the node's map): with the place's
// keyframe also in the map 0.3 m away, the query holds as many inliers at either, and its plain
// pose is refused; without the copy the pose stands, and with the check off a pose is published.
TEST(Localizer, TheRepeatCheckOfPlainPosesRefusesAPlaceTheMapHoldsTwice) {
  const Scene& s = TheScene();
  LocalizerOptions o = Options();
  o.retrieval.verification =
      LoadRetrievalConfig(GTBOW_CONFIG_DIR "/changing_floors.yaml").verification;
  ASSERT_GT(o.retrieval.verification.plain_repeat_below, 0);
  o.retrieval.verification.max_conflict_ratio = 0.0;      // first verified: no consensus
  o.retrieval.verification.plain_repeat_below = 1000000;  // every plain pose is checked
  const size_t d = 3;                                     // revisit 1 is database place 3
  auto map = [&](const LocalizerOptions& opt, bool copy) {
    return SceneMap(opt, copy ? static_cast<int>(d) : -1);
  };
  const auto single = map(o, false);
  const ProcessedImage img = single->Process(s.revisits[1]);
  const Localization kept = single->Localize(img);
  ASSERT_TRUE(kept.success) << kept.reason;
  const Pose2D& t = s.revisit_poses[1];
  EXPECT_LT(1000 * std::hypot(kept.estimate.floor_from_query.x - t.x,
                              kept.estimate.floor_from_query.y - t.y),
            4.8);
  // The copy added to the same map: the copies its checks kept (none) go with the change. (The
  // pose is keyframe d's, which ranks before its identical copy: lower ids first on a tie.)
  const uint32_t copy_id =
      single->Add(single->Process(s.db_images[d]), 5000,
                  Pose2D{s.db_poses[d].x + 0.3, s.db_poses[d].y, s.db_poses[d].theta});
  const Localization refused = single->Localize(img);
  EXPECT_FALSE(refused.success);
  EXPECT_NE(refused.reason.find("repeat: keyframe"), std::string::npos) << refused.reason;
  EXPECT_NE(refused.reason.find("plain_repeat_ratio 0.9"), std::string::npos) << refused.reason;
  // The copy retired: the copies kept (the copy) go with it, and the pose stands again.
  ASSERT_TRUE(single->Retire(copy_id));
  EXPECT_TRUE(single->Localize(img).success);
  // A map made with the copy alike; the backend then moves the copy onto the place's pose (the
  // same place twice, no repeat): the copies kept go with the move, and the pose stands.
  const auto twice = map(o, true);
  EXPECT_FALSE(twice->Localize(img).success);
  const uint32_t twin = static_cast<uint32_t>(s.db_images.size());
  ASSERT_EQ(twice->UpdateKeyframePoses({KeyframePose{twin, 5000, s.db_poses[d]}}), 1u);
  EXPECT_TRUE(twice->Localize(img).success);
  o.retrieval.verification.plain_repeat_below = 0;  // without it, the first verified pose
  EXPECT_TRUE(map(o, true)->Localize(img).success);
  // A map without descriptors has neither guided matching nor the repeat checks (both match
  // descriptors): the preset localizes with the words' pairs, first passes and combined views too.
  o.retrieval.verification.plain_repeat_below = 30;
  o.keep_descriptors = false;
  const auto words = map(o, false);
  ProcessedImage w = words->Process(s.revisits[1]);
  EXPECT_NO_THROW(words->Localize(w));
  w.first_pass = true;
  EXPECT_NO_THROW(words->Localize(w));
  w.first_pass = false;
  w.combined = true;
  EXPECT_NO_THROW(words->Localize(w));
}

TEST(Localizer, CandidatesCarryVerifiedRelativePosesAndNoFixWithoutPoses) {
  const Scene& s = TheScene();
  const auto loc = Mapped(false);  // a SLAM backend's keyframes: no poses
  for (size_t q = 0; q < s.revisits.size(); ++q) {
    const ProcessedImage img = loc->Process(s.revisits[q]);
    const auto cands = loc->Query(img, 3, true);
    ASSERT_FALSE(cands.empty());
    const Candidate& best = cands[0];
    EXPECT_EQ(best.stamp_ns, 1000 + static_cast<int64_t>(best.id));
    EXPECT_FALSE(best.has_pose);
    ASSERT_TRUE(best.verified) << best.relative.reason;
    EXPECT_EQ(best.inliers.size(), static_cast<size_t>(best.relative.inliers));
    const Pose2D truth = Relative(s.db_poses[best.id], s.revisit_poses[q]);
    const Pose2D& est = best.relative.floor_from_query;
    EXPECT_LT(1000 * std::hypot(est.x - truth.x, est.y - truth.y), 4.8);
    EXPECT_LT(std::abs(std::remainder(est.theta - truth.theta, 2 * M_PI)), 1.5 * M_PI / 180);
    // Without poses there is nothing to localize against.
    const Localization fix = loc->Localize(img);
    EXPECT_FALSE(fix.success);
    EXPECT_NE(fix.reason.find("no pose"), std::string::npos) << fix.reason;
  }
  // Unverified queries give no relative pose.
  const auto plain = loc->Query(loc->Process(s.revisits[0]), 3, false);
  ASSERT_FALSE(plain.empty());
  EXPECT_FALSE(plain[0].verified);
}

TEST(Localizer, QueryByKeyframeExcludesItselfAndFindsOverlappingNeighbours) {
  const Scene& s = TheScene();
  const auto loc = Mapped(true);
  const ImageGeometry geo = s.so.camera.Geometry();
  for (uint32_t id = 0; id < s.db_images.size(); id += 4) {
    const auto cands = loc->QueryKeyframe(id, 5, true);
    ASSERT_FALSE(cands.empty());
    for (const Candidate& c : cands) EXPECT_NE(c.id, id);
    EXPECT_GT(Overlap(s.db_poses[id], s.db_poses[cands[0].id], geo), 0.25);
  }
  EXPECT_THROW(loc->QueryKeyframe(100000, 5, false), std::out_of_range);
  // Excluding a range (the query's own recent past).
  const ProcessedImage img = loc->Process(s.db_images[5]);
  for (const Candidate& c : loc->Query(img, 5, false, 3, 8)) {
    EXPECT_TRUE(c.id < 3 || c.id >= 8) << c.id;
  }
}

// Everything a candidate or a fix carries, at full precision, for comparing answers.
std::string Describe(const Pose2D& p) {
  std::ostringstream o;
  o.precision(17);
  o << p.x << ' ' << p.y << ' ' << p.theta;
  return o.str();
}
template <size_t N>
std::string Describe(const std::array<double, N>& a) {
  std::ostringstream o;
  o.precision(17);
  for (double v : a) o << v << ' ';
  return o.str();
}
std::string Describe(const std::vector<Vec2>& points) {
  std::ostringstream o;
  o.precision(17);
  for (const Vec2& v : points) o << v.x << ',' << v.y << ' ';
  return o.str();
}
std::string Describe(const Candidate& c) {
  std::ostringstream o;
  o.precision(17);
  const PoseEstimate& r = c.relative;
  o << "id " << c.id << " score " << c.score << " stamp " << c.stamp_ns << " has_pose "
    << c.has_pose << " pose " << Describe(c.map_from_camera) << " verified " << c.verified
    << " relative " << r.success << " '" << r.reason << "' " << r.database_from_query.theta << ' '
    << r.database_from_query.t.x << ' ' << r.database_from_query.t.y << ' '
    << Describe(r.floor_from_query) << " inliers " << r.inliers << " rms " << r.residual_rms
    << " cov " << Describe(r.covariance) << " inlier pixels " << Describe(c.inliers);
  return o.str();
}
std::string Describe(const Localization& f) {
  std::ostringstream o;
  o.precision(17);
  const PoseEstimate& e = f.estimate;
  o << "success " << f.success << " '" << f.reason << "' image " << f.image << " rank " << f.rank
    << " score " << f.score << " pose " << Describe(e.floor_from_query) << " cov "
    << Describe(e.covariance) << " inliers " << e.inliers << " rms " << e.residual_rms << " pixels "
    << Describe(f.inlier_pixels);
  return o.str();
}

class LocalizerFiles : public testing_util::TempDirTest {
 protected:
  const std::filesystem::path& dir() const { return dir_; }
};

// Save swaps the saving map over to the file it wrote, so after a save both maps read the
// same bytes: the answers are recorded before the save, from the map in memory, and a save
// that wrote a wrong score, keypoint or pose shows here.
TEST_F(LocalizerFiles, SavedMapsLoadAndAnswerIdentically) {
  const Scene& s = TheScene();
  const auto loc = Mapped(true);
  const auto path = dir() / "map.gtmap";
  std::vector<ProcessedImage> images;
  std::vector<std::vector<std::string>> before;
  std::vector<std::string> fixes_before;
  for (const cv::Mat& revisit : s.revisits) {
    images.push_back(loc->Process(revisit));
    std::vector<std::string> described;
    for (const Candidate& c : loc->Query(images.back(), 5, true)) described.push_back(Describe(c));
    ASSERT_FALSE(described.empty());
    before.push_back(described);
    fixes_before.push_back(Describe(loc->Localize(images.back())));
  }
  const auto k7_before = loc->KeyframeInfo(7);
  const uint32_t by_id_before = loc->QueryKeyframe(7, 3, false)[0].id;
  ASSERT_TRUE(k7_before.has_value());
  loc->Save(path);
  EXPECT_EQ(Localizer::VocabularyPathOf(path), "test.gtvoc");
  Localizer fresh(s.vocabulary, "test.gtvoc", Options());
  fresh.Load(path);
  ASSERT_EQ(fresh.size(), loc->size());
  for (size_t q = 0; q < images.size(); ++q) {
    // Every field of every candidate and of the fix, bit for bit.
    std::vector<std::string> after;
    for (const Candidate& c : fresh.Query(images[q], 5, true)) after.push_back(Describe(c));
    EXPECT_EQ(after, before[q]) << q;
    EXPECT_EQ(Describe(fresh.Localize(images[q])), fixes_before[q]) << q;
  }
  const auto k7 = fresh.KeyframeInfo(7);
  ASSERT_TRUE(k7.has_value());
  EXPECT_EQ(k7->stamp_ns, 1007);
  EXPECT_EQ(k7->map_from_camera.x, s.db_poses[7].x);
  EXPECT_EQ(k7->map_from_camera.y, k7_before->map_from_camera.y);
  EXPECT_EQ(k7->map_from_camera.theta, k7_before->map_from_camera.theta);
  // Query by keyframe id works on a loaded map (descriptors were saved).
  EXPECT_EQ(fresh.QueryKeyframe(7, 3, false)[0].id, by_id_before);
}

// A paced save (the node's ~save_map and autosave, beside its localization) writes the same
// file as an unpaced one (the save at shutdown, the tools) and takes at least the paced time
// (only that lower bound is checked: a slow disk or a busy core makes it longer, never
// shorter). The options refuse a negative, non-finite or too slow pace (under 1 MB/s).
TEST_F(LocalizerFiles, PacedSavesWriteTheSameMapAtThePace) {
  const auto loc = Mapped(true);
  const auto unpaced = dir() / "unpaced.gtmap";
  loc->Save(unpaced, /*paced=*/false);
  const std::string bytes = ReadFile(unpaced);
  LocalizerOptions o = Options();
  // The whole file in 0.2 s, or longer at the slowest pace allowed (1 MB/s).
  o.save_rate_mb = std::max(1.0, static_cast<double>(bytes.size()) / 1e6 / 0.2);
  const double paced_seconds = static_cast<double>(bytes.size()) / (o.save_rate_mb * 1e6);
  Localizer slow(TheScene().vocabulary, "test.gtvoc", o);
  slow.Load(unpaced);
  const auto paced = dir() / "paced.gtmap";
  const auto start = std::chrono::steady_clock::now();
  slow.Save(paced);
  EXPECT_GE(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(),
            paced_seconds);
  EXPECT_EQ(ReadFile(paced), bytes);
  o.save_rate_mb = -1;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o.save_rate_mb = std::numeric_limits<double>::infinity();
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o.save_rate_mb = 0.5;  // a 6 GB map would take hours: refused
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o.save_rate_mb = 1;
  EXPECT_NO_THROW(o.Check());
  o.save_rate_mb = 0;
  EXPECT_NO_THROW(o.Check());
}

// A node that learns its scale from the camera: set while the map is empty, saved with the
// map, adopted by a node that loads it with adopt_scale, and refused otherwise.
TEST_F(LocalizerFiles, TheScaleIsSetWhileEmptySavedAndAdoptedOnRequest) {
  const Scene& s = TheScene();
  const double mpp = Options().meters_per_pixel;
  LocalizerOptions wrong = Options();
  wrong.meters_per_pixel = 2 * mpp;
  Localizer loc(s.vocabulary, "test.gtvoc", wrong);
  EXPECT_THROW(loc.SetMetersPerPixel(0.0), std::invalid_argument);
  EXPECT_THROW(loc.SetMetersPerPixel(std::nan("")), std::invalid_argument);
  loc.SetMetersPerPixel(mpp);
  EXPECT_EQ(loc.meters_per_pixel(), mpp);
  for (size_t i = 0; i < s.db_images.size(); ++i) {
    loc.Add(loc.Process(s.db_images[i]), static_cast<int64_t>(i), s.db_poses[i]);
  }
  // Verified at the set scale: a revisit's fix is within the protocol's tolerance (at twice
  // the scale it would be off by its distance from the keyframe).
  const Localization fix = loc.Localize(loc.Process(s.revisits[1]));
  ASSERT_TRUE(fix.success) << fix.reason;
  EXPECT_LT(1000 * std::hypot(fix.estimate.floor_from_query.x - s.revisit_poses[1].x,
                              fix.estimate.floor_from_query.y - s.revisit_poses[1].y),
            4.8);
  try {
    loc.SetMetersPerPixel(1.01 * mpp);
    FAIL() << "the scale of a map with keyframes changed";
  } catch (const std::logic_error& e) {
    EXPECT_NE(std::string(e.what()).find("keyframes made at"), std::string::npos) << e.what();
  }
  loc.SetMetersPerPixel(mpp);  // the same scale is no change
  const auto path = dir() / "scaled.gtmap";
  loc.Save(path);
  EXPECT_EQ(Localizer::ReadMapInfo(path).meters_per_pixel, mpp);
  Localizer strict(s.vocabulary, "test.gtvoc", wrong);
  EXPECT_THROW(strict.Load(path), std::runtime_error);
  EXPECT_EQ(strict.meters_per_pixel(), 2 * mpp);
  Localizer adopting(s.vocabulary, "test.gtvoc", wrong);
  EXPECT_EQ(adopting.Load(path, true), s.db_images.size());
  EXPECT_EQ(adopting.meters_per_pixel(), mpp);
  EXPECT_EQ(Describe(adopting.Localize(adopting.Process(s.revisits[1]))), Describe(fix));
}

TEST_F(LocalizerFiles, DamagedOrForeignMapsAreRefusedAndTheCurrentMapKept) {
  const Scene& s = TheScene();
  const auto loc = Mapped(true);
  const auto path = dir() / "map.gtmap";
  loc->Save(path);
  const std::string good = ReadFile(path);
  Localizer target(s.vocabulary, "test.gtvoc", Options());
  target.Add(target.Process(s.db_images[0]), 1, std::nullopt);
  // Each refusal names the file and the defect.
  auto expect_refused = [&](const std::string& bytes, const std::string& what,
                            const std::string& defect) {
    WriteFileAtomic(dir() / "bad.gtmap", bytes);
    try {
      target.Load(dir() / "bad.gtmap");
      ADD_FAILURE() << "loaded " << what;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("bad.gtmap"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(defect), std::string::npos) << what << ": " << e.what();
    }
    EXPECT_EQ(target.size(), 1u) << what;  // the current map is kept
  };
  const fuzz::MapLayout layout = fuzz::ParseMapLayout(good);
  ASSERT_TRUE(layout.ok);
  // A flipped byte in the index or the records: found by the 64 MB checksums at load.
  for (int section : {1, 2}) {
    std::string flipped = good;
    flipped[layout.offset[section] + layout.size[section] / 2] ^= 0x40;
    expect_refused(flipped, "a flipped byte in section " + std::to_string(section),
                   "checksum mismatch");
  }
  expect_refused(good.substr(0, good.size() / 3), "a truncated file", "truncated");
  expect_refused(good.substr(0, good.size() - 1), "a file short of one byte", "truncated");
  expect_refused(good + "x", "a file with a byte too many", "trailing bytes");
  expect_refused("not a map at all", "a foreign file", "too short");
  std::string future = good;
  future[8] = 99;  // the format version (after the 8-byte magic number)
  expect_refused(future, "a newer format", "format version 99 is not supported");
  std::string vocab_file;
  {
    s.vocabulary->Save(dir() / "v.gtvoc");
    vocab_file = ReadFile(dir() / "v.gtvoc");
  }
  expect_refused(vocab_file, "a vocabulary file", "wrong magic number");
  // Well-formed, checksummed files with a NaN in a keyframe pose: the value is found by its
  // bytes (unique in the file), replaced, and the checksums made right again.
  auto unique_in_file = [&](const void* value, size_t size) {
    const std::string needle(static_cast<const char*>(value), size);
    const size_t at = good.find(needle);
    return at != std::string::npos && good.find(needle, at + 1) == std::string::npos;
  };
  int posed = -1;
  double coordinate = 0;
  for (size_t i = 0; i < s.db_poses.size() && posed < 0; ++i) {
    for (const double v : {s.db_poses[i].x, s.db_poses[i].y, s.db_poses[i].theta}) {
      if (unique_in_file(&v, sizeof v)) {
        posed = static_cast<int>(i);
        coordinate = v;
        break;
      }
    }
  }
  ASSERT_GE(posed, 0);
  {
    std::string bytes = good;
    const double nan = std::nan("");
    std::memcpy(&bytes[good.find(std::string(reinterpret_cast<const char*>(&coordinate), 8))], &nan,
                sizeof nan);
    expect_refused(fuzz::RepairMap(bytes), "a NaN pose",
                   "keyframe " + std::to_string(posed) + " has a non-finite pose");
  }
  {
    // Keyframe 6 claims a keypoint more than its payload holds (checksums repaired).
    std::string bytes = good;
    const size_t count_at = layout.offset[2] + 6 * 64 + 44;
    uint32_t n;
    std::memcpy(&n, &bytes[count_at], 4);
    ++n;
    std::memcpy(&bytes[count_at], &n, 4);
    // (The payload offsets then disagree from keyframe 7 on, which the error names.)
    expect_refused(fuzz::RepairMap(bytes), "a keypoint count out of step",
                   "keyframe 7 is malformed");
  }
  // A flipped byte in a keyframe's stored keypoints: the map loads (a load reads the index and
  // the records, not every keypoint), and that keyframe alone refuses verification by name.
  {
    Localizer loaded(s.vocabulary, "test.gtvoc", Options());
    loaded.Load(path);
    const ProcessedImage img = loaded.Process(s.revisits[0]);
    const auto before = loaded.Query(img, 3, true);
    ASSERT_TRUE(before[0].verified);
    const uint32_t victim = before[0].id;
    std::string bytes = good;
    uint64_t payload_offset;
    std::memcpy(&payload_offset, &bytes[layout.offset[2] + victim * 64 + 48], 8);
    bytes[layout.offset[4] + payload_offset + 3] ^= 0x10;
    WriteFileAtomic(dir() / "payload.gtmap", bytes);
    loaded.Load(dir() / "payload.gtmap");
    const auto after = loaded.Query(img, 3, true);
    ASSERT_EQ(after[0].id, victim);
    EXPECT_FALSE(after[0].verified);
    EXPECT_NE(after[0].relative.reason.find("keyframe " + std::to_string(victim)),
              std::string::npos)
        << after[0].relative.reason;
    EXPECT_NE(after[0].relative.reason.find("checksum"), std::string::npos);
    EXPECT_EQ(after[1].verified, before[1].verified);  // the others are unaffected
    EXPECT_THROW(loaded.QueryKeyframe(victim, 3, false), std::runtime_error);
  }
  // A map made with another vocabulary (the fuzzers' 64-word fixture) is refused by name.
  {
    LocalizerOptions o = Options();
    o.retrieval.vocabulary.num_words = 64;
    Localizer other_vocab(Vocabulary::Load(GTBOW_FUZZ_DATA "/tiny.gtvoc"), "tiny.gtvoc", o);
    other_vocab.Add(other_vocab.Process(s.db_images[0]), 1, std::nullopt);
    other_vocab.Save(dir() / "other_vocabulary.gtmap");
    try {
      target.Load(dir() / "other_vocabulary.gtmap");
      ADD_FAILURE() << "loaded a map of another vocabulary";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("another vocabulary"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("other_vocabulary.gtmap"), std::string::npos)
          << e.what();
    }
    EXPECT_EQ(target.size(), 1u);
  }
  // Another preset (other BoW options) is refused with a reason.
  LocalizerOptions other = Options();
  other.retrieval.bow.soft_assignment = 1;
  Localizer fast(s.vocabulary, "test.gtvoc", other);
  try {
    fast.Load(path);
    ADD_FAILURE() << "loaded a map of another preset";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("preset"), std::string::npos) << e.what();
  }
  // A save that cannot be written throws, naming the path and the system's reason.
  try {
    loc->Save(dir() / "no_such_dir" / "map.gtmap");
    ADD_FAILURE() << "saved into a directory that does not exist";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("no_such_dir/map.gtmap"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("No such file or directory"), std::string::npos)
        << e.what();
  }
  // A save over the map itself that fails half-way (a file-size limit below the map's size,
  // as a full disk would) leaves the file exactly as it was, time stamp included.
  const auto mtime = std::filesystem::last_write_time(path);
  loc->Add(loc->Process(s.revisits[0]), 5000, std::nullopt);  // a different, larger map
  {
    testing_util::FileSizeLimit limit(good.size() / 2);
    try {
      loc->Save(path);
      ADD_FAILURE() << "a save past the file-size limit succeeded";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("File too large"), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(ReadFile(path), good);
  EXPECT_EQ(std::filesystem::last_write_time(path), mtime);
  EXPECT_TRUE(testing_util::Temporaries(dir()).empty());
}

// Answers of two maps to every revisit, bit for bit (candidates and fixes).
void ExpectSameAnswers(const Localizer& a, const Localizer& b, const std::string& what) {
  const Scene& s = TheScene();
  for (size_t q = 0; q < s.revisits.size(); ++q) {
    const ProcessedImage img = a.Process(s.revisits[q]);
    const auto ca = a.Query(img, 5, true), cb = b.Query(img, 5, true);
    ASSERT_EQ(ca.size(), cb.size()) << what;
    for (size_t k = 0; k < ca.size(); ++k)
      EXPECT_EQ(Describe(ca[k]), Describe(cb[k])) << what << ' ' << q << ' ' << k;
    EXPECT_EQ(Describe(a.Localize(img)), Describe(b.Localize(img))) << what << ' ' << q;
  }
}

// Mapping goes on after a load (new keyframes in a growable tail after the mapped ones), and
// after a save (which swaps the heap copy for the file's); a second save and load give the
// same answers again.
TEST_F(LocalizerFiles, MappingContinuesOnALoadedMapAndAcrossSaves) {
  const Scene& s = TheScene();
  const size_t half = s.db_images.size() / 2;
  Localizer online(s.vocabulary, "test.gtvoc", Options());
  for (size_t i = 0; i < half; ++i) online.Add(online.Process(s.db_images[i]), 1, s.db_poses[i]);
  const size_t heap = online.HeapBytes();
  online.Save(dir() / "half.gtmap");
  EXPECT_LT(online.HeapBytes(), heap) << "after a save the file's copy is used";
  Localizer loaded(s.vocabulary, "test.gtvoc", Options());
  loaded.Load(dir() / "half.gtmap");
  // Mapped, not copied: the heap of an empty map plus a byte of flags per keyframe.
  EXPECT_LE(loaded.HeapBytes(),
            Localizer(s.vocabulary, "test.gtvoc", Options()).HeapBytes() + 2 * half);
  for (size_t i = half; i < s.db_images.size(); ++i) {
    const ProcessedImage img = online.Process(s.db_images[i]);
    EXPECT_EQ(online.Add(img, 2, s.db_poses[i]), loaded.Add(img, 2, s.db_poses[i]));
    if (i == half + 3) online.Save(dir() / "during.gtmap");  // a save in the middle
  }
  ExpectSameAnswers(online, loaded, "loaded + tail");
  loaded.Save(dir() / "full.gtmap");
  ExpectSameAnswers(online, loaded, "after its own save");
  Localizer again(s.vocabulary, "test.gtvoc", Options());
  again.Load(dir() / "full.gtmap");
  ASSERT_EQ(again.size(), s.db_images.size());
  ExpectSameAnswers(online, again, "saved and loaded again");
  // Saved over the very file it is mapped from: the mapping keeps the old bytes valid.
  again.Add(again.Process(s.revisits[0]), 3, std::nullopt);
  again.Save(dir() / "full.gtmap");
  Localizer third(s.vocabulary, "test.gtvoc", Options());
  third.Load(dir() / "full.gtmap");
  EXPECT_EQ(third.size(), s.db_images.size() + 1);
  ExpectSameAnswers(again, third, "saved over its own file");
}

// Maintenance (maintenance.h) as the node applies it: every fix adds its view here (the refresh
// threshold is out of reach), a place keeps one view besides the map's keyframes, so the
// revisits retire views; a retired keyframe is never retrieved again, is flagged, and stays
// retired in a saved map; the map's own keyframes are never retired.
TEST_F(LocalizerFiles, AMaintainedMapAddsViewsRetiresKeyframesAndSavesBoth) {
  const Scene& s = TheScene();
  const auto loc = Mapped(true);
  MaintenanceOptions mo;
  mo.refresh_below_inliers = 100000;
  mo.max_views_per_place = 1;
  mo.place_fraction = 0.6;  // 72 mm: revisits of neighbours 64 mm apart share places
  MapMaintainer m(mo, {s.db_images[0].cols, s.db_images[0].rows, s.so.camera.meters_per_pixel});
  TrackMap(*loc, &m);
  EXPECT_EQ(m.tracked(), s.db_images.size());
  std::vector<uint32_t> retired, added;
  for (size_t q = 0; q < s.revisits.size(); ++q) {
    const int64_t stamp = 5000 + static_cast<int64_t>(q);
    const Localization fix =
        loc->Localize(loc->Process(s.revisits[q], Localizer::ImageUse::kQuery));
    ASSERT_TRUE(fix.success) << fix.reason;
    const MaintenanceStep step = m.Observe(fix, stamp);
    ASSERT_TRUE(step.add) << step.reason;
    const std::optional<uint32_t> id =
        ApplyMaintenance(step, fix, loc->Process(s.revisits[q]), stamp, loc.get(), &m);
    ASSERT_TRUE(id.has_value());
    added.push_back(*id);
    EXPECT_EQ(loc->KeyframeInfo(*id)->map_from_camera.x, fix.estimate.floor_from_query.x);
    for (uint32_t r : step.retire) {
      EXPECT_FALSE(loc->Retire(r)) << "retired twice";
      retired.push_back(r);
    }
  }
  ASSERT_FALSE(retired.empty()) << "no place was full";
  EXPECT_EQ(loc->live_size(), loc->size() - retired.size());
  EXPECT_EQ(m.tracked(), loc->live_size());
  auto is_retired = [&](uint32_t id) {
    return std::find(retired.begin(), retired.end(), id) != retired.end();
  };
  for (const Keyframe& k : loc->Keyframes()) {
    EXPECT_EQ(k.retired, is_retired(k.id)) << k.id;
    EXPECT_EQ(k.maintained, k.id >= s.db_images.size()) << k.id;
    if (!k.maintained) {
      EXPECT_FALSE(k.retired) << "the map's own keyframe " << k.id;
    }
  }
  size_t from_added = 0;
  for (size_t q = 0; q < s.revisits.size(); ++q) {
    const ProcessedImage img = loc->Process(s.revisits[q], Localizer::ImageUse::kQuery);
    for (const Candidate& c : loc->Query(img, 20, false)) EXPECT_FALSE(is_retired(c.id)) << c.id;
    const Localization again = loc->Localize(img);
    ASSERT_TRUE(again.success);
    EXPECT_FALSE(is_retired(again.image));
    from_added += again.image >= s.db_images.size() ? 1 : 0;
  }
  // The views added on day 30 give most day-30 fixes now (this one's or a neighbour's).
  EXPECT_GT(2 * from_added, s.revisits.size());
  loc->Save(dir() / "maintained.gtmap");
  Localizer loaded(s.vocabulary, "test.gtvoc", Options());
  loaded.Load(dir() / "maintained.gtmap");
  EXPECT_EQ(loaded.live_size(), loc->live_size());
  for (const Keyframe& k : loaded.Keyframes()) {
    EXPECT_EQ(k.retired, is_retired(k.id)) << k.id;
    EXPECT_EQ(k.maintained, k.id >= s.db_images.size()) << k.id;
  }
  EXPECT_TRUE(loaded.KeyframeInfo(retired[0])->retired);
  MapMaintainer resumed(mo,
                        {s.db_images[0].cols, s.db_images[0].rows, s.so.camera.meters_per_pixel});
  TrackMap(loaded, &resumed);  // a node resuming maintenance on the saved map
  EXPECT_EQ(resumed.tracked(), loaded.live_size());
  EXPECT_FALSE(loaded.Retire(retired[0]));
  EXPECT_FALSE(loaded.Retire(static_cast<uint32_t>(loaded.size())));
  ExpectSameAnswers(*loc, loaded, "a maintained map saved and loaded");
}

// A map of format version 1 is refused by Load with the command that converts it; converted
// (ImportVersion1 + Save) it answers as a map built here from the same images.
TEST_F(LocalizerFiles, VersionOneMapsAreRefusedWithTheirConversionAndConvertExactly) {
  const Scene& s = TheScene();
  Localizer built(s.vocabulary, "test.gtvoc", Options());
  std::vector<testing_util::Version1Keyframe> v1;
  for (size_t i = 0; i < s.db_images.size(); ++i) {
    ProcessedImage img = built.Process(s.db_images[i]);
    built.Add(img, 1000 + static_cast<int64_t>(i), s.db_poses[i]);
    v1.push_back(
        {img.features, img.width, img.height, 1000 + static_cast<int64_t>(i), s.db_poses[i]});
  }
  const auto old_path = dir() / "old.gtmap";
  testing_util::WriteVersion1Map(old_path, *s.vocabulary, "test.gtvoc", Options(), v1);
  const MapFileInfo info = Localizer::ReadMapInfo(old_path);
  EXPECT_EQ(info.version, 1u);
  EXPECT_EQ(info.keyframes, s.db_images.size());
  EXPECT_EQ(Localizer::VocabularyPathOf(old_path), "test.gtvoc");
  Localizer target(s.vocabulary, "test.gtvoc", Options());
  try {
    target.Load(old_path);
    ADD_FAILURE() << "a version-1 map loaded";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("gtbow convert-map --in " + old_path.string()),
              std::string::npos)
        << e.what();
  }
  target.ImportVersion1(old_path);
  ExpectSameAnswers(built, target, "imported");
  target.Save(dir() / "new.gtmap");
  Localizer converted(s.vocabulary, "test.gtvoc", Options());
  converted.Load(dir() / "new.gtmap");
  ExpectSameAnswers(built, converted, "converted");
  EXPECT_EQ(Localizer::ReadMapInfo(dir() / "new.gtmap").version, 3u);
}

// A map made with drifting odometry, re-posed by a SLAM backend's optimisation (the node's
// keyframe_poses): fixes follow the new poses, the map file carries them with its pose frame
// and the optimised flag, and an update meant for another map (unknown id, other stamp)
// changes nothing.
TEST_F(LocalizerFiles, KeyframePosesFromABackendAreUsedSavedAndRecorded) {
  const Scene& s = TheScene();
  // Odometry that drifted: every keyframe 20 mm and 2 degrees off, a keyframe without a pose.
  const Pose2D drift{0.02, -0.01, 0.035};
  Localizer loc(s.vocabulary, "test.gtvoc", Options());
  loc.SetPoseFrame("map");
  std::vector<KeyframePose> truth;
  for (size_t i = 0; i < s.db_images.size(); ++i) {
    const std::optional<Pose2D> odom =
        i == 4 ? std::nullopt : std::optional<Pose2D>(Compose(drift, s.db_poses[i]));
    const uint32_t id = loc.Add(loc.Process(s.db_images[i]), 1000 + static_cast<int64_t>(i), odom);
    truth.push_back({id, 1000 + static_cast<int64_t>(i), s.db_poses[i]});
  }
  auto fixes_ok = [&](const Localizer& l) {
    int ok = 0;
    for (size_t q = 0; q < s.revisits.size(); ++q) {
      const Localization fix = l.Localize(l.Process(s.revisits[q]));
      const Pose2D& t = s.revisit_poses[q];
      const Pose2D& p = fix.estimate.floor_from_query;
      ok += fix.success && 1000 * std::hypot(p.x - t.x, p.y - t.y) < 4.8 &&
            std::abs(WrapAngle(p.theta - t.theta)) < 1.5 * M_PI / 180;
    }
    return ok;
  };
  const int revisits = static_cast<int>(s.revisits.size());
  EXPECT_EQ(fixes_ok(loc), 0) << "the drifted map should place no revisit right";
  EXPECT_FALSE(loc.KeyframeInfo(4)->has_pose);
  loc.Save(dir() / "odometry.gtmap");
  EXPECT_FALSE(Localizer::ReadMapInfo(dir() / "odometry.gtmap").poses_optimised);

  // Updates for another map: an id beyond the map, a stamp that is not the keyframe's.
  EXPECT_EQ(loc.UpdateKeyframePoses({{9999, 1000, Pose2D{}}, {3, 5, Pose2D{}}}), 0u);
  EXPECT_FALSE(loc.poses_optimised());
  EXPECT_THROW(loc.UpdateKeyframePoses({{3, 1003, Pose2D{std::nan(""), 0, 0}}}),
               std::invalid_argument);
  // The backend's poses, in two messages (a later one replaces an earlier one's pose).
  std::vector<KeyframePose> first(truth.begin(), truth.begin() + 10),
      rest(truth.begin() + 5, truth.end());
  for (KeyframePose& k : first) k.map_from_camera.x += 0.5;  // replaced by `rest` or stays off
  EXPECT_EQ(loc.UpdateKeyframePoses(first), first.size());
  EXPECT_EQ(loc.UpdateKeyframePoses(rest), rest.size());
  EXPECT_EQ(loc.UpdateKeyframePoses({truth.begin(), truth.begin() + 5}), 5u);
  EXPECT_TRUE(loc.poses_optimised());
  ASSERT_TRUE(loc.KeyframeInfo(4)->has_pose);  // the keyframe added without one has it now
  for (const Keyframe& k : loc.Keyframes()) {
    ASSERT_TRUE(k.has_pose);
    EXPECT_EQ(Describe(k.map_from_camera), Describe(s.db_poses[k.id])) << k.id;
  }
  EXPECT_EQ(fixes_ok(loc), revisits);
  const auto candidates = loc.Query(loc.Process(s.revisits[0]), 3, false);
  ASSERT_FALSE(candidates.empty());
  EXPECT_EQ(Describe(candidates[0].map_from_camera), Describe(s.db_poses[candidates[0].id]));

  // Saved with them, its frame and the flag; loaded as saved.
  loc.Save(dir() / "optimised.gtmap");
  const MapFileInfo info = Localizer::ReadMapInfo(dir() / "optimised.gtmap");
  EXPECT_EQ(info.version, 3u);
  EXPECT_EQ(info.pose_frame, "map");
  EXPECT_TRUE(info.poses_optimised);
  Localizer fresh(s.vocabulary, "test.gtvoc", Options());
  fresh.Load(dir() / "optimised.gtmap");
  EXPECT_EQ(fresh.pose_frame(), "map");
  EXPECT_TRUE(fresh.poses_optimised());
  for (const Keyframe& k : fresh.Keyframes()) {
    EXPECT_EQ(Describe(k.map_from_camera), Describe(s.db_poses[k.id])) << k.id;
  }
  EXPECT_EQ(fixes_ok(fresh), revisits);
  // The saving map reads the file it wrote now: the poses stay, and a later update still counts.
  EXPECT_EQ(fixes_ok(loc), revisits);
  EXPECT_EQ(loc.UpdateKeyframePoses({{2, 1002, drift}}), 1u);
  EXPECT_EQ(Describe(loc.KeyframeInfo(2)->map_from_camera), Describe(drift));
  loc.Reset();
  EXPECT_FALSE(loc.poses_optimised());
  EXPECT_EQ(loc.pose_frame(), "map");

  // A map of format version 2 (no pose frame, no flag) still loads: the same file with the
  // header of version 2 (the frame's empty string and the flag taken out, sections moved up).
  {
    Localizer plain(s.vocabulary, "test.gtvoc", Options());
    plain.Load(dir() / "odometry.gtmap");
    plain.SetPoseFrame("");
    plain.Save(dir() / "plain.gtmap");
  }
  std::string f = ReadFile(dir() / "plain.gtmap");
  uint64_t hs;
  std::memcpy(&hs, f.data() + 16, 8);
  std::string header = f.substr(64, hs);
  const size_t kSectionTable = 5 * 16, kFrameAndFlag = 8 + 1;
  header.erase(header.size() - kSectionTable - kFrameAndFlag, kFrameAndFlag);
  uint64_t old_first, new_first = (64 + header.size() + 63) / 64 * 64;
  std::memcpy(&old_first, header.data() + header.size() - kSectionTable, 8);
  const uint64_t shift = old_first - new_first;
  for (int k = 0; k < 5; ++k) {
    uint64_t off;
    std::memcpy(&off, header.data() + header.size() - kSectionTable + 16 * k, 8);
    off -= shift;
    std::memcpy(header.data() + header.size() - kSectionTable + 16 * k, &off, 8);
  }
  std::string v2 = f.substr(0, 64) + header;
  v2.resize(new_first, '\0');
  v2 += f.substr(old_first);
  const uint32_t version = 2;
  const uint64_t fixed[3] = {header.size(), Checksum64(header.data(), header.size()), v2.size()};
  std::memcpy(v2.data() + 8, &version, 4);
  std::memcpy(v2.data() + 16, fixed, sizeof(fixed));
  WriteFileAtomic(dir() / "v2.gtmap", v2);
  const MapFileInfo old_info = Localizer::ReadMapInfo(dir() / "v2.gtmap");
  EXPECT_EQ(old_info.version, 2u);
  EXPECT_EQ(old_info.pose_frame, "");
  EXPECT_FALSE(old_info.poses_optimised);
  Localizer old(s.vocabulary, "test.gtvoc", Options());
  ASSERT_EQ(old.Load(dir() / "v2.gtmap"), s.db_images.size());
  EXPECT_EQ(Describe(old.KeyframeInfo(3)->map_from_camera),
            Describe(Compose(drift, s.db_poses[3])));
  EXPECT_EQ(fixes_ok(old), 0);
}

// Without descriptors a map is smaller by their size, verification uses word pairs, re-query
// by keyframe id says why it cannot, and the two kinds of map do not load into each other.
TEST_F(LocalizerFiles, MapsWithoutDescriptorsVerifyFromWordsAndSaySo) {
  const Scene& s = TheScene();
  LocalizerOptions o = Options();
  o.keep_descriptors = false;
  Localizer lean(s.vocabulary, "test.gtvoc", o);
  const auto full = Mapped(true);
  for (size_t i = 0; i < s.db_images.size(); ++i)
    lean.Add(lean.Process(s.db_images[i]), 1000 + static_cast<int64_t>(i), s.db_poses[i]);
  EXPECT_EQ(lean.effective_matches(), MatchSource::kWords);
  lean.Save(dir() / "lean.gtmap");
  full->Save(dir() / "full.gtmap");
  const MapFileInfo li = Localizer::ReadMapInfo(dir() / "lean.gtmap");
  const MapFileInfo fi = Localizer::ReadMapInfo(dir() / "full.gtmap");
  EXPECT_FALSE(li.descriptors);
  EXPECT_TRUE(fi.descriptors);
  size_t keypoints = 0;
  for (const Keyframe& k : full->Keyframes())
    keypoints += full->KeyframeInfo(k.id)->keypoints.size();
  EXPECT_EQ(fi.file_bytes - li.file_bytes, keypoints * 32);  // ORB: 32 bytes a keypoint
  int fixes = 0;
  for (const cv::Mat& r : s.revisits) fixes += lean.Localize(lean.Process(r)).success ? 1 : 0;
  EXPECT_GT(fixes, static_cast<int>(s.revisits.size()) / 2);
  try {
    lean.QueryKeyframe(3, 3, false);
    ADD_FAILURE() << "re-query without descriptors";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("keep_descriptors"), std::string::npos) << e.what();
  }
  for (const auto& [file, opts] :
       {std::pair{"lean.gtmap", Options()}, std::pair{"full.gtmap", o}}) {
    Localizer other(s.vocabulary, "test.gtvoc", opts);
    try {
      other.Load(dir() / file);
      ADD_FAILURE() << file << " loaded into the other kind";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("keep_descriptors"), std::string::npos) << e.what();
    }
  }
}

// Keypoints as a map keeps them: within a hundredth of a pixel and a tenth of a degree here.
TEST(StoredKeypoints, QuantisationIsFineEnoughForVerification) {
  std::vector<Keypoint> k(3);
  k[0] = {639.99f, 0.0f, 6.2831f, 31.0f, 0.1f, 0};
  k[1] = {320.123f, 240.456f, 1.234f, 44.64f, 0.2f, 2};
  k[2] = {1.0f, 479.5f, 0.0f, 111.1f, 0.3f, -1};
  const auto q = StoredKeypoints(k, 640, 480);
  ASSERT_EQ(q.size(), k.size());
  for (size_t i = 0; i < k.size(); ++i) {
    EXPECT_NEAR(q[i].x, k[i].x, 0.005) << i;
    EXPECT_NEAR(q[i].y, k[i].y, 0.005) << i;
    EXPECT_NEAR(std::remainder(q[i].angle - k[i].angle, 2 * M_PI), 0.0, M_PI / 4096) << i;
    EXPECT_NEAR(q[i].size, k[i].size, 1.0 / 32) << i;
    EXPECT_EQ(q[i].octave, k[i].octave) << i;
  }
  EXPECT_EQ(StoredKeypoints(q, 640, 480)[1].x, q[1].x);  // stable: stored twice, same value
}

// Every key a preset records guards the map: a map saved under one preset is refused under a
// preset that differs in any one key (or, where that key alone cannot change, with the keys it
// needs), and the refusal names the key. The keys come from the one option table (config.cpp).
TEST_F(LocalizerFiles, EveryKeyOfThePresetGuardsTheMap) {
  const Scene& s = TheScene();
  const auto path = dir() / "map.gtmap";
  {
    Localizer loc(s.vocabulary, "test.gtvoc", Options());
    for (size_t i = 0; i < 3; ++i) loc.Add(loc.Process(s.db_images[i]), 1, s.db_poses[i]);
    loc.Save(path);
  }
  const RetrievalConfig base = Options().retrieval;
  const std::string base_text = FormatRetrievalConfig(base);
  // Keys that cannot change alone, and what must change with them.
  const std::map<std::string, std::vector<std::string>> companions = {
      {"features.type", {"vocabulary.metric: l2", "bow.size_binning: percentile"}},
      {"features.grid_cols", {"features.grid_rows: 2"}},
      {"features.grid_rows", {"features.grid_cols: 2"}},
      {"vocabulary.kind", {"bow.soft_assignment: 1"}},
      {"bow.scoring", {"bow.orientation_verification: false"}}};
  const std::vector<std::string> names = {
      "orb",      "sift",    "none",   "normalize", "clahe", "akm",    "hkm",
      "l2_bytes", "hamming", "l2",     "flann",     "ivf",   "octave", "percentile",
      "dot",      "dbow_l1", "global", "per_bin",   "both",  "bright", "dark"};
  // The text with `section.key` set to `value`.
  auto with = [](std::string text, const std::string& dotted, const std::string& value) {
    const std::string section = dotted.substr(0, dotted.find('.')) + ":\n";
    const std::string line = "  " + dotted.substr(dotted.find('.') + 1) + ": ";
    const size_t at = text.find(line, text.find(section));
    const size_t end = text.find('\n', at);
    return text.replace(at + line.size(), end - at - line.size(), value);
  };
  int checked = 0;
  for (const std::string& key : RetrievalConfigKeys()) {
    const std::string line = "  " + key.substr(key.find('.') + 1) + ": ";
    const size_t at = base_text.find(line, base_text.find(key.substr(0, key.find('.')) + ":\n"));
    ASSERT_NE(at, std::string::npos) << key;
    const std::string old_value =
        base_text.substr(at + line.size(), base_text.find('\n', at) - at - line.size());
    std::vector<std::string> candidates;
    if (old_value == "true" || old_value == "false") {
      candidates = {old_value == "true" ? "false" : "true"};
    } else if (std::isdigit(static_cast<unsigned char>(old_value[0])) || old_value[0] == '-') {
      const double v = std::stod(old_value);
      for (double c : {v * 2, v + 1, v / 2, v - 1, 1.0, 2.0, 0.5, 0.0, 3.0}) {
        std::ostringstream o;
        o << c;
        candidates.push_back(o.str());
      }
    } else {
      candidates = names;
    }
    std::optional<RetrievalConfig> changed;
    for (const std::string& value : candidates) {
      std::string text = with(base_text, key, value);
      if (companions.count(key)) {
        for (const std::string& c : companions.at(key)) {
          text = with(text, c.substr(0, c.find(':')), c.substr(c.find(':') + 2));
        }
      }
      try {
        RetrievalConfig c = ParseRetrievalConfig(text, key);
        // The key itself must now have another value (not only its companions).
        const std::string formatted = FormatRetrievalConfig(c);
        const size_t pos =
            formatted.find(line, formatted.find(key.substr(0, key.find('.')) + ":\n"));
        const std::string new_value =
            formatted.substr(pos + line.size(), formatted.find('\n', pos) - pos - line.size());
        if (new_value != old_value) {
          changed = c;
          break;
        }
      } catch (const std::exception&) {
      }
    }
    if (!changed) {
      ADD_FAILURE() << key << ": no other valid value found to test it";
      continue;
    }
    LocalizerOptions o = Options();
    o.retrieval = *changed;
    std::string refusal;
    try {
      Localizer other(s.vocabulary, "test.gtvoc", o);
      other.Load(path);
    } catch (const std::exception& e) {
      refusal = e.what();
    }
    EXPECT_NE(refusal.find(key), std::string::npos)
        << key << ": " << (refusal.empty() ? "the map loaded" : refusal);
    ++checked;
  }
  EXPECT_EQ(checked, static_cast<int>(RetrievalConfigKeys().size()));
}

// Issue 28: an image that is only queried is extracted with query_num_features keypoints; it
// localizes on a map of 250-keypoint keyframes, and cannot be added as a keyframe by mistake.
TEST(Localizer, QueriesTakeMoreKeypointsThanKeyframes) {
  const Scene& s = TheScene();
  LocalizerOptions o = Options();
  o.retrieval.features.query_num_features = 500;
  Localizer loc(s.vocabulary, "test.gtvoc", o);
  for (size_t i = 0; i < s.db_images.size(); ++i) {
    loc.Add(loc.Process(s.db_images[i]), static_cast<int64_t>(i), s.db_poses[i]);
  }
  const ProcessedImage keyframe = loc.Process(s.revisits[0]);
  const ProcessedImage query = loc.Process(s.revisits[0], Localizer::ImageUse::kQuery);
  EXPECT_LE(keyframe.features.size(), 250u);
  EXPECT_GT(query.features.size(), 400u);
  EXPECT_LE(query.features.size(), 500u);
  for (size_t q = 0; q < s.revisits.size(); ++q) {
    const Localization fix = loc.Localize(loc.Process(s.revisits[q], Localizer::ImageUse::kQuery));
    ASSERT_TRUE(fix.success) << fix.reason;
    const Pose2D& t = s.revisit_poses[q];
    EXPECT_LT(1000 * std::hypot(fix.estimate.floor_from_query.x - t.x,
                                fix.estimate.floor_from_query.y - t.y),
              4.8);
  }
  try {
    loc.Add(query, 1, std::nullopt);
    ADD_FAILURE() << "a query's 500 keypoints were added as a keyframe";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("processed as a query"), std::string::npos) << e.what();
  }
  // Not recorded in the map: a map saved without it loads with it.
  EXPECT_EQ(FormatRetrievalConfig(o.retrieval), FormatRetrievalConfig(Options().retrieval));
}

// Issue 28: with query_escalate an image is localized first as a keyframe is extracted (without
// guided matching), and with query_num_features keypoints only when that gives no fix with
// escalate_min_inliers inliers
// (EscalatedFix), as LocalizeImage does for the node and the localize service.
TEST(Localizer, EscalatingQueriesTakeMoreKeypointsOnlyWhenTheFirstPassFails) {
  const Scene& s = TheScene();
  LocalizerOptions o = Options();
  o.retrieval.features.query_num_features = 500;
  o.retrieval.verification.matches = MatchSource::kDescriptors;
  o.retrieval.verification.guided_radius = 8.0;
  Localizer plain(s.vocabulary, "test.gtvoc", o);
  o.retrieval.features.query_escalate = true;
  Localizer loc(s.vocabulary, "test.gtvoc", o);
  ASSERT_TRUE(loc.escalates());
  ASSERT_FALSE(plain.escalates());
  for (size_t i = 0; i < s.db_images.size(); ++i) {
    loc.Add(loc.Process(s.db_images[i]), static_cast<int64_t>(i), s.db_poses[i]);
    plain.Add(plain.Process(s.db_images[i]), static_cast<int64_t>(i), s.db_poses[i]);
  }
  for (size_t q = 0; q < s.revisits.size(); ++q) {
    ProcessedImage used;
    bool escalated = true;
    const Localization fix = loc.LocalizeImage(s.revisits[q], &used, &escalated);
    ASSERT_TRUE(fix.success) << "place " << q << ": " << fix.reason;
    EXPECT_FALSE(escalated) << "place " << q;
    EXPECT_TRUE(used.first_pass);
    EXPECT_LE(used.features.size(), 250u);
    // The first pass is the image processed as a keyframe, verified with FirstPassOptions.
    ProcessedImage first = loc.Process(s.revisits[q]);
    first.first_pass = true;
    const Localization same = loc.Localize(first);
    ASSERT_TRUE(same.success);
    EXPECT_EQ(same.image, fix.image);
    EXPECT_EQ(same.estimate.inliers, fix.estimate.inliers);
    const Pose2D& t = s.revisit_poses[q];
    EXPECT_LT(1000 * std::hypot(fix.estimate.floor_from_query.x - t.x,
                                fix.estimate.floor_from_query.y - t.y),
              4.8);
    // Without query_escalate: the query's 500 keypoints at once.
    bool plain_escalated = true;
    ProcessedImage plain_used;
    const Localization full = plain.LocalizeImage(s.revisits[q], &plain_used, &plain_escalated);
    const Localization direct =
        plain.Localize(plain.Process(s.revisits[q], Localizer::ImageUse::kQuery));
    EXPECT_FALSE(plain_escalated);
    EXPECT_FALSE(plain_used.first_pass);
    EXPECT_GT(plain_used.features.size(), 400u);
    ASSERT_TRUE(full.success && direct.success);
    EXPECT_EQ(full.image, direct.image);
    EXPECT_EQ(full.estimate.inliers, direct.estimate.inliers);
  }
  // A first-pass fix with fewer than escalate_min_inliers goes on to the full pass, which gives
  // the query's own fix.
  o.retrieval.verification.escalate_min_inliers = 100000;
  Localizer strict(s.vocabulary, "test.gtvoc", o);
  for (size_t i = 0; i < s.db_images.size(); ++i) {
    strict.Add(strict.Process(s.db_images[i]), static_cast<int64_t>(i), s.db_poses[i]);
  }
  {
    ProcessedImage used;
    bool escalated = false;
    const Localization fix = strict.LocalizeImage(s.revisits[0], &used, &escalated);
    const Localization full =
        strict.Localize(strict.Process(s.revisits[0], Localizer::ImageUse::kQuery));
    ASSERT_TRUE(fix.success && full.success) << fix.reason;
    EXPECT_TRUE(escalated);
    EXPECT_FALSE(used.first_pass);
    EXPECT_GT(used.features.size(), 400u);
    EXPECT_EQ(fix.image, full.image);
    EXPECT_EQ(fix.estimate.inliers, full.estimate.inliers);
  }
  // Not recorded in the map: a map saved without them loads with them.
  EXPECT_EQ(FormatRetrievalConfig(o.retrieval), FormatRetrievalConfig(plain.options().retrieval));
  // An image that the first pass cannot localize goes on to the full pass.
  const cv::Mat blank(s.revisits[0].size(), CV_8UC1, cv::Scalar(128));
  ProcessedImage used;
  bool escalated = false;
  const Localization none = loc.LocalizeImage(blank, &used, &escalated);
  EXPECT_FALSE(none.success);
  EXPECT_TRUE(escalated);
  EXPECT_FALSE(used.first_pass);
  // EscalatedFix: the full pass runs only when the first gives no fix.
  int firsts = 0, fulls = 0;
  auto first = [&](bool ok) {
    return [&firsts, ok] {
      ++firsts;
      Localization l;
      l.success = ok;
      return l;
    };
  };
  auto full = [&] {
    ++fulls;
    Localization l;
    l.success = true;
    l.image = 7;
    return l;
  };
  LocalizationOptions lo;
  EXPECT_FALSE(EscalatedFix(true, lo, first(true), full, &escalated).image == 7);
  EXPECT_FALSE(escalated);
  EXPECT_EQ(EscalatedFix(true, lo, first(false), full, &escalated).image, 7u);
  EXPECT_TRUE(escalated);
  EXPECT_EQ(EscalatedFix(false, lo, first(true), full, &escalated).image, 7u);
  EXPECT_FALSE(escalated);
  // A first-pass fix with fewer than escalate_min_inliers goes on to the full pass.
  lo.escalate_min_inliers = 16;
  EXPECT_EQ(EscalatedFix(true, lo, first(true), full, &escalated).image, 7u);
  EXPECT_TRUE(escalated);
  EXPECT_EQ(firsts, 3);
  EXPECT_EQ(fulls, 3);
  // The first pass has no guided matching of its own; its plain poses are checked for repeats
  // (changing_floors' checks).
  const LocalizationOptions cf =
      LoadRetrievalConfig(GTBOW_CONFIG_DIR "/changing_floors.yaml").verification;
  ASSERT_TRUE(cf.guided && cf.guided_repeat_check && cf.plain_repeat_below > 0);
  const LocalizationOptions cf_first = FirstPassOptions(cf);
  EXPECT_FALSE(cf_first.guided);
  EXPECT_TRUE(cf_first.guided_repeat_check);
  EXPECT_EQ(cf_first.plain_repeat_below, cf.plain_repeat_below);
  EXPECT_EQ(cf_first.guided_radius, cf.guided_radius);  // the checks' own guided matches
  // It needs more query keypoints than a keyframe has.
  o.retrieval.features.query_num_features = 250;
  EXPECT_THROW(o.retrieval.features.Check(), std::invalid_argument);
}

// features.query_escalate_backoff: after first passes that fail, a stream's next images go
// straight to the full pass, 1, 3, 7, ... of them, at most the backoff; a first pass that stands
// starts again. The node's stream through LocalizeImage: a covered camera (blank images), then
// the floor again.
TEST(Localizer, EscalationBackoffSkipsFirstPassesAfterFailuresUntilOneStands) {
  // The pattern, pass by pass: 'F' a first pass that fails, 'S' one that stands, '-' skipped.
  auto run = [](int max_skip, const std::string& outcomes) {
    EscalationBackoff b(max_skip);
    std::string trace;
    size_t next = 0;
    while (next < outcomes.size()) {
      if (!b.TryFirstPass()) {
        trace += '-';
        continue;
      }
      const bool stood = outcomes[next++] == 'S';
      b.Record(stood);
      trace += stood ? 'S' : 'F';
    }
    EXPECT_EQ(b.skipped(), static_cast<size_t>(std::count(trace.begin(), trace.end(), '-')));
    return trace;
  };
  EXPECT_EQ(run(0, "FFFS"), "FFFS");
  EXPECT_EQ(run(5, "FFFFS"), "F-F---F-----F-----S");
  EXPECT_EQ(run(5, "FSFS"), "F-SF-S");
  EXPECT_EQ(run(2, "FFFS"), "F-F--F--S");
  EXPECT_THROW(EscalationBackoff(-1), std::invalid_argument);
  LocalizationOptions lo;
  EscalationBackoff b(3);
  int firsts = 0;
  auto first = [&firsts] {
    ++firsts;
    return Localization{};
  };
  auto full = [] { return Localization{}; };
  bool escalated = false;
  for (int i = 0; i < 5; ++i) (void)EscalatedFix(true, lo, first, full, &escalated, &b);
  EXPECT_TRUE(escalated);
  EXPECT_EQ(firsts, 2);  // F - F - -, one skip still to come
  EXPECT_EQ(b.skipped(), 3u);
  // Without escalation the backoff is not consulted: the pending skip stays for the next image.
  (void)EscalatedFix(false, lo, first, full, &escalated, &b);
  EXPECT_FALSE(escalated);
  EXPECT_EQ(b.skipped(), 3u);
  (void)EscalatedFix(true, lo, first, full, &escalated, &b);
  EXPECT_EQ(b.skipped(), 4u);
  EXPECT_EQ(firsts, 2);

  // The node's stream: LocalizeImage with the localizer's backoff.
  const Scene& s = TheScene();
  LocalizerOptions o = Options();
  o.retrieval.features.query_num_features = 500;
  o.retrieval.features.query_escalate = true;
  o.retrieval.features.query_escalate_backoff = 3;
  o.retrieval.features.Check();
  Localizer loc(s.vocabulary, "test.gtvoc", o);
  for (size_t i = 0; i < s.db_images.size(); ++i) {
    loc.Add(loc.Process(s.db_images[i]), static_cast<int64_t>(i), s.db_poses[i]);
  }
  EscalationBackoff stream = loc.NewBackoff();
  EXPECT_EQ(stream.max_skip(), 3);
  const cv::Mat blank(s.revisits[0].size(), CV_8UC1, cv::Scalar(128));
  std::string trace;
  auto image = [&](const cv::Mat& gray) {
    const size_t skipped = stream.skipped();
    ProcessedImage used;
    bool escalated = false;
    const Localization fix = loc.LocalizeImage(gray, &used, &escalated, &stream);
    // Skipped or escalated, the image was localized with the query's keypoints.
    EXPECT_EQ(used.first_pass, !escalated);
    trace += stream.skipped() != skipped ? '-' : escalated ? 'F' : 'S';
    return fix;
  };
  for (int i = 0; i < 3; ++i) EXPECT_FALSE(image(blank).success);
  // The floor again: the first three images go straight to the full pass and localize there;
  // the next tries the first pass, which stands, and so do the rest.
  ASSERT_GE(s.revisits.size(), 4u);
  for (size_t q = 0; q < s.revisits.size(); ++q) {
    const Localization fix = image(s.revisits[q]);
    ASSERT_TRUE(fix.success) << "place " << q << ": " << fix.reason;
    const Pose2D& t = s.revisit_poses[q];
    EXPECT_LT(1000 * std::hypot(fix.estimate.floor_from_query.x - t.x,
                                fix.estimate.floor_from_query.y - t.y),
              4.8);
  }
  EXPECT_EQ(trace, "F-F---" + std::string(s.revisits.size() - 3, 'S'));
  // Not recorded in the map.
  LocalizerOptions without = o;
  without.retrieval.features.query_escalate_backoff = 0;
  EXPECT_EQ(FormatRetrievalConfig(o.retrieval), FormatRetrievalConfig(without.retrieval));
}

// Sequence queries: an image mostly hidden (glare, a lens smudge: not the floor) localizes with
// the two images before it, combined through odometry that is 0.2 mm and 0.1 degree off.
TEST(Localizer, SequenceQueriesLocalizeAHiddenImageWithTheImagesBeforeIt) {
  const Scene& s = TheScene();
  const auto loc = Mapped(true);
  ASSERT_EQ(s.trails.size(), 3u);
  for (size_t q = 0; q < s.trails.size(); ++q) {
    cv::Mat hidden = s.revisits[q].clone();
    hidden.colRange(0, hidden.cols * 9 / 10).setTo(128);
    const ProcessedImage newest = loc->Process(hidden, Localizer::ImageUse::kQuery);
    const ProcessedImage t1 = loc->Process(s.trails[q][0], Localizer::ImageUse::kQuery);
    const ProcessedImage t2 = loc->Process(s.trails[q][1], Localizer::ImageUse::kQuery);
    const Pose2D odom_newest = s.revisit_poses[q];
    const Pose2D odom_t1 = Compose(s.trail_poses[q][0], {0.0002, -0.0001, 0.0017});
    const Pose2D odom_t2 = Compose(s.trail_poses[q][1], {-0.0001, 0.0002, -0.0017});
    const ProcessedImage seq = loc->Combine({&newest, &t1, &t2}, {odom_newest, odom_t1, odom_t2});
    EXPECT_GT(seq.features.size(), newest.features.size() + t1.features.size() / 2);
    EXPECT_EQ(seq.width, newest.width);
    EXPECT_TRUE(seq.combined);  // verified with CombinedViewOptions
    EXPECT_FALSE(newest.combined);
    const Localization single = loc->Localize(newest);
    const Localization fix = loc->Localize(seq);
    ASSERT_TRUE(fix.success) << "place " << q << ": " << fix.reason;
    const Pose2D& t = s.revisit_poses[q];
    const Pose2D& p = fix.estimate.floor_from_query;
    EXPECT_LT(1000 * std::hypot(p.x - t.x, p.y - t.y), 4.8) << "place " << q;
    EXPECT_LT(std::abs(std::remainder(p.theta - t.theta, 2 * M_PI)) * 180 / M_PI, 1.5);
    EXPECT_GT(fix.estimate.inliers, single.success ? 2 * single.estimate.inliers : 0)
        << "place " << q << ": the trail added no evidence";
  }
  const cv::Mat small = s.revisits[0](cv::Rect(0, 0, 320, 240)).clone();
  const ProcessedImage a = loc->Process(s.revisits[0], Localizer::ImageUse::kQuery);
  const ProcessedImage b = loc->Process(small, Localizer::ImageUse::kQuery);
  try {
    loc->Combine({&a, &b}, {Pose2D{}, Pose2D{}});
    ADD_FAILURE() << "images of two sizes were combined";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("differ in size"), std::string::npos) << e.what();
  }
}

TEST(Localizer, BadImagesAndPosesGetClearErrors) {
  const Scene& s = TheScene();
  Localizer loc(s.vocabulary, "test.gtvoc", Options());
  EXPECT_THROW(loc.Process(cv::Mat()), std::invalid_argument);
  EXPECT_THROW(loc.Process(cv::Mat(48, 64, CV_8UC3, cv::Scalar(1, 2, 3))), std::invalid_argument);
  EXPECT_THROW(loc.Process(cv::Mat(48, 64, CV_16UC1, cv::Scalar(1))), std::invalid_argument);
  // 1x1 (or any side under 32 pixels) and over 64 megapixels: refused, with the size named.
  try {
    loc.Process(cv::Mat(1, 1, CV_8UC1, cv::Scalar(7)));
    ADD_FAILURE() << "a 1x1 image was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("1x1"), std::string::npos) << e.what();
  }
  EXPECT_THROW(loc.Process(cv::Mat(8001, 8000, CV_8UC1, cv::Scalar(7))), std::invalid_argument);
  // A 20-megapixel image (5472 x 3648) is processed like any other: the features' budget
  // bounds its keypoints, and its size is kept for the geometry.
  {
    cv::Mat big(3648, 5472, CV_8UC1);
    cv::resize(s.db_images[0], big, big.size(), 0, 0, cv::INTER_LINEAR);
    const auto t0 = std::chrono::steady_clock::now();
    const ProcessedImage p = loc.Process(big);
    std::printf(
        "a 20-megapixel image: %.0f ms, %zu keypoints\n",
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count(),
        p.features.size());
    EXPECT_EQ(p.width, 5472);
    EXPECT_EQ(p.height, 3648);
    EXPECT_GT(p.features.size(), 0u);
    EXPECT_LE(p.features.size(), static_cast<size_t>(Options().retrieval.features.num_features));
  }
  const ProcessedImage blank = loc.Process(cv::Mat(480, 640, CV_8UC1, cv::Scalar(128)));
  EXPECT_EQ(blank.features.size(), 0u);
  const Localization fix = loc.Localize(blank);
  EXPECT_FALSE(fix.success);
  EXPECT_NE(fix.reason.find("no features"), std::string::npos);
  EXPECT_TRUE(loc.Query(blank, 5, true).empty());
  EXPECT_THROW(loc.Add(loc.Process(s.db_images[0]), 0, Pose2D{NAN, 0, 0}), std::invalid_argument);
  EXPECT_EQ(loc.size(), 0u);
  loc.Add(loc.Process(s.db_images[0]), 0, std::nullopt);
  loc.Reset();
  EXPECT_EQ(loc.size(), 0u);
  // A preset whose vocabulary kind does not match the file.
  LocalizerOptions hkm = Options();
  hkm.retrieval.vocabulary.kind = VocabularyKind::kHkm;
  hkm.retrieval.vocabulary.metric = Metric::kHamming;
  hkm.retrieval.bow.soft_assignment = 1;
  EXPECT_THROW(Localizer(s.vocabulary, "test.gtvoc", hkm), std::invalid_argument);
}

}  // namespace
}  // namespace gtbow
