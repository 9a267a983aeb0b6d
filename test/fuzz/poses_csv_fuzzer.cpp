// Fuzzes the poses.csv and sequence-file parsers (DATASET_FORMAT.md). Accepted poses must be
// finite, image names unique, and both files survive a round trip through their formatters.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <set>
#include <stdexcept>
#include <string>

#include "fuzz_util.h"
#include "ground_texture_bow/eval/dataset.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace gtbow;
  const std::string text(reinterpret_cast<const char*>(data), size);
  bool any = false;
  try {
    const std::vector<PoseRecord> poses = ParsePosesCsv(text, "poses.csv");
    any = true;
    std::set<std::string> names;
    for (const PoseRecord& p : poses) {
      GTBOW_FUZZ_CHECK(std::isfinite(p.pose.x) && std::isfinite(p.pose.y) &&
                       std::isfinite(p.pose.theta));
      GTBOW_FUZZ_CHECK(!p.image.empty() && names.insert(p.image).second);
    }
    const auto again = ParsePosesCsv(FormatPosesCsv(poses), "round trip");
    GTBOW_FUZZ_CHECK(again.size() == poses.size());
    for (size_t i = 0; i < poses.size(); ++i) {
      GTBOW_FUZZ_CHECK(again[i].image == poses[i].image);
      // The writer keeps 7 decimals (0.1 micrometre, 0.1 microradian).
      auto close = [](double a, double b) { return std::abs(a - b) <= 6e-8 + 1e-15 * std::abs(b); };
      GTBOW_FUZZ_CHECK(close(again[i].pose.x, poses[i].pose.x) &&
                       close(again[i].pose.y, poses[i].pose.y) &&
                       close(again[i].pose.theta, poses[i].pose.theta));
    }
  } catch (const std::runtime_error&) {
  }
  try {
    const std::vector<std::string> names = ParseSequence(text, "sequences/query.txt");
    any = true;
    GTBOW_FUZZ_CHECK(ParseSequence(FormatSequence(names), "round trip") == names);
  } catch (const std::runtime_error&) {
  }
  ++(any ? fuzz::Accepted() : fuzz::Rejected());
  return 0;
}
