#include "byte_distance.h"

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <stdexcept>

#include "ground_texture_bow/core/simd.h"
#include "simd_dispatch.h"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define GTBOW_HAVE_AVX2_KERNEL 1
#endif

namespace gtbow {

void PackRows(const uint8_t* rows, int n, int d, std::vector<int16_t>* out) {
  const int blocks = (n + kPackedBlockRows - 1) / kPackedBlockRows;
  const size_t base = out->size();
  out->resize(base + static_cast<size_t>(blocks) * kPackedBlockRows * d, 0);
  int16_t* o = out->data() + base;
  for (int i = 0; i < n; ++i) {
    const uint8_t* r = rows + static_cast<size_t>(i) * d;
    int16_t* blk = o + static_cast<size_t>(i / kPackedBlockRows) * kPackedBlockRows * d;
    const int lane = i % kPackedBlockRows;
    for (int k = 0; k < d / 2; ++k) {
      blk[k * 2 * kPackedBlockRows + 2 * lane] = r[2 * k];
      blk[k * 2 * kPackedBlockRows + 2 * lane + 1] = r[2 * k + 1];
    }
  }
}

void PackQuery(const uint8_t* q, int d, int16_t* out) {
  for (int k = 0; k < d / 2; ++k) {
    for (int lane = 0; lane < kPackedBlockRows; ++lane) {
      out[k * 2 * kPackedBlockRows + 2 * lane] = q[2 * k];
      out[k * 2 * kPackedBlockRows + 2 * lane + 1] = q[2 * k + 1];
    }
  }
}

namespace {

int PortableBelow(const int16_t* pq, const int16_t* blocks, int n, int d, int32_t threshold,
                  uint32_t* index, int32_t* distance) {
  int m = 0;
  for (int i = 0; i < n; ++i) {
    const int16_t* blk = blocks + static_cast<size_t>(i / kPackedBlockRows) * kPackedBlockRows * d;
    const int lane = i % kPackedBlockRows;
    int32_t s = 0;
    for (int k = 0; k < d / 2; ++k) {
      const int32_t a = pq[k * 2 * kPackedBlockRows] - blk[k * 2 * kPackedBlockRows + 2 * lane];
      const int32_t b =
          pq[k * 2 * kPackedBlockRows + 1] - blk[k * 2 * kPackedBlockRows + 2 * lane + 1];
      s += a * a + b * b;
    }
    if (s < threshold) {
      index[m] = static_cast<uint32_t>(i);
      distance[m++] = s;
    }
  }
  return m;
}

}  // namespace

#ifdef GTBOW_HAVE_AVX2_KERNEL
namespace {

// Per pair of dimensions: a subtraction, a madd (squares and pair sums into 32-bit lanes, one
// per row) and an add; no shuffles. The two halves of a block share each load of the query.
__attribute__((target("avx2"), always_inline)) inline void Emit8(__m256i v, __m256i t, int valid,
                                                                 int first, uint32_t* index,
                                                                 int32_t* distance, int* m) {
  unsigned mask =
      static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(t, v))));
  if (valid < 8) mask &= (1u << std::max(valid, 0)) - 1;  // padding rows of the last block
  if (mask == 0) return;
  alignas(32) int32_t s[8];
  _mm256_store_si256(reinterpret_cast<__m256i*>(s), v);
  while (mask != 0) {
    const int j = __builtin_ctz(mask);
    mask &= mask - 1;
    index[*m] = static_cast<uint32_t>(first + j);
    distance[(*m)++] = s[j];
  }
}

__attribute__((target("avx2"))) int Avx2PackedBelow(const int16_t* pq, const int16_t* blocks, int n,
                                                    int d, int32_t threshold, uint32_t* index,
                                                    int32_t* distance) {
  const int pairs = d / 2;
  const size_t block = static_cast<size_t>(kPackedBlockRows) * d;
  const __m256i t = _mm256_set1_epi32(threshold);
  const int nblocks = (n + kPackedBlockRows - 1) / kPackedBlockRows;
  int m = 0;
  for (int bi = 0; bi < nblocks; ++bi) {
    const int16_t* b = blocks + bi * block;
    __m256i acc0 = _mm256_setzero_si256(), acc1 = _mm256_setzero_si256();
    for (int k = 0; k < pairs; ++k) {
      const __m256i qk = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(pq + k * 32));
      const __m256i x =
          _mm256_sub_epi16(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(b + k * 32)), qk);
      const __m256i y = _mm256_sub_epi16(
          _mm256_loadu_si256(reinterpret_cast<const __m256i*>(b + k * 32 + 16)), qk);
      acc0 = _mm256_add_epi32(acc0, _mm256_madd_epi16(x, x));
      acc1 = _mm256_add_epi32(acc1, _mm256_madd_epi16(y, y));
    }
    const int first = bi * kPackedBlockRows;
    Emit8(acc0, t, n - first, first, index, distance, &m);
    Emit8(acc1, t, n - first - 8, first + 8, index, distance, &m);
  }
  return m;
}

// AVX-512 with VNNI: a whole block per register, and vpdpwssd squares, pair-sums and
// accumulates in one instruction.
__attribute__((target("avx512f,avx512bw,avx512vnni"))) int Avx512PackedBelow(
    const int16_t* pq, const int16_t* blocks, int n, int d, int32_t threshold, uint32_t* index,
    int32_t* distance) {
  const int pairs = d / 2;
  const size_t block = static_cast<size_t>(kPackedBlockRows) * d;
  const __m512i t = _mm512_set1_epi32(threshold);
  const int nblocks = (n + kPackedBlockRows - 1) / kPackedBlockRows;
  int m = 0;
  alignas(64) int32_t s[16];
  for (int bi = 0; bi < nblocks; ++bi) {
    const int16_t* b = blocks + bi * block;
    // Four independent accumulators: vpdpwssd's latency would otherwise bound the loop.
    __m512i acc0 = _mm512_setzero_si512(), acc1 = _mm512_setzero_si512();
    __m512i acc2 = _mm512_setzero_si512(), acc3 = _mm512_setzero_si512();
    int k = 0;
    for (; k + 4 <= pairs; k += 4) {
      const __m512i x0 =
          _mm512_sub_epi16(_mm512_loadu_si512(b + k * 32), _mm512_loadu_si512(pq + k * 32));
      const __m512i x1 = _mm512_sub_epi16(_mm512_loadu_si512(b + k * 32 + 32),
                                          _mm512_loadu_si512(pq + k * 32 + 32));
      const __m512i x2 = _mm512_sub_epi16(_mm512_loadu_si512(b + k * 32 + 64),
                                          _mm512_loadu_si512(pq + k * 32 + 64));
      const __m512i x3 = _mm512_sub_epi16(_mm512_loadu_si512(b + k * 32 + 96),
                                          _mm512_loadu_si512(pq + k * 32 + 96));
      acc0 = _mm512_dpwssd_epi32(acc0, x0, x0);
      acc1 = _mm512_dpwssd_epi32(acc1, x1, x1);
      acc2 = _mm512_dpwssd_epi32(acc2, x2, x2);
      acc3 = _mm512_dpwssd_epi32(acc3, x3, x3);
    }
    for (; k < pairs; ++k) {
      const __m512i x =
          _mm512_sub_epi16(_mm512_loadu_si512(b + k * 32), _mm512_loadu_si512(pq + k * 32));
      acc0 = _mm512_dpwssd_epi32(acc0, x, x);
    }
    acc0 = _mm512_add_epi32(acc0, acc2);
    acc1 = _mm512_add_epi32(acc1, acc3);
    const __m512i v = _mm512_add_epi32(acc0, acc1);
    const int first = bi * kPackedBlockRows;
    unsigned mask = _mm512_cmpgt_epi32_mask(t, v);
    const int valid = n - first;
    if (valid < 16) mask &= (1u << valid) - 1;  // padding rows of the last block
    if (mask == 0) continue;
    _mm512_store_si512(s, v);
    while (mask != 0) {
      const int j = __builtin_ctz(mask);
      mask &= mask - 1;
      index[m] = static_cast<uint32_t>(first + j);
      distance[m++] = s[j];
    }
  }
  return m;
}

}  // namespace
#endif

bool SimdKernelSupported(SimdKernel kernel) {
  switch (kernel) {
    case SimdKernel::kPortable:
      return true;
#ifdef GTBOW_HAVE_AVX2_KERNEL
    case SimdKernel::kAvx2:
      __builtin_cpu_init();
      return __builtin_cpu_supports("avx2");
    case SimdKernel::kAvx512:
      __builtin_cpu_init();
      return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
             __builtin_cpu_supports("avx512vnni");
#endif
    default:
      return false;
  }
}

int PackedSquaredDistancesBelowUsing(SimdKernel kernel, const int16_t* pq, const int16_t* blocks,
                                     int n, int d, int32_t threshold, uint32_t* index,
                                     int32_t* distance) {
  if (!SimdKernelSupported(kernel))
    throw std::invalid_argument("SIMD kernel not supported by this CPU");
#ifdef GTBOW_HAVE_AVX2_KERNEL
  if (kernel == SimdKernel::kAvx512)
    return Avx512PackedBelow(pq, blocks, n, d, threshold, index, distance);
  if (kernel == SimdKernel::kAvx2)
    return Avx2PackedBelow(pq, blocks, n, d, threshold, index, distance);
#endif
  return PortableBelow(pq, blocks, n, d, threshold, index, distance);
}

namespace {

// The widest kernel the CPU runs that GTBOW_SIMD allows (simd_dispatch.h: these kernels rank
// portable < avx2 < avx512; GTBOW_SIMD=popcnt allows the portable one only).
SimdKernel ChooseKernel() {
  const int allowed = SimdRankAllowed();
#ifdef GTBOW_HAVE_AVX2_KERNEL
  if (kSimdRankAvx512 <= allowed && SimdKernelSupported(SimdKernel::kAvx512))
    return SimdKernel::kAvx512;
  if (kSimdRankAvx2 <= allowed && SimdKernelSupported(SimdKernel::kAvx2)) return SimdKernel::kAvx2;
#else
  (void)allowed;
#endif
  return SimdKernel::kPortable;
}

}  // namespace

const char* SimdKernelName(SimdKernel kernel) {
  switch (kernel) {
    case SimdKernel::kPortable:
      return "portable";
    case SimdKernel::kAvx2:
      return "avx2";
    case SimdKernel::kAvx512:
      return "avx512";
  }
  return "unknown";
}

std::atomic<int> g_byte_kernel{-1};  // chosen on first use and again by SetSimdLimit

void RechooseByteDistanceKernel() {
  g_byte_kernel.store(static_cast<int>(ChooseKernel()), std::memory_order_relaxed);
}

SimdKernel ActiveSimdKernel() {
  if (g_byte_kernel.load(std::memory_order_relaxed) < 0) RechooseByteDistanceKernel();
  return static_cast<SimdKernel>(g_byte_kernel.load(std::memory_order_relaxed));
}

const char* ActiveByteDistanceKernelName() { return SimdKernelName(ActiveSimdKernel()); }

int PackedSquaredDistancesBelow(const int16_t* pq, const int16_t* blocks, int n, int d,
                                int32_t threshold, uint32_t* index, int32_t* distance) {
  return PackedSquaredDistancesBelowUsing(ActiveSimdKernel(), pq, blocks, n, d, threshold, index,
                                          distance);
}

}  // namespace gtbow
