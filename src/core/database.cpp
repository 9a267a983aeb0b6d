#include "ground_texture_bow/core/database.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <type_traits>

#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/file_util.h"

namespace gtbow {

namespace {

constexpr char kDatabaseMagic[8] = {'G', 'T', 'B', 'W', 'D', 'B', '\0', '\0'};
// 2: packed 8-byte entries in a framed file. 3: compact or precise entries, a header with its
// own checksum, entries at an aligned offset for memory mapping, a checksum per 64 MB chunk.
constexpr uint32_t kDatabaseVersion = 3;
constexpr size_t kFixedHeader = 32;           // magic, version, entry size, two sizes
constexpr size_t kEntriesAlignment = 64;
constexpr size_t kChecksumChunk = size_t{64} << 20;
constexpr float kTwoPi = static_cast<float>(2.0 * M_PI);
// Accumulator bytes per query block: about a quarter of this machine's per-core L2.
constexpr size_t kBlockBytes = size_t{1} << 20;

// Orientation stored in 8 bits: 256 steps per turn (1.4 degrees).
inline uint8_t QuantizeAngle(float a) {
  int q = static_cast<int>(std::lround(a / kTwoPi * 256.0f));
  return static_cast<uint8_t>(q & 255);
}

// Compact weights: code c stands for 2^(-c / 16), so 255 codes cover 2^-16 .. 1 with at most
// 2.2% relative error. Weights d_w * c_d lie in (0, 1] (normalised vectors, shares summing to 1).
constexpr float kLogStepsPerOctave = 16.0f;

struct LogWeightTable {
  float w[256];
  LogWeightTable() {
    for (int c = 0; c < 256; ++c) w[c] = std::exp2(-static_cast<float>(c) / kLogStepsPerOctave);
  }
};
const LogWeightTable kLogWeights;

}  // namespace

namespace detail {

// 6 bytes: image id << 8 | orientation (32 bits), keypoint id (8 bits), log weight (8 bits).
// Bytes, not fields: entries may sit at any address (a mapped file, an embedded blob).
struct CompactEntry {
  unsigned char b[6];
  static constexpr uint32_t kMaxKeypoints = 256;
  static CompactEntry Make(uint32_t image, uint8_t angle, uint32_t keypoint, float weight) {
    CompactEntry e;
    const uint32_t ia = image << 8 | angle;
    std::memcpy(e.b, &ia, 4);
    e.b[4] = static_cast<unsigned char>(keypoint);
    const float w = std::clamp(weight, 0.0f, 1.0f);
    const float c = w > 0.0f ? std::round(-std::log2(w) * kLogStepsPerOctave) : 255.0f;
    e.b[5] = static_cast<unsigned char>(std::clamp(c, 0.0f, 255.0f));
    return e;
  }
  uint32_t image() const {
    uint32_t v;
    std::memcpy(&v, b, 4);
    return v >> 8;
  }
  uint8_t angle() const { return b[0]; }
  uint16_t keypoint() const { return b[4]; }
  float weight() const { return kLogWeights.w[b[5]]; }
};
static_assert(sizeof(CompactEntry) == 6, "compact entries are 6 bytes");

// 8 bytes: image id << 8 | orientation (32 bits), keypoint id (16 bits), weight (16 bits, linear).
struct PreciseEntry {
  unsigned char b[8];
  static constexpr uint32_t kMaxKeypoints = 65536;
  static constexpr float kScale = 65535.0f;
  static PreciseEntry Make(uint32_t image, uint8_t angle, uint32_t keypoint, float weight) {
    PreciseEntry e;
    const uint32_t ia = image << 8 | angle;
    const uint16_t k = static_cast<uint16_t>(keypoint);
    // A present keypoint never weighs nothing.
    const long q = std::max(1L, std::lround(std::clamp(weight, 0.0f, 1.0f) * kScale));
    const uint16_t w = static_cast<uint16_t>(q);
    std::memcpy(e.b, &ia, 4);
    std::memcpy(e.b + 4, &k, 2);
    std::memcpy(e.b + 6, &w, 2);
    return e;
  }
  uint32_t image() const {
    uint32_t v;
    std::memcpy(&v, b, 4);
    return v >> 8;
  }
  uint8_t angle() const { return b[0]; }
  uint16_t keypoint() const {
    uint16_t k;
    std::memcpy(&k, b + 4, 2);
    return k;
  }
  float weight() const {
    uint16_t w;
    std::memcpy(&w, b + 6, 2);
    return static_cast<float>(w) * (1.0f / kScale);
  }
};
static_assert(sizeof(PreciseEntry) == 8, "precise entries are 8 bytes");

// Rows of entries: a read-only base segment (loaded) followed by a growable tail (added).
template <class E>
struct PostingIndex {
  struct Row {
    const E* base = nullptr;
    size_t base_count = 0;
    std::vector<E> tail;
  };
  explicit PostingIndex(uint32_t num_rows) : rows(num_rows) {}
  std::vector<Row> rows;
  std::shared_ptr<const void> keep_alive;  // owns the base segments (mapping or block)
  size_t base_bytes = 0;

  size_t Entries() const {
    size_t n = 0;
    for (const Row& r : rows) n += r.base_count + r.tail.size();
    return n;
  }
  size_t Bytes() const {
    size_t n = rows.capacity() * sizeof(Row) + base_bytes;
    for (const Row& r : rows) n += r.tail.capacity() * sizeof(E);
    return n;
  }
  // Calls f(pointer, count) for the row's base segment and its tail, in order.
  template <class F>
  void ForEachSegment(uint32_t row, F&& f) const {
    const Row& r = rows[row];
    if (r.base_count > 0) f(r.base, r.base_count);
    if (!r.tail.empty()) f(r.tail.data(), r.tail.size());
  }
};

}  // namespace detail

namespace {

using detail::CompactEntry;
using detail::PostingIndex;
using detail::PreciseEntry;

// Per-thread scratch for queries: an accumulator over one block of images x bins.
struct Scratch {
  std::vector<float> acc;
  std::vector<uint32_t> touched;  // images of the block (relative ids) with votes
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

inline const char* Bytes(const void* p) { return static_cast<const char*>(p); }

struct QueryPlan {
  int bins;
  bool ov;
  bool l1;
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
  const std::vector<uint8_t>& removed = *p.removed;
  const uint32_t first = b0 * p.block;
  std::vector<const E*> cur(segs.size());
  for (size_t j = 0; j < segs.size(); ++j) {
    cur[j] = std::lower_bound(segs[j].begin, segs[j].end, first,
                              [](const E& x, uint32_t img) { return x.image() < img; });
  }
  float* acc = s.acc.data();
  uint8_t* seen = s.seen.data();
  for (uint32_t b = b0; b < b1; ++b) {
    const uint32_t img0 = b * p.block;
    const uint32_t blen = std::min(p.n_images - img0, p.block);
    auto touch = [&](uint32_t rel) {
      if (!seen[rel]) {
        seen[rel] = 1;
        s.touched.push_back(rel);
      }
    };
    for (size_t j = 0; j < segs.size(); ++j) {
      const Segment<E>& g = segs[j];
      const E* x = cur[j];
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
          if (removed[img]) continue;
          touch(rel);
          acc[rel] += std::min(g.wq, w);
        }
      } else if (!p.ov) {
        for (; x < g.end; ++x) {
          const uint32_t img = x->image();
          const uint32_t rel = img - img0;
          if (rel >= blen) break;
          if (removed[img]) continue;
          touch(rel);
          acc[rel] += g.wq * x->weight();
        }
      } else {
        for (; x < g.end; ++x) {
          const uint32_t img = x->image();
          const uint32_t rel = img - img0;
          if (rel >= blen) break;
          if (removed[img]) continue;
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
    // Scores: the best bin of each touched image.
    for (uint32_t rel : s.touched) {
      float* a = acc + static_cast<size_t>(rel) * p.bins;
      int best = 0;
      for (int k = 1; k < p.bins; ++k) best = a[k] > a[best] ? k : best;
      top->Offer({a[best], img0 + rel, p.ov ? best : -1});
      std::fill(a, a + p.bins, 0.0f);
      seen[rel] = 0;
    }
    s.touched.clear();
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
  uint32_t block = 4096;
  while (static_cast<size_t>(block) * 2 * p.bins * sizeof(float) <= kBlockBytes) block *= 2;
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
      segs.push_back({data, data + count, static_cast<uint32_t>(kb), static_cast<uint32_t>(k), e.weight});
    });
  }

  const uint32_t n_blocks = (p.n_images + p.block - 1) / p.block;
  const uint32_t n_threads = std::max<uint32_t>(1, std::min<uint32_t>(threads, n_blocks));
  std::vector<TopN> tops(n_threads, TopN(top_n));
  if (n_threads == 1) {
    ScoreBlocks(segs, p, 0, n_blocks, &tops[0]);
  } else {
    std::vector<std::thread> pool;
    std::vector<std::exception_ptr> errors(n_threads);
    auto run = [&](uint32_t t) {
      try {
        ScoreBlocks(segs, p, n_blocks * t / n_threads, n_blocks * (t + 1) / n_threads, &tops[t]);
      } catch (...) {
        errors[t] = std::current_exception();
      }
    };
    for (uint32_t t = 1; t < n_threads; ++t) pool.emplace_back(run, t);
    run(0);
    for (auto& th : pool) th.join();
    for (auto& e : errors) {
      if (e) std::rethrow_exception(e);
    }
  }
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
          r.matches.push_back({q.keypoints[i].keypoint, y->keypoint(), w * q.keypoints[i].contribution});
        }
      }
    }
  }
  return results;
}

template <class E>
void AddToIndex(PostingIndex<E>* index, const BowVector& v, uint32_t id) {
  size_t k = 0;
  for (const BowEntry& e : v.entries) {
    auto& tail = index->rows[e.row].tail;
    while (k < v.keypoints.size() && v.keypoints[k].row < e.row) ++k;
    while (k < v.keypoints.size() && v.keypoints[k].row == e.row) {
      const KeypointEntry& ke = v.keypoints[k++];
      tail.push_back(E::Make(id, QuantizeAngle(v.angles[ke.keypoint]), ke.keypoint,
                             e.weight * ke.contribution));
    }
  }
}

// Writes the entries of every non-empty row (base, then tail) to `out`.
template <class E, class Out>
void WriteEntries(const PostingIndex<E>& index, Out&& out) {
  for (uint32_t i = 0; i < index.rows.size(); ++i) {
    index.ForEachSegment(i, [&](const E* data, size_t count) { out(data, count * sizeof(E)); });
  }
}

// The index's entries, written in chunks of kChecksumChunk bytes whose checksums are kept.
class ChunkedEntryWriter {
 public:
  explicit ChunkedEntryWriter(AtomicFileWriter* file) : file_(file) { buf_.reserve(kChecksumChunk); }
  void operator()(const void* data, size_t size) {
    const char* p = Bytes(data);
    while (size > 0) {
      const size_t n = std::min(size, kChecksumChunk - buf_.size());
      buf_.append(p, n);
      p += n;
      size -= n;
      if (buf_.size() == kChecksumChunk) Flush();
    }
  }
  // Writes the last partial chunk; returns the chunk checksums.
  const std::vector<uint64_t>& Finish() {
    if (!buf_.empty()) Flush();
    return sums_;
  }

 private:
  void Flush() {
    sums_.push_back(Checksum64(buf_.data(), buf_.size()));
    file_->Write(buf_.data(), buf_.size());
    buf_.clear();
  }
  AtomicFileWriter* file_;
  std::string buf_;
  std::vector<uint64_t> sums_;
};

}  // namespace

BowDatabase::BowDatabase(uint32_t num_rows, const BowOptions& options, uint64_t fingerprint)
    : num_rows_(num_rows), options_(options), fingerprint_(fingerprint) {
  options_.Check();
  if (num_rows == 0) throw std::invalid_argument("BowDatabase: num_rows must be positive");
  if (options_.compact_postings) {
    compact_ = std::make_unique<PostingIndex<CompactEntry>>(num_rows);
  } else {
    precise_ = std::make_unique<PostingIndex<PreciseEntry>>(num_rows);
  }
}

BowDatabase::~BowDatabase() = default;

void BowDatabase::set_query_threads(int threads) {
  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  query_threads_ = std::min(threads, 64);
}

uint32_t BowDatabase::Add(const BowVector& v) {
  for (const BowEntry& e : v.entries) {
    if (e.row >= num_rows_) throw std::invalid_argument("BowDatabase::Add: row out of range");
  }
  const uint32_t max_keypoints =
      options_.compact_postings ? CompactEntry::kMaxKeypoints : PreciseEntry::kMaxKeypoints;
  for (const KeypointEntry& ke : v.keypoints) {
    if (ke.keypoint >= v.angles.size()) {
      throw std::invalid_argument("BowDatabase::Add: keypoint without an orientation");
    }
    if (ke.keypoint >= max_keypoints) {
      throw std::invalid_argument("BowDatabase::Add: keypoint id " + std::to_string(ke.keypoint) +
                                  " does not fit compact postings (at most 256 keypoints per "
                                  "image); use bow.compact_postings: false");
    }
  }
  std::unique_lock<std::shared_mutex> lock(mutex_);
  if (removed_.size() >= kMaxImages) {
    throw std::length_error("BowDatabase::Add: the index holds at most " +
                            std::to_string(kMaxImages) + " image ids");
  }
  const uint32_t id = static_cast<uint32_t>(removed_.size());
  if (compact_) {
    AddToIndex(compact_.get(), v, id);
  } else {
    AddToIndex(precise_.get(), v, id);
  }
  removed_.push_back(0);
  ++live_;
  return id;
}

bool BowDatabase::Remove(uint32_t image) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  if (image >= removed_.size() || removed_[image]) return false;
  removed_[image] = 1;
  --live_;
  return true;
}

size_t BowDatabase::size() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return live_;
}

uint32_t BowDatabase::next_id() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return static_cast<uint32_t>(removed_.size());
}

size_t BowDatabase::MemoryBytes() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return removed_.capacity() + (compact_ ? compact_->Bytes() : precise_->Bytes());
}

size_t BowDatabase::num_entries() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return compact_ ? compact_->Entries() : precise_->Entries();
}

std::vector<QueryResult> BowDatabase::Query(const BowVector& q, size_t top_n,
                                            bool with_matches) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  if (compact_) {
    return QueryIndex(*compact_, num_rows_, options_, removed_, query_threads_, q, top_n, with_matches);
  }
  return QueryIndex(*precise_, num_rows_, options_, removed_, query_threads_, q, top_n, with_matches);
}

namespace {

// The index header (what Serialize writes before the entries): sizes, options, image flags
// and the table of non-empty rows.
template <class E>
std::string SerializeHeader(const PostingIndex<E>& index, uint32_t num_rows, uint64_t fingerprint,
                            const BowOptions& o, const std::vector<uint8_t>& removed,
                            uint64_t* entries_bytes) {
  BinaryWriter w;
  w.Put<uint32_t>(num_rows);
  w.Put<uint64_t>(fingerprint);
  w.Put<uint8_t>(static_cast<uint8_t>(o.size_binning));
  w.Put<int32_t>(o.num_size_bins);
  w.Put<int32_t>(o.soft_assignment);
  w.Put<double>(o.sigma);
  w.Put<uint8_t>(o.orientation_verification ? 1 : 0);
  w.Put<int32_t>(o.orientation_bins);
  w.Put<uint8_t>(static_cast<uint8_t>(o.scoring));
  w.Put<uint8_t>(o.compact_postings ? 1 : 0);
  w.Put<uint32_t>(sizeof(E));
  w.PutVector(removed);
  // Compressed sparse rows: the non-empty rows' indices and sizes; the entries follow.
  std::vector<uint32_t> rows, counts;
  uint64_t total = 0;
  for (uint32_t i = 0; i < num_rows; ++i) {
    const auto& r = index.rows[i];
    const uint64_t c = r.base_count + r.tail.size();
    if (c == 0) continue;
    rows.push_back(i);
    counts.push_back(static_cast<uint32_t>(c));
    total += c;
  }
  w.PutVector(rows);
  w.PutVector(counts);
  w.Put<uint64_t>(total);
  *entries_bytes = total * sizeof(E);
  return std::move(w.buffer());
}

uint64_t Get64(const char* p) {
  uint64_t v;
  std::memcpy(&v, p, 8);
  return v;
}

}  // namespace

std::string BowDatabase::Serialize() const {
  std::string out;
  SerializeTo([&out](uint64_t size) { out.reserve(size); },
              [&out](const void* data, size_t size) { out.append(Bytes(data), size); });
  return out;
}

void BowDatabase::SerializeTo(const std::function<void(uint64_t size)>& begin,
                              const std::function<void(const void* data, size_t size)>& write) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  uint64_t entries_bytes = 0;
  const std::string header =
      compact_ ? SerializeHeader(*compact_, num_rows_, fingerprint_, options_, removed_, &entries_bytes)
               : SerializeHeader(*precise_, num_rows_, fingerprint_, options_, removed_, &entries_bytes);
  const uint64_t hs = header.size();
  begin(8 + hs + entries_bytes);
  write(&hs, 8);
  write(header.data(), header.size());
  if (compact_) {
    WriteEntries(*compact_, write);
  } else {
    WriteEntries(*precise_, write);
  }
}

void BowDatabase::Deserialize(const char* data, size_t size, const std::string& source) {
  if (size < 8) throw std::runtime_error(source + ": database is truncated");
  const uint64_t hs = Get64(data);
  if (hs > size - 8) throw std::runtime_error(source + ": database header is truncated");
  // One owned block for the entries, which the rows then point into.
  const size_t n = size - 8 - hs;
  std::shared_ptr<char> block(new char[std::max<size_t>(n, 1)], std::default_delete<char[]>());
  if (n > 0) std::memcpy(block.get(), data + 8 + hs, n);
  const char* entries = block.get();
  Attach(data + 8, hs, entries, n, std::move(block), source);
}

void BowDatabase::Save(const std::filesystem::path& path) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  uint64_t entries_bytes = 0;
  const uint32_t entry_size = compact_ ? sizeof(CompactEntry) : sizeof(PreciseEntry);
  const std::string header =
      compact_ ? SerializeHeader(*compact_, num_rows_, fingerprint_, options_, removed_, &entries_bytes)
               : SerializeHeader(*precise_, num_rows_, fingerprint_, options_, removed_, &entries_bytes);
  std::string head(kFixedHeader, '\0');
  std::memcpy(&head[0], kDatabaseMagic, 8);
  std::memcpy(&head[8], &kDatabaseVersion, 4);
  std::memcpy(&head[12], &entry_size, 4);
  const uint64_t hs = header.size();
  std::memcpy(&head[16], &hs, 8);
  std::memcpy(&head[24], &entries_bytes, 8);
  head += header;
  const uint64_t head_sum = Checksum64(head.data(), head.size());
  head.append(reinterpret_cast<const char*>(&head_sum), 8);
  head.resize((head.size() + kEntriesAlignment - 1) / kEntriesAlignment * kEntriesAlignment, '\0');

  AtomicFileWriter file(path);
  file.Write(head);
  ChunkedEntryWriter chunks(&file);
  if (compact_) {
    WriteEntries(*compact_, chunks);
  } else {
    WriteEntries(*precise_, chunks);
  }
  const std::vector<uint64_t>& sums = chunks.Finish();
  file.Write(sums.data(), sums.size() * 8);
  const uint64_t table_sum = Checksum64(sums.data(), sums.size() * 8);
  file.Write(&table_sum, 8);
  file.Commit();
}

void BowDatabase::Load(const std::filesystem::path& path, int threads) {
  const std::string src = path.string();
  const auto map = MappedFile::Open(path);
  const char* d = map->data();
  const size_t size = map->size();
  auto fail = [&src](const std::string& what) { throw std::runtime_error(src + ": " + what); };
  if (size < kFixedHeader + 8) fail("not a database file (too short: " + std::to_string(size) + " bytes)");
  if (std::memcmp(d, kDatabaseMagic, 8) != 0) fail("not a database file (wrong magic number)");
  uint32_t version, entry_size;
  std::memcpy(&version, d + 8, 4);
  std::memcpy(&entry_size, d + 12, 4);
  if (version != kDatabaseVersion) {
    fail("database format version " + std::to_string(version) +
         " is not supported (this build reads version " + std::to_string(kDatabaseVersion) + ")");
  }
  const uint64_t hs = Get64(d + 16);
  const uint64_t entries_bytes = Get64(d + 24);
  if (hs > size - kFixedHeader - 8) fail("database file is truncated (header)");
  if (Checksum64(d, kFixedHeader + hs) != Get64(d + kFixedHeader + hs)) {
    fail("database file is corrupt (header checksum mismatch)");
  }
  const uint64_t at = (kFixedHeader + hs + 8 + kEntriesAlignment - 1) / kEntriesAlignment * kEntriesAlignment;
  const uint64_t n_chunks = (entries_bytes + kChecksumChunk - 1) / kChecksumChunk;
  if (entries_bytes > size || at > size - entries_bytes ||
      size - at - entries_bytes != n_chunks * 8 + 8) {
    fail("database file is truncated or has trailing bytes");
  }
  const char* table = d + at + entries_bytes;
  if (Checksum64(table, n_chunks * 8) != Get64(table + n_chunks * 8)) {
    fail("database file is corrupt (checksum table mismatch)");
  }
  // Every chunk of entries against its checksum, chunks shared among threads.
  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const size_t n_threads = std::max<size_t>(1, std::min<size_t>(threads, n_chunks));
  std::vector<uint64_t> bad(n_threads, UINT64_MAX);
  auto verify = [&](size_t t) {
    for (uint64_t c = t; c < n_chunks; c += n_threads) {
      const uint64_t off = c * kChecksumChunk;
      const size_t len = std::min<uint64_t>(kChecksumChunk, entries_bytes - off);
      if (Checksum64(d + at + off, len) != Get64(table + c * 8)) {
        bad[t] = c;
        return;
      }
    }
  };
  std::vector<std::thread> pool;
  for (size_t t = 1; t < n_threads; ++t) pool.emplace_back(verify, t);
  verify(0);
  for (auto& th : pool) th.join();
  for (uint64_t c : bad) {
    if (c != UINT64_MAX) {
      fail("database file is corrupt (checksum mismatch in entries at byte " +
           std::to_string(at + c * kChecksumChunk) + ")");
    }
  }
  if (entry_size != (options_.compact_postings ? sizeof(CompactEntry) : sizeof(PreciseEntry))) {
    fail("database has " + std::to_string(entry_size) + "-byte entries; these BoW options use " +
         (options_.compact_postings ? "compact 6-byte" : "precise 8-byte") + " entries");
  }
  Attach(d + kFixedHeader, hs, d + at, entries_bytes, map, src);
}

void BowDatabase::Attach(const char* header, size_t header_size, const char* entries,
                         size_t entries_size, std::shared_ptr<const void> keep_alive,
                         const std::string& source) {
  BinaryReader r(header, header_size, source);
  const uint32_t rows = r.Get<uint32_t>();
  const uint64_t fp = r.Get<uint64_t>();
  if (fp != fingerprint_) r.Fail("database was built with a different vocabulary");
  if (rows != num_rows_) {
    r.Fail("database has " + std::to_string(rows) + " rows, this vocabulary and size binning give " +
           std::to_string(num_rows_));
  }
  BowOptions o;
  o.size_binning = static_cast<SizeBinning>(r.Get<uint8_t>());
  o.num_size_bins = r.Get<int32_t>();
  o.soft_assignment = r.Get<int32_t>();
  o.sigma = r.Get<double>();
  o.orientation_verification = r.Get<uint8_t>() != 0;
  o.orientation_bins = r.Get<int32_t>();
  o.scoring = static_cast<Scoring>(r.Get<uint8_t>());
  o.compact_postings = r.Get<uint8_t>() != 0;
  const uint32_t entry_size = r.Get<uint32_t>();
  if (o.size_binning != options_.size_binning || o.num_size_bins != options_.num_size_bins ||
      o.soft_assignment != options_.soft_assignment || o.sigma != options_.sigma ||
      o.orientation_verification != options_.orientation_verification ||
      o.orientation_bins != options_.orientation_bins || o.scoring != options_.scoring ||
      o.compact_postings != options_.compact_postings) {
    r.Fail("database was built with different BoW options");
  }
  const size_t want_entry = options_.compact_postings ? sizeof(CompactEntry) : sizeof(PreciseEntry);
  if (entry_size != want_entry) r.Fail("entry size does not match the options");
  auto removed = r.GetVector<uint8_t>(kMaxImages);
  const auto index = r.GetVector<uint32_t>(num_rows_);
  const auto count = r.GetVector<uint32_t>(num_rows_);
  const uint64_t total = r.Get<uint64_t>();
  if (r.remaining() != 0) r.Fail("trailing bytes after the row table");
  if (count.size() != index.size()) r.Fail("row table is inconsistent");
  uint64_t sum = 0;
  for (size_t n = 0; n < index.size(); ++n) {
    if (index[n] >= num_rows_ || (n > 0 && index[n] <= index[n - 1])) r.Fail("row index out of order");
    if (count[n] == 0) r.Fail("empty row in the row table");
    sum += count[n];
  }
  if (sum != total || total * entry_size != entries_size) r.Fail("entry count does not match the rows");
  // Rows point into the entries block; an entry's image id is checked where it is read (a
  // query only visits ids below the image count), so the block is not scanned here.
  auto attach = [&](auto* fresh) {
    using E = std::remove_reference_t<decltype(fresh->rows[0].tail[0])>;
    const char* p = entries;
    for (size_t n = 0; n < index.size(); ++n) {
      auto& row = fresh->rows[index[n]];
      row.base = reinterpret_cast<const E*>(p);
      row.base_count = count[n];
      p += static_cast<size_t>(count[n]) * sizeof(E);
    }
    fresh->keep_alive = keep_alive;
    fresh->base_bytes = entries_size;
  };
  std::unique_ptr<PostingIndex<CompactEntry>> c;
  std::unique_ptr<PostingIndex<PreciseEntry>> pr;
  if (options_.compact_postings) {
    c = std::make_unique<PostingIndex<CompactEntry>>(num_rows_);
    attach(c.get());
  } else {
    pr = std::make_unique<PostingIndex<PreciseEntry>>(num_rows_);
    attach(pr.get());
  }
  size_t live = 0;
  for (uint8_t x : removed) live += x ? 0 : 1;
  std::unique_lock<std::shared_mutex> lock(mutex_);
  compact_.swap(c);
  precise_.swap(pr);
  removed_.swap(removed);
  live_ = live;
}

}  // namespace gtbow
