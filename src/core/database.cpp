// The inverted index: construction, insertion, removal and sizes. The query engine is in
// database_query.cpp, the file form in database_io.cpp, the entries in database_entries.h.
#include "ground_texture_bow/core/database.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <mutex>
#include <stdexcept>
#include <type_traits>

#include "database_entries.h"
#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/parallel.h"

namespace gtbow {

using namespace database_internal;

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
  query_threads_ = std::min(ThreadCount(threads), 64);
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

bool BowDatabase::Contains(uint32_t image) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return image < removed_.size() && !removed_[image];
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

size_t BowDatabase::MappedBytes() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const size_t b = compact_ ? compact_->base_bytes : precise_->base_bytes;
  return (compact_ ? compact_->base_mapped : precise_->base_mapped) ? b : 0;
}

size_t BowDatabase::num_entries() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return compact_ ? compact_->Entries() : precise_->Entries();
}

}  // namespace gtbow
