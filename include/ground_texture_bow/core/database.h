// The inverted index of the paper (§II-E, Fig. 2): one row per (word, size bin); a posting
// holds the image id, the word's weight in that image's vector, and the image's keypoints on
// that row with their orientation and contributing weight. Queries verify orientation
// consistency inside the index (§II-B): every (query keypoint, database keypoint) pair on a
// shared row votes q_w * d_w * c_q * c_d into the orientation-difference bin of its image, and
// the image's score is its best bin.
//
// Layout: a row is an array of keypoint entries, nothing per posting; a posting is the run of
// consecutive entries of one image, and runs are in image-id order. An entry packs the image id
// (24 bits, so at most 2^24 image ids), the keypoint's orientation (8 bits, 1.4 degree steps),
// the keypoint id and d_w * c_d. Compact entries (BowOptions::compact_postings, the default)
// take 6 bytes: an 8-bit keypoint id and an 8-bit weight on a log scale (2^(-1/16) steps, at
// most 2.2% off); precise entries take 8 bytes: 16-bit keypoint id, 16-bit linear weight.
// Since the c_d of a posting sum to 1, d_w is the sum of its entries' weights; the plain dot
// product and the DBoW2 L1 score are computed from that.
//
// Storage: each row is a read-only base segment (from Load or a map file: a memory-mapped
// file, so loading does not copy the entries; from Deserialize: one owned block), the entries
// a map save has sealed while it writes them (none otherwise), and a growable tail that Add()
// appends to; each kind is one array over the rows, so a save swaps arrays, not rows.
// Insertion costs the same at any size.
//
// Queries accumulate votes block by block over image ids (a block's accumulator fits in the
// core's cache), each row scanned once with a cursor, and may split the blocks over several
// threads (set_query_threads). Results are identical for any thread count.
//
// Thread safety: any number of concurrent Query() calls with one writer. Add(), Remove() and
// Load() take the index's mutex exclusively; Query(), size() and Save() take it shared.
// Freeze() and Rebase() take it exclusively for a few swaps; WriteFrozen() takes it not at all.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <shared_mutex>
#include <string>
#include <vector>

#include "ground_texture_bow/core/bow.h"

namespace gtbow {

namespace detail {
struct CompactEntry;
struct PreciseEntry;
template <class E>
struct PostingIndex;
}  // namespace detail

// A query keypoint matched to a database keypoint on a shared row, in the winning bin.
struct MatchPair {
  uint16_t query_keypoint = 0;
  uint16_t database_keypoint = 0;
  float weight = 0.0f;  // q_w * d_w * c_q * c_d: its vote
};

struct QueryResult {
  uint32_t image = 0;              // database image id (as returned by Add)
  float score = 0.0f;              // similarity: best-bin vote (OV) or dot / L1 score
  int orientation_bin = -1;        // winning bin, -1 without orientation verification
  std::vector<MatchPair> matches;  // pairs voting in the winning bin (or all shared-row pairs)
};

class BowDatabase {
 public:
  // An empty index with `num_rows` rows (S x V) scoring as `options` says. The fingerprint
  // identifies the vocabulary; Load() refuses a file made with another one.
  BowDatabase(uint32_t num_rows, const BowOptions& options, uint64_t vocabulary_fingerprint);
  ~BowDatabase();
  BowDatabase(const BowDatabase&) = delete;
  BowDatabase& operator=(const BowDatabase&) = delete;

  // The largest number of image ids an index hands out.
  static constexpr uint32_t kMaxImages = 1u << 24;

  // Inserts an image's BoW vector; returns its id (0, 1, 2, ...). Cost is independent of the
  // database size. Throws std::length_error once kMaxImages ids have been handed out.
  uint32_t Add(const BowVector& vector);
  // Removes an image; its id is not reused. Returns false for an unknown or removed id.
  bool Remove(uint32_t image);
  // Whether an id was handed out and not removed.
  bool Contains(uint32_t image) const;
  // The `top_n` most similar images, best first. With `with_matches` each result lists the
  // matched keypoint pairs of its winning orientation bin.
  std::vector<QueryResult> Query(const BowVector& query, size_t top_n,
                                 bool with_matches = true) const;

  size_t size() const;       // images present
  uint32_t next_id() const;  // ids handed out so far
  uint32_t num_rows() const { return num_rows_; }
  const BowOptions& options() const { return options_; }
  size_t MemoryBytes() const;  // rows, entries (mapped, owned, spare capacity) and image flags
  size_t MappedBytes() const;  // the part of MemoryBytes in a memory-mapped file
  size_t num_entries() const;  // keypoint entries in all rows
  // Threads one query may use (blocks of image ids are shared among them); 1 by default.
  void set_query_threads(int threads);
  int query_threads() const { return query_threads_; }

  // Writes the index atomically: magic, version, a header with its checksum, the entries at a
  // 64-byte aligned offset, and a checksum per 64 MB of entries. Streams; no copy in memory.
  void Save(const std::filesystem::path& path) const;
  // Replaces the contents with a saved index, memory-mapping its entries (no copy; the file
  // may be replaced or removed afterwards). Every checksum is verified (on `threads` threads,
  // 0 = all cores). Throws std::runtime_error naming the file when it is damaged, of another
  // version, or made with another vocabulary or other options; the current contents are kept.
  void Load(const std::filesystem::path& path, int threads = 0);
  // The payload of Save (no framing), for files that embed an index (the ROS map file), and
  // its inverse; Deserialize has Load's checks and guarantees, naming `source` in errors.
  std::string Serialize() const;
  void Deserialize(const char* data, size_t size, const std::string& source);
  // Serialize's bytes streamed: `begin` gets their total size, then `write` the bytes in
  // pieces, all under one lock (no copy of the index).
  void SerializeTo(const std::function<void(uint64_t size)>& begin,
                   const std::function<void(const void* data, size_t size)>& write) const;

  // Writing the index into a map file while it keeps serving (Localizer::Save):
  // - PrepareFreeze() then Freeze() seal what the index holds (the tails become the sealed
  //   entries: two swaps under the lock); DescribeFrozen() then gives Serialize's header for those
  //   entries and their size, without the lock;
  // - WriteFrozen() streams them without the lock: Add and Query go on, touching only tails;
  // - Rebase() then points every row's frozen entries at the written copy (`entries`, in a
  //   memory-mapped file kept alive by `keep_alive`) and frees their heap copies.
  // One saver at a time, in this order, and no Load() meanwhile. Without Rebase (a failed
  // save) the sealed entries stay in the heap and the next Freeze() includes them.
  struct Frozen {
    uint32_t images = 0;           // ids handed out at the freeze
    std::vector<uint8_t> removed;  // their flags
    std::string header;            // DescribeFrozen's
    uint64_t entries_bytes = 0;
    std::shared_ptr<void> spare;  // PrepareFreeze's empty tails
  };
  // Makes the empty tails that replace the sealed ones (outside any lock: O(rows) allocation).
  Frozen PrepareFreeze() const;
  void Freeze(Frozen* frozen);
  void DescribeFrozen(Frozen* frozen) const;
  void WriteFrozen(const std::function<void(const void* data, size_t size)>& write) const;
  // Returns how long it held the lock, milliseconds. What the swap replaced (the sealed heap
  // copies, the old base array and mapping) goes to *replaced, for the caller to free where it
  // chooses (a save frees it on its low-priority thread), or is freed here when it is null.
  double Rebase(const Frozen& frozen, const char* entries, std::shared_ptr<const void> keep_alive,
                std::shared_ptr<void>* replaced = nullptr);
  // Attaches an index embedded in a memory-mapped file (the map file): Serialize's header and
  // entries at addresses that `keep_alive` keeps valid; nothing is copied. Load's checks, but
  // not its checksums (the embedding file has its own); errors name `source`.
  void AttachMapped(const char* header, size_t header_size, const char* entries,
                    size_t entries_size, std::shared_ptr<const void> keep_alive,
                    const std::string& source);

 private:
  void Attach(const char* header, size_t header_size, const char* entries, size_t entries_size,
              std::shared_ptr<const void> keep_alive, const std::string& source, bool mapped);

  uint32_t num_rows_;
  BowOptions options_;
  uint64_t fingerprint_;
  int query_threads_ = 1;
  mutable std::shared_mutex mutex_;
  // One of the two, as options_.compact_postings says; guarded by mutex_.
  std::unique_ptr<detail::PostingIndex<detail::CompactEntry>> compact_;
  std::unique_ptr<detail::PostingIndex<detail::PreciseEntry>> precise_;
  std::vector<uint8_t> removed_;  // per image id; guarded by mutex_
  size_t live_ = 0;               // guarded by mutex_
};

}  // namespace gtbow
