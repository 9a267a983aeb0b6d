#include "ground_texture_bow/core/vocabulary.h"

// FLANN 1.9 headers are not self-contained: this order compiles. (flann::Index<> itself is not
// used: it instantiates the LSH index, whose serialisation does not compile.)
#include <flann/general.h>
#include <flann/util/random.h>
#include <flann/algorithms/dist.h>
#include <flann/algorithms/center_chooser.h>
#include <flann/algorithms/hierarchical_clustering_index.h>
#include <flann/algorithms/kdtree_index.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>
#include <numeric>
#include <random>
#include <stdexcept>
#include <thread>

#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/progress.h"
#include "binary_ivf.h"
#include "byte_distance.h"
#include "hamming_distance.h"

namespace gtbow {

namespace {

constexpr char kVocabularyMagic[8] = {'G', 'T', 'B', 'W', 'V', 'O', 'C', '\0'};
// 2: IVF lists stored with AKM words; 3: the extractor the vocabulary was trained with (and
// binary IVF lists for Hamming words). Version 2 files are read.
constexpr uint32_t kVocabularyVersion = 3;
constexpr uint32_t kOldestVocabularyVersion = 2;

int ThreadCount(int requested) {
  return requested > 0 ? requested
                       : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

// Runs f(begin, end) over [0, n) split into contiguous chunks, one per thread.
template <typename F>
void ParallelChunks(size_t n, int threads, F&& f) {
  threads = std::max(1, std::min<int>(threads, static_cast<int>(n / 64) + 1));
  std::vector<std::thread> pool;
  const size_t chunk = (n + threads - 1) / threads;
  for (int t = 0; t < threads; ++t) {
    const size_t b = t * chunk, e = std::min(n, b + chunk);
    if (b >= e) break;
    pool.emplace_back([&f, b, e, t]() { f(b, e, t); });
  }
  for (auto& th : pool) th.join();
}

// FLANN's randomisation uses the C library's global generator: serialise index builds so that
// a seed gives the same trees whatever else runs.
std::mutex& FlannSeedMutex() {
  static std::mutex m;
  return m;
}

// ---------------------------------------------------------------------------------------------
// Descriptor spaces: how to compare and average descriptors.

// Float vectors under L2 (SIFT, or ORB bytes taken as 32 numbers).
struct FloatSpace {
  using Element = float;
  using FlannDistance = flann::L2<float>;
  using FlannIndex = flann::KDTreeIndex<FlannDistance>;
  static float Distance(const float* a, const float* b, int d) {
    float s = 0;
    for (int i = 0; i < d; ++i) {
      const float x = a[i] - b[i];
      s += x * x;
    }
    return std::sqrt(s);
  }
  // FLANN reports squared L2.
  static float FromFlann(float d) { return std::sqrt(std::max(0.0f, d)); }
};

// Packed binary descriptors under Hamming distance.
struct BinarySpace {
  using Element = unsigned char;
  using FlannDistance = flann::Hamming<unsigned char>;
  using FlannIndex = flann::HierarchicalClusteringIndex<FlannDistance>;
  static float Distance(const unsigned char* a, const unsigned char* b, int d) {
    int s = 0;
    for (int i = 0; i < d; ++i) s += __builtin_popcount(static_cast<unsigned>(a[i] ^ b[i]));
    return static_cast<float>(s);
  }
  static float FromFlann(unsigned int d) { return static_cast<float>(d); }
};

// Converts descriptors to the element type of the metric's space.
cv::Mat ToSpace(const cv::Mat& desc, Metric metric) {
  if (metric == Metric::kHamming) {
    if (desc.type() != CV_8U) throw std::invalid_argument("hamming vocabulary needs CV_8U descriptors");
    return desc.isContinuous() ? desc : desc.clone();
  }
  if (metric == Metric::kL2Bytes && desc.type() != CV_8U) {
    throw std::invalid_argument("l2_bytes vocabulary needs CV_8U (ORB) descriptors");
  }
  if (metric == Metric::kL2 && desc.type() != CV_32F) {
    throw std::invalid_argument("l2 vocabulary needs CV_32F (SIFT) descriptors");
  }
  cv::Mat f;
  desc.convertTo(f, CV_32F);
  return f;
}

// ---------------------------------------------------------------------------------------------
// IVF: an inverted file over the words (float vectors under L2).

// Not under ThreadSanitizer: the clones' ifunc resolvers run during relocation, before the
// TSan runtime is up, and crash once instrumented.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_THREAD__)
#define GTBOW_VOCAB_CLONE __attribute__((target_clones("avx2", "default")))
#else
#define GTBOW_VOCAB_CLONE
#endif

void UpdateCentroids(const cv::Mat& data, const std::vector<uint32_t>& label, cv::Mat* centroids,
                     std::mt19937_64& rng, int threads);

// Squared L2 distances from `q` to `n` contiguous rows of dimension `d`. Eight partial sums
// in a fixed order let the compiler vectorise without reassociating (results are identical on
// every CPU).
GTBOW_VOCAB_CLONE
void SquaredDistances(const float* __restrict q, const float* __restrict rows, int n, int d,
                      float* __restrict out) {
  const int d8 = d & ~7;
  for (int i = 0; i < n; ++i) {
    const float* r = rows + static_cast<size_t>(i) * d;
    float acc[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    for (int k = 0; k < d8; k += 8) {
      for (int j = 0; j < 8; ++j) {
        const float x = q[k + j] - r[k + j];
        acc[j] += x * x;
      }
    }
    float s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (int k = d8; k < d; ++k) {
      const float x = q[k] - r[k];
      s += x * x;
    }
    out[i] = s;
  }
}

class IvfIndex {
 public:
  // Groups the rows of `words` (V x d, CV_32F) around about sqrt(V) coarse centres.
  // `bytes`: the words are means of byte vectors (l2_bytes), searched in integer arithmetic.
  IvfIndex(const cv::Mat& words, bool bytes, uint64_t seed, int threads) : d_(words.cols) {
    const int v = words.rows;
    const int nlist = std::max(1, static_cast<int>(std::lround(std::sqrt(static_cast<double>(v)))));
    std::mt19937_64 rng(seed ^ 0x1f1f);
    std::vector<int> order(v);
    std::iota(order.begin(), order.end(), 0);
    std::shuffle(order.begin(), order.end(), rng);
    coarse_.create(nlist, d_, CV_32F);
    for (int c = 0; c < nlist; ++c) words.row(order[c]).copyTo(coarse_.row(c));
    std::vector<uint32_t> label(v);
    for (int it = 0; it < 8; ++it) {
      ParallelChunks(static_cast<size_t>(v), ThreadCount(threads), [&](size_t b, size_t e, int) {
        std::vector<float> dist(nlist);
        for (size_t i = b; i < e; ++i) {
          SquaredDistances(words.ptr<float>(static_cast<int>(i)), coarse_.ptr<float>(), nlist, d_, dist.data());
          label[i] = static_cast<uint32_t>(std::min_element(dist.begin(), dist.end()) - dist.begin());
        }
      });
      UpdateCentroids(words, label, &coarse_, rng, 1);
    }
    // Lists: word ids grouped by coarse centre, with their vectors stored contiguously.
    offsets_.assign(nlist + 1, 0);
    for (uint32_t l : label) ++offsets_[l + 1];
    for (int c = 0; c < nlist; ++c) offsets_[c + 1] += offsets_[c];
    ids_.resize(v);
    std::vector<uint32_t> fill(offsets_.begin(), offsets_.end() - 1);
    for (int i = 0; i < v; ++i) ids_[fill[label[i]]++] = static_cast<uint32_t>(i);
    vectors_.create(v, d_, CV_32F);
    for (int i = 0; i < v; ++i) words.row(static_cast<int>(ids_[i])).copyTo(vectors_.row(i));
    if (bytes && d_ % 2 == 0) MakeByteCopies();  // packed pairs of dimensions
  }

  // Restores an index saved by Save() for the words `words`; throws via `r` when inconsistent.
  IvfIndex(const cv::Mat& words, bool bytes, BinaryReader* r) : d_(words.cols) {
    const int32_t nlist = r->Get<int32_t>();
    if (nlist < 1 || nlist > words.rows) r->Fail("invalid IVF header");
    auto coarse = r->GetVector<float>(static_cast<uint64_t>(nlist) * d_);
    if (coarse.size() != static_cast<size_t>(nlist) * d_) r->Fail("invalid IVF centres");
    ReadIvfLists(r, nlist, words.rows, "IVF", &offsets_, &ids_);
    coarse_ = cv::Mat(nlist, d_, CV_32F, coarse.data()).clone();
    vectors_.create(words.rows, d_, CV_32F);
    for (int i = 0; i < words.rows; ++i) words.row(static_cast<int>(ids_[i])).copyTo(vectors_.row(i));
    if (bytes && d_ % 2 == 0) MakeByteCopies();  // packed pairs of dimensions
  }

  bool bytes() const { return !coarse_packed_.empty(); }

  void Save(BinaryWriter* w) const {
    w->Put<int32_t>(coarse_.rows);
    w->PutArray(coarse_.ptr<float>(), coarse_.total());
    w->PutVector(offsets_);
    w->PutVector(ids_);
  }

  // The r nearest words of each row of `q` among the lists of its `nprobe` nearest centres.
  // Work is grouped by list, so each list's vectors are read from memory once per batch
  // rather than once per descriptor (the scan is memory-bound otherwise).
  void Search(const cv::Mat& q, int r, int nprobe, std::vector<WordHit>* out) const {
    const int nlist = coarse_.rows;
    nprobe = std::min(nprobe, nlist);
    out->assign(static_cast<size_t>(q.rows) * r, WordHit{0, std::numeric_limits<float>::max()});
    std::vector<float> cd(nlist);
    std::vector<int> probe(nlist);
    // list -> descriptors probing it
    std::vector<std::vector<int>> visitors(nlist);
    for (int i = 0; i < q.rows; ++i) {
      SquaredDistances(q.ptr<float>(i), coarse_.ptr<float>(), nlist, d_, cd.data());
      std::iota(probe.begin(), probe.end(), 0);
      std::partial_sort(probe.begin(), probe.begin() + nprobe, probe.end(),
                        [&](int a, int b) { return cd[a] != cd[b] ? cd[a] < cd[b] : a < b; });
      for (int p = 0; p < nprobe; ++p) visitors[probe[p]].push_back(i);
    }
    std::vector<float> dist;
    for (int list = 0; list < nlist; ++list) {
      if (visitors[list].empty()) continue;
      const uint32_t b = offsets_[list], e = offsets_[list + 1];
      dist.resize(e - b);
      for (int i : visitors[list]) {
        SquaredDistances(q.ptr<float>(i), vectors_.ptr<float>(static_cast<int>(b)),
                         static_cast<int>(e - b), d_, dist.data());
        WordHit* best = out->data() + static_cast<size_t>(i) * r;  // sorted, squared for now
        for (uint32_t k = 0; k < e - b; ++k) {
          const WordHit hit{ids_[b + k], dist[k]};
          if (!Closer(hit, best[r - 1])) continue;
          int j = r - 1;
          while (j > 0 && Closer(hit, best[j - 1])) {
            best[j] = best[j - 1];
            --j;
          }
          best[j] = hit;
        }
      }
    }
    for (auto& h : *out) h.distance = std::sqrt(std::max(0.0f, h.distance));
  }

  // Search() for byte descriptors (CV_8U rows) of an l2_bytes vocabulary. Lists are scanned
  // with words rounded to bytes in exact integer arithmetic (a quarter of the memory traffic of
  // floats, and SIMD-friendly); the best r + kRerank words of each descriptor are then ranked
  // again by their exact float distance, so rounding cannot reorder the reported words unless
  // it pushes a word past kRerank others.
  void SearchBytes(const cv::Mat& q, int r, int nprobe, std::vector<WordHit>* out) const {
    constexpr int kRerank = 4;
    const int nlist = coarse_.rows;
    const int k = r + kRerank;
    nprobe = std::min(nprobe, nlist);
    struct Cand {
      int32_t dist;
      uint32_t pos;  // row of vectors_
    };
    std::vector<Cand> cand(static_cast<size_t>(q.rows) * k,
                           Cand{std::numeric_limits<int32_t>::max(), 0});
    std::vector<int32_t> cd(nlist);
    std::vector<uint32_t> cid(nlist);
    std::vector<uint64_t> key(nlist);
    std::vector<std::vector<int>> visitors(nlist);
    // Each descriptor packed once for the SIMD scans.
    const size_t packed_size = static_cast<size_t>(kPackedBlockRows) * d_;
    std::vector<int16_t> pq(packed_size * q.rows);
    for (int i = 0; i < q.rows; ++i) PackQuery(q.ptr<uint8_t>(i), d_, pq.data() + packed_size * i);
    for (int i = 0; i < q.rows; ++i) {
      PackedSquaredDistancesBelow(pq.data() + packed_size * i, coarse_packed_.data(), nlist, d_,
                                  std::numeric_limits<int32_t>::max(), cid.data(), cd.data());
      // The set of the nprobe nearest lists (their order does not matter: lists are visited
      // in index order below). Keys pack distance and list so that ties resolve by index.
      for (int c = 0; c < nlist; ++c) key[c] = (static_cast<uint64_t>(cd[c]) << 32) | static_cast<uint32_t>(c);
      std::nth_element(key.begin(), key.begin() + (nprobe - 1), key.end());
      for (int p = 0; p < nprobe; ++p) visitors[static_cast<uint32_t>(key[p])].push_back(i);
    }
    std::vector<int32_t> dist;
    std::vector<uint32_t> row;
    for (int list = 0; list < nlist; ++list) {
      if (visitors[list].empty()) continue;
      const uint32_t b = offsets_[list], e = offsets_[list + 1];
      dist.resize(e - b);
      row.resize(e - b);
      for (int i : visitors[list]) {
        Cand* best = cand.data() + static_cast<size_t>(i) * k;  // sorted by (dist, pos)
        const int found = PackedSquaredDistancesBelow(
            pq.data() + packed_size * i, packed_.data() + packed_offsets_[list], static_cast<int>(e - b), d_,
            best[k - 1].dist, row.data(), dist.data());
        for (int j = 0; j < found; ++j) {
          if (dist[j] >= best[k - 1].dist) continue;  // ties: the earlier row stays
          const Cand c{dist[j], b + row[j]};
          int m = k - 1;
          while (m > 0 && c.dist < best[m - 1].dist) {
            best[m] = best[m - 1];
            --m;
          }
          best[m] = c;
        }
      }
    }
    // Exact re-ranking of each descriptor's candidates.
    out->assign(static_cast<size_t>(q.rows) * r, WordHit{});
    std::vector<float> qf(d_);
    std::vector<WordHit> hits;
    for (int i = 0; i < q.rows; ++i) {
      const uint8_t* qi = q.ptr<uint8_t>(i);
      for (int t = 0; t < d_; ++t) qf[t] = qi[t];
      hits.clear();
      const Cand* best = cand.data() + static_cast<size_t>(i) * k;
      for (int m = 0; m < k; ++m) {
        if (best[m].dist == std::numeric_limits<int32_t>::max()) break;
        float d2;
        SquaredDistances(qf.data(), vectors_.ptr<float>(static_cast<int>(best[m].pos)), 1, d_, &d2);
        hits.push_back({ids_[best[m].pos], d2});
      }
      std::sort(hits.begin(), hits.end(), Closer);
      for (int j = 0; j < r && j < static_cast<int>(hits.size()); ++j) {
        (*out)[static_cast<size_t>(i) * r + j] = {hits[j].word, std::sqrt(std::max(0.0f, hits[j].distance))};
      }
    }
  }

 private:
  static uint8_t ToByte(float x) { return static_cast<uint8_t>(std::clamp(std::lround(x), 0L, 255L)); }
  void MakeByteCopies() {
    std::vector<uint8_t> rows(vectors_.total());
    const float* v = vectors_.ptr<float>();
    for (size_t i = 0; i < rows.size(); ++i) rows[i] = ToByte(v[i]);
    packed_.clear();
    packed_offsets_.resize(coarse_.rows);
    for (int c = 0; c < coarse_.rows; ++c) {
      packed_offsets_[c] = packed_.size();
      PackRows(rows.data() + static_cast<size_t>(offsets_[c]) * d_,
               static_cast<int>(offsets_[c + 1] - offsets_[c]), d_, &packed_);
    }
    std::vector<uint8_t> coarse(coarse_.total());
    const float* c = coarse_.ptr<float>();
    for (size_t i = 0; i < coarse.size(); ++i) coarse[i] = ToByte(c[i]);
    coarse_packed_.clear();
    PackRows(coarse.data(), coarse_.rows, d_, &coarse_packed_);
  }

  // Order of hits: by distance, ties by word id (independent of the list visiting order).
  static bool Closer(const WordHit& a, const WordHit& b) {
    return a.distance != b.distance ? a.distance < b.distance : a.word < b.word;
  }

  int d_;
  cv::Mat coarse_;                 // nlist x d centres
  std::vector<uint32_t> offsets_;  // list c holds rows [offsets_[c], offsets_[c + 1])
  std::vector<uint32_t> ids_;      // word id of each row of vectors_
  cv::Mat vectors_;                // V x d word vectors grouped by list
  std::vector<int16_t> packed_;          // vectors_ rounded to bytes, packed (l2_bytes only)
  std::vector<size_t> packed_offsets_;   // list c starts at packed_[packed_offsets_[c]]
  std::vector<int16_t> coarse_packed_;   // coarse_ rounded to bytes, packed (l2_bytes only)
};

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
      }
    }
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
      ivf_->SearchBytes(descriptors.isContinuous() ? descriptors : descriptors.clone(), r, nprobe_, out);
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
      uint32_t arg = 0;
      for (int c = 0; c < centroids_.rows; ++c) {
        const float d = Space::Distance(q.ptr<E>(i), centroids_.ptr<E>(c), q.cols);
        if (d < best) {
          best = d;
          arg = static_cast<uint32_t>(c);
        }
      }
      (*out)[i] = {arg, best};
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
          data, flann::HierarchicalClusteringIndexParams(32, flann::FLANN_CENTERS_KMEANSPP, trees_, 100));
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
  std::unique_ptr<IvfIndex> ivf_;          // float spaces
  std::unique_ptr<BinaryIvfIndex> bivf_;   // Hamming
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
    ParallelChunks(static_cast<size_t>(data.rows), threads, [&](size_t b, size_t e, int t) {
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
void SeedPlusPlus(const cv::Mat& data, const std::vector<int>& members, int k,
                  std::mt19937_64& rng, cv::Mat* centers);

template <typename Space>
std::unique_ptr<Vocabulary> TrainAkm(const VocabularyOptions& o, const cv::Mat& data,
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
      ivf = std::make_unique<BinaryIvfIndex>(centroids, o.seed + static_cast<uint64_t>(it), threads);
    } else {
      current = std::make_unique<AkmVocabulary<Space>>(o.metric, centroids.clone(), o.num_trees, train_checks);
    }
    std::atomic<size_t> changed{0};
    ParallelChunks(static_cast<size_t>(data.rows), threads, [&](size_t b, size_t e, int) {
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
              Space::Distance(rows.ptr<E>(static_cast<int>(i)), centroids.ptr<E>(static_cast<int>(old)),
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

// ---------------------------------------------------------------------------------------------
// HKM: a DBoW2-style vocabulary tree (Nister & Stewenius 2006; Galvez-Lopez & Tardos 2012).

template <typename Space>
class HkmVocabulary : public Vocabulary {
 public:
  using E = typename Space::Element;
  struct Node {
    int32_t first_child = -1;  // index of the first child in nodes_, -1 for a leaf
    int32_t num_children = 0;
    int32_t word = -1;         // word id of a leaf
  };

  HkmVocabulary(Metric metric, std::vector<Node> nodes, cv::Mat centroids)
      : metric_(metric), nodes_(std::move(nodes)), centroids_(std::move(centroids)) {
    num_words_ = 0;
    for (const auto& n : nodes_) num_words_ += n.word >= 0 ? 1 : 0;
    fingerprint_ = Checksum64(centroids_.data, centroids_.total() * centroids_.elemSize()) ^
                   Checksum64(nodes_.data(), nodes_.size() * sizeof(Node));
  }

  VocabularyKind kind() const override { return VocabularyKind::kHkm; }
  Metric metric() const override { return metric_; }
  uint32_t size() const override { return num_words_; }
  int max_neighbours() const override { return 1; }

  void AssignExact(const cv::Mat& descriptors, std::vector<WordHit>* out) const override {
    Assign(descriptors, 1, out);  // the tree defines the words: descent is exact
  }

  void Assign(const cv::Mat& descriptors, int r, std::vector<WordHit>* out) const override {
    if (r != 1) throw std::invalid_argument("an HKM vocabulary assigns one word per descriptor (r = 1)");
    const cv::Mat q = ToSpace(descriptors, metric_);
    out->assign(static_cast<size_t>(q.rows), WordHit{});
    if (q.rows > 0 && q.cols != centroids_.cols) {
      throw std::invalid_argument("Assign: descriptor length does not match the vocabulary");
    }
    for (int i = 0; i < q.rows; ++i) {
      const E* x = q.ptr<E>(i);
      int32_t node = 0;
      float best = 0.0f;
      while (nodes_[node].first_child >= 0) {
        const Node& n = nodes_[node];
        int32_t arg = n.first_child;
        best = std::numeric_limits<float>::max();
        for (int32_t c = n.first_child; c < n.first_child + n.num_children; ++c) {
          const float dist = Space::Distance(x, centroids_.ptr<E>(c), q.cols);
          if (dist < best) {
            best = dist;
            arg = c;
          }
        }
        node = arg;
      }
      (*out)[i] = {static_cast<uint32_t>(nodes_[node].word), best};
    }
  }

 protected:
  void SaveWords(BinaryWriter* w) const override {
    w->PutVector(nodes_);
    w->Put<int32_t>(centroids_.rows);
    w->Put<int32_t>(centroids_.cols);
    w->PutArray(centroids_.ptr<E>(), centroids_.total());
  }

 private:
  Metric metric_;
  std::vector<Node> nodes_;  // node 0 is the root; children are contiguous
  cv::Mat centroids_;        // one row per node (the root's row is unused)
  uint32_t num_words_;
};

// Greedy k-means++ seeding (Arthur & Vassilvitskii 2007, with the 2 + log k local trials of
// scikit-learn): each new centre is the best of several rows drawn with probability
// proportional to their squared distance to the nearest centre so far.
template <typename Space>
void SeedPlusPlus(const cv::Mat& data, const std::vector<int>& members, int k,
                  std::mt19937_64& rng, cv::Mat* centers) {
  using E = typename Space::Element;
  const int d = data.cols;
  const int n = static_cast<int>(members.size());
  centers->create(k, d, data.type());
  const int trials = 2 + static_cast<int>(std::log(static_cast<double>(k)));
  std::vector<double> dmin(n), cand(n), best_cand(n);
  std::uniform_int_distribution<int> first(0, n - 1);
  data.row(members[first(rng)]).copyTo(centers->row(0));
  double potential = 0;
  for (int i = 0; i < n; ++i) {
    const double dd = Space::Distance(data.ptr<E>(members[i]), centers->ptr<E>(0), d);
    dmin[i] = dd * dd;
    potential += dmin[i];
  }
  for (int c = 1; c < k; ++c) {
    double best_potential = std::numeric_limits<double>::max();
    int best = 0;
    for (int t = 0; t < trials; ++t) {
      std::uniform_real_distribution<double> u(0, potential);
      double x = u(rng);
      int pick = n - 1;
      for (int i = 0; i < n; ++i) {
        x -= dmin[i];
        if (x <= 0) {
          pick = i;
          break;
        }
      }
      double pot = 0;
      for (int i = 0; i < n; ++i) {
        const double dd = Space::Distance(data.ptr<E>(members[i]), data.ptr<E>(members[pick]), d);
        cand[i] = std::min(dmin[i], dd * dd);
        pot += cand[i];
      }
      if (pot < best_potential) {
        best_potential = pot;
        best = pick;
        best_cand.swap(cand);
      }
    }
    data.row(members[best]).copyTo(centers->row(c));
    dmin.swap(best_cand);
    best_cand.resize(n);
    potential = best_potential;
  }
}

// k-means++ seeding then Lloyd iterations on the rows `members` of `data`; returns the k
// centroids and each member's cluster.
template <typename Space>
void KMeansPP(const cv::Mat& data, const std::vector<int>& members, int k, std::mt19937_64& rng,
              cv::Mat* centers, std::vector<int>* assign) {
  using E = typename Space::Element;
  const int d = data.cols;
  const int n = static_cast<int>(members.size());
  SeedPlusPlus<Space>(data, members, k, rng, centers);
  assign->assign(n, 0);
  cv::Mat sub(n, d, data.type());
  for (int i = 0; i < n; ++i) data.row(members[i]).copyTo(sub.row(i));
  for (int it = 0; it < 10; ++it) {
    bool changed = false;
    for (int i = 0; i < n; ++i) {
      float best = std::numeric_limits<float>::max();
      int arg = 0;
      for (int c = 0; c < k; ++c) {
        const float dist = Space::Distance(sub.ptr<E>(i), centers->ptr<E>(c), d);
        if (dist < best) {
          best = dist;
          arg = c;
        }
      }
      if ((*assign)[i] != arg || it == 0) changed = changed || (*assign)[i] != arg;
      (*assign)[i] = arg;
    }
    std::vector<uint32_t> label(assign->begin(), assign->end());
    UpdateCentroids(sub, label, centers, rng, 1);
    if (!changed && it > 0) break;
  }
}

template <typename Space>
std::unique_ptr<Vocabulary> TrainHkm(const VocabularyOptions& o, const cv::Mat& data,
                                     bool progress) {
  using Node = typename HkmVocabulary<Space>::Node;
  const int k = o.hkm_branching;
  std::mt19937_64 rng(o.seed);
  std::vector<Node> nodes(1);
  std::vector<cv::Mat> rows(1, cv::Mat::zeros(1, data.cols, data.type()));
  // Breadth-first: (node, depth, members).
  struct Task {
    int node;
    int depth;
    std::vector<int> members;
  };
  std::vector<Task> queue;
  std::vector<int> all(data.rows);
  std::iota(all.begin(), all.end(), 0);
  queue.push_back({0, 0, std::move(all)});
  int32_t words = 0;
  ProgressBar bar("hkm levels", static_cast<size_t>(o.hkm_depth), progress);
  int last_depth = 0;
  for (size_t qi = 0; qi < queue.size(); ++qi) {
    Task task = std::move(queue[qi]);
    if (task.depth > last_depth) {
      bar.Add(task.depth - last_depth);
      last_depth = task.depth;
    }
    const int n = static_cast<int>(task.members.size());
    cv::Mat centers;
    std::vector<int> assign;
    int kk;
    if (n <= k) {
      // Too few descriptors to split: each becomes its own child (DBoW2 does the same).
      kk = n;
      centers.create(n, data.cols, data.type());
      for (int i = 0; i < n; ++i) data.row(task.members[i]).copyTo(centers.row(i));
      assign.resize(n);
      std::iota(assign.begin(), assign.end(), 0);
    } else {
      kk = k;
      KMeansPP<Space>(data, task.members, k, rng, &centers, &assign);
    }
    const int first = static_cast<int>(nodes.size());
    nodes[task.node].first_child = first;
    nodes[task.node].num_children = kk;
    std::vector<std::vector<int>> child_members(kk);
    for (int i = 0; i < n; ++i) child_members[assign[i]].push_back(task.members[i]);
    for (int c = 0; c < kk; ++c) {
      nodes.push_back(Node{});
      rows.push_back(centers.row(c).clone());
    }
    for (int c = 0; c < kk; ++c) {
      const int id = first + c;
      const bool leaf = task.depth + 1 >= o.hkm_depth || child_members[c].size() <= 1;
      if (leaf) {
        nodes[id].word = words++;
      } else {
        queue.push_back({id, task.depth + 1, std::move(child_members[c])});
      }
    }
    task.members.clear();
    task.members.shrink_to_fit();
  }
  bar.Finish();
  cv::Mat centroids;
  cv::vconcat(rows, centroids);
  return std::make_unique<HkmVocabulary<Space>>(o.metric, std::move(nodes), std::move(centroids));
}

}  // namespace

AnnIndex ParseAnnIndex(const std::string& name) {
  if (name == "flann") return AnnIndex::kFlann;
  if (name == "ivf") return AnnIndex::kIvf;
  throw std::invalid_argument("unknown ann index '" + name + "' (valid: flann, ivf)");
}

std::string AnnIndexName(AnnIndex index) { return index == AnnIndex::kFlann ? "flann" : "ivf"; }

VocabularyKind ParseVocabularyKind(const std::string& name) {
  if (name == "akm") return VocabularyKind::kAkm;
  if (name == "hkm") return VocabularyKind::kHkm;
  throw std::invalid_argument("unknown vocabulary kind '" + name + "' (valid: akm, hkm)");
}

std::string VocabularyKindName(VocabularyKind kind) {
  return kind == VocabularyKind::kAkm ? "akm" : "hkm";
}

Metric ParseMetric(const std::string& name) {
  if (name == "l2_bytes") return Metric::kL2Bytes;
  if (name == "hamming") return Metric::kHamming;
  if (name == "l2") return Metric::kL2;
  throw std::invalid_argument("unknown metric '" + name + "' (valid: l2_bytes, hamming, l2)");
}

std::string MetricName(Metric metric) {
  switch (metric) {
    case Metric::kL2Bytes: return "l2_bytes";
    case Metric::kHamming: return "hamming";
    case Metric::kL2: return "l2";
  }
  return "?";
}

void VocabularyOptions::Check() const {
  auto need = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("vocabulary: ") + what);
  };
  need(num_words >= 2, "num_words must be >= 2");
  need(kmeans_iterations >= 1, "kmeans_iterations must be >= 1");
  need(kmeans_stop_fraction >= 0.0 && kmeans_stop_fraction < 1.0, "kmeans_stop_fraction must be in [0, 1)");
  need(kmeans_min_iterations >= 1, "kmeans_min_iterations must be >= 1");
  need(train_checks >= 0, "train_checks must be >= 0 (0: max(2000, V / 5))");
  need(train_nprobe >= 0, "train_nprobe must be >= 0 (0: all lists)");
  need(num_trees >= 1 && num_trees <= 64, "num_trees must be in 1..64");
  need(checks >= 1, "checks must be >= 1");
  need(nprobe >= 1, "nprobe must be >= 1");
  need(hkm_branching >= 2, "hkm_branching must be >= 2");
  need(hkm_depth >= 1 && hkm_depth <= 12, "hkm_depth must be in 1..12");
  need(threads >= 0, "threads must be >= 0");
}

std::unique_ptr<Vocabulary> TrainVocabulary(const VocabularyOptions& o, const cv::Mat& descriptors,
                                            const std::vector<uint32_t>& image_of, bool progress) {
  o.Check();
  if (descriptors.empty()) throw std::invalid_argument("TrainVocabulary: no descriptors");
  if (image_of.size() != static_cast<size_t>(descriptors.rows)) {
    throw std::invalid_argument("TrainVocabulary: image_of must have one entry per descriptor");
  }
  const cv::Mat data = ToSpace(descriptors, o.metric);
  std::unique_ptr<Vocabulary> vocab;
  const bool binary = o.metric == Metric::kHamming;
  if (o.kind == VocabularyKind::kAkm) {
    vocab = binary ? TrainAkm<BinarySpace>(o, data, progress) : TrainAkm<FloatSpace>(o, data, progress);
  } else {
    vocab = binary ? TrainHkm<BinarySpace>(o, data, progress) : TrainHkm<FloatSpace>(o, data, progress);
  }
  // idf = log(N / n_w) over the training images (paper §III: standard tf-idf).
  std::vector<WordHit> hits;
  vocab->Assign(descriptors, 1, &hits);
  // Document frequency: distinct training images per word.
  std::vector<std::pair<uint32_t, uint32_t>> word_image(hits.size());
  for (size_t i = 0; i < hits.size(); ++i) word_image[i] = {hits[i].word, image_of[i]};
  std::sort(word_image.begin(), word_image.end());
  word_image.erase(std::unique(word_image.begin(), word_image.end()), word_image.end());
  std::vector<uint32_t> df(vocab->size(), 0);
  for (const auto& wi : word_image) ++df[wi.first];
  std::vector<uint32_t> images(image_of);
  std::sort(images.begin(), images.end());
  const auto num_images =
      static_cast<uint32_t>(std::unique(images.begin(), images.end()) - images.begin());
  std::vector<float> idf(vocab->size(), 0.0f);
  for (uint32_t w = 0; w < vocab->size(); ++w) {
    if (df[w] > 0) idf[w] = static_cast<float>(std::log(static_cast<double>(num_images) / df[w]));
  }
  vocab->set_idf(std::move(idf));
  vocab->set_search(o.ann, o.nprobe);
  return vocab;
}

void Vocabulary::Save(const std::filesystem::path& path) const {
  BinaryWriter w;
  w.Put<uint8_t>(static_cast<uint8_t>(kind()));
  w.Put<uint8_t>(static_cast<uint8_t>(metric()));
  w.Put<uint32_t>(size());
  w.PutVector(idf_);
  w.PutVector(size_thresholds_);
  w.PutString(extractor_);
  SaveWords(&w);
  WriteFramedFile(path, kVocabularyMagic, kVocabularyVersion, w.buffer());
}

namespace {

std::unique_ptr<Vocabulary> MakeVocabularyFromFile(BinaryReader* r, VocabularyKind kind,
                                                   Metric metric) {
  constexpr uint64_t kMaxWords = 100000000;
  if (kind == VocabularyKind::kAkm) {
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
  auto read_tree = [&](auto space_tag) -> std::unique_ptr<Vocabulary> {
    using Space = decltype(space_tag);
    using V = HkmVocabulary<Space>;
    auto nodes = r->GetVector<typename V::Node>(kMaxWords * 2);
    const int32_t rows = r->Get<int32_t>(), cols = r->Get<int32_t>();
    auto v = r->GetVector<typename Space::Element>(kMaxWords * 256);
    if (rows < 1 || cols < 1 || v.size() != static_cast<size_t>(rows) * cols ||
        nodes.size() != static_cast<size_t>(rows)) {
      r->Fail("invalid HKM tree");
    }
    // Children come after their parent (so a descent ends), every leaf has a word, the words
    // are 0..W-1 once each (they index the idf table), inner nodes have none.
    std::vector<uint8_t> seen(nodes.size(), 0);
    size_t leaves = 0;
    for (size_t i = 0; i < nodes.size(); ++i) {
      const auto& n = nodes[i];
      if (n.first_child >= 0) {
        if (n.num_children < 1 || static_cast<size_t>(n.first_child) <= i ||
            static_cast<int64_t>(n.first_child) + n.num_children > rows || n.word >= 0) {
          r->Fail("invalid HKM tree node " + std::to_string(i));
        }
        continue;
      }
      if (n.word < 0 || static_cast<size_t>(n.word) >= nodes.size() || seen[n.word]++) {
        r->Fail("HKM leaf " + std::to_string(i) + " has an invalid or repeated word id");
      }
      ++leaves;
    }
    for (size_t w = 0; w < leaves; ++w) {
      if (!seen[w]) r->Fail("HKM word ids are not 0.." + std::to_string(leaves - 1));
    }
    cv::Mat c(rows, cols, metric == Metric::kHamming ? CV_8U : CV_32F, v.data());
    return std::make_unique<V>(metric, std::move(nodes), c.clone());
  };
  return metric == Metric::kHamming ? read_tree(BinarySpace{}) : read_tree(FloatSpace{});
}

}  // namespace

std::unique_ptr<Vocabulary> Vocabulary::Load(const std::filesystem::path& path) {
  const FramedPayload payload =
      ReadFramedFile(path, kVocabularyMagic, kOldestVocabularyVersion, kVocabularyVersion, "vocabulary");
  BinaryReader r(payload.data(), payload.size(), path.string());
  const uint8_t kind = r.Get<uint8_t>(), metric = r.Get<uint8_t>();
  if (kind > 1 || metric > 2) r.Fail("unknown vocabulary kind or metric");
  const uint32_t words = r.Get<uint32_t>();
  auto idf = r.GetVector<float>(100000000);
  auto thresholds = r.GetVector<float>(256);
  std::string extractor;
  if (payload.version() >= 3) extractor = r.GetString(1u << 16);
  auto vocab = MakeVocabularyFromFile(&r, static_cast<VocabularyKind>(kind), static_cast<Metric>(metric));
  if (vocab->size() != words || idf.size() != words) r.Fail("word count mismatch");
  if (r.remaining() != 0) r.Fail("unexpected trailing data");
  vocab->set_idf(std::move(idf));
  vocab->set_size_thresholds(std::move(thresholds));
  vocab->set_extractor(std::move(extractor));
  return vocab;
}

}  // namespace gtbow
