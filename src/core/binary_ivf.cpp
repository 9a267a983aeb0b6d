#include "binary_ivf.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <random>
#include <thread>

#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/parallel.h"
#include "hamming_distance.h"

namespace gtbow {

namespace {

std::vector<uint64_t> PackedQuery(const uint8_t* q, int bytes) {
  std::vector<uint64_t> out(bytes / 8);
  std::memcpy(out.data(), q, bytes);
  return out;
}

// Order of hits: by distance, ties by word id (independent of the order lists are visited).
inline bool Closer(const WordHit& a, const WordHit& b) {
  return a.distance != b.distance ? a.distance < b.distance : a.word < b.word;
}

}  // namespace

BinaryIvfIndex::BinaryIvfIndex(const cv::Mat& words, uint64_t seed, int threads)
    : bytes_(words.cols), chunks_(words.cols / 8) {
  if (words.type() != CV_8U || words.cols % 8 != 0 || words.rows < 1) {
    throw std::invalid_argument(
        "BinaryIvfIndex: words must be CV_8U rows of a multiple of 8 bytes");
  }
  threads = ThreadCount(threads);
  const int v = words.rows;
  const int nlist = std::max(1, static_cast<int>(std::lround(std::sqrt(static_cast<double>(v)))));
  std::mt19937_64 rng(seed ^ 0xb1f1f);
  std::vector<int> order(v);
  std::iota(order.begin(), order.end(), 0);
  std::shuffle(order.begin(), order.end(), rng);
  coarse_.create(nlist, bytes_, CV_8U);
  for (int c = 0; c < nlist; ++c) words.row(order[c]).copyTo(coarse_.row(c));
  std::vector<uint32_t> label(v, 0);
  const int bits = bytes_ * 8;
  // Each word's nearest centre (ties: the lower index), the centres packed first.
  auto assign = [&]() {
    coarse_packed_.clear();
    PackBinaryRows(coarse_.ptr<uint8_t>(), nlist, bytes_, &coarse_packed_);
    ParallelParts(static_cast<size_t>(v), threads, 256, [&](size_t b, size_t e, int) {
      std::vector<uint32_t> idx(nlist), dist(nlist);
      for (size_t i = b; i < e; ++i) {
        const auto q = PackedQuery(words.ptr<uint8_t>(static_cast<int>(i)), bytes_);
        HammingBelow(q.data(), coarse_packed_.data(), nlist, chunks_,
                     std::numeric_limits<uint32_t>::max(), idx.data(), dist.data());
        label[i] = static_cast<uint32_t>(std::min_element(dist.begin(), dist.end()) - dist.begin());
      }
    });
  };
  for (int it = 0; it < 10; ++it) {
    assign();
    // Bitwise-majority centres; an empty list restarts at a random word.
    std::vector<uint32_t> count(nlist, 0), ones(static_cast<size_t>(nlist) * bits, 0);
    for (int i = 0; i < v; ++i) {
      ++count[label[i]];
      const uint8_t* x = words.ptr<uint8_t>(i);
      uint32_t* o = ones.data() + static_cast<size_t>(label[i]) * bits;
      for (int k = 0; k < bits; ++k) o[k] += (x[k >> 3] >> (7 - (k & 7))) & 1;
    }
    std::uniform_int_distribution<int> pick(0, v - 1);
    for (int c = 0; c < nlist; ++c) {
      uint8_t* out = coarse_.ptr<uint8_t>(c);
      if (count[c] == 0) {
        words.row(pick(rng)).copyTo(coarse_.row(c));
        continue;
      }
      std::fill(out, out + bytes_, 0);
      const uint32_t* o = ones.data() + static_cast<size_t>(c) * bits;
      for (int k = 0; k < bits; ++k) {
        if (2 * o[k] > count[c]) out[k >> 3] |= static_cast<uint8_t>(1 << (7 - (k & 7)));
      }
    }
  }
  // Final lists: each word in the list of its nearest (final) centre.
  assign();
  offsets_.assign(nlist + 1, 0);
  for (uint32_t l : label) ++offsets_[l + 1];
  for (int c = 0; c < nlist; ++c) offsets_[c + 1] += offsets_[c];
  ids_.resize(v);
  std::vector<uint32_t> fill(offsets_.begin(), offsets_.end() - 1);
  for (int i = 0; i < v; ++i) ids_[fill[label[i]]++] = static_cast<uint32_t>(i);
  Pack(words);
}

void ReadIvfLists(BinaryReader* r, int32_t nlist, int words, const std::string& what,
                  std::vector<uint32_t>* offsets, std::vector<uint32_t>* ids) {
  *offsets = r->GetVector<uint32_t>(static_cast<uint64_t>(nlist) + 1);
  *ids = r->GetVector<uint32_t>(static_cast<uint64_t>(words));
  if (offsets->size() != static_cast<size_t>(nlist) + 1 ||
      ids->size() != static_cast<size_t>(words) || offsets->front() != 0 ||
      offsets->back() != static_cast<uint32_t>(words)) {
    r->Fail("invalid " + what + " lists");
  }
  for (int c = 0; c < nlist; ++c) {
    if ((*offsets)[c] > (*offsets)[c + 1]) r->Fail("invalid " + what + " lists");
  }
  std::vector<uint8_t> seen(words, 0);
  for (uint32_t id : *ids) {
    if (id >= static_cast<uint32_t>(words) || seen[id]++) r->Fail("invalid " + what + " word id");
  }
}

BinaryIvfIndex::BinaryIvfIndex(const cv::Mat& words, BinaryReader* r)
    : bytes_(words.cols), chunks_(words.cols / 8) {
  if (words.type() != CV_8U || words.cols % 8 != 0)
    r->Fail("binary IVF lists for words that are not binary");
  const int32_t nlist = r->Get<int32_t>();
  if (nlist < 1 || nlist > words.rows) r->Fail("invalid binary IVF header");
  auto coarse = r->GetVector<uint8_t>(static_cast<uint64_t>(nlist) * bytes_);
  if (coarse.size() != static_cast<size_t>(nlist) * bytes_) r->Fail("invalid binary IVF centres");
  ReadIvfLists(r, nlist, words.rows, "binary IVF", &offsets_, &ids_);
  coarse_ = cv::Mat(nlist, bytes_, CV_8U, coarse.data()).clone();
  PackBinaryRows(coarse_.ptr<uint8_t>(), nlist, bytes_, &coarse_packed_);
  Pack(words);
}

void BinaryIvfIndex::Pack(const cv::Mat& words) {
  const int nlist = coarse_.rows;
  packed_.clear();
  packed_offsets_.resize(nlist);
  scan_ids_.resize(ids_.size());
  scan_centre_.resize(ids_.size());
  std::vector<uint8_t> rows;
  std::vector<std::pair<uint32_t, uint32_t>> order;  // (distance to the centre, word id)
  for (int c = 0; c < nlist; ++c) {
    packed_offsets_[c] = packed_.size();
    const uint32_t b = offsets_[c], e = offsets_[c + 1];
    order.clear();
    for (uint32_t k = b; k < e; ++k) {
      const uint8_t* w = words.ptr<uint8_t>(static_cast<int>(ids_[k]));
      order.emplace_back(HammingDistance(w, coarse_.ptr<uint8_t>(c), bytes_), ids_[k]);
    }
    std::sort(order.begin(), order.end());
    rows.resize(static_cast<size_t>(e - b) * bytes_);
    for (uint32_t k = b; k < e; ++k) {
      const auto& [centre, id] = order[k - b];
      scan_ids_[k] = id;
      scan_centre_[k] = static_cast<uint16_t>(centre);
      std::memcpy(rows.data() + static_cast<size_t>(k - b) * bytes_,
                  words.ptr<uint8_t>(static_cast<int>(id)), bytes_);
    }
    PackBinaryRows(rows.data(), static_cast<int>(e - b), bytes_, &packed_);
  }
}

void BinaryIvfIndex::Save(BinaryWriter* w) const {
  w->Put<int32_t>(coarse_.rows);
  w->PutArray(coarse_.ptr<uint8_t>(), coarse_.total());
  w->PutVector(offsets_);
  w->PutVector(ids_);
}

void BinaryIvfIndex::Search(const cv::Mat& q, int r, int nprobe, std::vector<WordHit>* out) const {
  if (q.type() != CV_8U || q.cols != bytes_) {
    throw std::invalid_argument("BinaryIvfIndex::Search: descriptors must be CV_8U rows of " +
                                std::to_string(bytes_) + " bytes");
  }
  const int nlist = coarse_.rows;
  nprobe = std::max(1, std::min(nprobe, nlist));
  out->assign(static_cast<size_t>(q.rows) * r, WordHit{0, std::numeric_limits<float>::infinity()});
  std::vector<uint64_t> pq(static_cast<size_t>(q.rows) * chunks_);
  for (int i = 0; i < q.rows; ++i)
    std::memcpy(pq.data() + static_cast<size_t>(i) * chunks_, q.ptr<uint8_t>(i), bytes_);
  // list -> descriptors probing it, with their distance to its centre. Each descriptor's
  // nearest list (ties: the lower index) goes to `first`, the others to `rest`.
  struct Visit {
    int query;
    uint32_t centre;
  };
  std::vector<std::vector<Visit>> first(nlist), rest(nlist);
  std::vector<uint32_t> centre_dist(nlist);
  // The nprobe nearest lists by (distance, index), chosen by counting: the distances are at
  // most bytes * 8, so a histogram finds the cut-off distance, and at it the lowest indices
  // fill the remaining places. The same lists as a selection by sort, at a fraction of its
  // cost (it had been half of the search's own time).
  std::vector<uint32_t> hist(static_cast<size_t>(bytes_) * 8 + 1, 0);
  std::vector<int> chosen(nlist);
  for (int i = 0; i < q.rows; ++i) {
    HammingAll(pq.data() + static_cast<size_t>(i) * chunks_, coarse_packed_.data(), nlist, chunks_,
               centre_dist.data());
    // The nearest list, (distance, index) smallest, is always among the chosen.
    int nearest = 0;
    for (int c = 1; c < nlist; ++c) {
      if (centre_dist[c] < centre_dist[nearest]) nearest = c;
    }
    uint32_t cut = std::numeric_limits<uint32_t>::max();  // every list when nprobe == nlist
    int at_cut = 0;                                       // lists still taken at the cut-off
    if (nprobe < nlist) {
      for (int c = 0; c < nlist; ++c) ++hist[centre_dist[c]];
      int below = 0;
      for (cut = centre_dist[nearest]; below + static_cast<int>(hist[cut]) < nprobe; ++cut)
        below += static_cast<int>(hist[cut]);
      at_cut = nprobe - below;
      for (int c = 0; c < nlist; ++c) hist[centre_dist[c]] = 0;
    }
    int n = 0;  // without branches: about a third of the lists are taken, in no pattern
    for (int c = 0; c < nlist; ++c) {
      const uint32_t d = centre_dist[c];
      const int equal = d == cut ? 1 : 0;
      const int take = (d < cut ? 1 : 0) | (equal & (at_cut > 0 ? 1 : 0));
      at_cut -= equal;
      chosen[n] = c;
      n += take;
    }
    for (int k = 0; k < n; ++k) {
      const int c = chosen[k];
      (c == nearest ? first : rest)[c].push_back(Visit{i, centre_dist[c]});
    }
  }
  // Each list's words are read once for all the descriptors that probe it: the nearest lists
  // first, in full, then the others, each on the run of words the bound leaves.
  std::vector<uint32_t> idx, dist;
  uint64_t scanned = 0;
  for (const auto* visits : {&first, &rest}) {
    for (int list = 0; list < nlist; ++list) {
      if ((*visits)[list].empty()) continue;
      const uint32_t b = offsets_[list], e = offsets_[list + 1];
      idx.resize(e - b);
      dist.resize(e - b);
      const uint16_t* centre = scan_centre_.data() + b;
      for (const Visit& v : (*visits)[list]) {
        WordHit* best = out->data() + static_cast<size_t>(v.query) * r;  // sorted by Closer
        const float worst = best[r - 1].distance;
        // Distances up to the current worst (ties may still win on the word id).
        const bool open = std::isinf(worst);
        const uint32_t t = open ? 0 : static_cast<uint32_t>(worst);
        const uint32_t threshold = open ? std::numeric_limits<uint32_t>::max() : t + 1;
        uint32_t lo = 0, hi = e - b;
        if (bound_ && !open) {  // the words with |D - dc(w)| <= t
          const uint32_t from = v.centre > t ? v.centre - t : 0, to = v.centre + t;
          lo = static_cast<uint32_t>(std::lower_bound(centre, centre + (e - b), from) - centre);
          hi = static_cast<uint32_t>(std::upper_bound(centre + lo, centre + (e - b), to) - centre);
          if (lo >= hi) continue;
          lo -= lo % kBinaryBlockRows;  // scans start on a packed block
        }
        scanned += hi - lo;
        const uint64_t* blocks =
            packed_.data() + packed_offsets_[list] + static_cast<size_t>(lo) * chunks_;
        const int found =
            HammingBelow(pq.data() + static_cast<size_t>(v.query) * chunks_, blocks,
                         static_cast<int>(hi - lo), chunks_, threshold, idx.data(), dist.data());
        for (int j = 0; j < found; ++j) {
          const WordHit hit{scan_ids_[b + lo + idx[j]], static_cast<float>(dist[j])};
          if (!Closer(hit, best[r - 1])) continue;
          int m = r - 1;
          while (m > 0 && Closer(hit, best[m - 1])) {
            best[m] = best[m - 1];
            --m;
          }
          best[m] = hit;
        }
      }
    }
  }
  rows_scanned_.fetch_add(scanned, std::memory_order_relaxed);
}

}  // namespace gtbow
