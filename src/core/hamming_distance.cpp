#include "hamming_distance.h"

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>

#include "ground_texture_bow/core/simd.h"
#include "simd_dispatch.h"

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define GTBOW_HAVE_X86_HAMMING_KERNELS 1
#elif defined(__aarch64__) && defined(__GNUC__)
#include <arm_neon.h>
#define GTBOW_HAVE_NEON_HAMMING_KERNEL 1
#endif

// Inlined into each kernel's entry points, so that each is compiled for that kernel's target.
#define GTBOW_KERNEL_INLINE inline __attribute__((always_inline))

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

namespace {

// ---------------------------------------------------------------------------------------------
// The scalar loops, over a 64-bit popcount `Pop`: the portable kernel's (a bit-twiddling
// count) and the popcnt kernel's (the instruction).

// The sideways sum of Hacker's Delight (5-2): bits added in fields of 2, 4 and 8 bits, the 8
// bytes then summed by one multiplication. Plain C++: GCC turns it into the instruction only
// where the target has one, and never into a call of libgcc's __popcountdi2.
struct BitTwiddlingPopcount {
  static GTBOW_KERNEL_INLINE uint32_t Count(uint64_t x) {
    x = x - ((x >> 1) & 0x5555555555555555ULL);
    x = (x & 0x3333333333333333ULL) + ((x >> 2) & 0x3333333333333333ULL);
    x = (x + (x >> 4)) & 0x0f0f0f0f0f0f0f0fULL;
    return static_cast<uint32_t>((x * 0x0101010101010101ULL) >> 56);
  }
};

#ifdef GTBOW_HAVE_X86_HAMMING_KERNELS
// The POPCNT instruction: only ever inlined into functions compiled with target("popcnt").
struct PopcntInstruction {
  static GTBOW_KERNEL_INLINE uint32_t Count(uint64_t x) {
    return static_cast<uint32_t>(__builtin_popcountll(x));
  }
};
#endif

GTBOW_KERNEL_INLINE uint64_t Load64(const uint8_t* p) {
  uint64_t x;
  std::memcpy(&x, p, 8);
  return x;
}

// The last `n` < 8 bytes of a descriptor, zero-extended to 64 bits.
GTBOW_KERNEL_INLINE uint64_t LoadTail(const uint8_t* p, int n) {
  uint64_t x = 0;
  std::memcpy(&x, p, static_cast<size_t>(n));
  return x;
}

template <class Pop>
GTBOW_KERNEL_INLINE uint32_t PairLoop(const uint8_t* a, const uint8_t* b, int bytes) {
  uint32_t s = 0;
  int k = 0;
  for (; k + 8 <= bytes; k += 8) s += Pop::Count(Load64(a + k) ^ Load64(b + k));
  if (k < bytes) s += Pop::Count(LoadTail(a + k, bytes - k) ^ LoadTail(b + k, bytes - k));
  return s;
}

// The distance of a 32-byte row `r` to the query chunks q0..q3 (ORB). (A function, not a
// lambda: a lambda's body is not compiled for the target of the function it is written in.)
template <class Pop>
GTBOW_KERNEL_INLINE uint32_t Distance32(uint64_t q0, uint64_t q1, uint64_t q2, uint64_t q3,
                                        const uint8_t* r) {
  return Pop::Count(q0 ^ Load64(r)) + Pop::Count(q1 ^ Load64(r + 8)) +
         Pop::Count(q2 ^ Load64(r + 16)) + Pop::Count(q3 ^ Load64(r + 24));
}

template <class Pop>
GTBOW_KERNEL_INLINE int NearestLoop(const uint8_t* q, const uint8_t* rows, size_t stride, int n,
                                    int bytes, uint32_t* distance) {
  if (n <= 0) return -1;
  int arg = 0;
  uint32_t best;
  if (bytes == 32) {  // ORB: the query's four chunks stay in registers
    const uint64_t q0 = Load64(q), q1 = Load64(q + 8), q2 = Load64(q + 16), q3 = Load64(q + 24);
    best = Distance32<Pop>(q0, q1, q2, q3, rows);
    for (int i = 1; i < n; ++i) {
      const uint32_t d = Distance32<Pop>(q0, q1, q2, q3, rows + static_cast<size_t>(i) * stride);
      if (d < best) {
        best = d;
        arg = i;
      }
    }
  } else {
    best = PairLoop<Pop>(q, rows, bytes);
    for (int i = 1; i < n; ++i) {
      const uint32_t d = PairLoop<Pop>(q, rows + static_cast<size_t>(i) * stride, bytes);
      if (d < best) {
        best = d;
        arg = i;
      }
    }
  }
  *distance = best;
  return arg;
}

// The distance of packed row `i` to `q`, one 64-bit count per chunk.
template <class Pop>
GTBOW_KERNEL_INLINE uint32_t PackedRowDistance(const uint64_t* q, const uint64_t* blocks, int i,
                                               int chunks) {
  const uint64_t* blk =
      blocks + static_cast<size_t>(i / kBinaryBlockRows) * kBinaryBlockRows * chunks;
  const int lane = i % kBinaryBlockRows;
  uint32_t s = 0;
  for (int k = 0; k < chunks; ++k) s += Pop::Count(q[k] ^ blk[k * kBinaryBlockRows + lane]);
  return s;
}

// The distances of the `valid` rows of packed block `b` to the ORB query q0..q3 (4 chunks):
// the chunk k of the block's 8 rows side by side, so row j reads b[j], b[8 + j], ...
template <class Pop, class Emit>
GTBOW_KERNEL_INLINE void Block4(uint64_t q0, uint64_t q1, uint64_t q2, uint64_t q3,
                                const uint64_t* b, int valid, Emit emit) {
  for (int j = 0; j < valid; ++j) {
    emit(j, Pop::Count(q0 ^ b[j]) + Pop::Count(q1 ^ b[kBinaryBlockRows + j]) +
                Pop::Count(q2 ^ b[2 * kBinaryBlockRows + j]) +
                Pop::Count(q3 ^ b[3 * kBinaryBlockRows + j]));
  }
}

// Block by block; for ORB (4 chunks) the query stays in registers and the chunk loop is
// unrolled. The row is written before the comparison decides whether it counts (no branch on
// the distance), so `index` and `distance` need room for n values.
template <class Pop>
GTBOW_KERNEL_INLINE int BelowLoop(const uint64_t* q, const uint64_t* blocks, int n, int chunks,
                                  uint32_t threshold, uint32_t* index, uint32_t* distance) {
  int m = 0;
  const int nblocks = (n + kBinaryBlockRows - 1) / kBinaryBlockRows;
  if (chunks == 4) {
    // A block's 8 distances first, then the rows below the threshold, only where one is: once
    // the threshold is tight (the word search after each descriptor's first list) most blocks
    // have none. Skipping their stores took an eighth off the popcnt kernel's scan on an AMD
    // EPYC (4 POPCNTs a cycle, so the stores were a bound there): its transform on the real
    // floors 4.52-4.55 ms before, 4.23-4.28 ms after (two runs each, one thread).
    uint32_t s[kBinaryBlockRows];
    for (int bi = 0; bi < nblocks; ++bi) {
      const int first = bi * kBinaryBlockRows, valid = std::min(kBinaryBlockRows, n - first);
      uint32_t low = std::numeric_limits<uint32_t>::max();
      Block4<Pop>(q[0], q[1], q[2], q[3], blocks + static_cast<size_t>(bi) * 4 * kBinaryBlockRows,
                  valid, [&](int j, uint32_t d) {
                    s[j] = d;
                    low = std::min(low, d);
                  });
      if (low >= threshold) continue;
      for (int j = 0; j < valid; ++j) {
        index[m] = static_cast<uint32_t>(first + j);
        distance[m] = s[j];
        m += s[j] < threshold ? 1 : 0;
      }
    }
    return m;
  }
  for (int i = 0; i < n; ++i) {
    const uint32_t s = PackedRowDistance<Pop>(q, blocks, i, chunks);
    if (s < threshold) {
      index[m] = static_cast<uint32_t>(i);
      distance[m++] = s;
    }
  }
  return m;
}

template <class Pop>
GTBOW_KERNEL_INLINE void AllLoop(const uint64_t* q, const uint64_t* blocks, int n, int chunks,
                                 uint32_t* out) {
  if (chunks == 4) {
    const int nblocks = (n + kBinaryBlockRows - 1) / kBinaryBlockRows;
    for (int bi = 0; bi < nblocks; ++bi) {
      const int first = bi * kBinaryBlockRows;
      Block4<Pop>(q[0], q[1], q[2], q[3], blocks + static_cast<size_t>(bi) * 4 * kBinaryBlockRows,
                  std::min(kBinaryBlockRows, n - first),
                  [&](int j, uint32_t s) { out[first + j] = s; });
    }
    return;
  }
  for (int i = 0; i < n; ++i) out[i] = PackedRowDistance<Pop>(q, blocks, i, chunks);
}

// The portable kernel: the fallback where the CPU has none of the instructions below (and
// the reference the others are tested against).
int PortableBelow(const uint64_t* q, const uint64_t* blocks, int n, int chunks, uint32_t threshold,
                  uint32_t* index, uint32_t* distance) {
  return BelowLoop<BitTwiddlingPopcount>(q, blocks, n, chunks, threshold, index, distance);
}
void PortableAll(const uint64_t* q, const uint64_t* blocks, int n, int chunks, uint32_t* out) {
  AllLoop<BitTwiddlingPopcount>(q, blocks, n, chunks, out);
}
uint32_t PortablePair(const uint8_t* a, const uint8_t* b, int bytes) {
  return PairLoop<BitTwiddlingPopcount>(a, b, bytes);
}
int PortableNearest(const uint8_t* q, const uint8_t* rows, size_t stride, int n, int bytes,
                    uint32_t* distance) {
  return NearestLoop<BitTwiddlingPopcount>(q, rows, stride, n, bytes, distance);
}

#ifdef GTBOW_HAVE_X86_HAMMING_KERNELS
// ---------------------------------------------------------------------------------------------
// The popcnt kernel: the same loops, compiled for the POPCNT instruction. The avx2 and avx512
// kernels use its pair and nearest-row functions (one descriptor at a time is four POPCNTs).
__attribute__((target("popcnt"))) int PopcntBelow(const uint64_t* q, const uint64_t* blocks, int n,
                                                  int chunks, uint32_t threshold, uint32_t* index,
                                                  uint32_t* distance) {
  return BelowLoop<PopcntInstruction>(q, blocks, n, chunks, threshold, index, distance);
}
__attribute__((target("popcnt"))) void PopcntAll(const uint64_t* q, const uint64_t* blocks, int n,
                                                 int chunks, uint32_t* out) {
  AllLoop<PopcntInstruction>(q, blocks, n, chunks, out);
}
__attribute__((target("popcnt"))) uint32_t PopcntPair(const uint8_t* a, const uint8_t* b,
                                                      int bytes) {
  return PairLoop<PopcntInstruction>(a, b, bytes);
}
__attribute__((target("popcnt"))) int PopcntNearest(const uint8_t* q, const uint8_t* rows,
                                                    size_t stride, int n, int bytes,
                                                    uint32_t* distance) {
  return NearestLoop<PopcntInstruction>(q, rows, stride, n, bytes, distance);
}

// ---------------------------------------------------------------------------------------------
// The avx2 kernel (packed scans): each byte's bits counted by two lookups of a 16-entry table
// (vpshufb, one per nibble), the byte counts of up to 31 chunks added as bytes (at most 8 each,
// so at most 248), then summed into each row's 64-bit lane by vpsadbw. A register holds 4 rows.
__attribute__((target("avx2"), always_inline)) inline __m256i Avx2ByteCounts(__m256i v) {
  const __m256i table = _mm256_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2,
                                         1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
  const __m256i low = _mm256_set1_epi8(0x0f);
  const __m256i lo = _mm256_and_si256(v, low);
  const __m256i hi = _mm256_and_si256(_mm256_srli_epi16(v, 4), low);
  return _mm256_add_epi8(_mm256_shuffle_epi8(table, lo), _mm256_shuffle_epi8(table, hi));
}

// The distances of the 8 rows of block `b` to `q`: rows 0-3 in *r0, rows 4-7 in *r1.
__attribute__((target("avx2"), always_inline)) inline void Avx2BlockDistances(
    const uint64_t* q, const uint64_t* b, int chunks, __m256i* r0, __m256i* r1) {
  const __m256i zero = _mm256_setzero_si256();
  __m256i s0 = zero, s1 = zero;
  for (int k = 0; k < chunks;) {
    const int end = std::min(chunks, k + 31);
    __m256i c0 = zero, c1 = zero;
    for (; k < end; ++k) {
      const __m256i qk = _mm256_set1_epi64x(static_cast<long long>(q[k]));
      const __m256i x0 =
          _mm256_xor_si256(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(b + 8 * k)), qk);
      const __m256i x1 =
          _mm256_xor_si256(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(b + 8 * k + 4)), qk);
      c0 = _mm256_add_epi8(c0, Avx2ByteCounts(x0));
      c1 = _mm256_add_epi8(c1, Avx2ByteCounts(x1));
    }
    s0 = _mm256_add_epi64(s0, _mm256_sad_epu8(c0, zero));
    s1 = _mm256_add_epi64(s1, _mm256_sad_epu8(c1, zero));
  }
  *r0 = s0;
  *r1 = s1;
}

// Appends the rows `first` .. `first` + 3 (of `n`) whose distance in `v` is below `t` (both
// non-negative, so the signed 64-bit comparison is exact).
__attribute__((target("avx2"), always_inline)) inline void Avx2Emit(__m256i v, __m256i t, int first,
                                                                    int n, uint32_t* index,
                                                                    uint32_t* distance, int* m) {
  unsigned mask =
      static_cast<unsigned>(_mm256_movemask_pd(_mm256_castsi256_pd(_mm256_cmpgt_epi64(t, v))));
  const int valid = n - first;
  if (valid < 4) mask &= (1u << std::max(valid, 0)) - 1;  // padding rows of the last block
  if (mask == 0) return;
  alignas(32) uint64_t s[4];
  _mm256_store_si256(reinterpret_cast<__m256i*>(s), v);
  while (mask != 0) {
    const int j = __builtin_ctz(mask);
    mask &= mask - 1;
    index[*m] = static_cast<uint32_t>(first + j);
    distance[(*m)++] = static_cast<uint32_t>(s[j]);
  }
}

__attribute__((target("avx2"))) int Avx2Below(const uint64_t* q, const uint64_t* blocks, int n,
                                              int chunks, uint32_t threshold, uint32_t* index,
                                              uint32_t* distance) {
  const int nblocks = (n + kBinaryBlockRows - 1) / kBinaryBlockRows;
  const size_t block = static_cast<size_t>(kBinaryBlockRows) * chunks;
  const __m256i t = _mm256_set1_epi64x(static_cast<long long>(threshold));
  int m = 0;
  for (int bi = 0; bi < nblocks; ++bi) {
    __m256i r0, r1;
    if (chunks == 4) {  // ORB: the chunk loop unrolled
      Avx2BlockDistances(q, blocks + bi * block, 4, &r0, &r1);
    } else {
      Avx2BlockDistances(q, blocks + bi * block, chunks, &r0, &r1);
    }
    const int first = bi * kBinaryBlockRows;
    Avx2Emit(r0, t, first, n, index, distance, &m);
    Avx2Emit(r1, t, first + 4, n, index, distance, &m);
  }
  return m;
}

__attribute__((target("avx2"))) void Avx2All(const uint64_t* q, const uint64_t* blocks, int n,
                                             int chunks, uint32_t* out) {
  const int nblocks = (n + kBinaryBlockRows - 1) / kBinaryBlockRows;
  const size_t block = static_cast<size_t>(kBinaryBlockRows) * chunks;
  alignas(32) uint64_t lanes[kBinaryBlockRows];
  for (int bi = 0; bi < nblocks; ++bi) {
    __m256i r0, r1;
    if (chunks == 4) {
      Avx2BlockDistances(q, blocks + bi * block, 4, &r0, &r1);
    } else {
      Avx2BlockDistances(q, blocks + bi * block, chunks, &r0, &r1);
    }
    const int first = bi * kBinaryBlockRows, valid = std::min(kBinaryBlockRows, n - first);
    if (valid == kBinaryBlockRows) {
      // A whole block: the 8 distances (each in the low half of its 64-bit lane) gathered into
      // one register and stored at once, not reloaded from the lanes one by one.
      const __m256i low = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
      const __m256i s = _mm256_blend_epi32(_mm256_permutevar8x32_epi32(r0, low),
                                           _mm256_permutevar8x32_epi32(r1, low), 0xf0);
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + first), s);
      continue;
    }
    _mm256_store_si256(reinterpret_cast<__m256i*>(lanes), r0);
    _mm256_store_si256(reinterpret_cast<__m256i*>(lanes + 4), r1);
    for (int j = 0; j < valid; ++j) out[first + j] = static_cast<uint32_t>(lanes[j]);
  }
}

// ---------------------------------------------------------------------------------------------
// The avx512 kernel (packed scans): AVX-512 VPOPCNTDQ, a block of 8 rows per register.
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

#ifdef GTBOW_HAVE_NEON_HAMMING_KERNEL
// ---------------------------------------------------------------------------------------------
// The neon kernel: vcnt counts the bits of each byte; the byte counts of up to 31 chunks (at
// most 8 each) are added as bytes, then widened pairwise (vpaddl) into 64-bit lanes. A block
// of 8 packed rows takes 4 registers of 2 rows.
GTBOW_KERNEL_INLINE void NeonBlockDistances(const uint64_t* q, const uint64_t* b, int chunks,
                                            uint64_t* lanes) {
  uint64x2_t s[4] = {vdupq_n_u64(0), vdupq_n_u64(0), vdupq_n_u64(0), vdupq_n_u64(0)};
  for (int k = 0; k < chunks;) {
    const int end = std::min(chunks, k + 31);
    uint8x16_t c[4] = {vdupq_n_u8(0), vdupq_n_u8(0), vdupq_n_u8(0), vdupq_n_u8(0)};
    for (; k < end; ++k) {
      const uint64x2_t qk = vdupq_n_u64(q[k]);
      for (int j = 0; j < 4; ++j) {
        const uint64x2_t x = veorq_u64(vld1q_u64(b + 8 * k + 2 * j), qk);
        c[j] = vaddq_u8(c[j], vcntq_u8(vreinterpretq_u8_u64(x)));
      }
    }
    for (int j = 0; j < 4; ++j) s[j] = vaddq_u64(s[j], vpaddlq_u32(vpaddlq_u16(vpaddlq_u8(c[j]))));
  }
  for (int j = 0; j < 4; ++j) vst1q_u64(lanes + 2 * j, s[j]);
}

int NeonBelow(const uint64_t* q, const uint64_t* blocks, int n, int chunks, uint32_t threshold,
              uint32_t* index, uint32_t* distance) {
  const int nblocks = (n + kBinaryBlockRows - 1) / kBinaryBlockRows;
  const size_t block = static_cast<size_t>(kBinaryBlockRows) * chunks;
  uint64_t lanes[kBinaryBlockRows];
  int m = 0;
  for (int bi = 0; bi < nblocks; ++bi) {
    if (chunks == 4) {  // ORB: the chunk loop unrolled
      NeonBlockDistances(q, blocks + bi * block, 4, lanes);
    } else {
      NeonBlockDistances(q, blocks + bi * block, chunks, lanes);
    }
    const int first = bi * kBinaryBlockRows, valid = std::min(kBinaryBlockRows, n - first);
    for (int j = 0; j < valid; ++j) {
      if (lanes[j] < threshold) {
        index[m] = static_cast<uint32_t>(first + j);
        distance[m++] = static_cast<uint32_t>(lanes[j]);
      }
    }
  }
  return m;
}

void NeonAll(const uint64_t* q, const uint64_t* blocks, int n, int chunks, uint32_t* out) {
  const int nblocks = (n + kBinaryBlockRows - 1) / kBinaryBlockRows;
  const size_t block = static_cast<size_t>(kBinaryBlockRows) * chunks;
  uint64_t lanes[kBinaryBlockRows];
  for (int bi = 0; bi < nblocks; ++bi) {
    if (chunks == 4) {
      NeonBlockDistances(q, blocks + bi * block, 4, lanes);
    } else {
      NeonBlockDistances(q, blocks + bi * block, chunks, lanes);
    }
    const int first = bi * kBinaryBlockRows, valid = std::min(kBinaryBlockRows, n - first);
    for (int j = 0; j < valid; ++j) out[first + j] = static_cast<uint32_t>(lanes[j]);
  }
}

// Two descriptors: 16 bytes per vcnt, byte counts widened into 16-bit lanes (vpadal, at most 16
// per lane and step: flushed every 2048 steps), then 8 bytes and the last < 8 bytes.
GTBOW_KERNEL_INLINE uint32_t NeonPairInline(const uint8_t* a, const uint8_t* b, int bytes) {
  uint32_t s = 0;
  int k = 0;
  while (k + 16 <= bytes) {
    uint16x8_t acc = vdupq_n_u16(0);
    for (int steps = 0; steps < 2048 && k + 16 <= bytes; ++steps, k += 16)
      acc = vpadalq_u8(acc, vcntq_u8(veorq_u8(vld1q_u8(a + k), vld1q_u8(b + k))));
    s += vaddlvq_u16(acc);
  }
  if (k + 8 <= bytes) {
    s += vaddv_u8(vcnt_u8(veor_u8(vld1_u8(a + k), vld1_u8(b + k))));
    k += 8;
  }
  if (k < bytes) {
    const uint64_t x = LoadTail(a + k, bytes - k) ^ LoadTail(b + k, bytes - k);
    s += vaddv_u8(vcnt_u8(vcreate_u8(x)));
  }
  return s;
}

// One 32-byte row: 32 byte counts of at most 8, their pairwise sums at most 16.
GTBOW_KERNEL_INLINE uint32_t NeonDistance32(uint8x16_t q0, uint8x16_t q1, const uint8_t* r) {
  return vaddlvq_u8(
      vaddq_u8(vcntq_u8(veorq_u8(q0, vld1q_u8(r))), vcntq_u8(veorq_u8(q1, vld1q_u8(r + 16)))));
}

uint32_t NeonPair(const uint8_t* a, const uint8_t* b, int bytes) {
  return NeonPairInline(a, b, bytes);
}

int NeonNearest(const uint8_t* q, const uint8_t* rows, size_t stride, int n, int bytes,
                uint32_t* distance) {
  if (n <= 0) return -1;
  int arg = 0;
  uint32_t best;
  if (bytes == 32) {  // ORB: the query stays in two registers
    const uint8x16_t q0 = vld1q_u8(q), q1 = vld1q_u8(q + 16);
    best = NeonDistance32(q0, q1, rows);
    for (int i = 1; i < n; ++i) {
      const uint32_t d = NeonDistance32(q0, q1, rows + static_cast<size_t>(i) * stride);
      if (d < best) {
        best = d;
        arg = i;
      }
    }
  } else {
    best = NeonPairInline(q, rows, bytes);
    for (int i = 1; i < n; ++i) {
      const uint32_t d = NeonPairInline(q, rows + static_cast<size_t>(i) * stride, bytes);
      if (d < best) {
        best = d;
        arg = i;
      }
    }
  }
  *distance = best;
  return arg;
}
#endif

// ---------------------------------------------------------------------------------------------
// Dispatch.

struct Kernels {
  int (*below)(const uint64_t*, const uint64_t*, int, int, uint32_t, uint32_t*, uint32_t*);
  void (*all)(const uint64_t*, const uint64_t*, int, int, uint32_t*);
  uint32_t (*pair)(const uint8_t*, const uint8_t*, int);
  int (*nearest)(const uint8_t*, const uint8_t*, size_t, int, int, uint32_t*);
};

constexpr Kernels kPortableKernels{PortableBelow, PortableAll, PortablePair, PortableNearest};
#ifdef GTBOW_HAVE_X86_HAMMING_KERNELS
constexpr Kernels kPopcntKernels{PopcntBelow, PopcntAll, PopcntPair, PopcntNearest};
constexpr Kernels kAvx2Kernels{Avx2Below, Avx2All, PopcntPair, PopcntNearest};
constexpr Kernels kAvx512Kernels{Avx512Below, Avx512All, PopcntPair, PopcntNearest};
#endif
#ifdef GTBOW_HAVE_NEON_HAMMING_KERNEL
constexpr Kernels kNeonKernels{NeonBelow, NeonAll, NeonPair, NeonNearest};
#endif

#ifdef GTBOW_HAVE_X86_HAMMING_KERNELS
// AMD's first Zen cores (family 17h below model 30h: Ryzen 1000 and 2000, EPYC 7001, Ryzen
// Embedded V1000) run each 256-bit instruction as two 128-bit halves, and POPCNT on all four
// integer ports. There the popcnt kernel is the faster one (December 2026, an EPYC 7001-class
// VM, make benchmark-kernels' real floors, one thread, medians: transform 4.23 against 4.68 ms,
// pose 1.18 against 1.39 ms, end to end 9.95 against 10.57 ms). Later Zen cores have whole
// 256-bit units; on another EPYC, measured earlier (its model not recorded), the AVX2 kernel's
// transform was 1.56 times faster than POPCNT's.
bool PopcntBeatsAvx2() {
  __builtin_cpu_init();
  return __builtin_cpu_is("znver1");
}
#endif

// The kernel's rank in simd_dispatch.h's order; -1 for none of this architecture.
int RankOf(HammingKernel kernel) {
  switch (kernel) {
    case HammingKernel::kPortable:
      return kSimdRankPortable;
#ifdef GTBOW_HAVE_X86_HAMMING_KERNELS
    case HammingKernel::kPopcnt:
      return kSimdRankPopcnt;
    case HammingKernel::kAvx2:
      return kSimdRankAvx2;
    case HammingKernel::kAvx512:
      return kSimdRankAvx512;
#endif
#ifdef GTBOW_HAVE_NEON_HAMMING_KERNEL
    case HammingKernel::kNeon:
      return kSimdRankNeon;
#endif
    default:
      return -1;
  }
}

const Kernels& KernelsOf(HammingKernel kernel) {
  if (!HammingKernelSupported(kernel)) {
    throw std::invalid_argument(std::string("Hamming kernel ") + HammingKernelName(kernel) +
                                " is not supported by this build and CPU");
  }
  switch (kernel) {
#ifdef GTBOW_HAVE_X86_HAMMING_KERNELS
    case HammingKernel::kPopcnt:
      return kPopcntKernels;
    case HammingKernel::kAvx2:
      return kAvx2Kernels;
    case HammingKernel::kAvx512:
      return kAvx512Kernels;
#endif
#ifdef GTBOW_HAVE_NEON_HAMMING_KERNEL
    case HammingKernel::kNeon:
      return kNeonKernels;
#endif
    default:
      return kPortableKernels;
  }
}

HammingKernel ChooseKernel() {
  const int allowed = SimdRankAllowed();
  HammingKernel best = HammingKernel::kPortable;
  int best_rank = kSimdRankPortable;
  for (HammingKernel k : kAllHammingKernels) {
    const int rank = RankOf(k);
    if (rank > best_rank && rank <= allowed && HammingKernelSupported(k)) {
      best = k;
      best_rank = rank;
    }
  }
#ifdef GTBOW_HAVE_X86_HAMMING_KERNELS
  // Unless GTBOW_SIMD names avx2 itself: the popcnt kernel where it is the faster one.
  if (best == HammingKernel::kAvx2 && allowed > kSimdRankAvx2 && PopcntBeatsAvx2()) {
    best = HammingKernel::kPopcnt;
  }
#endif
  return best;
}

// The active kernel and its functions, chosen on first use and again by SetSimdLimit.
std::atomic<int> g_kernel{-1};
std::atomic<const Kernels*> g_kernels{nullptr};

const Kernels& Active() {
  const Kernels* k = g_kernels.load(std::memory_order_acquire);
  if (k != nullptr) return *k;
  RechooseHammingKernel();
  return *g_kernels.load(std::memory_order_acquire);
}

}  // namespace

const char* HammingKernelName(HammingKernel kernel) {
  switch (kernel) {
    case HammingKernel::kPortable:
      return "portable";
    case HammingKernel::kPopcnt:
      return "popcnt";
    case HammingKernel::kAvx2:
      return "avx2";
    case HammingKernel::kAvx512:
      return "avx512";
    case HammingKernel::kNeon:
      return "neon";
  }
  return "unknown";
}

bool HammingKernelSupported(HammingKernel kernel) {
  switch (kernel) {
    case HammingKernel::kPortable:
      return true;
#ifdef GTBOW_HAVE_X86_HAMMING_KERNELS
    case HammingKernel::kPopcnt:
      __builtin_cpu_init();
      return __builtin_cpu_supports("popcnt");
    case HammingKernel::kAvx2:
      __builtin_cpu_init();
      return __builtin_cpu_supports("popcnt") && __builtin_cpu_supports("avx2");
    case HammingKernel::kAvx512:
      __builtin_cpu_init();
      return __builtin_cpu_supports("popcnt") && __builtin_cpu_supports("avx512f") &&
             __builtin_cpu_supports("avx512vpopcntdq");
#endif
#ifdef GTBOW_HAVE_NEON_HAMMING_KERNEL
    case HammingKernel::kNeon:
      return true;  // Advanced SIMD is part of every aarch64 CPU
#endif
    default:
      return false;
  }
}

void RechooseHammingKernel() {
  const HammingKernel kernel = ChooseKernel();
  g_kernel.store(static_cast<int>(kernel), std::memory_order_relaxed);
  g_kernels.store(&KernelsOf(kernel), std::memory_order_release);
}

HammingKernel ActiveHammingKernel() {
  if (g_kernel.load(std::memory_order_relaxed) < 0) RechooseHammingKernel();
  return static_cast<HammingKernel>(g_kernel.load(std::memory_order_relaxed));
}

const char* ActiveHammingKernelName() { return HammingKernelName(ActiveHammingKernel()); }

int HammingBelowUsing(HammingKernel kernel, const uint64_t* q, const uint64_t* blocks, int n,
                      int chunks, uint32_t threshold, uint32_t* index, uint32_t* distance) {
  return KernelsOf(kernel).below(q, blocks, n, chunks, threshold, index, distance);
}

void HammingAllUsing(HammingKernel kernel, const uint64_t* q, const uint64_t* blocks, int n,
                     int chunks, uint32_t* out) {
  KernelsOf(kernel).all(q, blocks, n, chunks, out);
}

uint32_t HammingDistanceUsing(HammingKernel kernel, const uint8_t* a, const uint8_t* b, int bytes) {
  return KernelsOf(kernel).pair(a, b, bytes);
}

int HammingNearestUsing(HammingKernel kernel, const uint8_t* q, const uint8_t* rows, size_t stride,
                        int n, int bytes, uint32_t* distance) {
  return KernelsOf(kernel).nearest(q, rows, stride, n, bytes, distance);
}

int HammingBelow(const uint64_t* q, const uint64_t* blocks, int n, int chunks, uint32_t threshold,
                 uint32_t* index, uint32_t* distance) {
  return Active().below(q, blocks, n, chunks, threshold, index, distance);
}

void HammingAll(const uint64_t* q, const uint64_t* blocks, int n, int chunks, uint32_t* out) {
  Active().all(q, blocks, n, chunks, out);
}

uint32_t HammingDistance(const uint8_t* a, const uint8_t* b, int bytes) {
  return Active().pair(a, b, bytes);
}

int HammingNearest(const uint8_t* q, const uint8_t* rows, size_t stride, int n, int bytes,
                   uint32_t* distance) {
  return Active().nearest(q, rows, stride, n, bytes, distance);
}

}  // namespace gtbow
