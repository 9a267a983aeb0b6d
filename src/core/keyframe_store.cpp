#include "keyframe_store.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "ground_texture_bow/core/binary_io.h"

namespace gtbow {
namespace detail {

namespace {

constexpr double kTwoPi = 2.0 * M_PI;
constexpr int kBlockShift = 40;
constexpr size_t kMinBlock = size_t{1} << 20;   // heap payload blocks grow from 1 MB ...
constexpr size_t kMaxBlock = size_t{64} << 20;  // ... to 64 MB

uint16_t Clamp16(double v) { return static_cast<uint16_t>(std::clamp(std::lround(v), 0L, 65535L)); }

}  // namespace

double CoordinateStep(uint32_t width, uint32_t height) {
  return std::max<double>(1.0, std::max(width, height)) / 65535.0;
}

PackedKeypoint PackKeypoint(const Keypoint& k, double step) {
  PackedKeypoint p;
  p.x = Clamp16(k.x / step);
  p.y = Clamp16(k.y / step);
  double a = std::fmod(static_cast<double>(k.angle), kTwoPi);
  if (a < 0) a += kTwoPi;
  const uint32_t angle = static_cast<uint32_t>(std::lround(a / kTwoPi * 4096.0)) & 4095u;
  const uint32_t octave = static_cast<uint32_t>(std::clamp(k.octave + 1, 0, 15));
  p.angle_octave = static_cast<uint16_t>(angle << 4 | octave);
  p.size = Clamp16(k.size * 16.0);
  return p;
}

Keypoint UnpackKeypoint(const PackedKeypoint& p, double step) {
  Keypoint k;
  k.x = static_cast<float>(p.x * step);
  k.y = static_cast<float>(p.y * step);
  k.angle = static_cast<float>((p.angle_octave >> 4) * (kTwoPi / 4096.0));
  k.octave = static_cast<int>(p.angle_octave & 15u) - 1;
  k.size = static_cast<float>(p.size / 16.0);
  return k;
}

KeyframeSegment::KeyframeSegment(const KeyframeRecord* records, size_t count,
                                 const uint8_t* payload, size_t payload_bytes,
                                 size_t payload_stride, std::shared_ptr<const void> keep)
    : mapped_(true),
      mapped_records_(records),
      count_(count),
      mapped_payload_(payload),
      payload_bytes_(payload_bytes),
      stride_(payload_stride),
      keep_(std::move(keep)) {}

KeyframeView KeyframeSegment::Get(size_t i) const {
  KeyframeView v;
  if (mapped_) {
    v.record = &mapped_records_[i];
    v.payload = mapped_payload_ + v.record->payload_offset;
    v.payload_bytes = static_cast<size_t>(v.record->num_keypoints) * stride_;
    v.verify = true;
  } else {
    v.record = &records_[i];
    const uint64_t off = v.record->payload_offset;
    v.payload = blocks_[off >> kBlockShift].get() + (off & ((uint64_t{1} << kBlockShift) - 1));
    v.payload_bytes = static_cast<size_t>(-1);  // set by the store (it knows the stride)
  }
  return v;
}

void KeyframeSegment::Append(KeyframeRecord record, const std::string& payload) {
  if (mapped_) throw std::logic_error("KeyframeSegment: a mapped segment is read-only");
  if (blocks_.empty() || block_used_ + payload.size() > block_size_) {
    block_size_ = std::max(payload.size(), std::min(kMaxBlock, kMinBlock << blocks_.size()));
    // Not value-initialised: zeroing 64 MB would stall this Add by tens of milliseconds.
    blocks_.push_back(std::unique_ptr<uint8_t[]>(new uint8_t[std::max<size_t>(block_size_, 1)]));
    block_used_ = 0;
  }
  record.payload_offset = static_cast<uint64_t>(blocks_.size() - 1) << kBlockShift | block_used_;
  record.payload_checksum = Checksum64(payload.data(), payload.size());
  if (!payload.empty())
    std::memcpy(blocks_.back().get() + block_used_, payload.data(), payload.size());
  block_used_ += payload.size();
  records_.push_back(record);
}

size_t KeyframeSegment::MemoryBytes() const {
  size_t n = records_.size() * sizeof(KeyframeRecord);
  const size_t blocks = blocks_.size();
  for (size_t b = 0; b < blocks; ++b) n += std::min(kMaxBlock, kMinBlock << b);
  return n;
}

KeyframeView KeyframeStore::Get(uint32_t id) const {
  if (id >= size_) throw std::out_of_range("no keyframe " + std::to_string(id));
  KeyframeView v;
  if (id >= frozen_count_) {
    v = tail_->Get(id - frozen_count_);
  } else {
    const size_t s = static_cast<size_t>(
        std::upper_bound(first_.begin(), first_.end(), static_cast<size_t>(id)) - first_.begin() -
        1);
    v = frozen_[s]->Get(id - first_[s]);
  }
  v.payload_bytes = static_cast<size_t>(v.record->num_keypoints) * stride_;
  return v;
}

void KeyframeStore::Append(const KeyframeRecord& record, const std::string& payload) {
  tail_->Append(record, payload);
  ++size_;
}

std::vector<std::shared_ptr<const KeyframeSegment>> KeyframeStore::Freeze() {
  if (tail_->size() > 0) {
    first_.push_back(frozen_count_);
    frozen_count_ += tail_->size();
    frozen_.push_back(std::move(tail_));
    tail_ = std::make_shared<KeyframeSegment>();
  }
  return frozen_;
}

void KeyframeStore::Rebase(std::shared_ptr<const KeyframeSegment> mapped) {
  if (mapped->size() != frozen_count_) {
    throw std::logic_error("KeyframeStore::Rebase: the frozen keyframes changed since Freeze");
  }
  frozen_.clear();
  first_.clear();
  if (frozen_count_ > 0) {
    frozen_.push_back(std::move(mapped));
    first_.push_back(0);
  }
}

void KeyframeStore::Attach(std::shared_ptr<const KeyframeSegment> mapped) {
  frozen_.clear();
  first_.clear();
  tail_ = std::make_shared<KeyframeSegment>();
  frozen_count_ = size_ = mapped->size();
  if (size_ > 0) {
    frozen_.push_back(std::move(mapped));
    first_.push_back(0);
  }
}

size_t KeyframeStore::MemoryBytes() const {
  size_t n = tail_->MemoryBytes();
  for (const auto& s : frozen_) n += s->MemoryBytes();
  return n;
}

std::string MakePayload(const std::vector<Keypoint>& keypoints, const cv::Mat& descriptors,
                        uint32_t width, uint32_t height) {
  const double step = CoordinateStep(width, height);
  const size_t row = descriptors.empty() ? 0 : descriptors.cols * descriptors.elemSize();
  std::string out(keypoints.size() * (sizeof(PackedKeypoint) + row), '\0');
  char* p = out.data();
  for (const Keypoint& k : keypoints) {
    const PackedKeypoint pk = PackKeypoint(k, step);
    std::memcpy(p, &pk, sizeof(pk));
    p += sizeof(pk);
  }
  for (int r = 0; r < descriptors.rows && row > 0; ++r) {
    std::memcpy(p, descriptors.ptr(r), row);
    p += row;
  }
  return out;
}

std::vector<Keypoint> PayloadKeypoints(const KeyframeView& v) {
  const double step = CoordinateStep(v.record->width, v.record->height);
  std::vector<Keypoint> out(v.record->num_keypoints);
  for (size_t i = 0; i < out.size(); ++i) {
    PackedKeypoint pk;
    std::memcpy(&pk, v.payload + i * sizeof(PackedKeypoint), sizeof(pk));
    out[i] = UnpackKeypoint(pk, step);
  }
  return out;
}

cv::Mat PayloadDescriptors(const KeyframeView& v, int cols, int type) {
  const size_t n = v.record->num_keypoints;
  const size_t row = static_cast<size_t>(cols) * CV_ELEM_SIZE(type);
  if (n == 0 || v.payload_bytes != n * (sizeof(PackedKeypoint) + row) || row == 0) {
    return cv::Mat();
  }
  // Read-only use: cv::Mat has no const element type.
  auto* data = const_cast<uint8_t*>(v.payload + n * sizeof(PackedKeypoint));
  return cv::Mat(static_cast<int>(n), cols, type, data);
}

}  // namespace detail
}  // namespace gtbow
