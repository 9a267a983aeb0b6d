// Fuzzes the map file reader (Localizer::Load) with the fixture vocabulary and options
// (fuzz_fixture.h). Mode byte bit 0 repairs the file's checksums (fuzz_util.h's RepairMap). An
// accepted map must answer a query for each of its keyframes (candidates in range, verification run
// on the stored keypoints) and save again.
#include <cstdint>

#include "fuzz_fixture.h"
#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace gtbow;
  static Localizer localizer(fuzz::FixtureVocabulary(), fuzz::FixtureVocabularyPath(),
                             fuzz::FixtureOptions());
  const auto& path = fuzz::ScratchFile("map");
  fuzz::WriteScratch(path, fuzz::FileFromInput(data, size, fuzz::RepairMap));
  try {
    localizer.Load(path);
  } catch (const std::runtime_error&) {
    ++fuzz::Rejected();
    return 0;
  }
  ++fuzz::Accepted();
  const size_t n = localizer.size();
  for (uint32_t id = 0; id < n && id < 8; ++id) {
    for (const Candidate& c : localizer.QueryKeyframe(id, 3, true)) {
      GTBOW_FUZZ_CHECK(c.id < n && c.id != id);
    }
  }
  const auto again = fuzz::ScratchFile("map_again");
  localizer.Save(again);
  return 0;
}
