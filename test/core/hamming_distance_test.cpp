// The Hamming kernels of the binary word search against a plain reference.
#include "hamming_distance.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

namespace gtbow {
namespace {

uint32_t Reference(const uint8_t* a, const uint8_t* b, int bytes) {
  uint32_t s = 0;
  for (int k = 0; k < bytes; ++k) {
    for (int bit = 0; bit < 8; ++bit) s += ((a[k] ^ b[k]) >> bit) & 1;
  }
  return s;
}

TEST(HammingDistance, KernelsMatchTheReferenceForEverySizeAndThreshold) {
  std::printf("Hamming kernels on this CPU: portable%s\n",
              HammingKernelSupported(HammingKernel::kAvx512) ? ", avx512-vpopcntdq" : "");
  std::mt19937 rng(11);
  for (int bytes : {8, 32, 64}) {
    for (int n : {0, 1, 7, 8, 9, 31, 141}) {
      std::vector<uint8_t> rows(static_cast<size_t>(n) * bytes), q(bytes);
      for (auto& x : rows) x = static_cast<uint8_t>(rng());
      for (auto& x : q) x = static_cast<uint8_t>(rng());
      if (n > 2) {  // extremes: an identical row and its complement
        for (int k = 0; k < bytes; ++k) {
          rows[k] = q[k];
          rows[static_cast<size_t>(bytes) + k] = static_cast<uint8_t>(~q[k]);
        }
      }
      std::vector<uint64_t> packed;
      PackBinaryRows(rows.data(), n, bytes, &packed);
      ASSERT_EQ(packed.size(), static_cast<size_t>((n + 7) / 8) * 8 * (bytes / 8));
      std::vector<uint64_t> pq(bytes / 8);
      std::memcpy(pq.data(), q.data(), bytes);
      for (uint32_t threshold : {0u, 100u, 129u, std::numeric_limits<uint32_t>::max()}) {
        std::vector<uint32_t> want_i, want_d;
        for (int i = 0; i < n; ++i) {
          const uint32_t d =
              Reference(q.data(), rows.data() + static_cast<size_t>(i) * bytes, bytes);
          EXPECT_EQ(HammingDistance(q.data(), rows.data() + static_cast<size_t>(i) * bytes, bytes),
                    d);
          if (d < threshold) {
            want_i.push_back(i);
            want_d.push_back(d);
          }
        }
        for (HammingKernel k : {HammingKernel::kPortable, HammingKernel::kAvx512}) {
          if (!HammingKernelSupported(k)) continue;
          std::vector<uint32_t> idx(n + 1), dist(n + 1);
          const int m = HammingBelowUsing(k, pq.data(), packed.data(), n, bytes / 8, threshold,
                                          idx.data(), dist.data());
          ASSERT_EQ(m, static_cast<int>(want_i.size())) << "bytes " << bytes << " n " << n;
          for (int j = 0; j < m; ++j) {
            EXPECT_EQ(idx[j], want_i[j]);
            EXPECT_EQ(dist[j], want_d[j]);
          }
        }
      }
      // Every distance, in row order, and nothing written past the last row (the padding rows
      // of the last block are not rows).
      std::vector<uint32_t> all(static_cast<size_t>(n) + 1, 12345u);
      HammingAll(pq.data(), packed.data(), n, bytes / 8, all.data());
      for (int i = 0; i < n; ++i) {
        EXPECT_EQ(all[i], Reference(q.data(), rows.data() + static_cast<size_t>(i) * bytes, bytes));
      }
      EXPECT_EQ(all[n], 12345u) << "bytes " << bytes << " n " << n;
    }
  }
  std::vector<uint64_t> out;
  const uint8_t odd[12] = {};
  EXPECT_THROW(PackBinaryRows(odd, 1, 12, &out), std::invalid_argument);  // not whole 64-bit chunks
}

}  // namespace
}  // namespace gtbow
