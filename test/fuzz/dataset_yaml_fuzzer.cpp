// Fuzzes the dataset.yaml parser (DATASET_FORMAT.md). An accepted file must describe a usable
// dataset (positive image size and scale) and survive a round trip through FormatDatasetYaml.
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "fuzz_util.h"
#include "ground_texture_bow/eval/dataset.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace gtbow;
  const std::string text(reinterpret_cast<const char*>(data), size);
  DatasetInfo info;
  try {
    info = ParseDatasetYaml(text, "dataset.yaml");
  } catch (const std::runtime_error&) {
    ++fuzz::Rejected();
    return 0;
  }
  ++fuzz::Accepted();
  GTBOW_FUZZ_CHECK(info.geometry.width > 0 && info.geometry.height > 0);
  GTBOW_FUZZ_CHECK(std::isfinite(info.geometry.meters_per_pixel) &&
                   info.geometry.meters_per_pixel > 0);
  for (const auto& [split, day] : info.query_days) GTBOW_FUZZ_CHECK(std::isfinite(day));
  const DatasetInfo again = ParseDatasetYaml(FormatDatasetYaml(info), "round trip");
  GTBOW_FUZZ_CHECK(again.geometry.width == info.geometry.width);
  GTBOW_FUZZ_CHECK(again.geometry.height == info.geometry.height);
  GTBOW_FUZZ_CHECK(again.geometry.meters_per_pixel == info.geometry.meters_per_pixel);
  GTBOW_FUZZ_CHECK(again.query_days == info.query_days);
  GTBOW_FUZZ_CHECK(again.name == info.name && again.surface == info.surface);
  return 0;
}
