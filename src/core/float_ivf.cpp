#include "float_ivf.h"

namespace gtbow {
namespace vocabulary_internal {

// Not under ThreadSanitizer: the clones' ifunc resolvers run during relocation, before the
// TSan runtime is up, and crash once instrumented.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_THREAD__)
#define GTBOW_VOCAB_CLONE __attribute__((target_clones("avx2", "default")))
#else
#define GTBOW_VOCAB_CLONE
#endif

// Squared L2 distances from `q` to `n` contiguous rows of dimension `d`. Eight partial sums
// in a fixed order let the compiler vectorise without reassociating (results are identical on
// every CPU).
GTBOW_VOCAB_CLONE
void SquaredDistances(const float* __restrict q, const float* __restrict rows, int n, int d,
                      float* __restrict out) {
  const int d8 = d & ~7;
  for (int i = 0; i < n; ++i) {
    const float* r = rows + static_cast<size_t>(i) * d;
    float acc[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    for (int k = 0; k < d8; k += 8) {
      for (int j = 0; j < 8; ++j) {
        const float x = q[k + j] - r[k + j];
        acc[j] += x * x;
      }
    }
    float s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (int k = d8; k < d; ++k) {
      const float x = q[k] - r[k];
      s += x * x;
    }
    out[i] = s;
  }
}

}  // namespace vocabulary_internal
}  // namespace gtbow
