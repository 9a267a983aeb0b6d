// Bag-of-words vectors with the paper's modifications (Wilhelm & Napp, ICRA 2025, §II):
// keypoints binned by size (§II-A), soft assignment to the r nearest words with Gaussian
// weights (§II-D), and per-keypoint contributing weights and orientations kept for the
// orientation verification of the inverted index (§II-B, §II-E). Each modification can be
// switched off to reproduce the ablation of Table I.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "ground_texture_bow/core/features.h"
#include "ground_texture_bow/core/vocabulary.h"

namespace gtbow {

enum class SizeBinning { kNone, kOctave, kPercentile };
SizeBinning ParseSizeBinning(const std::string& name);  // "none", "octave" or "percentile"
std::string SizeBinningName(SizeBinning binning);

// How the S x V vector is normalised. kGlobal: once, over the whole vector (the paper's text,
// §II-A). kPerBin: each size bin's part first, so that every non-empty bin weighs the same,
// then the whole vector (the authors' code, napp-lab/GTBoW SizeBinnedVocabulary::transform).
enum class Normalization { kGlobal, kPerBin };
Normalization ParseNormalization(const std::string& name);  // "global" or "per_bin"
std::string NormalizationName(Normalization normalization);

// kDot: tf-idf, L2-normalised, scored by dot product (the paper's method).
// kDbowL1: tf-idf, L1-normalised, scored by DBoW2's L1 score sum(min(q, d)) (the baseline).
enum class Scoring { kDot, kDbowL1 };
Scoring ParseScoring(const std::string& name);  // "dot" or "dbow_l1"
std::string ScoringName(Scoring scoring);

struct BowOptions {
  SizeBinning size_binning = SizeBinning::kOctave;  // §II-A; kNone means S = 1
  int num_size_bins = 8;    // S (octave binning: one bin per ORB pyramid level)
  int soft_assignment = 3;  // r nearest words per descriptor; 1 = hard assignment
  // Soft-assignment scale sigma of exp(-d^2 / 2 sigma^2), in the metric's units (L2 of the
  // descriptor bytes, or Hamming bits). The paper's "sigma = 580" read as an L2 scale is 580;
  // the authors' code uses 580 as sigma^2 of Hamming bits, i.e. sigma = sqrt(580) = 24.08.
  double sigma = 580.0;
  Normalization normalization = Normalization::kGlobal;
  bool orientation_verification = true;  // §II-B; off: the score is the plain dot product
  int orientation_bins = 6;              // R
  Scoring scoring = Scoring::kDot;
  // Inverted-index entry layout (database.h): compact 6-byte entries (8-bit keypoint ids, so
  // at most 256 keypoints per image, and 8-bit log-scale weights) or precise 8-byte entries
  // (16-bit keypoint ids, 16-bit linear weights). Retrieval is the same up to rounding.
  bool compact_postings = true;

  // Throws std::invalid_argument naming the first bad field.
  void Check() const;
  // The number of size bins actually used (1 when binning is off).
  int SizeBins() const { return size_binning == SizeBinning::kNone ? 1 : num_size_bins; }
};

// One non-zero of the concatenated S x V vector: row = size_bin * V + word.
struct BowEntry {
  uint32_t row = 0;
  float weight = 0.0f;
};

// One keypoint's assignment to a row (a keypoint has up to r of them): its contributing
// weight is its soft-assignment weight divided by the total weight of the image's keypoints
// on that row (§II-E).
struct KeypointEntry {
  uint32_t row = 0;
  uint16_t keypoint = 0;      // index into the image's keypoints
  float contribution = 0.0f;  // c in [0, 1]; sums to 1 over a row's keypoints
  float assignment = 0.0f;    // soft-assignment weight, L1-normalised over the keypoint's words
};

struct BowVector {
  std::vector<BowEntry> entries;         // sorted by row, normalised per the scoring
  std::vector<KeypointEntry> keypoints;  // sorted by row
  std::vector<float> angles;             // keypoint orientations, radians
  std::vector<Keypoint> source;          // the keypoints themselves (for pose estimation)
  cv::Mat source_descriptors;            // their descriptors (shared, not copied), for
                                         // verification from descriptor matches
};

class BowEncoder {
 public:
  // The vocabulary must outlive the encoder.
  BowEncoder(const Vocabulary& vocabulary, const BowOptions& options);

  // Rows of the inverted index: S x V.
  uint32_t num_rows() const;
  // Size bin of a keypoint in [0, S): its octave, or its size against the vocabulary's
  // percentile thresholds.
  int SizeBin(const Keypoint& keypoint) const;
  // The BoW vector of an image's features.
  BowVector Encode(const ImageFeatures& features) const;
  // The second half of Encode: from `vector.keypoints` holding each keypoint's rows with their
  // soft-assignment weights (`assignment`; any order) to the finished vector: tf-idf row
  // weights over `num_keypoints` keypoints, normalisation, contributions, entries sorted by row.
  // Used by Encode and by the scaling benchmark's synthetic images.
  BowVector FromAssignments(BowVector vector, size_t num_keypoints) const;

  const BowOptions& options() const { return options_; }
  const Vocabulary& vocabulary() const { return vocabulary_; }
  // Threads one Encode may use for descriptor assignment (1 by default; an image with fewer
  // than 2 x kMinDescriptorsPerThread keypoints uses one). The result does not depend on it.
  void set_threads(int threads) { threads_ = threads < 1 ? 1 : threads; }
  int threads() const { return threads_; }
  static constexpr int kMinDescriptorsPerThread = 32;

 private:
  const Vocabulary& vocabulary_;
  BowOptions options_;
  int threads_ = 1;
};

// Percentile thresholds splitting `sizes` into `bins` equally populated bins (bins - 1 values).
std::vector<float> SizePercentileThresholds(std::vector<float> sizes, int bins);

}  // namespace gtbow
