// The SIMD distance kernels of the IVF word search against a plain reference.
#include "byte_distance.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <limits>
#include <random>
#include <vector>

namespace gtbow {
namespace {

int32_t Reference(const uint8_t* a, const uint8_t* b, int d) {
  int32_t s = 0;
  for (int k = 0; k < d; ++k) s += (a[k] - b[k]) * (a[k] - b[k]);
  return s;
}

TEST(ByteDistance, KernelsMatchTheReferenceForEverySizeAndThreshold) {
  std::printf("kernels on this CPU: portable%s%s\n",
              SimdKernelSupported(SimdKernel::kAvx2) ? ", avx2" : "",
              SimdKernelSupported(SimdKernel::kAvx512) ? ", avx512-vnni" : "");
  std::mt19937 rng(7);
  for (int d : {2, 30, 32, 64}) {
    for (int n : {0, 1, 7, 15, 16, 17, 33, 316}) {
      std::vector<uint8_t> rows(static_cast<size_t>(n) * d), q(d);
      for (auto& x : rows) x = static_cast<uint8_t>(rng());
      for (auto& x : q) x = static_cast<uint8_t>(rng());
      if (n > 2) {  // extremes: identical row and maximal difference
        for (int k = 0; k < d; ++k) {
          rows[k] = q[k];
          q[k] = 255;
          rows[static_cast<size_t>(d) + k] = 0;
        }
      }
      std::vector<int16_t> packed;
      PackRows(rows.data(), n, d, &packed);
      ASSERT_EQ(packed.size(), static_cast<size_t>((n + kPackedBlockRows - 1) / kPackedBlockRows) *
                                   kPackedBlockRows * d);
      std::vector<int16_t> pq(static_cast<size_t>(kPackedBlockRows) * d);
      PackQuery(q.data(), d, pq.data());
      std::vector<int32_t> ref(n);
      for (int i = 0; i < n; ++i)
        ref[i] = Reference(q.data(), rows.data() + static_cast<size_t>(i) * d, d);
      for (int32_t threshold :
           {0, 1, 65025 * d / 4, 65025 * d / 2, std::numeric_limits<int32_t>::max()}) {
        for (SimdKernel kernel : {SimdKernel::kPortable, SimdKernel::kAvx2, SimdKernel::kAvx512}) {
          if (!SimdKernelSupported(kernel)) continue;
          std::vector<uint32_t> idx(n + 1);
          std::vector<int32_t> dist(n + 1);
          const int m = PackedSquaredDistancesBelowUsing(kernel, pq.data(), packed.data(), n, d,
                                                         threshold, idx.data(), dist.data());
          int expected = 0;
          for (int i = 0; i < n; ++i) {
            if (ref[i] >= threshold) continue;
            ASSERT_LT(expected, m)
                << "kernel " << static_cast<int>(kernel) << " d " << d << " n " << n;
            EXPECT_EQ(idx[expected], static_cast<uint32_t>(i));
            EXPECT_EQ(dist[expected], ref[i]);
            ++expected;
          }
          EXPECT_EQ(m, expected) << "kernel " << static_cast<int>(kernel) << " d " << d << " n "
                                 << n << " threshold " << threshold;
        }
      }
    }
  }
}

}  // namespace
}  // namespace gtbow
