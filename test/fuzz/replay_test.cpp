// Replays a fuzz target's inputs through the target, built with the ordinary compiler flags
// (or the sanitizers, in `make test-sanitize`): every input runs again on every build. Inputs
// are under GTBOW_FUZZ_ROOT (test/fuzz): corpus/<target> (what the fuzzer kept, minimised),
// seeds/<target> (make_seeds.cpp) and regressions/<target> (inputs that once found a bug).
#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

TEST(FuzzCorpus, EveryInputRunsCleanAndTheCorpusReachesBothOutcomes) {
  std::vector<std::filesystem::path> files;
  for (const char* kind : {"corpus", "seeds", "regressions"}) {
    const std::filesystem::path dir =
        std::filesystem::path(GTBOW_FUZZ_ROOT) / kind / GTBOW_FUZZ_TARGET;
    if (!std::filesystem::is_directory(dir)) continue;
    for (const auto& e : std::filesystem::directory_iterator(dir)) {
      if (e.is_regular_file()) files.push_back(e.path());
    }
  }
  std::sort(files.begin(), files.end());
  ASSERT_GE(files.size(), 3u) << "the corpus of " << GTBOW_FUZZ_TARGET << " is (nearly) empty";
  for (const auto& f : files) {
    SCOPED_TRACE(f.string());
    std::ifstream in(f, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    LLVMFuzzerTestOneInput(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
  }
  // A corpus of only rejected inputs would test nothing behind the first check.
  EXPECT_GT(gtbow::fuzz::Accepted(), 0u) << "no input of the corpus is accepted";
  EXPECT_GT(gtbow::fuzz::Rejected(), 0u) << "no input of the corpus is rejected";
  std::printf("%zu inputs: %zu accepted, %zu rejected\n", files.size(), gtbow::fuzz::Accepted(),
              gtbow::fuzz::Rejected());
}
