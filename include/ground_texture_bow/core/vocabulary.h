// Visual vocabularies behind one interface (paper §II-C): a flat approximate k-means (AKM)
// vocabulary whose words are found through an ANN index (Philbin et al. 2007), and a
// DBoW2-style hierarchical k-means (HKM) tree for the baseline. No ANN library appears in this
// header: implementations live in the .cpp files.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace gtbow {

class BinaryWriter;

enum class VocabularyKind { kAkm, kHkm };

// How descriptors are compared.
//  kL2Bytes: ORB's 32 bytes as a 32-D vector under L2 (what the paper's sigma = 580 implies).
//  kHamming: binary descriptors under Hamming distance, bitwise-majority centroids.
//  kL2:      float descriptors (SIFT) under L2.
enum class Metric { kL2Bytes, kHamming, kL2 };

// How an AKM vocabulary finds the words of a descriptor at query time.
//  kFlann: FLANN's randomized kd-tree forest (L2 metrics) or hierarchical clustering tree
//          (Hamming): the paper's structure (Philbin et al. 2007), also used in training.
//  kIvf:   an inverted file over the words: the words are grouped around sqrt(V) coarse
//          centres; a descriptor is compared exhaustively with the words of its `nprobe`
//          nearest groups (integer SIMD for l2_bytes, vector popcount for Hamming; nprobe >=
//          sqrt(V) is exact). Much more accurate than the trees at the same speed on 32-byte ORB
//          descriptors (measured in the README).
enum class AnnIndex { kFlann, kIvf };
AnnIndex ParseAnnIndex(const std::string& name);  // "flann" or "ivf"
std::string AnnIndexName(AnnIndex index);

VocabularyKind ParseVocabularyKind(const std::string& name);  // "akm" or "hkm"
std::string VocabularyKindName(VocabularyKind kind);
Metric ParseMetric(const std::string& name);  // "l2_bytes", "hamming" or "l2"
std::string MetricName(Metric metric);

struct VocabularyOptions {
  VocabularyKind kind = VocabularyKind::kAkm;
  Metric metric = Metric::kL2Bytes;
  int num_words = 100000;      // AKM: V, the number of words
  int kmeans_iterations = 10;  // AKM: Lloyd iterations (the most, with kmeans_stop_fraction)
  // AKM: stop k-means early once fewer than this fraction of the descriptors change word in an
  // iteration, after at least kmeans_min_iterations (the authors' code: 0.01 after 5, at most
  // 200 iterations). 0 runs all kmeans_iterations.
  double kmeans_stop_fraction = 0.0;
  int kmeans_min_iterations = 5;
  int num_trees = 8;  // AKM: randomized kd-trees (L2) or clustering trees (Hamming)
  int checks = 64;    // AKM, flann: leaves visited per ANN query (speed vs accuracy)
  // AKM training: leaves visited per FLANN search in k-means (0: max(2000, V / 5), the authors'
  // rule). Training of a Hamming vocabulary with ann: ivf searches the binary IVF instead.
  int train_checks = 0;
  AnnIndex ann = AnnIndex::kIvf;  // AKM: query-time word search
  int nprobe = 16;                // AKM, ivf: groups of words searched per descriptor
  // AKM, Hamming with ann: ivf: skip the words of a group that the triangle inequality proves
  // farther than the r-th nearest found so far (binary_ivf.h; the same answers with fewer
  // distances). ivf_bound at query time: off by default, since with r = 3 it skips few
  // distances and on real floors costs more than it saves (docs/RESULTS.md, "Kernels");
  // train_bound in k-means training (r = 1, every group): 8.4 s against 14.5 s there.
  bool ivf_bound = false;
  bool train_bound = true;
  // AKM, Hamming with ann: ivf: lists searched per descriptor in k-means training (0 = all:
  // exact assignment).
  int train_nprobe = 0;
  int hkm_branching = 10;  // HKM: k, children per node
  int hkm_depth = 5;       // HKM: L, levels (k = 10, L = 5: the paper's DBoW baseline)
  uint64_t seed = 1;       // k-means seeding and kd-tree randomisation
  int threads = 0;         // training threads, 0 = all cores

  // Throws std::invalid_argument naming the first bad field.
  void Check() const;
};

// A descriptor's assignment to one word: word id in [0, V) and distance in metric units
// (L2 distance, not squared; or Hamming bits).
struct WordHit {
  uint32_t word = 0;
  float distance = 0.0f;
};

class Vocabulary {
 public:
  virtual ~Vocabulary() = default;
  Vocabulary(const Vocabulary&) = delete;
  Vocabulary& operator=(const Vocabulary&) = delete;

  virtual VocabularyKind kind() const = 0;
  virtual Metric metric() const = 0;
  // Number of words V.
  virtual uint32_t size() const = 0;
  // Largest r that Assign supports (1 for HKM).
  virtual int max_neighbours() const = 0;
  // For each descriptor row, its `r` nearest words sorted by distance: out[i * r + j].
  // Descriptors must match the metric (CV_8U for kL2Bytes and kHamming, CV_32F for kL2).
  virtual void Assign(const cv::Mat& descriptors, int r, std::vector<WordHit>* out) const = 0;
  // The exact nearest word of each descriptor by linear scan (AKM) or tree descent (HKM): the
  // reference for measuring how often Assign's approximate first word agrees.
  virtual void AssignExact(const cv::Mat& descriptors, std::vector<WordHit>* out) const = 0;

  // Overrides the ANN search effort (leaves checked per descriptor) of an AKM vocabulary; no
  // effect on HKM. Not thread-safe with concurrent Assign calls.
  virtual void set_checks(int /*checks*/) {}
  // Selects the query-time search of an AKM vocabulary (an IVF index is built on demand);
  // no effect on HKM. Not thread-safe with concurrent Assign calls.
  virtual void set_search(AnnIndex /*ann*/, int /*nprobe*/) {}
  // Turns the triangle bound of a Hamming IVF search on or off (VocabularyOptions::ivf_bound);
  // the answers are the same either way. No effect on other searches.
  virtual void set_search_bound(bool /*on*/) {}

  // Inverse document frequency of each word, log(N / n_w) over the N training images
  // (0 for words no training image has).
  const std::vector<float>& idf() const { return idf_; }
  void set_idf(std::vector<float> idf) { idf_ = std::move(idf); }
  // Keypoint-size thresholds (pixels) for percentile size bins, learned in training:
  // S - 1 ascending values. Empty when bins follow the ORB octave.
  const std::vector<float>& size_thresholds() const { return size_thresholds_; }
  void set_size_thresholds(std::vector<float> t) { size_thresholds_ = std::move(t); }
  // A fingerprint of the words, stored in databases to detect a mismatched vocabulary.
  uint64_t fingerprint() const { return fingerprint_; }
  // The feature extractor the vocabulary was trained with: the `features` section of the
  // retrieval configuration as YAML (config.h). Empty for files written before format 3.
  const std::string& extractor() const { return extractor_; }
  void set_extractor(std::string yaml) { extractor_ = std::move(yaml); }

  // Writes the vocabulary file atomically (magic, version, checksum).
  void Save(const std::filesystem::path& path) const;
  // Loads a vocabulary file; throws std::runtime_error naming the file on any defect.
  static std::unique_ptr<Vocabulary> Load(const std::filesystem::path& path);

 protected:
  Vocabulary() = default;
  // Serialises the words (centroids or tree) into `out` / restores them.
  virtual void SaveWords(BinaryWriter* out) const = 0;
  std::vector<float> idf_;
  std::vector<float> size_thresholds_;
  uint64_t fingerprint_ = 0;
  std::string extractor_;
};

// Trains a vocabulary on `descriptors` (one row each, all training images stacked). `image_of`
// gives the training image of each row; it is used for the idf weights. Progress is shown
// on stderr when `progress`.
std::unique_ptr<Vocabulary> TrainVocabulary(const VocabularyOptions& options,
                                            const cv::Mat& descriptors,
                                            const std::vector<uint32_t>& image_of, bool progress);

}  // namespace gtbow
