// Hamming distances between binary descriptors (ORB: 32 bytes = 256 bits), the only place of the
// core that counts bits. Kernels, chosen at run time (simd_dispatch.h; GTBOW_SIMD):
//   portable  plain C++ with a bit-twiddling popcount (no instruction set beyond the baseline;
//             never the libgcc call __builtin_popcountll becomes on baseline x86-64)
//   popcnt    x86-64's 64-bit POPCNT instruction
//   avx2      packed scans: a 4-bit table lookup (vpshufb) per byte and a sum of absolute
//             differences (vpsadbw) per 64-bit lane, 4 rows per register; POPCNT for pairs
//             (not chosen on AMD's first Zen cores unless GTBOW_SIMD=avx2: popcnt is faster there)
//   avx512    packed scans: AVX-512 VPOPCNTDQ, 8 rows per register; POPCNT for pairs
//   neon      aarch64's per-byte count (vcnt) and pairwise widening adds
// Every kernel gives the same distances, bit for bit. Private to the core.
#pragma once

#include <cstddef>
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
// `index` and `distance` need room for n values (a kernel may write past the count).
int HammingBelow(const uint64_t* query, const uint64_t* blocks, int n, int chunks,
                 uint32_t threshold, uint32_t* index, uint32_t* distance);
// The distances of `query` to all `n` packed rows, in row order (out: n values).
void HammingAll(const uint64_t* query, const uint64_t* blocks, int n, int chunks, uint32_t* out);
// Hamming distance of two descriptors of `bytes` bytes (any length).
uint32_t HammingDistance(const uint8_t* a, const uint8_t* b, int bytes);
// The first of `n` rows of `bytes` bytes, `stride` bytes apart, at the smallest distance to `q`
// (ties: the lower index); its distance in *distance. -1 (and *distance untouched) when n = 0.
int HammingNearest(const uint8_t* q, const uint8_t* rows, size_t stride, int n, int bytes,
                   uint32_t* distance);

// The kernels by name, for tests and reports. The calls above use ActiveHammingKernel().
enum class HammingKernel { kPortable, kPopcnt, kAvx2, kAvx512, kNeon };
constexpr HammingKernel kAllHammingKernels[] = {HammingKernel::kPortable, HammingKernel::kPopcnt,
                                                HammingKernel::kAvx2, HammingKernel::kAvx512,
                                                HammingKernel::kNeon};
const char* HammingKernelName(HammingKernel kernel);  // "portable", "popcnt", ...
// Whether this build has the kernel and the CPU runs it.
bool HammingKernelSupported(HammingKernel kernel);
// The kernel the calls above use: the widest supported one that GTBOW_SIMD allows.
HammingKernel ActiveHammingKernel();
// The calls above through a given kernel; std::invalid_argument when it is not supported.
int HammingBelowUsing(HammingKernel kernel, const uint64_t* query, const uint64_t* blocks, int n,
                      int chunks, uint32_t threshold, uint32_t* index, uint32_t* distance);
void HammingAllUsing(HammingKernel kernel, const uint64_t* query, const uint64_t* blocks, int n,
                     int chunks, uint32_t* out);
uint32_t HammingDistanceUsing(HammingKernel kernel, const uint8_t* a, const uint8_t* b, int bytes);
int HammingNearestUsing(HammingKernel kernel, const uint8_t* q, const uint8_t* rows, size_t stride,
                        int n, int bytes, uint32_t* distance);

}  // namespace gtbow
