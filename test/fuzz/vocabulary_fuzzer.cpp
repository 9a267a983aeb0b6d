// Fuzzes the vocabulary file reader (Vocabulary::Load). An accepted vocabulary must be usable:
// descriptors are assigned to words in range, and saving and loading it again gives the same
// fingerprint.
#include <algorithm>
#include <cstdint>

#include <opencv2/core.hpp>

#include "fuzz_util.h"
#include "ground_texture_bow/core/vocabulary.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace gtbow;
  const std::string file = fuzz::FileFromInput(data, size, fuzz::RepairFramed);
  const auto& path = fuzz::ScratchFile("vocabulary");
  fuzz::WriteScratch(path, file);
  std::unique_ptr<Vocabulary> v;
  try {
    v = Vocabulary::Load(path);
  } catch (const std::runtime_error&) {
    ++fuzz::Rejected();
    return 0;
  }
  ++fuzz::Accepted();
  GTBOW_FUZZ_CHECK(v->size() > 0);
  GTBOW_FUZZ_CHECK(v->idf().size() == v->size());
  // A few descriptors as the features give them (ORB: 32 bytes; SIFT: 128 floats), assigned
  // with both word searches. A vocabulary of another length refuses them (invalid_argument).
  const bool sift = v->metric() == Metric::kL2;
  cv::Mat d(3, sift ? 128 : 32, sift ? CV_32F : CV_8U);
  cv::randu(d, 0, 255);
  const int r = std::min(2, v->max_neighbours());
  for (const AnnIndex ann : {AnnIndex::kFlann, AnnIndex::kIvf}) {
    v->set_search(ann, 4);
    std::vector<WordHit> hits;
    try {
      v->Assign(d, r, &hits);
    } catch (const std::invalid_argument&) {
      break;
    }
    GTBOW_FUZZ_CHECK(hits.size() == static_cast<size_t>(d.rows * r));
    for (const WordHit& h : hits) GTBOW_FUZZ_CHECK(h.word < v->size());
  }
  const auto again = fuzz::ScratchFile("vocabulary_again");
  v->Save(again);
  GTBOW_FUZZ_CHECK(Vocabulary::Load(again)->fingerprint() == v->fingerprint());
  return 0;
}
