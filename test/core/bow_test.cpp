#include "ground_texture_bow/core/bow.h"

#include <cmath>
#include <map>

#include <gtest/gtest.h>

namespace gtbow {
namespace {

// A vocabulary whose 4 words are exactly these points (32-D, ORB bytes under L2):
// w0 = 0, w1 = 100, w2 = 200 everywhere, w3 = 255 on the first 8 bytes and 0 elsewhere.
std::unique_ptr<Vocabulary> HandMade() {
  cv::Mat pts(4, 32, CV_8U, cv::Scalar(0));
  pts.row(1).setTo(100);
  pts.row(2).setTo(200);
  pts(cv::Rect(0, 3, 8, 1)).setTo(255);
  VocabularyOptions o;
  o.num_words = 4;
  o.kmeans_iterations = 2;
  o.checks = 128;
  auto v = TrainVocabulary(o, pts, {0, 1, 2, 3}, false);
  v->set_idf({1.0f, 1.0f, 1.0f, 1.0f});
  return v;
}

// The word id the vocabulary gave each point (k-means may permute them).
std::vector<uint32_t> WordOf(const Vocabulary& v) {
  cv::Mat pts(4, 32, CV_8U, cv::Scalar(0));
  pts.row(1).setTo(100);
  pts.row(2).setTo(200);
  pts(cv::Rect(0, 3, 8, 1)).setTo(255);
  std::vector<WordHit> hits;
  v.Assign(pts, 1, &hits);
  return {hits[0].word, hits[1].word, hits[2].word, hits[3].word};
}

ImageFeatures OneKeypoint(uint8_t value, int octave = 0, float size = 10.0f) {
  ImageFeatures f;
  Keypoint k;
  k.octave = octave;
  k.size = size;
  k.angle = 1.0f;
  f.keypoints.push_back(k);
  f.descriptors = cv::Mat(1, 32, CV_8U, cv::Scalar(value));
  return f;
}

TEST(Bow, SoftAssignmentWeightsMatchTheGaussian) {
  const auto v = HandMade();
  const auto w = WordOf(*v);
  BowOptions o;
  o.size_binning = SizeBinning::kNone;
  o.soft_assignment = 3;
  o.sigma = 580;
  const BowEncoder enc(*v, o);
  const BowVector b = enc.Encode(OneKeypoint(50));
  // Distances: w0 and w1 at 50 sqrt(32) = 282.8; w3 at sqrt(8 * 205^2 + 24 * 50^2) = 629.4.
  const double a01 = std::exp(-(50.0 * 50 * 32) / (2 * 580.0 * 580));
  const double a3 = std::exp(-(8.0 * 205 * 205 + 24.0 * 50 * 50) / (2 * 580.0 * 580));
  const double s = 2 * a01 + a3;
  ASSERT_EQ(b.keypoints.size(), 3u);
  std::map<uint32_t, double> assign;
  for (const auto& k : b.keypoints) {
    assign[k.row] = k.assignment;
    EXPECT_FLOAT_EQ(k.contribution, 1.0f);  // the only keypoint on its row
  }
  EXPECT_NEAR(assign.at(w[0]), a01 / s, 1e-5);
  EXPECT_NEAR(assign.at(w[1]), a01 / s, 1e-5);
  EXPECT_NEAR(assign.at(w[3]), a3 / s, 1e-5);
  EXPECT_EQ(assign.count(w[2]), 0u);
  // tf-idf then L2: weights proportional to the assignments, unit norm.
  double norm = 0;
  for (const auto& e : b.entries) norm += e.weight * e.weight;
  EXPECT_NEAR(norm, 1.0, 1e-6);
  const double l2 = std::sqrt(2 * a01 * a01 + a3 * a3) / s;
  for (const auto& e : b.entries) EXPECT_NEAR(e.weight, assign.at(e.row) / l2, 1e-5);
}

TEST(Bow, HardAssignmentIdfAndL1) {
  auto v = HandMade();
  const auto w = WordOf(*v);
  std::vector<float> idf(4, 0.0f);
  idf[w[0]] = 2.0f;
  idf[w[2]] = 0.5f;
  v->set_idf(idf);
  BowOptions o;
  o.size_binning = SizeBinning::kNone;
  o.soft_assignment = 1;
  o.scoring = Scoring::kDbowL1;
  o.orientation_verification = true;
  EXPECT_THROW(BowEncoder(*v, o), std::invalid_argument);  // OV votes need the dot product
  o.orientation_verification = false;
  const BowEncoder enc(*v, o);
  ImageFeatures f = OneKeypoint(10);
  ImageFeatures g = OneKeypoint(190);
  ImageFeatures h = OneKeypoint(110);  // word 1 has idf 0: dropped
  f.keypoints.push_back(g.keypoints[0]);
  f.keypoints.push_back(h.keypoints[0]);
  cv::vconcat(std::vector<cv::Mat>{f.descriptors, g.descriptors, h.descriptors}, f.descriptors);
  const BowVector b = enc.Encode(f);
  ASSERT_EQ(b.entries.size(), 2u);
  std::map<uint32_t, float> weight;
  for (const auto& e : b.entries) weight[e.row] = e.weight;
  // tf 1/3 each; times idf 2 and 0.5; L1-normalised: 0.8 and 0.2.
  EXPECT_NEAR(weight.at(w[0]), 0.8, 1e-6);
  EXPECT_NEAR(weight.at(w[2]), 0.2, 1e-6);
  EXPECT_EQ(b.keypoints.size(), 2u);  // the idf-0 keypoint has no entry
}

TEST(Bow, SizeBinsMakeSeparateRowsAndContributionsSplitARow) {
  const auto v = HandMade();
  const auto w = WordOf(*v);
  BowOptions o;
  o.soft_assignment = 1;
  o.num_size_bins = 8;
  const BowEncoder enc(*v, o);
  EXPECT_EQ(enc.num_rows(), 32u);
  // Three keypoints of word 0: two at octave 2, one at octave 5.
  ImageFeatures f = OneKeypoint(0, 2);
  for (int oct : {2, 5}) {
    ImageFeatures g = OneKeypoint(0, oct);
    f.keypoints.push_back(g.keypoints[0]);
    cv::vconcat(f.descriptors, g.descriptors, f.descriptors);
  }
  const BowVector b = enc.Encode(f);
  ASSERT_EQ(b.entries.size(), 2u);
  EXPECT_EQ(b.entries[0].row, 2 * 4 + w[0]);
  EXPECT_EQ(b.entries[1].row, 5 * 4 + w[0]);
  EXPECT_NEAR(b.entries[0].weight / b.entries[1].weight, 2.0, 1e-5);  // tf 2 vs 1
  ASSERT_EQ(b.keypoints.size(), 3u);
  EXPECT_FLOAT_EQ(b.keypoints[0].contribution, 0.5f);
  EXPECT_FLOAT_EQ(b.keypoints[1].contribution, 0.5f);
  EXPECT_FLOAT_EQ(b.keypoints[2].contribution, 1.0f);
  // Octaves beyond S - 1 go to the last bin.
  Keypoint k;
  k.octave = 12;
  EXPECT_EQ(enc.SizeBin(k), 7);
}

TEST(Bow, PercentileSizeBins) {
  const std::vector<float> t = SizePercentileThresholds({1, 2, 3, 4, 5, 6, 7, 8}, 4);
  EXPECT_EQ(t, (std::vector<float>{3, 5, 7}));
  auto v = HandMade();
  v->set_size_thresholds(t);
  BowOptions o;
  o.size_binning = SizeBinning::kPercentile;
  o.num_size_bins = 4;
  o.soft_assignment = 1;
  const BowEncoder enc(*v, o);
  Keypoint k;
  for (auto [size, bin] : {std::pair<float, int>{1, 0}, {2.9f, 0}, {3, 1}, {6, 2}, {100, 3}}) {
    k.size = size;
    EXPECT_EQ(enc.SizeBin(k), bin) << size;
  }
  o.num_size_bins = 8;  // the vocabulary has thresholds for 4 bins only
  EXPECT_THROW(BowEncoder(*v, o), std::invalid_argument);
}

TEST(Bow, EmptyImageAndBadOptions) {
  const auto v = HandMade();
  const BowEncoder enc(*v, BowOptions{});
  ImageFeatures none;
  const BowVector b = enc.Encode(none);
  EXPECT_TRUE(b.entries.empty());
  BowOptions o;
  o.soft_assignment = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = {};
  o.sigma = 0;
  EXPECT_THROW(o.Check(), std::invalid_argument);
}

TEST(Bow, PerBinNormalisationWeighsEveryNonEmptySizeBinTheSame) {
  auto v = HandMade();
  const auto w = WordOf(*v);
  // Three keypoints in bin 0 (two words) and one in bin 2.
  ImageFeatures f;
  for (auto [value, octave] : {std::pair<uint8_t, int>{0, 0}, {0, 0}, {100, 0}, {200, 2}}) {
    const ImageFeatures k = OneKeypoint(value, octave);
    f.keypoints.push_back(k.keypoints[0]);
    f.descriptors.push_back(k.descriptors);
  }
  BowOptions o;
  o.soft_assignment = 1;
  o.num_size_bins = 4;
  o.normalization = Normalization::kPerBin;
  const BowVector pb = BowEncoder(*v, o).Encode(f);
  o.normalization = Normalization::kGlobal;
  const BowVector gl = BowEncoder(*v, o).Encode(f);
  std::map<uint32_t, double> bin_norm_pb, bin_norm_gl;
  double total = 0;
  for (const auto& e : pb.entries) {
    bin_norm_pb[e.row / v->size()] += e.weight * e.weight;
    total += e.weight * e.weight;
  }
  for (const auto& e : gl.entries) bin_norm_gl[e.row / v->size()] += e.weight * e.weight;
  EXPECT_NEAR(total, 1.0, 1e-5);
  ASSERT_EQ(bin_norm_pb.size(), 2u);
  EXPECT_NEAR(bin_norm_pb[0], 0.5, 1e-5);  // each non-empty bin: norm 1 / sqrt(2)
  EXPECT_NEAR(bin_norm_pb[2], 0.5, 1e-5);
  EXPECT_GT(bin_norm_gl[0], 0.8);  // globally, the crowded bin dominates
  // Within a bin the proportions are kept: bin 0 holds word w0 twice, word w1 once.
  double w0 = 0, w1 = 0;
  for (const auto& e : pb.entries) {
    if (e.row == w[0]) w0 = e.weight;
    if (e.row == w[1]) w1 = e.weight;
  }
  EXPECT_NEAR(w0 / w1, 2.0, 1e-4);
  // With one size bin both normalisations are the same.
  o.num_size_bins = 1;
  o.size_binning = SizeBinning::kNone;
  const BowVector one_gl = BowEncoder(*v, o).Encode(f);
  o.normalization = Normalization::kPerBin;
  const BowVector one_pb = BowEncoder(*v, o).Encode(f);
  ASSERT_EQ(one_gl.entries.size(), one_pb.entries.size());
  for (size_t i = 0; i < one_gl.entries.size(); ++i)
    EXPECT_FLOAT_EQ(one_gl.entries[i].weight, one_pb.entries[i].weight);
}

}  // namespace
}  // namespace gtbow
