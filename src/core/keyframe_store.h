// Internal to the engine (src/core/localizer*.cpp): the keyframes of a Localizer in the form
// the map file stores them, so that a loaded map is used where it lies (memory-mapped) and a
// save writes what the store holds without converting it.
//
// A keyframe is a 64-byte record (stamp, pose, image size, keypoint count, where its payload
// is and the payload's checksum) and a payload: its keypoints packed in 8 bytes each
// (PackedKeypoint), then, when the map keeps them, its descriptors as the extractor made them.
//
// The store is a run of segments in id order: frozen ones (a memory-mapped map file, or heap
// segments sealed by a save that is still writing them) and one growable heap tail. Frozen
// segments never change, so a save writes them without holding any lock while Add appends to
// the tail (Localizer::Save).
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "ground_texture_bow/core/features.h"
#include "ground_texture_bow/core/geometry.h"

namespace gtbow {
namespace detail {

struct KeyframeRecord {
  int64_t stamp_ns = 0;
  double x = 0, y = 0, theta = 0;  // map_from_camera (valid with kHasPose)
  uint32_t width = 0, height = 0;
  uint32_t flags = 0;
  uint32_t num_keypoints = 0;
  uint64_t payload_offset = 0;  // in the file: from the payload section's start
  uint64_t payload_checksum = 0;
  static constexpr uint32_t kHasPose = 1;
  static constexpr uint32_t kMaintained = 2;  // added by map maintenance (maintenance.h)
  static constexpr uint32_t kKnownFlags = kHasPose | kMaintained;
};
static_assert(sizeof(KeyframeRecord) == 64, "keyframe records are 64 bytes");

// A keypoint as the map stores it: x and y in steps of max(width, height) / 65535 pixels
// (0.01 pixel at 640 x 480), orientation in 4096 steps per turn (0.09 degrees), pyramid level
// (-1..14) and size in 1/16 pixel (up to 4096 pixels). The detector score is not kept:
// verification and the BoW encoding do not read it.
struct PackedKeypoint {
  uint16_t x = 0, y = 0;
  uint16_t angle_octave = 0;  // angle << 4 | (octave + 1)
  uint16_t size = 0;
};
static_assert(sizeof(PackedKeypoint) == 8, "packed keypoints are 8 bytes");

PackedKeypoint PackKeypoint(const Keypoint& k, double step);
Keypoint UnpackKeypoint(const PackedKeypoint& p, double step);
// The pixel step of x and y for an image of width x height.
double CoordinateStep(uint32_t width, uint32_t height);

// One keyframe as read from a segment.
struct KeyframeView {
  const KeyframeRecord* record = nullptr;
  const uint8_t* payload = nullptr;
  size_t payload_bytes = 0;
  bool verify = false;  // the payload comes from a file: check record->payload_checksum
};

class KeyframeSegment {
 public:
  // A heap segment (a tail).
  KeyframeSegment() = default;
  // A view of a mapped file's records and payload section; `keep_alive` owns the mapping.
  KeyframeSegment(const KeyframeRecord* records, size_t count, const uint8_t* payload,
                  size_t payload_bytes, size_t payload_stride, std::shared_ptr<const void> keep);
  KeyframeSegment(const KeyframeSegment&) = delete;
  KeyframeSegment& operator=(const KeyframeSegment&) = delete;

  size_t size() const { return mapped_ ? count_ : records_.size(); }
  KeyframeView Get(size_t i) const;
  // Appends a keyframe to a heap segment: `record`'s offset and checksum are set here.
  void Append(KeyframeRecord record, const std::string& payload);
  size_t MemoryBytes() const;  // heap bytes (a mapped segment's pages belong to the file)

 private:
  bool mapped_ = false;
  // mapped
  const KeyframeRecord* mapped_records_ = nullptr;
  size_t count_ = 0;
  const uint8_t* mapped_payload_ = nullptr;
  size_t payload_bytes_ = 0;
  size_t stride_ = 0;  // payload bytes per keypoint
  std::shared_ptr<const void> keep_;
  // heap: records, and payloads in blocks that never move (offset = block << 40 | position)
  std::deque<KeyframeRecord> records_;  // grows without copying (a vector's doubling would
                                        // stall one Add by copying every record)
  std::vector<std::unique_ptr<uint8_t[]>> blocks_;
  size_t block_size_ = 0, block_used_ = 0;
};

class KeyframeStore {
 public:
  explicit KeyframeStore(size_t payload_stride) : stride_(payload_stride) {}
  size_t size() const { return size_; }
  size_t payload_stride() const { return stride_; }
  KeyframeView Get(uint32_t id) const;
  void Append(const KeyframeRecord& record, const std::string& payload);
  // Seals the tail; returns every frozen segment (what a save writes), in id order.
  std::vector<std::shared_ptr<const KeyframeSegment>> Freeze();
  // After a save: the first `count` keyframes (all frozen segments) now come from `mapped`.
  void Rebase(std::shared_ptr<const KeyframeSegment> mapped);
  // A loaded map: `mapped` holds every keyframe, the tail is empty.
  void Attach(std::shared_ptr<const KeyframeSegment> mapped);
  size_t MemoryBytes() const;

 private:
  size_t stride_;
  std::vector<std::shared_ptr<const KeyframeSegment>> frozen_;
  std::vector<size_t> first_;  // first id of each frozen segment
  size_t frozen_count_ = 0;
  std::shared_ptr<KeyframeSegment> tail_ = std::make_shared<KeyframeSegment>();
  size_t size_ = 0;
};

// The payload of a keyframe: packed keypoints, then the descriptors' bytes (when `descriptors`
// is not empty).
std::string MakePayload(const std::vector<Keypoint>& keypoints, const cv::Mat& descriptors,
                        uint32_t width, uint32_t height);
std::vector<Keypoint> PayloadKeypoints(const KeyframeView& v);
// The descriptors in the payload without copying (a header on the stored bytes), or an empty
// matrix when the map keeps none. `cols`/`type`: the extractor's (32/CV_8U for ORB).
cv::Mat PayloadDescriptors(const KeyframeView& v, int cols, int type);

}  // namespace detail
}  // namespace gtbow
