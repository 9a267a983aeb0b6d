// AKM vocabularies: flat k-means over all training descriptors with approximate nearest-centroid
// search (FLANN kd-forest, or the inverted files), their training and their file form.
#include <atomic>

#include "binary_ivf.h"
#include "float_ivf.h"
#include "ground_texture_bow/core/parallel.h"
#include "ground_texture_bow/core/progress.h"
#include "vocabulary_internal.h"

namespace gtbow {
namespace vocabulary_internal {

// ---------------------------------------------------------------------------------------------
// AKM: flat k-means with approximate assignment (Philbin et al. 2007, paper §II-C).

template <typename Space>
class AkmVocabulary : public Vocabulary {
 public:
  using E = typename Space::Element;

  AkmVocabulary(Metric metric, cv::Mat centroids, int trees, int checks)
      : metric_(metric), centroids_(std::move(centroids)), trees_(trees), checks_(checks) {
    fingerprint_ = Checksum64(centroids_.data, centroids_.total() * centroids_.elemSize());
  }

  VocabularyKind kind() const override { return VocabularyKind::kAkm; }
  Metric metric() const override { return metric_; }
  uint32_t size() const override { return static_cast<uint32_t>(centroids_.rows); }
  int max_neighbours() const override { return 16; }
  void set_checks(int checks) override {
    if (checks < 1) throw std::invalid_argument("checks must be >= 1");
    checks_ = checks;
  }
  void set_search(AnnIndex ann, int nprobe) override {
    if (nprobe < 1) throw std::invalid_argument("nprobe must be >= 1");
    nprobe_ = nprobe;
    ann_ = ann;
    if (ann == AnnIndex::kIvf) {
      if constexpr (std::is_same<Space, FloatSpace>::value) {
        if (!ivf_) ivf_ = std::make_unique<IvfIndex>(centroids_, metric_ == Metric::kL2Bytes, 1, 0);
      } else {
        if (!bivf_) bivf_ = std::make_unique<BinaryIvfIndex>(centroids_, 1, 0);
        bivf_->set_bound(bound_);
      }
    }
  }
  void set_search_bound(bool on) override {
    bound_ = on;
    if (bivf_) bivf_->set_bound(on);
  }

  void Assign(const cv::Mat& descriptors, int r, std::vector<WordHit>* out) const override {
    if (r < 1 || r > max_neighbours()) throw std::invalid_argument("Assign: r out of range");
    out->assign(static_cast<size_t>(descriptors.rows) * r, WordHit{});
    if (descriptors.rows == 0) return;
    if (descriptors.cols != centroids_.cols) {
      throw std::invalid_argument("Assign: descriptor length " + std::to_string(descriptors.cols) +
                                  " does not match the vocabulary's " +
                                  std::to_string(centroids_.cols));
    }
    if constexpr (std::is_same<Space, BinarySpace>::value) {
      if (ann_ == AnnIndex::kIvf && bivf_) {
        bivf_->Search(ToSpace(descriptors, metric_), r, nprobe_, out);
        return;
      }
    }
    if (ann_ == AnnIndex::kIvf && ivf_ && ivf_->bytes() && descriptors.type() == CV_8U) {
      ivf_->SearchBytes(descriptors.isContinuous() ? descriptors : descriptors.clone(), r, nprobe_,
                        out);
      return;
    }
    const cv::Mat q = ToSpace(descriptors, metric_);
    if (ann_ == AnnIndex::kIvf && ivf_) {
      ivf_->Search(q, r, nprobe_, out);
    } else {
      Search(q, r, out);
    }
  }

  void AssignExact(const cv::Mat& descriptors, std::vector<WordHit>* out) const override {
    const cv::Mat q = ToSpace(descriptors, metric_);
    out->assign(static_cast<size_t>(q.rows), WordHit{});
    for (int i = 0; i < q.rows; ++i) {
      float best = std::numeric_limits<float>::max();
      const int c = Space::Nearest(q.ptr<E>(i), centroids_.ptr<E>(), centroids_.step[0],
                                   centroids_.rows, q.cols, &best);
      (*out)[i] = {c >= 0 ? static_cast<uint32_t>(c) : 0u, best};
    }
  }

  // Nearest `r` centroids of each row of `q` (already in the space's element type).
  void Search(const cv::Mat& q, int r, std::vector<WordHit>* out) const {
    using DT = typename Space::FlannDistance::ResultType;
    const flann::Matrix<E> queries(const_cast<E*>(q.ptr<E>()), q.rows, q.cols);
    std::vector<size_t> idx(static_cast<size_t>(q.rows) * r);
    std::vector<DT> dist(static_cast<size_t>(q.rows) * r);
    flann::Matrix<size_t> mi(idx.data(), q.rows, r);
    flann::Matrix<DT> md(dist.data(), q.rows, r);
    flann::SearchParams params(checks_);
    params.cores = 1;
    {
      // Built on first use: a vocabulary searched through the IVF index never needs it.
      std::call_once(index_once_, [this]() { const_cast<AkmVocabulary*>(this)->BuildIndex(0); });
    }
    index_->knnSearch(queries, mi, md, r, params);
    out->resize(idx.size());
    for (size_t i = 0; i < idx.size(); ++i) {
      (*out)[i].word = static_cast<uint32_t>(idx[i]);
      (*out)[i].distance = Space::FromFlann(dist[i]);
    }
  }

  const cv::Mat& centroids() const { return centroids_; }

 protected:
  void SaveWords(BinaryWriter* w) const override {
    w->Put<int32_t>(centroids_.rows);
    w->Put<int32_t>(centroids_.cols);
    w->Put<int32_t>(trees_);
    w->Put<int32_t>(checks_);
    w->PutArray(centroids_.ptr<E>(), centroids_.total());
    // The IVF lists, when built, so that loading does not cluster the words again.
    w->Put<uint8_t>(ivf_ || bivf_ ? 1 : 0);
    if (ivf_) ivf_->Save(w);
    if (bivf_) bivf_->Save(w);
  }

  // Restores IVF lists saved with the words.
 public:
  void LoadIvf(BinaryReader* r) {
    if constexpr (std::is_same<Space, FloatSpace>::value) {
      ivf_ = std::make_unique<IvfIndex>(centroids_, metric_ == Metric::kL2Bytes, r);
    } else {
      bivf_ = std::make_unique<BinaryIvfIndex>(centroids_, r);
      bivf_->set_bound(bound_);
    }
    ann_ = AnnIndex::kIvf;
  }

 protected:
 private:
  void BuildIndex(uint64_t seed) {
    std::lock_guard<std::mutex> lock(FlannSeedMutex());
    flann::seed_random(static_cast<unsigned int>(seed));
    const flann::Matrix<E> data(centroids_.ptr<E>(), centroids_.rows, centroids_.cols);
    if constexpr (std::is_same<Space, BinarySpace>::value) {
      // k-means++ centres: FLANN's random chooser draws from std::random_device, which no
      // seed controls (searches then differed from run to run); k-means++ uses the seeded rand().
      index_ = std::make_unique<typename Space::FlannIndex>(
          data,
          flann::HierarchicalClusteringIndexParams(32, flann::FLANN_CENTERS_KMEANSPP, trees_, 100));
    } else {
      index_ = std::make_unique<typename Space::FlannIndex>(data, flann::KDTreeIndexParams(trees_));
    }
    index_->buildIndex();
  }

  Metric metric_;
  cv::Mat centroids_;  // V x D, CV_32F (L2 metrics) or CV_8U (Hamming)
  int trees_;
  int checks_;
  std::unique_ptr<typename Space::FlannIndex> index_;
  mutable std::once_flag index_once_;
  AnnIndex ann_ = AnnIndex::kFlann;
  int nprobe_ = 8;
  bool bound_ = false;                    // VocabularyOptions::ivf_bound
  std::unique_ptr<IvfIndex> ivf_;         // float spaces
  std::unique_ptr<BinaryIvfIndex> bivf_;  // Hamming
};

// Recomputes centroid c from its members: the mean (float) or the bitwise majority (binary).
void UpdateCentroids(const cv::Mat& data, const std::vector<uint32_t>& label, cv::Mat* centroids,
                     std::mt19937_64& rng, int threads) {
  const int v = centroids->rows, d = centroids->cols;
  std::vector<uint32_t> count(v, 0);
  for (uint32_t l : label) ++count[l];
  if (data.type() == CV_32F) {
    cv::Mat sum = cv::Mat::zeros(v, d, CV_64F);
    for (int i = 0; i < data.rows; ++i) {
      double* s = sum.ptr<double>(label[i]);
      const float* x = data.ptr<float>(i);
      for (int k = 0; k < d; ++k) s[k] += x[k];
    }
    for (int c = 0; c < v; ++c) {
      if (count[c] == 0) continue;
      float* out = centroids->ptr<float>(c);
      const double* s = sum.ptr<double>(c);
      for (int k = 0; k < d; ++k) out[k] = static_cast<float>(s[k] / count[c]);
    }
  } else {
    // Bit counts per centroid, accumulated per thread over contiguous chunks.
    const int bits = d * 8;
    std::vector<std::vector<uint32_t>> partial(threads);
    ParallelParts(static_cast<size_t>(data.rows), threads, 64, [&](size_t b, size_t e, int t) {
      auto& ones = partial[t];
      ones.assign(static_cast<size_t>(v) * bits, 0);
      for (size_t i = b; i < e; ++i) {
        const unsigned char* x = data.ptr<unsigned char>(static_cast<int>(i));
        uint32_t* o = ones.data() + static_cast<size_t>(label[i]) * bits;
        for (int k = 0; k < bits; ++k) o[k] += (x[k >> 3] >> (7 - (k & 7))) & 1;
      }
    });
    for (int c = 0; c < v; ++c) {
      if (count[c] == 0) continue;
      unsigned char* out = centroids->ptr<unsigned char>(c);
      for (int k = 0; k < d; ++k) out[k] = 0;
      for (int k = 0; k < bits; ++k) {
        uint32_t ones = 0;
        for (const auto& p : partial) {
          if (!p.empty()) ones += p[static_cast<size_t>(c) * bits + k];
        }
        if (2 * ones > count[c]) out[k >> 3] |= static_cast<unsigned char>(1 << (7 - (k & 7)));
      }
    }
  }
  // Empty clusters restart at a random descriptor.
  std::uniform_int_distribution<int> pick(0, data.rows - 1);
  for (int c = 0; c < v; ++c) {
    if (count[c] == 0) data.row(pick(rng)).copyTo(centroids->row(c));
  }
}

template <typename Space>
std::unique_ptr<Vocabulary> TrainAkmIn(const VocabularyOptions& o, const cv::Mat& data,
                                       bool progress) {
  using E = typename Space::Element;
  const int v = o.num_words;
  if (data.rows < v) {
    throw std::invalid_argument("AKM training needs at least num_words = " + std::to_string(v) +
                                " descriptors, got " + std::to_string(data.rows));
  }
  std::mt19937_64 rng(o.seed);
  std::vector<int> order(data.rows);
  std::iota(order.begin(), order.end(), 0);
  cv::Mat centroids(v, data.cols, data.type());
  if (static_cast<double>(v) * data.rows <= 2e6) {
    // Small problems: k-means++ seeding, which avoids most poor local minima.
    SeedPlusPlus<Space>(data, order, v, rng, &centroids);
  } else {
    // Large vocabularies: random distinct descriptors, as Philbin et al. (k-means++ would cost
    // V x N exact distances).
    std::shuffle(order.begin(), order.end(), rng);
    for (int c = 0; c < v; ++c) data.row(order[c]).copyTo(centroids.row(c));
  }
  const int threads = ThreadCount(o.threads);
  // Searches in training are more thorough than at query time: k-means needs accurate nearest
  // centroids to converge (the authors' code uses max(2000, V / 5) FLANN checks).
  const int train_checks = o.train_checks > 0 ? o.train_checks : std::max(2000, v / 5);
  constexpr bool kBinary = std::is_same<Space, BinarySpace>::value;
  const bool binary_ivf = kBinary && o.ann == AnnIndex::kIvf;
  std::vector<uint32_t> label(data.rows, std::numeric_limits<uint32_t>::max());
  const bool early_stop = o.kmeans_stop_fraction > 0.0;
  ProgressBar bar(early_stop ? "akm k-means (until converged)" : "akm k-means",
                  static_cast<size_t>(o.kmeans_iterations) * data.rows, progress);
  for (int it = 0; it < o.kmeans_iterations; ++it) {
    std::unique_ptr<AkmVocabulary<Space>> current;
    std::unique_ptr<BinaryIvfIndex> ivf;
    if (binary_ivf) {
      ivf =
          std::make_unique<BinaryIvfIndex>(centroids, o.seed + static_cast<uint64_t>(it), threads);
      ivf->set_bound(o.train_bound);
    } else {
      current = std::make_unique<AkmVocabulary<Space>>(o.metric, centroids.clone(), o.num_trees,
                                                       train_checks);
    }
    std::atomic<size_t> changed{0};
    ParallelParts(static_cast<size_t>(data.rows), threads, 64, [&](size_t b, size_t e, int) {
      constexpr size_t kBlock = 4096;
      std::vector<WordHit> hits;
      size_t moved = 0;
      for (size_t s = b; s < e; s += kBlock) {
        const size_t n = std::min(kBlock, e - s);
        const cv::Mat rows = data.rowRange(static_cast<int>(s), static_cast<int>(s + n));
        if (ivf) {
          ivf->Search(rows, 1, o.train_nprobe > 0 ? o.train_nprobe : ivf->num_lists(), &hits);
        } else {
          current->Search(rows, 1, &hits);
        }
        for (size_t i = 0; i < n; ++i) {
          uint32_t l = hits[i].word;
          const uint32_t old = label[s + i];
          // A descriptor keeps its centroid unless the search found a strictly closer one: an
          // approximate search must not move it back and forth between equally near words.
          if (old != std::numeric_limits<uint32_t>::max() && l != old &&
              Space::Distance(rows.ptr<E>(static_cast<int>(i)),
                              centroids.ptr<E>(static_cast<int>(old)),
                              data.cols) <= hits[i].distance) {
            l = old;
          }
          moved += l != old ? 1 : 0;
          label[s + i] = l;
        }
        bar.Add(n);
      }
      changed += moved;
    });
    UpdateCentroids(data, label, &centroids, rng, threads);
    const double fraction = static_cast<double>(changed) / data.rows;
    if (it > 0 && (changed == 0 || (early_stop && it >= o.kmeans_min_iterations &&
                                    fraction < o.kmeans_stop_fraction))) {
      break;
    }
  }
  bar.Finish();
  return std::make_unique<AkmVocabulary<Space>>(o.metric, centroids, o.num_trees, o.checks);
}

std::unique_ptr<Vocabulary> TrainAkm(const VocabularyOptions& o, const cv::Mat& data,
                                     bool progress) {
  return o.metric == Metric::kHamming ? TrainAkmIn<BinarySpace>(o, data, progress)
                                      : TrainAkmIn<FloatSpace>(o, data, progress);
}

std::unique_ptr<Vocabulary> ReadAkm(BinaryReader* r, Metric metric) {
  const int32_t rows = r->Get<int32_t>(), cols = r->Get<int32_t>();
  const int32_t trees = r->Get<int32_t>(), checks = r->Get<int32_t>();
  if (rows < 1 || cols < 1 || cols > 4096 || trees < 1 || trees > 64 || checks < 1) {
    r->Fail("invalid AKM header");
  }
  if (metric == Metric::kHamming) {
    auto v = r->GetVector<unsigned char>(kMaxWords * 64);
    if (v.size() != static_cast<size_t>(rows) * cols) r->Fail("centroid count mismatch");
    cv::Mat c(rows, cols, CV_8U, v.data());
    auto vocab = std::make_unique<AkmVocabulary<BinarySpace>>(metric, c.clone(), trees, checks);
    if (r->Get<uint8_t>() != 0) vocab->LoadIvf(r);
    return vocab;
  }
  auto v = r->GetVector<float>(kMaxWords * 128);
  if (v.size() != static_cast<size_t>(rows) * cols) r->Fail("centroid count mismatch");
  cv::Mat c(rows, cols, CV_32F, v.data());
  auto vocab = std::make_unique<AkmVocabulary<FloatSpace>>(metric, c.clone(), trees, checks);
  if (r->Get<uint8_t>() != 0) vocab->LoadIvf(r);
  return vocab;
}

}  // namespace vocabulary_internal
}  // namespace gtbow
