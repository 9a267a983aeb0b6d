// Internal to the engine's vocabularies (src/core/vocabulary*.cpp, float_ivf.*): descriptor
// spaces, k-means pieces shared by AKM and HKM, and the two kinds' trainers and file readers.
#pragma once

// FLANN 1.9 headers are not self-contained: this order compiles. (flann::Index<> itself is not
// used: it instantiates the LSH index, whose serialisation does not compile.)
// clang-format off
#include <flann/general.h>
#include <flann/util/random.h>
#include <flann/algorithms/dist.h>
#include <flann/algorithms/center_chooser.h>
#include <flann/algorithms/hierarchical_clustering_index.h>
#include <flann/algorithms/kdtree_index.h>
// clang-format on

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <numeric>
#include <random>
#include <stdexcept>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "ground_texture_bow/core/binary_io.h"
#include "ground_texture_bow/core/vocabulary.h"
#include "hamming_distance.h"

namespace gtbow {
namespace vocabulary_internal {

// FLANN's randomisation uses the C library's global generator: serialise index builds so that
// a seed gives the same trees whatever else runs.
inline std::mutex& FlannSeedMutex() {
  static std::mutex m;
  return m;
}

// ---------------------------------------------------------------------------------------------
// Descriptor spaces: how to compare and average descriptors.

// Float vectors under L2 (SIFT, or ORB bytes taken as 32 numbers).
struct FloatSpace {
  using Element = float;
  using FlannDistance = flann::L2<float>;
  using FlannIndex = flann::KDTreeIndex<FlannDistance>;
  static float Distance(const float* a, const float* b, int d) {
    float s = 0;
    for (int i = 0; i < d; ++i) {
      const float x = a[i] - b[i];
      s += x * x;
    }
    return std::sqrt(s);
  }
  // FLANN reports squared L2.
  static float FromFlann(float d) { return std::sqrt(std::max(0.0f, d)); }
  // Of `n` rows (`step` bytes apart), the first nearest to `x` if it is strictly nearer than
  // *best: its index, and its distance in *best. Otherwise -1 and *best unchanged. (The scan
  // "if (distance < best) take it" over the rows in order.)
  static int Nearest(const float* x, const float* rows, size_t step, int n, int d, float* best) {
    int arg = -1;
    for (int c = 0; c < n; ++c) {
      const float dist = Distance(
          x, reinterpret_cast<const float*>(reinterpret_cast<const char*>(rows) + c * step), d);
      if (dist < *best) {
        *best = dist;
        arg = c;
      }
    }
    return arg;
  }
};

// FLANN's Hamming distance (flann::Hamming: whole 64-bit words on x86-64, 32-bit words
// elsewhere, trailing bytes ignored) through the core's dispatched kernels: the same counts,
// with the CPU's popcount instruction instead of FLANN's bit-twiddling.
struct FlannHamming {
  using ElementType = unsigned char;
  using ResultType = unsigned int;
  template <typename Iterator1, typename Iterator2>
  ResultType operator()(Iterator1 a, Iterator2 b, size_t size, ResultType /*worst*/ = 0) const {
#ifdef FLANN_PLATFORM_64_BIT
    const size_t counted = size / 8 * 8;
#else
    const size_t counted = size / 4 * 4;
#endif
    return HammingDistance(&*a, &*b, static_cast<int>(counted));
  }
};

// Packed binary descriptors under Hamming distance.
struct BinarySpace {
  using Element = unsigned char;
  using FlannDistance = FlannHamming;
  using FlannIndex = flann::HierarchicalClusteringIndex<FlannDistance>;
  // Bits, through the dispatched kernels (hamming_distance.h).
  static float Distance(const unsigned char* a, const unsigned char* b, int d) {
    return static_cast<float>(HammingDistance(a, b, d));
  }
  static float FromFlann(unsigned int d) { return static_cast<float>(d); }
  // As FloatSpace::Nearest, in one call of the kernel: distances are whole numbers of bits, so
  // the scan takes the first row at the smallest count if that is below *best.
  static int Nearest(const unsigned char* x, const unsigned char* rows, size_t step, int n, int d,
                     float* best) {
    uint32_t bits = 0;
    const int arg = HammingNearest(x, rows, step, n, d, &bits);
    if (arg < 0 || !(static_cast<float>(bits) < *best)) return -1;
    *best = static_cast<float>(bits);
    return arg;
  }
};

// Converts descriptors to the element type of the metric's space.
inline cv::Mat ToSpace(const cv::Mat& desc, Metric metric) {
  if (metric == Metric::kHamming) {
    if (desc.type() != CV_8U)
      throw std::invalid_argument("hamming vocabulary needs CV_8U descriptors");
    return desc.isContinuous() ? desc : desc.clone();
  }
  if (metric == Metric::kL2Bytes && desc.type() != CV_8U) {
    throw std::invalid_argument("l2_bytes vocabulary needs CV_8U (ORB) descriptors");
  }
  if (metric == Metric::kL2 && desc.type() != CV_32F) {
    throw std::invalid_argument("l2 vocabulary needs CV_32F (SIFT) descriptors");
  }
  cv::Mat f;
  desc.convertTo(f, CV_32F);
  return f;
}

// ---------------------------------------------------------------------------------------------
// k-means pieces shared by AKM and HKM.

// Recomputes each centroid from its members (the mean, or the bitwise majority for binary
// descriptors); empty clusters restart at a random descriptor (vocabulary_akm.cpp).
void UpdateCentroids(const cv::Mat& data, const std::vector<uint32_t>& label, cv::Mat* centroids,
                     std::mt19937_64& rng, int threads);

// Greedy k-means++ seeding (Arthur & Vassilvitskii 2007, with the 2 + log k local trials of
// scikit-learn): each new centre is the best of several rows drawn with probability
// proportional to their squared distance to the nearest centre so far.
template <typename Space>
void SeedPlusPlus(const cv::Mat& data, const std::vector<int>& members, int k, std::mt19937_64& rng,
                  cv::Mat* centers) {
  using E = typename Space::Element;
  const int d = data.cols;
  const int n = static_cast<int>(members.size());
  centers->create(k, d, data.type());
  const int trials = 2 + static_cast<int>(std::log(static_cast<double>(k)));
  std::vector<double> dmin(n), cand(n), best_cand(n);
  std::uniform_int_distribution<int> first(0, n - 1);
  data.row(members[first(rng)]).copyTo(centers->row(0));
  double potential = 0;
  for (int i = 0; i < n; ++i) {
    const double dd = Space::Distance(data.ptr<E>(members[i]), centers->ptr<E>(0), d);
    dmin[i] = dd * dd;
    potential += dmin[i];
  }
  for (int c = 1; c < k; ++c) {
    double best_potential = std::numeric_limits<double>::max();
    int best = 0;
    for (int t = 0; t < trials; ++t) {
      std::uniform_real_distribution<double> u(0, potential);
      double x = u(rng);
      int pick = n - 1;
      for (int i = 0; i < n; ++i) {
        x -= dmin[i];
        if (x <= 0) {
          pick = i;
          break;
        }
      }
      double pot = 0;
      for (int i = 0; i < n; ++i) {
        const double dd = Space::Distance(data.ptr<E>(members[i]), data.ptr<E>(members[pick]), d);
        cand[i] = std::min(dmin[i], dd * dd);
        pot += cand[i];
      }
      if (pot < best_potential) {
        best_potential = pot;
        best = pick;
        best_cand.swap(cand);
      }
    }
    data.row(members[best]).copyTo(centers->row(c));
    dmin.swap(best_cand);
    best_cand.resize(n);
    potential = best_potential;
  }
}

// ---------------------------------------------------------------------------------------------
// The two kinds: training on descriptors already in the metric's space (ToSpace), and reading
// the words a file stores after the common header (vocabulary.cpp writes that header).

// Flat k-means with approximate assignment (vocabulary_akm.cpp).
std::unique_ptr<Vocabulary> TrainAkm(const VocabularyOptions& options, const cv::Mat& data,
                                     bool progress);
std::unique_ptr<Vocabulary> ReadAkm(BinaryReader* r, Metric metric);
// The vocabulary tree (vocabulary_hkm.cpp).
std::unique_ptr<Vocabulary> TrainHkm(const VocabularyOptions& options, const cv::Mat& data,
                                     bool progress);
std::unique_ptr<Vocabulary> ReadHkm(BinaryReader* r, Metric metric);

// Limits on what a file may claim (a damaged size must not allocate the machine away).
constexpr uint64_t kMaxWords = 100000000;

}  // namespace vocabulary_internal
}  // namespace gtbow
