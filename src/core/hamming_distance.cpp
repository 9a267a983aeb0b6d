#include "hamming_distance.h"

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <stdexcept>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define GTBOW_HAVE_AVX512_POPCNT_KERNEL 1
#endif

namespace gtbow {

void PackBinaryRows(const uint8_t* rows, int n, int bytes, std::vector<uint64_t>* out) {
  if (bytes % 8 != 0)
    throw std::invalid_argument("PackBinaryRows: descriptor bytes must be a multiple of 8");
  const int chunks = bytes / 8;
  const int blocks = (n + kBinaryBlockRows - 1) / kBinaryBlockRows;
  const size_t base = out->size();
  out->resize(base + static_cast<size_t>(blocks) * kBinaryBlockRows * chunks, 0);
  uint64_t* o = out->data() + base;
  for (int i = 0; i < n; ++i) {
    uint64_t* blk = o + static_cast<size_t>(i / kBinaryBlockRows) * kBinaryBlockRows * chunks;
    const int lane = i % kBinaryBlockRows;
    for (int k = 0; k < chunks; ++k) {
      uint64_t c;
      std::memcpy(&c, rows + static_cast<size_t>(i) * bytes + 8 * k, 8);
      blk[k * kBinaryBlockRows + lane] = c;
    }
  }
}

uint32_t HammingDistance(const uint8_t* a, const uint8_t* b, int bytes) {
  uint32_t s = 0;
  int k = 0;
  for (; k + 8 <= bytes; k += 8) {
    uint64_t x, y;
    std::memcpy(&x, a + k, 8);
    std::memcpy(&y, b + k, 8);
    s += static_cast<uint32_t>(__builtin_popcountll(x ^ y));
  }
  for (; k < bytes; ++k)
    s += static_cast<uint32_t>(__builtin_popcount(static_cast<unsigned>(a[k] ^ b[k])));
  return s;
}

namespace {

// The distance of packed row `i` to `q`, one 64-bit popcount per chunk.
uint32_t PortableDistance(const uint64_t* q, const uint64_t* blocks, int i, int chunks) {
  const uint64_t* blk =
      blocks + static_cast<size_t>(i / kBinaryBlockRows) * kBinaryBlockRows * chunks;
  const int lane = i % kBinaryBlockRows;
  uint32_t s = 0;
  for (int k = 0; k < chunks; ++k) {
    s += static_cast<uint32_t>(__builtin_popcountll(q[k] ^ blk[k * kBinaryBlockRows + lane]));
  }
  return s;
}

int PortableBelow(const uint64_t* q, const uint64_t* blocks, int n, int chunks, uint32_t threshold,
                  uint32_t* index, uint32_t* distance) {
  int m = 0;
  for (int i = 0; i < n; ++i) {
    const uint32_t s = PortableDistance(q, blocks, i, chunks);
    if (s < threshold) {
      index[m] = static_cast<uint32_t>(i);
      distance[m++] = s;
    }
  }
  return m;
}

#ifdef GTBOW_HAVE_AVX512_POPCNT_KERNEL
// Appends the rows of block `first` whose distance in `v` is below the threshold `t`.
__attribute__((target("avx512f,avx512vpopcntdq"), always_inline)) inline void Emit(
    __m512i v, __m512i t, int first, int n, uint32_t* index, uint32_t* distance, int* m) {
  unsigned mask = _mm512_cmplt_epu64_mask(v, t);
  const int valid = n - first;
  if (valid < 8) mask &= (1u << valid) - 1;  // padding rows of the last block
  if (mask == 0) return;
  alignas(64) uint64_t s[8];
  _mm512_store_si512(s, v);
  while (mask != 0) {
    const int j = __builtin_ctz(mask);
    mask &= mask - 1;
    index[*m] = static_cast<uint32_t>(first + j);
    distance[(*m)++] = static_cast<uint32_t>(s[j]);
  }
}

// The distances of one packed block `b` of 8 rows to `q`: per chunk an xor with the broadcast
// query chunk, a vector popcount and an add; the 8 lanes end up holding the 8 rows' distances.
__attribute__((target("avx512f,avx512vpopcntdq"), always_inline)) inline __m512i BlockDistances(
    const uint64_t* q, const uint64_t* b, int chunks) {
  __m512i v = _mm512_setzero_si512();
  for (int k = 0; k < chunks; ++k) {
    const __m512i qk = _mm512_set1_epi64(static_cast<long long>(q[k]));
    v = _mm512_add_epi64(v,
                         _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(b + 8 * k), qk)));
  }
  return v;
}

// One block of 8 rows per register (BlockDistances; unrolled for ORB's 4 chunks).
__attribute__((target("avx512f,avx512vpopcntdq"))) int Avx512Below(const uint64_t* q,
                                                                   const uint64_t* blocks, int n,
                                                                   int chunks, uint32_t threshold,
                                                                   uint32_t* index,
                                                                   uint32_t* distance) {
  const int nblocks = (n + kBinaryBlockRows - 1) / kBinaryBlockRows;
  const size_t block = static_cast<size_t>(kBinaryBlockRows) * chunks;
  const __m512i t = _mm512_set1_epi64(static_cast<long long>(threshold));
  int m = 0;
  if (chunks == 4) {  // ORB: unrolled
    const __m512i q0 = _mm512_set1_epi64(static_cast<long long>(q[0]));
    const __m512i q1 = _mm512_set1_epi64(static_cast<long long>(q[1]));
    const __m512i q2 = _mm512_set1_epi64(static_cast<long long>(q[2]));
    const __m512i q3 = _mm512_set1_epi64(static_cast<long long>(q[3]));
    for (int bi = 0; bi < nblocks; ++bi) {
      const uint64_t* b = blocks + bi * block;
      const __m512i a0 = _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(b), q0));
      const __m512i a1 = _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(b + 8), q1));
      const __m512i a2 = _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(b + 16), q2));
      const __m512i a3 = _mm512_popcnt_epi64(_mm512_xor_si512(_mm512_loadu_si512(b + 24), q3));
      const __m512i v = _mm512_add_epi64(_mm512_add_epi64(a0, a1), _mm512_add_epi64(a2, a3));
      Emit(v, t, bi * kBinaryBlockRows, n, index, distance, &m);
    }
    return m;
  }
  for (int bi = 0; bi < nblocks; ++bi) {
    const uint64_t* b = blocks + bi * block;
    const __m512i v = BlockDistances(q, b, chunks);
    Emit(v, t, bi * kBinaryBlockRows, n, index, distance, &m);
  }
  return m;
}
#endif

#ifdef GTBOW_HAVE_AVX512_POPCNT_KERNEL
__attribute__((target("avx512f,avx512vpopcntdq"))) void Avx512All(const uint64_t* q,
                                                                  const uint64_t* blocks, int n,
                                                                  int chunks, uint32_t* out) {
  const int nblocks = (n + kBinaryBlockRows - 1) / kBinaryBlockRows;
  const size_t block = static_cast<size_t>(kBinaryBlockRows) * chunks;
  for (int bi = 0; bi < nblocks; ++bi) {
    const uint64_t* b = blocks + bi * block;
    const __m512i v = BlockDistances(q, b, chunks);
    const int first = bi * kBinaryBlockRows, valid = std::min(kBinaryBlockRows, n - first);
    // The 8 lanes' distances as 32-bit values, without the padding rows of the last block.
    // (the masked form: the plain one reads an undefined register, which GCC 12 warns about)
    const __m256i d32 = _mm512_mask_cvtepi64_epi32(_mm256_setzero_si256(), 0xFF, v);
    if (valid == kBinaryBlockRows) {
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + first), d32);
    } else {
      alignas(32) uint32_t lanes[kBinaryBlockRows];
      _mm256_store_si256(reinterpret_cast<__m256i*>(lanes), d32);
      std::memcpy(out + first, lanes, sizeof(uint32_t) * static_cast<size_t>(valid));
    }
  }
}
#endif

HammingKernel BestKernel() {
  const char* cap = std::getenv("GTBOW_SIMD");
  const bool capped =
      cap != nullptr && (std::strcmp(cap, "portable") == 0 || std::strcmp(cap, "avx2") == 0);
  if (!capped && HammingKernelSupported(HammingKernel::kAvx512)) return HammingKernel::kAvx512;
  return HammingKernel::kPortable;
}

}  // namespace

bool HammingKernelSupported(HammingKernel kernel) {
  switch (kernel) {
    case HammingKernel::kPortable:
      return true;
#ifdef GTBOW_HAVE_AVX512_POPCNT_KERNEL
    case HammingKernel::kAvx512:
      return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vpopcntdq");
#endif
    default:
      return false;
  }
}

int HammingBelowUsing(HammingKernel kernel, const uint64_t* q, const uint64_t* blocks, int n,
                      int chunks, uint32_t threshold, uint32_t* index, uint32_t* distance) {
  if (!HammingKernelSupported(kernel))
    throw std::invalid_argument("Hamming kernel not supported by this CPU");
#ifdef GTBOW_HAVE_AVX512_POPCNT_KERNEL
  if (kernel == HammingKernel::kAvx512)
    return Avx512Below(q, blocks, n, chunks, threshold, index, distance);
#endif
  return PortableBelow(q, blocks, n, chunks, threshold, index, distance);
}

void HammingAll(const uint64_t* q, const uint64_t* blocks, int n, int chunks, uint32_t* out) {
  static const HammingKernel kernel = BestKernel();
#ifdef GTBOW_HAVE_AVX512_POPCNT_KERNEL
  if (kernel == HammingKernel::kAvx512) return Avx512All(q, blocks, n, chunks, out);
#endif
  for (int i = 0; i < n; ++i) out[i] = PortableDistance(q, blocks, i, chunks);
}

int HammingBelow(const uint64_t* q, const uint64_t* blocks, int n, int chunks, uint32_t threshold,
                 uint32_t* index, uint32_t* distance) {
  static const HammingKernel kernel = BestKernel();
  return HammingBelowUsing(kernel, q, blocks, n, chunks, threshold, index, distance);
}

}  // namespace gtbow
