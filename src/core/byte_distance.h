// Squared L2 distances between byte vectors (ORB descriptors taken as 32 numbers), in exact
// integer arithmetic: AVX2 and AVX-512 VNNI kernels where the CPU has them, a portable loop
// otherwise. All give identical results. Private to the core.
#pragma once

#include <cstdint>
#include <vector>

namespace gtbow {

// Byte rows packed for a shuffle-free SIMD scan: blocks of 16 rows; within a block, for each
// pair of dimensions (2k, 2k + 1), the 16 rows' two values as 32 int16:
// [r0[2k], r0[2k+1], r1[2k], r1[2k+1], ..., r15[2k+1]]. A block takes 16 * d int16; the last
// block of a run is padded with zero rows. `d` must be even.
constexpr int kPackedBlockRows = 16;
void PackRows(const uint8_t* rows, int n, int d, std::vector<int16_t>* out);  // appends
// The query repeated to match: for each pair k, [q[2k], q[2k+1]] x 16 (16 * d int16).
void PackQuery(const uint8_t* q, int d, int16_t* out);
// Rows among `n` packed rows (ceil(n / 8) blocks) whose squared distance to the query is
// below `threshold`: writes their indices and distances in increasing index order and returns
// how many there are.
int PackedSquaredDistancesBelow(const int16_t* packed_query, const int16_t* blocks, int n, int d,
                                int32_t threshold, uint32_t* index, int32_t* distance);

// The kernels by name, so that tests can run each one the CPU supports. The dispatched call
// above uses ActiveSimdKernel(): the widest the CPU runs, capped by the environment variable
// GTBOW_SIMD (simd_dispatch.h: portable, popcnt (= portable here), avx2, avx512).
enum class SimdKernel { kPortable, kAvx2, kAvx512 };
const char* SimdKernelName(SimdKernel kernel);  // "portable", "avx2", "avx512"
bool SimdKernelSupported(SimdKernel kernel);
SimdKernel ActiveSimdKernel();
int PackedSquaredDistancesBelowUsing(SimdKernel kernel, const int16_t* packed_query,
                                     const int16_t* blocks, int n, int d, int32_t threshold,
                                     uint32_t* index, int32_t* distance);

}  // namespace gtbow
