#include "ground_texture_bow/core/config.h"

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
  EXPECT_DOUBLE_EQ(hi.bow.sigma, 580.0);

  const RetrievalConfig fast = LoadRetrievalConfig(kDir + "/fast.yaml");
  EXPECT_EQ(fast.bow.soft_assignment, 1);
  EXPECT_EQ(fast.vocabulary.num_words, 100000);
  EXPECT_TRUE(fast.bow.orientation_verification);

  const RetrievalConfig dbow = LoadRetrievalConfig(kDir + "/dbow_baseline.yaml");
  EXPECT_EQ(dbow.vocabulary.kind, VocabularyKind::kHkm);
  EXPECT_EQ(dbow.vocabulary.metric, Metric::kHamming);
  EXPECT_EQ(dbow.vocabulary.hkm_branching, 10);
  EXPECT_EQ(dbow.vocabulary.hkm_depth, 5);
  EXPECT_EQ(dbow.bow.size_binning, SizeBinning::kNone);
  EXPECT_FALSE(dbow.bow.orientation_verification);
  EXPECT_EQ(dbow.bow.scoring, Scoring::kDbowL1);
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
}

}  // namespace
}  // namespace gtbow
