// Fuzzes the retrieval-preset parser (config/*.yaml, ParseRetrievalConfig). An accepted preset
// must pass its own checks and survive a round trip through FormatRetrievalConfig.
#include <cstdint>
#include <stdexcept>
#include <string>

#include "fuzz_util.h"
#include "ground_texture_bow/core/config.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace gtbow;
  const std::string text(reinterpret_cast<const char*>(data), size);
  RetrievalConfig c;
  try {
    c = ParseRetrievalConfig(text, "preset.yaml");
  } catch (const std::runtime_error&) {
    ++fuzz::Rejected();
    return 0;
  }
  ++fuzz::Accepted();
  c.Check();  // throws (a finding) if the parser let a bad value through
  const std::string formatted = FormatRetrievalConfig(c);
  GTBOW_FUZZ_CHECK(FormatRetrievalConfig(ParseRetrievalConfig(formatted, "round trip")) ==
                   formatted);
  return 0;
}
