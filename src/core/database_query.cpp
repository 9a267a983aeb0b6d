// The inverted index's query engine: votes accumulated block by block over image ids (a
// block's accumulator fits in the core's cache), with orientation verification, on one or more
// threads; the top N kept in a heap. Results are identical for any thread count.
#include "ground_texture_bow/core/database.h"

#include <unistd.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <type_traits>

#include "database_entries.h"
#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/parallel.h"

namespace gtbow {
namespace {

using namespace database_internal;

constexpr size_t kPrefetchAhead = 8;  // segments

// Bytes of the accumulator of one block of images: a quarter of the core's L2 cache (the
// postings stream through it beside the accumulator), between 64 KB and 1 MB; 1 MB when the
// system does not say (and before December 2026 on every machine). GTBOW_QUERY_BLOCK_BYTES
// overrides it, for benchmarks. Answers do not depend on it (each image's votes add up in
// segment order whatever the blocks).
size_t BlockBytes() {
  static const size_t bytes = [] {
    if (const char* env = std::getenv("GTBOW_QUERY_BLOCK_BYTES"); env != nullptr && *env) {
      const long long v = std::atoll(env);
      if (v >= 4096) return static_cast<size_t>(v);
    }
    const long l2 = ::sysconf(_SC_LEVEL2_CACHE_SIZE);
    if (l2 <= 0) return size_t{1} << 20;
    return std::clamp(static_cast<size_t>(l2) / 4, size_t{64} << 10, size_t{1} << 20);
  }();
  return bytes;
}

// Whether any of the n floats at `a` is above `lo` (NaN is not).
constexpr size_t kCellsPerCheck = 16;
inline bool AnyAbove(const float* a, size_t n, float lo) {
#if defined(__SSE2__)
  if (n == kCellsPerCheck) {
    const __m128 l = _mm_set1_ps(lo);
    const __m128 m = _mm_or_ps(
        _mm_or_ps(_mm_cmpgt_ps(_mm_loadu_ps(a), l), _mm_cmpgt_ps(_mm_loadu_ps(a + 4), l)),
        _mm_or_ps(_mm_cmpgt_ps(_mm_loadu_ps(a + 8), l), _mm_cmpgt_ps(_mm_loadu_ps(a + 12), l)));
    return _mm_movemask_ps(m) != 0;
  }
#endif
  bool any = false;
  for (size_t i = 0; i < n; ++i) any |= a[i] > lo;
  return any;
}

// An image's best orientation bin of `bins` (the first of equal ones).
inline int BestBin(const float* a, int bins) {
  int best = 0;
  for (int k = 1; k < bins; ++k) best = a[k] > a[best] ? k : best;
  return best;
}

// Per-thread scratch for queries: an accumulator over one block of images x bins (all zero
// between blocks).
struct Scratch {
  std::vector<float> acc;
  std::vector<uint32_t> touched;  // images of the block (relative ids) with votes (not dense)
  std::vector<uint8_t> seen;
};

Scratch& ThreadScratch() {
  thread_local Scratch s;
  return s;
}

struct Candidate {
  float score;
  uint32_t image;
  int bin;
};

// Best first: higher score, then lower image id (a strict total order, so results do not
// depend on how the blocks were split among threads).
inline bool Better(const Candidate& a, const Candidate& b) {
  return a.score != b.score ? a.score > b.score : a.image < b.image;
}

// The `top_n` best candidates seen so far; the heap's front is the worst of them.
class TopN {
 public:
  explicit TopN(size_t n) : n_(n) { heap_.reserve(std::min<size_t>(n, 1 << 16)); }
  void Offer(const Candidate& c) {
    if (heap_.size() < n_) {
      heap_.push_back(c);
      std::push_heap(heap_.begin(), heap_.end(), Better);
    } else if (n_ > 0 && Better(c, heap_.front())) {
      std::pop_heap(heap_.begin(), heap_.end(), Better);
      heap_.back() = c;
      std::push_heap(heap_.begin(), heap_.end(), Better);
    }
  }
  std::vector<Candidate>& items() { return heap_; }
  // Offer takes no score at or below this: zero (images without votes are not offered) while
  // fewer than N are kept, then just below the worst kept score (a tie may still enter, by id).
  float EntryBound() const {
    if (n_ == 0) return std::numeric_limits<float>::infinity();
    if (heap_.size() < n_ || !(heap_.front().score > 0.0f)) return 0.0f;
    return std::nextafter(heap_.front().score, 0.0f);
  }

 private:
  size_t n_;
  std::vector<Candidate> heap_;
};

// The query's side of one row segment.
template <class E>
struct Segment {
  const E* begin;
  const E* end;
  uint32_t kb, ke;  // the query keypoint entries on this row
  float wq;         // the query's weight on this row
};

struct QueryPlan {
  int bins;
  bool ov;
  bool l1;
  bool any_removed;  // some image is removed: entries are checked against `removed`
  // Each block's scores read from the whole accumulator rather than from a list of the images
  // voted for, kept entry by entry (all but the sparsest queries: QueryIndex).
  bool dense;
  uint32_t n_images;
  uint32_t block;
  const std::vector<uint8_t>* removed;
  std::vector<float> qwc;     // per query keypoint entry: q_w * c_q
  std::vector<uint8_t> qang;  // per query keypoint entry: its quantised angle
  uint8_t bin_of[256];        // orientation bin of an angle difference
};

// Votes of blocks [b0, b1) into `top`.
template <class E>
void ScoreBlocks(const std::vector<Segment<E>>& segs, const QueryPlan& p, uint32_t b0, uint32_t b1,
                 TopN* top) {
  Scratch& s = ThreadScratch();
  const size_t acc_size = static_cast<size_t>(p.block) * p.bins;
  if (s.acc.size() < acc_size) s.acc.assign(acc_size, 0.0f);
  if (s.seen.size() < p.block) s.seen.assign(p.block, 0);
  s.touched.clear();
  uint8_t* seen = s.seen.data();
  const std::vector<uint8_t>& removed = *p.removed;
  const uint32_t first = b0 * p.block;
  std::vector<const E*> cur(segs.size());
  for (size_t j = 0; j < segs.size(); ++j) {
    cur[j] = std::lower_bound(segs[j].begin, segs[j].end, first,
                              [](const E& x, uint32_t img) { return x.image() < img; });
  }
  float* acc = s.acc.data();
  for (uint32_t b = b0; b < b1; ++b) {
    const uint32_t img0 = b * p.block;
    const uint32_t blen = std::min(p.n_images - img0, p.block);
    auto touch = [&](uint32_t rel) {
      if (!p.dense && !seen[rel]) {
        seen[rel] = 1;
        s.touched.push_back(rel);
      }
    };
    for (size_t j = 0; j < segs.size(); ++j) {
      const Segment<E>& g = segs[j];
      const E* x = cur[j];
      // The run of a segment a few ahead: its first cache lines are a miss each block (a block
      // reads hundreds of short runs, more streams than the hardware prefetcher follows).
      if (j + kPrefetchAhead < segs.size()) __builtin_prefetch(cur[j + kPrefetchAhead]);
      // Entries past the block end the scan; ids are in order within a segment (an id below
      // the block, possible only in a damaged file, also ends it: the scan stays in bounds).
      if (p.l1) {
        // DBoW2's L1 score needs each posting's d_w: the sum of its entries' weights.
        while (x < g.end) {
          const uint32_t img = x->image();
          const uint32_t rel = img - img0;
          if (rel >= blen) break;
          float w = 0.0f;
          for (; x < g.end && x->image() == img; ++x) w += x->weight();
          if (p.any_removed && removed[img]) continue;
          touch(rel);
          acc[rel] += std::min(g.wq, w);
        }
      } else if (!p.ov) {
        for (; x < g.end; ++x) {
          const uint32_t img = x->image();
          const uint32_t rel = img - img0;
          if (rel >= blen) break;
          if (p.any_removed && removed[img]) continue;
          touch(rel);
          acc[rel] += g.wq * x->weight();
        }
      } else {
        for (; x < g.end; ++x) {
          const uint32_t img = x->image();
          const uint32_t rel = img - img0;
          if (rel >= blen) break;
          if (p.any_removed && removed[img]) continue;
          touch(rel);
          float* a = acc + static_cast<size_t>(rel) * p.bins;
          const uint8_t ang = x->angle();
          const float w = x->weight();
          for (uint32_t i = g.kb; i < g.ke; ++i) {
            a[p.bin_of[static_cast<uint8_t>(ang - p.qang[i])]] += p.qwc[i] * w;
          }
        }
      }
      cur[j] = x;
    }
    // Scores: the best bin of each image with votes. Dense: every vote is positive, so an image
    // has votes exactly when its best bin is above zero; images that cannot enter the top N are
    // not offered, and the top N depends neither on them nor on the order of the offers.
    if (p.dense) {
      // The accumulator is read as one array, 16 cells at a time: only where a cell could enter
      // the top N (above zero, and not below the worst of a full top N) are its images scored.
      // Most images of a large map have no such cell. Each image is scored once, in id order.
      const size_t cells = static_cast<size_t>(blen) * p.bins;
      float lo = top->EntryBound();
      uint32_t next = 0;  // images below it are scored
      for (size_t c0 = 0; c0 < cells; c0 += kCellsPerCheck) {
        const size_t c1 = std::min(cells, c0 + kCellsPerCheck);
        if (!AnyAbove(acc + c0, c1 - c0, lo)) continue;
        for (uint32_t rel = std::max(next, static_cast<uint32_t>(c0 / p.bins));
             static_cast<size_t>(rel) * p.bins < c1; ++rel) {
          const float* a = acc + static_cast<size_t>(rel) * p.bins;
          const int best = BestBin(a, p.bins);
          if (a[best] > lo) {
            top->Offer({a[best], img0 + rel, p.ov ? best : -1});
            lo = top->EntryBound();
          }
          next = rel + 1;
        }
      }
      std::fill(acc, acc + cells, 0.0f);
    } else {
      for (uint32_t rel : s.touched) {
        float* a = acc + static_cast<size_t>(rel) * p.bins;
        const int best = BestBin(a, p.bins);
        top->Offer({a[best], img0 + rel, p.ov ? best : -1});
        std::fill(a, a + p.bins, 0.0f);
        seen[rel] = 0;
      }
      s.touched.clear();
    }
  }
}

template <class E>
std::vector<QueryResult> QueryIndex(const PostingIndex<E>& index, uint32_t num_rows,
                                    const BowOptions& options, const std::vector<uint8_t>& removed,
                                    int threads, const BowVector& q, size_t top_n,
                                    bool with_matches) {
  QueryPlan p;
  p.ov = options.orientation_verification;
  p.bins = p.ov ? options.orientation_bins : 1;
  p.l1 = options.scoring == Scoring::kDbowL1;
  p.n_images = static_cast<uint32_t>(removed.size());
  p.removed = &removed;
  p.any_removed = !removed.empty() && std::memchr(removed.data(), 1, removed.size()) != nullptr;
  uint32_t block = 1024;
  while (static_cast<size_t>(block) * 2 * p.bins * sizeof(float) <= BlockBytes()) block *= 2;
  p.block = block;
  for (int d = 0; d < 256; ++d) p.bin_of[d] = static_cast<uint8_t>(d * p.bins / 256);
  std::vector<uint8_t> qa(q.angles.size());
  for (size_t i = 0; i < qa.size(); ++i) qa[i] = QuantizeAngle(q.angles[i]);
  p.qwc.resize(q.keypoints.size());
  p.qang.resize(q.keypoints.size());
  for (size_t i = 0; i < q.keypoints.size(); ++i) {
    const uint16_t kp = q.keypoints[i].keypoint;
    p.qang[i] = kp < qa.size() ? qa[kp] : 0;
  }

  // The rows the query shares with the index, as segments.
  std::vector<Segment<E>> segs;
  segs.reserve(q.entries.size() * 2);
  size_t k = 0;
  for (const BowEntry& e : q.entries) {
    if (e.row >= num_rows) continue;
    while (k < q.keypoints.size() && q.keypoints[k].row < e.row) ++k;
    const size_t kb = k;
    while (k < q.keypoints.size() && q.keypoints[k].row == e.row) ++k;
    for (size_t i = kb; i < k; ++i) p.qwc[i] = e.weight * q.keypoints[i].contribution;
    index.ForEachSegment(e.row, [&](const E* data, size_t count) {
      segs.push_back(
          {data, data + count, static_cast<uint32_t>(kb), static_cast<uint32_t>(k), e.weight});
    });
  }

  // Dense when the query's postings hold more entries than a 32nd of the accumulator's cells.
  // Measured at 1,000,000 keyframes (`gtbow bench-scaling`, an AMD EPYC, December 2026): high
  // accuracy fills 0.50 of the cells, the fast preset 0.061, and the dense scan was faster at
  // both and down to 0.027 (queries cut short), the list of images voted for below about 0.018.
  // GTBOW_QUERY_DENSE=1 or 0 forces either scan (tests, measurements); the answers are the same.
  size_t entries = 0;
  for (const Segment<E>& g : segs) entries += static_cast<size_t>(g.end - g.begin);
  p.dense = 32 * entries > static_cast<size_t>(p.n_images) * static_cast<size_t>(p.bins);
  if (const char* d = std::getenv("GTBOW_QUERY_DENSE"); d != nullptr && *d) p.dense = *d == '1';
  const uint32_t n_blocks = (p.n_images + p.block - 1) / p.block;
  const uint32_t n_threads = std::max<uint32_t>(1, std::min<uint32_t>(threads, n_blocks));
  std::vector<TopN> tops(n_threads, TopN(top_n));
  RunTasks(static_cast<int>(n_threads), [&](int t) {
    const uint32_t u = static_cast<uint32_t>(t);
    ScoreBlocks(segs, p, n_blocks * u / n_threads, n_blocks * (u + 1) / n_threads, &tops[u]);
  });
  std::vector<Candidate> all;
  for (TopN& t : tops) all.insert(all.end(), t.items().begin(), t.items().end());
  std::sort(all.begin(), all.end(), Better);
  if (all.size() > top_n) all.resize(top_n);
  std::vector<QueryResult> results(all.size());
  for (size_t i = 0; i < all.size(); ++i) {
    results[i].image = all[i].image;
    results[i].score = all[i].score;
    results[i].orientation_bin = all[i].bin;
  }
  if (!with_matches || results.empty()) return results;

  // Second pass, restricted to the results: the keypoint pairs of each winning bin. Each
  // segment is searched for the results' images (ids are in order within a segment).
  std::vector<uint32_t> by_image(results.size());
  for (size_t i = 0; i < by_image.size(); ++i) by_image[i] = static_cast<uint32_t>(i);
  std::sort(by_image.begin(), by_image.end(),
            [&](uint32_t a, uint32_t b) { return results[a].image < results[b].image; });
  for (const Segment<E>& g : segs) {
    const E* x = g.begin;
    for (uint32_t ri : by_image) {
      QueryResult& r = results[ri];
      x = std::lower_bound(x, g.end, r.image,
                           [](const E& y, uint32_t img) { return y.image() < img; });
      for (const E* y = x; y < g.end && y->image() == r.image; ++y) {
        const float w = g.wq * y->weight();
        for (uint32_t i = g.kb; i < g.ke; ++i) {
          if (p.ov && p.bin_of[static_cast<uint8_t>(y->angle() - p.qang[i])] != r.orientation_bin) {
            continue;
          }
          r.matches.push_back(
              {q.keypoints[i].keypoint, y->keypoint(), w * q.keypoints[i].contribution});
        }
      }
    }
  }
  return results;
}

}  // namespace

std::vector<QueryResult> BowDatabase::Query(const BowVector& q, size_t top_n,
                                            bool with_matches) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  if (compact_) {
    return QueryIndex(*compact_, num_rows_, options_, removed_, query_threads_, q, top_n,
                      with_matches);
  }
  return QueryIndex(*precise_, num_rows_, options_, removed_, query_threads_, q, top_n,
                    with_matches);
}

}  // namespace gtbow
