// Deterministic hashing and noise for the procedural floor. Private to the core.
// Everything is a pure function of integer lattice coordinates and a seed, so any region of
// the unbounded floor renders identically whatever view it is seen from.
#pragma once

#include <cmath>
#include <cstdint>

namespace gtbow {
namespace synth {

// splitmix64 finaliser: a strong 64-bit mixer.
inline uint64_t Mix64(uint64_t x) {
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ULL;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebULL;
  x ^= x >> 31;
  return x;
}

inline uint64_t HashCell(int64_t ix, int64_t iy, uint64_t seed) {
  return Mix64(seed ^ Mix64(static_cast<uint64_t>(ix) * 0x9E3779B97F4A7C15ULL +
                            static_cast<uint64_t>(iy) * 0xC2B2AE3D27D4EB4FULL));
}

inline uint64_t HashCombine(uint64_t a, uint64_t b) {
  return Mix64(a ^ (b + 0x9E3779B97F4A7C15ULL));
}

// Cheap 32-bit lattice hash for per-pixel value noise; returns a value in [-1, 1).
inline float LatticeValue(int32_t ix, int32_t iy, uint32_t seed) {
  uint32_t h =
      seed ^ (static_cast<uint32_t>(ix) * 0x8da6b343U) ^ (static_cast<uint32_t>(iy) * 0xd8163841U);
  h ^= h >> 15;
  h *= 0x2c1b3c6dU;
  h ^= h >> 12;
  h *= 0x297a2d39U;
  h ^= h >> 15;
  return static_cast<float>(h) * (2.0f / 4294967296.0f) - 1.0f;
}

// floor() as an integer, inlined (std::floor is a library call on baseline x86-64).
inline int64_t FloorToInt(double x) {
  const int64_t i = static_cast<int64_t>(x);
  return i - (x < static_cast<double>(i) ? 1 : 0);
}

// Value noise with smoothstep interpolation, unit lattice spacing, range about [-1, 1].
inline float ValueNoise(double x, double y, uint32_t seed) {
  const int64_t lx = FloorToInt(x);
  const int64_t ly = FloorToInt(y);
  const int32_t ix = static_cast<int32_t>(lx);
  const int32_t iy = static_cast<int32_t>(ly);
  const float tx = static_cast<float>(x - static_cast<double>(lx));
  const float ty = static_cast<float>(y - static_cast<double>(ly));
  const float sx = tx * tx * (3.0f - 2.0f * tx);
  const float sy = ty * ty * (3.0f - 2.0f * ty);
  const float a = LatticeValue(ix, iy, seed);
  const float b = LatticeValue(ix + 1, iy, seed);
  const float c = LatticeValue(ix, iy + 1, seed);
  const float d = LatticeValue(ix + 1, iy + 1, seed);
  const float ab = a + sx * (b - a);
  const float cd = c + sx * (d - c);
  return ab + sy * (cd - ab);
}

// Fractal sum of `octaves` value-noise octaves starting at lattice spacing 1.
inline float Fbm(double x, double y, uint32_t seed, int octaves, float gain = 0.5f) {
  float sum = 0.0f;
  float amp = 1.0f;
  float norm = 0.0f;
  for (int o = 0; o < octaves; ++o) {
    sum += amp * ValueNoise(x, y, seed + 0x9E37U * static_cast<uint32_t>(o));
    norm += amp;
    amp *= gain;
    x *= 2.03;
    y *= 2.03;
  }
  return sum / norm;
}

// A small counter-based generator for per-element random draws.
class CellRng {
 public:
  explicit CellRng(uint64_t seed) : state_(seed) {}
  uint64_t Next() {
    state_ += 0x9E3779B97F4A7C15ULL;
    return Mix64(state_);
  }
  double Uniform() { return static_cast<double>(Next() >> 11) * (1.0 / 9007199254740992.0); }
  double Uniform(double lo, double hi) { return lo + (hi - lo) * Uniform(); }
  double Normal() {
    const double u1 = Uniform() + 1e-300;
    const double u2 = Uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
  }
  // Approximately standard normal (Irwin-Hall sum of four uniforms): cheap, bounded by +-3.5.
  double ApproxNormal() {
    return (Uniform() + Uniform() + Uniform() + Uniform() - 2.0) * 1.7320508075688772;
  }
  // Poisson count given exp(-mean) (Knuth; means are small here).
  int PoissonExp(double exp_minus_mean) {
    int k = 0;
    double p = Uniform();
    while (p > exp_minus_mean && k < 64) {
      ++k;
      p *= Uniform();
    }
    return k;
  }
  // Poisson-distributed count with the given mean (Knuth; means are small here).
  int Poisson(double mean) {
    const double l = std::exp(-mean);
    int k = 0;
    double p = Uniform();
    while (p > l && k < 64) {
      ++k;
      p *= Uniform();
    }
    return k;
  }

 private:
  uint64_t state_;
};

inline float SmoothStep(float e0, float e1, float x) {
  float t = (x - e0) / (e1 - e0);
  t = t < 0.0f ? 0.0f : (t > 1.0f ? 1.0f : t);
  return t * t * (3.0f - 2.0f * t);
}

}  // namespace synth
}  // namespace gtbow
