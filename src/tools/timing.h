// Timing helpers shared by the benchmarking tools.
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <vector>

namespace gtbow {
namespace tools {

inline double Ms(std::chrono::steady_clock::duration d) {
  return std::chrono::duration<double, std::milli>(d).count();
}

// Mean, standard deviation, median, 95th and 99th percentiles and maximum of a set of timings.
struct TimingStats {
  double mean = 0, sd = 0, median = 0, p95 = 0, p99 = 0, max = 0;
};

inline TimingStats Summarise(std::vector<double> v) {
  TimingStats s;
  if (v.empty()) return s;
  for (double x : v) s.mean += x / v.size();
  for (double x : v) s.sd += (x - s.mean) * (x - s.mean) / v.size();
  s.sd = std::sqrt(s.sd);
  std::sort(v.begin(), v.end());
  s.median = v[v.size() / 2];
  s.p95 = v[std::min(v.size() - 1, v.size() * 95 / 100)];
  s.p99 = v[std::min(v.size() - 1, v.size() * 99 / 100)];
  s.max = v.back();
  return s;
}

}  // namespace tools
}  // namespace gtbow
