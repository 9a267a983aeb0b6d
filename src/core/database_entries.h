// Internal to the engine's inverted index (src/core/database*.cpp): the posting entries (compact
// 6-byte and precise 8-byte encodings), the rows that hold them, and the file constants.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <vector>

#include "ground_texture_bow/core/bow.h"
#include "ground_texture_bow/core/database.h"

namespace gtbow {
namespace database_internal {

inline constexpr char kDatabaseMagic[8] = {'G', 'T', 'B', 'W', 'D', 'B', '\0', '\0'};
// 2: packed 8-byte entries in a framed file. 3: compact or precise entries, a header with its
// own checksum, entries at an aligned offset for memory mapping, a checksum per 64 MB chunk.
inline constexpr uint32_t kDatabaseVersion = 3;
inline constexpr size_t kFixedHeader = 32;  // magic, version, entry size, two sizes
inline constexpr size_t kEntriesAlignment = 64;
inline constexpr size_t kChecksumChunk = size_t{64} << 20;
inline constexpr float kTwoPi = static_cast<float>(2.0 * M_PI);

// Orientation stored in 8 bits: 256 steps per turn (1.4 degrees).
inline uint8_t QuantizeAngle(float a) {
  int q = static_cast<int>(std::lround(a / kTwoPi * 256.0f));
  return static_cast<uint8_t>(q & 255);
}

// Compact weights: code c stands for 2^(-c / 16), so 255 codes cover 2^-16 .. 1 with at most
// 2.2% relative error. Weights d_w * c_d lie in (0, 1] (normalised vectors, shares summing to 1).
inline constexpr float kLogStepsPerOctave = 16.0f;

struct LogWeightTable {
  float w[256];
  LogWeightTable() {
    for (int c = 0; c < 256; ++c) w[c] = std::exp2(-static_cast<float>(c) / kLogStepsPerOctave);
  }
};
inline const LogWeightTable kLogWeights;

}  // namespace database_internal

namespace detail {

using namespace database_internal;

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

// Rows of entries, three arrays indexed by row so that a map save swaps whole arrays, not rows:
// a read-only base segment per row (loaded, or the file a save wrote), the entries sealed by a
// save that is still writing them (`sealed`: empty, no row at all, otherwise), and a growable
// tail per row (added).
template <class E>
struct PostingIndex {
  using Entry = E;
  struct Base {
    const E* data = nullptr;
    size_t count = 0;
  };
  explicit PostingIndex(uint32_t num_rows) : base(num_rows), tail(num_rows) {}
  uint32_t num_rows() const { return static_cast<uint32_t>(tail.size()); }
  std::vector<Base> base;
  std::vector<std::vector<E>> sealed;
  std::vector<std::vector<E>> tail;
  std::shared_ptr<const void> keep_alive;  // owns the base segments (mapping or block)
  size_t base_bytes = 0;
  bool base_mapped = false;  // the base segments lie in a memory-mapped file, not the heap

  // Entries of a row that a map save writes (immutable until BowDatabase::Rebase).
  size_t Frozen(uint32_t row) const {
    return base[row].count + (sealed.empty() ? 0 : sealed[row].size());
  }
  size_t Entries() const {
    size_t n = 0;
    for (uint32_t r = 0; r < num_rows(); ++r) n += Frozen(r) + tail[r].size();
    return n;
  }
  size_t Bytes() const {
    size_t n = base.capacity() * sizeof(Base) + base_bytes +
               (sealed.capacity() + tail.capacity()) * sizeof(std::vector<E>);
    for (const auto& v : sealed) n += v.capacity() * sizeof(E);
    for (const auto& v : tail) n += v.capacity() * sizeof(E);
    return n;
  }
  // Calls f(pointer, count) for the row's base segment, sealed entries and tail, in order.
  template <class F>
  void ForEachSegment(uint32_t row, F&& f) const {
    ForEachFrozenSegment(row, f);
    if (!tail[row].empty()) f(tail[row].data(), tail[row].size());
  }
  // The same without the tail.
  template <class F>
  void ForEachFrozenSegment(uint32_t row, F&& f) const {
    if (base[row].count > 0) f(base[row].data, base[row].count);
    if (!sealed.empty() && !sealed[row].empty()) f(sealed[row].data(), sealed[row].size());
  }
};

}  // namespace detail

namespace database_internal {

using detail::CompactEntry;
using detail::PostingIndex;
using detail::PreciseEntry;

inline const char* Bytes(const void* p) { return static_cast<const char*>(p); }

// Appends image `id`'s entries to the rows' tails.
template <class E>
void AddToIndex(PostingIndex<E>* index, const BowVector& v, uint32_t id) {
  size_t k = 0;
  for (const BowEntry& e : v.entries) {
    auto& tail = index->tail[e.row];
    while (k < v.keypoints.size() && v.keypoints[k].row < e.row) ++k;
    while (k < v.keypoints.size() && v.keypoints[k].row == e.row) {
      const KeypointEntry& ke = v.keypoints[k++];
      tail.push_back(E::Make(id, QuantizeAngle(v.angles[ke.keypoint]), ke.keypoint,
                             e.weight * ke.contribution));
    }
  }
}

}  // namespace database_internal
}  // namespace gtbow
