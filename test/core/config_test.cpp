#include "ground_texture_bow/core/config.h"

#include <cmath>
#include <filesystem>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

namespace gtbow {
namespace {

const std::string kDir = GTBOW_CONFIG_DIR;

TEST(Config, PresetsAreThePapersConfigurations) {
  const RetrievalConfig hi = LoadRetrievalConfig(kDir + "/high_accuracy.yaml");
  EXPECT_EQ(hi.features.type, FeatureType::kOrb);
  EXPECT_EQ(hi.features.num_features, 250);
  EXPECT_EQ(hi.features.orb_num_levels, 8);
  EXPECT_FLOAT_EQ(hi.features.orb_scale_factor, 1.2f);
  EXPECT_EQ(hi.vocabulary.kind, VocabularyKind::kAkm);
  EXPECT_EQ(hi.vocabulary.num_words, 100000);
  EXPECT_EQ(hi.bow.size_binning, SizeBinning::kOctave);
  EXPECT_EQ(hi.bow.num_size_bins, 8);
  EXPECT_EQ(hi.bow.orientation_bins, 6);
  EXPECT_TRUE(hi.bow.orientation_verification);
  EXPECT_EQ(hi.bow.soft_assignment, 3);
  // The authors' reading (issue 14): Hamming words, sigma^2 = 580 bits, converged k-means,
  // one global normalisation; floor-adaptive features.
  EXPECT_EQ(hi.vocabulary.metric, Metric::kHamming);
  EXPECT_NEAR(hi.bow.sigma * hi.bow.sigma, 580.0, 0.1);
  EXPECT_DOUBLE_EQ(hi.vocabulary.kmeans_stop_fraction, 0.01);
  EXPECT_EQ(hi.bow.normalization, Normalization::kGlobal);
  EXPECT_EQ(hi.features.contrast, Contrast::kClahe);
  EXPECT_GT(hi.features.grid_cols, 0);

  const RetrievalConfig fast = LoadRetrievalConfig(kDir + "/fast.yaml");
  EXPECT_EQ(fast.bow.soft_assignment, 1);
  EXPECT_EQ(fast.vocabulary.num_words, 100000);
  EXPECT_TRUE(fast.bow.orientation_verification);
  // Everything but r is the high-accuracy preset.
  RetrievalConfig fast_as_ha = fast;
  fast_as_ha.bow.soft_assignment = 3;
  EXPECT_EQ(RetrievalConfigDifference(fast_as_ha, "fast", hi, "high"), "");

  // The paper read literally: sigma = 580 of an L2 distance over the descriptor bytes, plain ORB.
  const RetrievalConfig lit = LoadRetrievalConfig(kDir + "/paper_literal.yaml");
  EXPECT_EQ(lit.vocabulary.metric, Metric::kL2Bytes);
  EXPECT_DOUBLE_EQ(lit.bow.sigma, 580.0);
  EXPECT_TRUE(IsPlainExtractor(lit.features));
  EXPECT_EQ(LoadRetrievalConfig(kDir + "/paper_literal_fast.yaml").bow.soft_assignment, 1);

  // The authors' code: per-bin normalisation and FLANN's clustering tree.
  const RetrievalConfig au = LoadRetrievalConfig(kDir + "/authors.yaml");
  EXPECT_EQ(au.bow.normalization, Normalization::kPerBin);
  EXPECT_EQ(au.vocabulary.ann, AnnIndex::kFlann);
  EXPECT_EQ(au.vocabulary.checks, 1000);
  EXPECT_TRUE(IsPlainExtractor(au.features));

  const RetrievalConfig dbow = LoadRetrievalConfig(kDir + "/dbow_baseline.yaml");
  EXPECT_EQ(dbow.vocabulary.kind, VocabularyKind::kHkm);
  EXPECT_EQ(dbow.vocabulary.metric, Metric::kHamming);
  EXPECT_EQ(dbow.vocabulary.hkm_branching, 10);
  EXPECT_EQ(dbow.vocabulary.hkm_depth, 5);
  EXPECT_EQ(dbow.bow.size_binning, SizeBinning::kNone);
  EXPECT_FALSE(dbow.bow.orientation_verification);
  EXPECT_EQ(dbow.bow.scoring, Scoring::kDbowL1);
}

TEST(Config, VerificationIsPartOfThePresetButNotOfTheMap) {
  // Issue 15: our presets verify from descriptor matches with the rotation and consensus
  // checks; the paper's reading keeps word pairs and the first candidate that verifies.
  for (const char* name : {"/high_accuracy.yaml", "/fast.yaml"}) {
    const LocalizationOptions v = LoadRetrievalConfig(kDir + name).verification;
    EXPECT_EQ(v.matches, MatchSource::kDescriptors) << name;
    EXPECT_NEAR(v.pose.max_theta_sigma, 0.4 * M_PI / 180.0, 1e-6) << name;
    EXPECT_DOUBLE_EQ(v.max_conflict_ratio, 0.5) << name;
    EXPECT_EQ(v.candidates, 5) << name;
    EXPECT_EQ(v.pose.min_inliers, 6) << name;
  }
  const LocalizationOptions lit = LoadRetrievalConfig(kDir + "/paper_literal.yaml").verification;
  EXPECT_EQ(lit.matches, MatchSource::kWords);
  EXPECT_EQ(lit.pose.max_theta_sigma, 0.0);
  EXPECT_EQ(lit.max_conflict_ratio, 0.0);
  // Read, written and checked like every option, but a map does not record them: a map keeps
  // loading when only the verification changes.
  RetrievalConfig c = ParseRetrievalConfig(
      "verification:\n  matches: descriptors\n  min_spread: 12.5\n  angle_tolerance: 0.2\n"
      "  max_second_ratio: 0.6\n  candidates: 7\n",
      "v.yaml");
  EXPECT_EQ(c.verification.candidates, 7);
  EXPECT_DOUBLE_EQ(c.verification.pose.min_spread, 12.5);
  EXPECT_DOUBLE_EQ(c.verification.pose.angle_tolerance, 0.2);
  EXPECT_DOUBLE_EQ(c.verification.pose.max_second_ratio, 0.6);
  const std::string text = FormatVerificationOptions(c.verification);
  EXPECT_NE(text.find("  matches: descriptors\n"), std::string::npos) << text;
  EXPECT_NE(text.find("  min_spread: 12.5\n"), std::string::npos) << text;
  EXPECT_EQ(ParseRetrievalConfig(text, "again").verification.pose.min_spread, 12.5);
  for (const std::string& key : RetrievalConfigKeys())
    EXPECT_NE(key.rfind("verification.", 0), 0u) << key;
  EXPECT_EQ(RetrievalConfigDifference(c, "a", RetrievalConfig{}, "b"), "");
  try {
    ParseRetrievalConfig("verification:\n  matches: pixels\n", "bad.yaml");
    ADD_FAILURE() << "a bad match source was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.yaml:2"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("pixels"), std::string::npos) << e.what();
  }
  EXPECT_THROW(ParseRetrievalConfig("verification:\n  max_theta_sigma: -1\n", "neg.yaml"),
               std::runtime_error);
}

TEST(Config, EveryShippedPresetLoads) {
  // config/ and every ablation directory: a preset that no longer parses fails here, not an
  // hour into a benchmark.
  size_t n = 0;
  for (const auto& e : std::filesystem::recursive_directory_iterator(kDir)) {
    if (e.path().extension() != ".yaml" || e.path().filename() == "localizer.yaml" ||
        e.path().filename() == "backend.yaml") {
      continue;
    }
    EXPECT_NO_THROW(LoadRetrievalConfig(e.path())) << e.path();
    ++n;
  }
  EXPECT_GE(n, 30u);
}

TEST(Config, RoundTripThroughYaml) {
  RetrievalConfig c;
  c.bow.soft_assignment = 2;
  c.vocabulary.num_words = 1234;
  c.bow.scoring = Scoring::kDbowL1;
  c.bow.orientation_verification = false;
  const RetrievalConfig back = ParseRetrievalConfig(FormatRetrievalConfig(c), "x.yaml");
  EXPECT_EQ(back.bow.soft_assignment, 2);
  EXPECT_EQ(back.vocabulary.num_words, 1234);
  EXPECT_EQ(back.bow.scoring, Scoring::kDbowL1);
}

TEST(Config, ErrorsNameFileLineAndKey) {
  auto expect = [](const std::string& yaml, const std::string& part) {
    try {
      ParseRetrievalConfig(yaml, "p.yaml");
      FAIL() << yaml;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << e.what();
    }
  };
  expect("bow:\n  soft_asignment: 3\n", "p.yaml:2: unknown key 'bow.soft_asignment'");
  expect("bow:\n  sigma: wide\n", "p.yaml:2: bad value for 'bow.sigma'");
  expect("vocab:\n  kind: akm\n", "unknown section 'vocab'");
  expect("vocabulary:\n  kind: tree\n", "unknown vocabulary kind 'tree'");
  expect("vocabulary:\n  kind: hkm\nbow:\n  soft_assignment: 3\n", "soft_assignment must be 1");
  expect("bow:\n  orientation_bins: 0\n", "orientation_bins");
  expect("bow: [1, 2\n", "invalid YAML");
  expect("bow:\n  normalization: per_word\n", "unknown normalization 'per_word'");
  expect("features:\n  contrast: hdr\n", "unknown contrast 'hdr'");
  expect("features:\n  grid_cols: 4\n", "grid_cols and grid_rows");
  expect(
      "features:\n  type: sift\n  contrast: clahe\nvocabulary:\n  metric: l2\nbow:\n  "
      "size_binning: percentile\n",
      "for ORB only");
  expect("vocabulary:\n  kmeans_stop_fraction: 1.5\n", "kmeans_stop_fraction");
}

TEST(Config, EveryKeyRoundTripsAndDifferencesNameTheKey) {
  RetrievalConfig c;
  c.features.contrast = Contrast::kNormalize;
  c.features.orb_fast_threshold = 12;
  c.features.orb_min_fast_threshold = 5;
  c.features.grid_cols = 5;
  c.features.grid_rows = 4;
  c.vocabulary.kmeans_stop_fraction = 0.02;
  c.vocabulary.train_nprobe = 40;
  c.bow.normalization = Normalization::kPerBin;
  const RetrievalConfig back = ParseRetrievalConfig(FormatRetrievalConfig(c), "x.yaml");
  EXPECT_EQ(FormatRetrievalConfig(back), FormatRetrievalConfig(c));
  EXPECT_EQ(RetrievalConfigDifference(back, "a", c, "b"), "");
  RetrievalConfig d = c;
  d.features.orb_fast_threshold = 20;
  d.bow.normalization = Normalization::kGlobal;
  EXPECT_EQ(RetrievalConfigDifference(c, "the map", d, "this node"),
            "features.orb_fast_threshold: 12 (the map), 20 (this node); "
            "bow.normalization: per_bin (the map), global (this node)");
}

TEST(Config, AVocabularyTrainedWithAnotherExtractorIsRefused) {
  cv::Mat words(8, 32, CV_8U);
  cv::randu(words, 0, 256);
  VocabularyOptions vo;
  vo.metric = Metric::kHamming;
  vo.num_words = 8;
  vo.kmeans_iterations = 1;
  auto v = TrainVocabulary(vo, words, {0, 1, 2, 3, 4, 5, 6, 7}, false);
  FeatureOptions adaptive;
  adaptive.contrast = Contrast::kClahe;
  // No record (a vocabulary from before format 3): only the plain extractor may use it.
  EXPECT_NO_THROW(CheckVocabularyExtractor(*v, "old.gtvoc", FeatureOptions{}));
  EXPECT_THROW(CheckVocabularyExtractor(*v, "old.gtvoc", adaptive), std::invalid_argument);
  v->set_extractor(FormatFeatureOptions(adaptive));
  EXPECT_NO_THROW(CheckVocabularyExtractor(*v, "v.gtvoc", adaptive));
  try {
    CheckVocabularyExtractor(*v, "v.gtvoc", FeatureOptions{});
    ADD_FAILURE() << "a vocabulary of another extractor was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("v.gtvoc"), std::string::npos) << e.what();
    EXPECT_NE(
        std::string(e.what()).find("features.contrast: clahe (the vocabulary), none (the preset)"),
        std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace gtbow
