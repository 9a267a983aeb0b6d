// An inverted file over binary words (Hamming metric): the words are grouped around about
// sqrt(V) binary coarse centres (k-means under Hamming distance, bitwise-majority centres); a
// descriptor is compared exhaustively, with a SIMD popcount, with the words of the `nprobe`
// lists whose centres are nearest. With nprobe >= num_lists() the search is exact. Private to
// the core (vocabulary.cpp uses it for query-time word search and for k-means training).
//
// The triangle bound (set_bound, on by default here; see VocabularyOptions) gives the same answers
// with less work. Each list's words are kept sorted by their distance to the list's centre, dc(w).
// A descriptor q at distance D from that centre is at least |D - dc(w)| from w, so only the words
// with dc(w) in [D - t, D + t], a contiguous run, can be within the current r-th distance t. With
// or without it, each descriptor's own nearest list is scanned first, in full, so that t is tight
// for the rest (fewer hits to sort).
#pragma once

#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "ground_texture_bow/core/vocabulary.h"

namespace gtbow {

class BinaryReader;
class BinaryWriter;

// Reads the lists of an inverted file over `words` words in `nlist` lists, as both IVF indexes
// save them (offsets, then word ids), and checks them: offsets from 0 to `words`, not
// decreasing, every word id in range and listed once. Fails through `r` naming `what`.
void ReadIvfLists(BinaryReader* r, int32_t nlist, int words, const std::string& what,
                  std::vector<uint32_t>* offsets, std::vector<uint32_t>* ids);

class BinaryIvfIndex {
 public:
  // Groups the rows of `words` (V x bytes, CV_8U, bytes % 8 == 0) into lists; deterministic
  // for a seed.
  BinaryIvfIndex(const cv::Mat& words, uint64_t seed, int threads);
  // Restores lists saved by Save() for the same words; fails through `r` when inconsistent.
  BinaryIvfIndex(const cv::Mat& words, BinaryReader* r);

  void Save(BinaryWriter* w) const;
  int num_lists() const { return coarse_.rows; }

  // The r nearest words of each row of `q` (CV_8U) among the lists of its `nprobe` nearest
  // centres, sorted by (distance in bits, word id): out[i * r + j]. Fewer than r candidates
  // (tiny vocabularies) leave the rest at distance +inf.
  void Search(const cv::Mat& q, int r, int nprobe, std::vector<WordHit>* out) const;

  // The triangle bound on or off (vocabulary.ivf_bound, train_bound); the same answers either way.
  void set_bound(bool on) { bound_ = on; }
  bool bound() const { return bound_; }
  // Word distances computed by the Search calls so far (all threads), for benchmarks.
  uint64_t rows_scanned() const { return rows_scanned_.load(std::memory_order_relaxed); }

 private:
  void Pack(const cv::Mat& words);

  int bytes_;
  int chunks_;
  cv::Mat coarse_;                 // nlist x bytes binary centres
  std::vector<uint32_t> offsets_;  // list c holds positions [offsets_[c], offsets_[c + 1])
  std::vector<uint32_t> ids_;      // word id at each position (as saved)
  // The scan order: within each list, the words sorted by (distance to the centre, id).
  std::vector<uint32_t> scan_ids_;      // word id at each position of the scan order
  std::vector<uint16_t> scan_centre_;   // its distance to the list's centre, in bits
  std::vector<uint64_t> packed_;        // the words in scan order, packed per list
  std::vector<size_t> packed_offsets_;  // list c starts at packed_[packed_offsets_[c]]
  std::vector<uint64_t> coarse_packed_;
  bool bound_ = true;
  mutable std::atomic<uint64_t> rows_scanned_{0};
};

}  // namespace gtbow
