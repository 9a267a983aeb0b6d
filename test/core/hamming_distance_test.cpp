// The Hamming kernels against a plain reference and against the portable kernel, bit for bit:
// every kernel this build has and this CPU runs (on x86-64 portable, popcnt, avx2, avx512; on
// aarch64 portable and neon), whatever GTBOW_SIMD says. Free of OpenCV, so that it also
// cross-builds for aarch64 and runs under qemu (scripts/test_arm.sh).
#include "hamming_distance.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "ground_texture_bow/core/simd.h"

namespace gtbow {
namespace {

uint32_t Reference(const uint8_t* a, const uint8_t* b, int bytes) {
  uint32_t s = 0;
  for (int k = 0; k < bytes; ++k) {
    for (int bit = 0; bit < 8; ++bit) s += ((a[k] ^ b[k]) >> bit) & 1;
  }
  return s;
}

std::vector<HammingKernel> Kernels() {
  std::vector<HammingKernel> out;
  for (HammingKernel k : kAllHammingKernels) {
    if (HammingKernelSupported(k)) out.push_back(k);
  }
  return out;
}

TEST(HammingDistance, EveryKernelIsReportedAndThePortableOneIsAlwaysThere) {
  std::string names;
  for (HammingKernel k : Kernels())
    names += std::string(names.empty() ? "" : ", ") + HammingKernelName(k);
  std::printf("Hamming kernels on this CPU: %s; active: %s (%s)\n", names.c_str(),
              ActiveHammingKernelName(), ActiveSimdKernels().c_str());
  EXPECT_TRUE(HammingKernelSupported(HammingKernel::kPortable));
  EXPECT_TRUE(HammingKernelSupported(ActiveHammingKernel()));
  EXPECT_STREQ(ActiveHammingKernelName(), HammingKernelName(ActiveHammingKernel()));
#if defined(__x86_64__)
  EXPECT_FALSE(HammingKernelSupported(HammingKernel::kNeon));
#elif defined(__aarch64__)
  EXPECT_TRUE(HammingKernelSupported(HammingKernel::kNeon));  // part of every aarch64 CPU
  EXPECT_FALSE(HammingKernelSupported(HammingKernel::kPopcnt));
#endif
  for (HammingKernel k : kAllHammingKernels) {
    if (HammingKernelSupported(k)) continue;
    const uint64_t q[1] = {0};
    uint32_t i[1], d[1];
    EXPECT_THROW(HammingBelowUsing(k, q, q, 0, 1, 1, i, d), std::invalid_argument)
        << HammingKernelName(k);
  }
}

// SetSimdLimit (gtbow eval --timing-kernels) switches the dispatched calls to each kernel the
// CPU has, and back; unknown names change nothing.
TEST(HammingDistance, SetSimdLimitSwitchesTheDispatchedKernelAndBack) {
  const std::string limit = SimdLimit(), before = ActiveHammingKernelName();
  std::mt19937 rng(5);
  std::vector<uint8_t> rows(37 * 32);
  for (auto& b : rows) b = static_cast<uint8_t>(rng());
  std::vector<uint64_t> packed;
  PackBinaryRows(rows.data(), 37, 32, &packed);
  uint64_t q[4];
  std::memcpy(q, rows.data() + 5 * 32, 32);
  std::vector<uint32_t> want(37), got(37);
  HammingAllUsing(HammingKernel::kPortable, q, packed.data(), 37, 4, want.data());
  for (HammingKernel k : Kernels()) {
    ASSERT_TRUE(SetSimdLimit(HammingKernelName(k)));
    EXPECT_EQ(ActiveHammingKernel(), k);
    HammingAll(q, packed.data(), 37, 4, got.data());
    EXPECT_EQ(got, want) << HammingKernelName(k);
  }
  EXPECT_FALSE(SetSimdLimit("sse9"));
  ASSERT_TRUE(SetSimdLimit(limit));
  EXPECT_EQ(SimdLimit(), limit);
  EXPECT_STREQ(ActiveHammingKernelName(), before.c_str());
}

// With no cap, the widest kernel the CPU runs, except on AMD's first Zen cores (their 256-bit
// instructions run as two halves), where the popcnt kernel is the faster one; GTBOW_SIMD=avx2
// still forces avx2 there.
TEST(HammingDistance, TheWidestKernelRunsButPopcntOnTheFirstZenCores) {
  const std::string limit = SimdLimit(), before = ActiveHammingKernelName();
  HammingKernel widest = HammingKernel::kPortable;
  for (HammingKernel k : Kernels()) widest = k;  // kAllHammingKernels is in rank order
  bool first_zen = false;
#if defined(__x86_64__)
  __builtin_cpu_init();
  first_zen = __builtin_cpu_is("znver1");
#endif
  std::printf("widest kernel %s, first Zen core: %s\n", HammingKernelName(widest),
              first_zen ? "yes" : "no");
  ASSERT_TRUE(SetSimdLimit(""));
  EXPECT_EQ(SimdLimit(), "");
  if (widest == HammingKernel::kAvx2 && first_zen) {
    EXPECT_EQ(ActiveHammingKernel(), HammingKernel::kPopcnt);
    ASSERT_TRUE(SetSimdLimit("avx2"));
    EXPECT_EQ(ActiveHammingKernel(), HammingKernel::kAvx2);
  } else {
    EXPECT_EQ(ActiveHammingKernel(), widest);
  }
  ASSERT_TRUE(SetSimdLimit(limit));
  EXPECT_STREQ(ActiveHammingKernelName(), before.c_str());
}

// The packed scans (HammingBelow, HammingAll) of every kernel: chunk counts up to 40 (past the
// 31 chunks whose byte counts the vector kernels add before widening), row counts around the
// block of 8.
TEST(HammingDistance, KernelsMatchTheReferenceForEverySizeAndThreshold) {
  std::mt19937 rng(11);
  for (int bytes : {8, 16, 24, 32, 64, 248, 256, 320}) {
    for (int n : {0, 1, 3, 4, 5, 7, 8, 9, 31, 141}) {
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
      std::vector<uint32_t> want_all(n);
      for (int i = 0; i < n; ++i)
        want_all[i] = Reference(q.data(), rows.data() + static_cast<size_t>(i) * bytes, bytes);
      for (uint32_t threshold : {0u, 1u, 100u, 129u, 1300u, std::numeric_limits<uint32_t>::max()}) {
        std::vector<uint32_t> want_i, want_d;
        for (int i = 0; i < n; ++i) {
          if (want_all[i] < threshold) {
            want_i.push_back(i);
            want_d.push_back(want_all[i]);
          }
        }
        for (HammingKernel k : Kernels()) {
          std::vector<uint32_t> idx(n + 1), dist(n + 1);
          const int m = HammingBelowUsing(k, pq.data(), packed.data(), n, bytes / 8, threshold,
                                          idx.data(), dist.data());
          ASSERT_EQ(m, static_cast<int>(want_i.size()))
              << HammingKernelName(k) << " bytes " << bytes << " n " << n << " t " << threshold;
          for (int j = 0; j < m; ++j) {
            EXPECT_EQ(idx[j], want_i[j]) << HammingKernelName(k);
            EXPECT_EQ(dist[j], want_d[j]) << HammingKernelName(k);
          }
        }
      }
      // Every distance, in row order, and nothing written past the last row (the padding rows
      // of the last block are not rows).
      for (HammingKernel k : Kernels()) {
        std::vector<uint32_t> all(static_cast<size_t>(n) + 1, 12345u);
        HammingAllUsing(k, pq.data(), packed.data(), n, bytes / 8, all.data());
        for (int i = 0; i < n; ++i) EXPECT_EQ(all[i], want_all[i]) << HammingKernelName(k);
        EXPECT_EQ(all[n], 12345u) << HammingKernelName(k) << " bytes " << bytes << " n " << n;
      }
      std::vector<uint32_t> all(static_cast<size_t>(n) + 1, 12345u);
      HammingAll(pq.data(), packed.data(), n, bytes / 8, all.data());  // the dispatched one
      for (int i = 0; i < n; ++i) EXPECT_EQ(all[i], want_all[i]);
      EXPECT_EQ(all[n], 12345u);
    }
  }
  std::vector<uint64_t> out;
  const uint8_t odd[12] = {};
  EXPECT_THROW(PackBinaryRows(odd, 1, 12, &out), std::invalid_argument);  // not whole 64-bit chunks
}

// Pairs of descriptors of any length (whole chunks, a tail of 1 to 7 bytes, long vectors), at
// any alignment.
TEST(HammingDistance, PairsOfAnyLengthMatchTheReference) {
  std::mt19937 rng(5);
  std::vector<int> lengths;
  for (int b = 0; b <= 72; ++b) lengths.push_back(b);
  for (int b : {255, 256, 257, 1000, 40000}) lengths.push_back(b);
  for (int bytes : lengths) {
    for (int offset : {0, 1, 3}) {
      std::vector<uint8_t> buf_a(bytes + 3), buf_b(bytes + 3);
      for (auto& x : buf_a) x = static_cast<uint8_t>(rng());
      for (auto& x : buf_b) x = static_cast<uint8_t>(rng());
      const uint8_t* a = buf_a.data() + offset;
      const uint8_t* b = buf_b.data() + offset;
      std::vector<uint8_t> not_a(a, a + bytes);
      for (auto& x : not_a) x = static_cast<uint8_t>(~x);
      const uint32_t want = Reference(a, b, bytes);
      for (HammingKernel k : Kernels()) {
        EXPECT_EQ(HammingDistanceUsing(k, a, b, bytes), want)
            << HammingKernelName(k) << " bytes " << bytes << " offset " << offset;
        EXPECT_EQ(HammingDistanceUsing(k, a, a, bytes), 0u) << HammingKernelName(k);
        EXPECT_EQ(HammingDistanceUsing(k, a, not_a.data(), bytes), 8u * bytes)
            << HammingKernelName(k);
      }
      EXPECT_EQ(HammingDistance(a, b, bytes), want);
    }
  }
}

// The nearest of rows `stride` bytes apart: the first one at the smallest distance.
TEST(HammingDistance, NearestRowIsTheFirstAtTheSmallestDistance) {
  std::mt19937 rng(3);
  for (int bytes : {1, 8, 13, 32, 64}) {
    for (int n : {0, 1, 2, 10, 33}) {
      for (size_t stride : {static_cast<size_t>(bytes), static_cast<size_t>(bytes) + 5}) {
        std::vector<uint8_t> rows(stride * std::max(n, 1)), q(bytes);
        for (auto& x : rows) x = static_cast<uint8_t>(rng());
        for (auto& x : q) x = static_cast<uint8_t>(rng());
        if (n >= 10) {  // a tie for the nearest: rows 4 and 7 one bit from the query
          for (int r : {4, 7}) {
            std::memcpy(rows.data() + r * stride, q.data(), bytes);
            rows[r * stride] ^= 1;
          }
        }
        int want = -1;
        uint32_t want_d = 0;
        for (int i = 0; i < n; ++i) {
          const uint32_t d = Reference(q.data(), rows.data() + i * stride, bytes);
          if (want < 0 || d < want_d) {
            want = i;
            want_d = d;
          }
        }
        if (n >= 10) {
          ASSERT_EQ(want, 4);
          ASSERT_EQ(want_d, 1u);
        }
        for (HammingKernel k : Kernels()) {
          uint32_t d = 777;
          const int got = HammingNearestUsing(k, q.data(), rows.data(), stride, n, bytes, &d);
          EXPECT_EQ(got, want) << HammingKernelName(k) << " bytes " << bytes << " n " << n;
          EXPECT_EQ(d, n > 0 ? want_d : 777u) << HammingKernelName(k);
        }
        uint32_t d = 777;
        EXPECT_EQ(HammingNearest(q.data(), rows.data(), stride, n, bytes, &d), want);
      }
    }
  }
}

}  // namespace
}  // namespace gtbow
