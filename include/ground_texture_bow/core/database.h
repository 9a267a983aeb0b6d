// The inverted index of the paper (§II-E, Fig. 2): one row per (word, size bin); a posting
// holds the image id, the word's weight in that image's vector, and the image's keypoints on
// that row with their orientation and contributing weight. Queries verify orientation
// consistency inside the index (§II-B): every (query keypoint, database keypoint) pair on a
// shared row votes q_w * d_w * c_q * c_d into the orientation-difference bin of its image, and
// the image's score is its best bin.
//
// Layout (8 bytes per database keypoint on a row, nothing per posting): a row is one
// contiguous array of keypoint entries; a posting is the run of consecutive entries of one
// image. An entry packs the image id (24 bits) with the keypoint's orientation (8 bits, 1.4
// degree steps), the keypoint id (16 bits) and d_w * c_d quantised to 16 bits. Since the c_d of
// a posting sum to 1, d_w is the sum of its entries' weights; the plain dot product and the
// DBoW2 L1 score are computed from that. At most 2^24 image ids.
//
// Thread safety: any number of concurrent Query() calls with one writer. Add(), Remove() and
// Load() take the index's mutex exclusively; Query(), size() and Save() take it shared.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <shared_mutex>
#include <string>
#include <vector>

#include "ground_texture_bow/core/bow.h"

namespace gtbow {

// A query keypoint matched to a database keypoint on a shared row, in the winning bin.
struct MatchPair {
  uint16_t query_keypoint = 0;
  uint16_t database_keypoint = 0;
  float weight = 0.0f;  // q_w * d_w * c_q * c_d: its vote
};

struct QueryResult {
  uint32_t image = 0;            // database image id (as returned by Add)
  float score = 0.0f;            // similarity: best-bin vote (OV) or dot / L1 score
  int orientation_bin = -1;      // winning bin, -1 without orientation verification
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
  // The `top_n` most similar images, best first. With `with_matches` each result lists the
  // matched keypoint pairs of its winning orientation bin.
  std::vector<QueryResult> Query(const BowVector& query, size_t top_n,
                                 bool with_matches = true) const;

  size_t size() const;          // images present
  uint32_t next_id() const;     // ids handed out so far
  uint32_t num_rows() const { return num_rows_; }
  const BowOptions& options() const { return options_; }
  size_t MemoryBytes() const;   // rows, entries (with spare capacity) and image flags

  // Writes the index atomically (magic, version, checksum).
  void Save(const std::filesystem::path& path) const;
  // Replaces the contents with a saved index. Throws std::runtime_error naming the file when it
  // is damaged, of another version, or made with another vocabulary or other options; the
  // current contents are kept then.
  void Load(const std::filesystem::path& path);
  // The payload of Save (no framing), for files that embed an index (the ROS map file), and
  // its inverse; Deserialize has Load's checks and guarantees, naming `source` in errors.
  std::string Serialize() const;
  void Deserialize(const char* data, size_t size, const std::string& source);

 private:
  struct Row;
  uint32_t num_rows_;
  BowOptions options_;
  uint64_t fingerprint_;
  mutable std::shared_mutex mutex_;
  std::vector<Row> rows_;          // guarded by mutex_
  std::vector<uint8_t> removed_;   // per image id; guarded by mutex_
  size_t live_ = 0;                // guarded by mutex_
};

}  // namespace gtbow
