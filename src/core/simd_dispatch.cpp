#include "simd_dispatch.h"

#include <atomic>
#include <climits>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "ground_texture_bow/core/simd.h"

namespace gtbow {

namespace {

struct NamedRank {
  const char* name;
  int rank;
};

constexpr NamedRank kRanks[] = {
    {"portable", kSimdRankPortable},
#if defined(__x86_64__)
    {"popcnt", kSimdRankPopcnt},
    {"avx2", kSimdRankAvx2},
    {"avx512", kSimdRankAvx512},
#elif defined(__aarch64__)
    {"neon", kSimdRankNeon},
#endif
};

int ReadRank() {
  const char* value = std::getenv("GTBOW_SIMD");
  if (value == nullptr || value[0] == '\0') return INT_MAX;
  for (const NamedRank& r : kRanks) {
    if (std::strcmp(value, r.name) == 0) return r.rank;
  }
  std::string names;
  for (const NamedRank& r : kRanks) names += std::string(names.empty() ? "" : ", ") + r.name;
  std::fprintf(stderr, "gtbow: GTBOW_SIMD=%s is not a kernel of this build (%s): ignored\n", value,
               names.c_str());
  return INT_MAX;
}

std::atomic<int> g_rank_override{-1};  // SetSimdLimit's cap; -1: GTBOW_SIMD's

}  // namespace

int SimdRankAllowed() {
  const int over = g_rank_override.load(std::memory_order_relaxed);
  if (over >= 0) return over;
  static const int rank = ReadRank();
  return rank;
}

bool SetSimdLimit(const std::string& name) {
  int rank = -1;
  if (name.empty()) rank = INT_MAX;
  for (const NamedRank& r : kRanks) {
    if (name == r.name) rank = r.rank;
  }
  if (rank < 0) return false;
  g_rank_override.store(rank, std::memory_order_relaxed);
  RechooseHammingKernel();
  RechooseByteDistanceKernel();
  return true;
}

std::string SimdLimit() {
  const int rank = SimdRankAllowed();
  for (const NamedRank& r : kRanks) {
    if (r.rank == rank) return r.name;
  }
  return "";
}

std::string ActiveSimdKernels() {
  return std::string("hamming ") + ActiveHammingKernelName() + ", l2_bytes " +
         ActiveByteDistanceKernelName();
}

}  // namespace gtbow
