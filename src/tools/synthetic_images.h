// Synthetic database images for the benchmarks that go beyond a dataset's real images (gtbow
// bench, gtbow bench-map). Each synthetic image draws its keypoint count from a real image and
// each keypoint's rows (word and size bin, with its soft-assignment weights) and orientation
// from a real keypoint of the same surface, then goes through the encoder's tf-idf and
// normalisation. Row frequencies, weights and orientations thus follow the measured
// statistics; what is lost is the co-occurrence of words within one place (synthetic images
// are unrelated to each other and to the queries).
#pragma once

#include <cstdint>
#include <random>
#include <stdexcept>
#include <utility>
#include <vector>

#include "ground_texture_bow/core/bow.h"

namespace gtbow {
namespace tools {

// Keypoints of the real images, each with its rows and soft-assignment weights, for sampling
// synthetic images.
class KeypointPool {
 public:
  KeypointPool() = default;
  explicit KeypointPool(const std::vector<BowVector>& real) {
    for (const BowVector& v : real) Add(v);
    if (empty())
      throw std::runtime_error("the real images have no keypoints to sample synthetic ones from");
  }

  // Adds a real image's keypoints (its vector's rows, weights and orientations; not its source
  // keypoints, so that the caller need not keep the real vectors).
  void Add(const BowVector& v) {
    counts_.push_back(static_cast<uint32_t>(v.angles.size()));
    // Group the vector's keypoint entries (sorted by row) by keypoint.
    std::vector<std::vector<std::pair<uint32_t, float>>> by_kp(v.angles.size());
    for (const KeypointEntry& k : v.keypoints) by_kp[k.keypoint].push_back({k.row, k.assignment});
    for (size_t i = 0; i < by_kp.size(); ++i) {
      if (by_kp[i].empty()) continue;
      angles_.push_back(v.angles[i]);
      for (const auto& [row, a] : by_kp[i]) {
        rows_.push_back(row);
        assignments_.push_back(a);
      }
      offsets_.push_back(static_cast<uint32_t>(rows_.size()));
    }
  }
  bool empty() const { return angles_.empty(); }

  // A synthetic image, reproducible from `seed`. `count_from`, when given, receives the index
  // (in the order they were added) of the real image whose keypoint count it has: that image's
  // keypoints cover every keypoint index of the sample.
  BowVector Sample(const BowEncoder& enc, uint64_t seed, size_t* count_from = nullptr) const {
    std::mt19937_64 rng(seed);
    const size_t image = rng() % counts_.size();
    if (count_from) *count_from = image;
    const uint32_t n = counts_[image];
    BowVector v;
    v.angles.resize(n);
    for (uint32_t j = 0; j < n; ++j) {
      const size_t p = rng() % angles_.size();
      v.angles[j] = angles_[p];
      for (uint32_t e = offsets_[p]; e < offsets_[p + 1]; ++e) {
        v.keypoints.push_back({rows_[e], static_cast<uint16_t>(j), 0.0f, assignments_[e]});
      }
    }
    return enc.FromAssignments(std::move(v), n);
  }
  size_t keypoints() const { return angles_.size(); }
  // Memory the pool holds, bytes.
  size_t bytes() const {
    return 4 * (counts_.capacity() + offsets_.capacity() + rows_.capacity() +
                assignments_.capacity() + angles_.capacity());
  }

 private:
  std::vector<uint32_t> counts_;         // keypoints of each real image
  std::vector<uint32_t> offsets_ = {0};  // keypoint p's rows: [offsets_[p], offsets_[p + 1])
  std::vector<uint32_t> rows_;
  std::vector<float> assignments_;
  std::vector<float> angles_;
};

}  // namespace tools
}  // namespace gtbow
