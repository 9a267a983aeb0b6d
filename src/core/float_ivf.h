// The inverted file over float words (l2 and l2_bytes vocabularies): about sqrt(V) coarse
// centres, each with the words nearest to it; a query searches the nprobe nearest lists. Exact
// when every list is searched. Internal to the engine (src/core/vocabulary_akm.cpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <random>
#include <vector>

#include <opencv2/core.hpp>

#include "binary_ivf.h"
#include "byte_distance.h"
#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/parallel.h"
#include "ground_texture_bow/core/vocabulary.h"
#include "vocabulary_internal.h"

namespace gtbow {
namespace vocabulary_internal {

// Squared L2 distances from `q` to `n` contiguous rows of dimension `d` (float_ivf.cpp).
void SquaredDistances(const float* __restrict q, const float* __restrict rows, int n, int d,
                      float* __restrict out);

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
      ParallelParts(static_cast<size_t>(v), ThreadCount(threads), 64, [&](size_t b, size_t e, int) {
        std::vector<float> dist(nlist);
        for (size_t i = b; i < e; ++i) {
          SquaredDistances(words.ptr<float>(static_cast<int>(i)), coarse_.ptr<float>(), nlist, d_,
                           dist.data());
          label[i] =
              static_cast<uint32_t>(std::min_element(dist.begin(), dist.end()) - dist.begin());
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
    for (int i = 0; i < words.rows; ++i)
      words.row(static_cast<int>(ids_[i])).copyTo(vectors_.row(i));
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
      for (int c = 0; c < nlist; ++c)
        key[c] = (static_cast<uint64_t>(cd[c]) << 32) | static_cast<uint32_t>(c);
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
            pq.data() + packed_size * i, packed_.data() + packed_offsets_[list],
            static_cast<int>(e - b), d_, best[k - 1].dist, row.data(), dist.data());
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
        (*out)[static_cast<size_t>(i) * r + j] = {hits[j].word,
                                                  std::sqrt(std::max(0.0f, hits[j].distance))};
      }
    }
  }

 private:
  static uint8_t ToByte(float x) {
    return static_cast<uint8_t>(std::clamp(std::lround(x), 0L, 255L));
  }
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
  cv::Mat coarse_;                      // nlist x d centres
  std::vector<uint32_t> offsets_;       // list c holds rows [offsets_[c], offsets_[c + 1])
  std::vector<uint32_t> ids_;           // word id of each row of vectors_
  cv::Mat vectors_;                     // V x d word vectors grouped by list
  std::vector<int16_t> packed_;         // vectors_ rounded to bytes, packed (l2_bytes only)
  std::vector<size_t> packed_offsets_;  // list c starts at packed_[packed_offsets_[c]]
  std::vector<int16_t> coarse_packed_;  // coarse_ rounded to bytes, packed (l2_bytes only)
};

}  // namespace vocabulary_internal
}  // namespace gtbow
