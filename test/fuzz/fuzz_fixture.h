// The small map the binary-file fuzzers work on: a 64-word vocabulary (test/fuzz/data/
// tiny.gtvoc, made by make_seeds.cpp) and the retrieval options its seed maps were built with.
// GTBOW_FUZZ_DATA is the data directory (a compile definition).
#pragma once

#include <memory>

#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/vocabulary.h"

namespace gtbow {
namespace fuzz {

inline const char* FixtureVocabularyPath() { return GTBOW_FUZZ_DATA "/tiny.gtvoc"; }

// `compact`: compact or precise postings (the database fuzzer covers both layouts).
inline LocalizerOptions FixtureOptions(bool compact = true) {
  LocalizerOptions o;
  o.retrieval.features.num_features = 40;
  o.retrieval.vocabulary.num_words = 64;
  o.retrieval.vocabulary.nprobe = 4;
  o.retrieval.bow.compact_postings = compact;
  o.meters_per_pixel = 0.0002;
  o.threads = 1;
  return o;
}

inline std::shared_ptr<Vocabulary> FixtureVocabulary() {
  static const std::shared_ptr<Vocabulary> v = [] {
    std::shared_ptr<Vocabulary> voc = Vocabulary::Load(FixtureVocabularyPath());
    voc->set_search(FixtureOptions().retrieval.vocabulary.ann,
                    FixtureOptions().retrieval.vocabulary.nprobe);
    return voc;
  }();
  return v;
}

}  // namespace fuzz
}  // namespace gtbow
