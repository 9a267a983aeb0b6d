// The choice of SIMD kernels at run time, shared by every kernel family of the core (Hamming
// distances, hamming_distance.h; squared L2 between bytes, byte_distance.h). Private to the core.
//
// Each family ranks its kernels by the instruction sets they need:
//   x86-64:  portable (0) < popcnt (1) < avx2 (2) < avx512 (3)
//   aarch64: portable (0) < neon (1)
// and runs the highest-ranked kernel that this build has, the CPU supports and GTBOW_SIMD
// allows (one exception: the Hamming distances run popcnt rather than avx2 on AMD's first Zen
// cores unless the cap is avx2 itself; hamming_distance.cpp, PopcntBeatsAvx2). GTBOW_SIMD=NAME
// (one of the names above) allows the kernels up to NAME's rank: it forces NAME where the
// family has that kernel and the CPU runs it, else the next narrower one
// (the byte distances have no popcnt kernel: GTBOW_SIMD=popcnt runs their portable one).
// Unset or empty: everything the CPU supports. A name this build does not know (or one of the
// other architecture's) is reported once on stderr and ignored. The variable is read once per
// process, when the first kernel is chosen; SetSimdLimit (simd.h) changes the cap later.
#pragma once

namespace gtbow {

constexpr int kSimdRankPortable = 0;
#if defined(__x86_64__)
constexpr int kSimdRankPopcnt = 1;
constexpr int kSimdRankAvx2 = 2;
constexpr int kSimdRankAvx512 = 3;
#elif defined(__aarch64__)
constexpr int kSimdRankNeon = 1;
#endif

// The highest rank GTBOW_SIMD (or SetSimdLimit) allows (a large number when it allows
// everything).
int SimdRankAllowed();
// Each family chooses its kernel again under the current cap (called by SetSimdLimit).
void RechooseHammingKernel();
void RechooseByteDistanceKernel();

}  // namespace gtbow
