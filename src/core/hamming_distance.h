// Hamming distances between binary descriptors (ORB: 32 bytes = 256 bits): an AVX-512 kernel
// with the vector popcount (VPOPCNTDQ) where the CPU has it, a scalar popcount loop otherwise.
// Both give identical results. Private to the core.
#pragma once

#include <cstdint>
#include <vector>

namespace gtbow {

// Binary rows packed for the scan: blocks of 8 rows; within a block, for each 64-bit chunk k of
// the descriptor, the 8 rows' chunk k side by side (8 uint64). The last block of a run is padded
// with zero rows. Descriptors must be a whole number of 64-bit chunks (`bytes` % 8 == 0).
constexpr int kBinaryBlockRows = 8;
void PackBinaryRows(const uint8_t* rows, int n, int bytes, std::vector<uint64_t>* out);  // appends
// Rows among `n` packed rows whose Hamming distance to `query` (bytes / 8 chunks) is below
// `threshold`: writes their indices and distances in increasing index order, returns the count.
int HammingBelow(const uint64_t* query, const uint64_t* blocks, int n, int chunks,
                 uint32_t threshold, uint32_t* index, uint32_t* distance);
// The distances of `query` to all `n` packed rows, in row order (out: n values).
void HammingAll(const uint64_t* query, const uint64_t* blocks, int n, int chunks, uint32_t* out);
// Hamming distance of two descriptors of `bytes` bytes.
uint32_t HammingDistance(const uint8_t* a, const uint8_t* b, int bytes);

// The kernels by name, for tests. The dispatched call uses the widest the CPU runs;
// GTBOW_SIMD=portable (or avx2, which has no vector popcount) caps it.
enum class HammingKernel { kPortable, kAvx512 };
bool HammingKernelSupported(HammingKernel kernel);
int HammingBelowUsing(HammingKernel kernel, const uint64_t* query, const uint64_t* blocks, int n,
                      int chunks, uint32_t threshold, uint32_t* index, uint32_t* distance);

}  // namespace gtbow
