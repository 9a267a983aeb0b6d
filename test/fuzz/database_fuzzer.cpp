// Fuzzes the inverted-index readers: the database file (BowDatabase::Load, format 3,
// memory-mapped) and its in-memory form inside map files (BowDatabase::Deserialize). Mode
// byte: bit 0 repairs the checksums (fuzz_util.h), bit 1 selects precise postings instead of
// compact ones, bit 2 the in-memory form. An accepted index must answer queries with images it
// holds, survive new insertions and round-trip through Serialize.
#include <cstdint>

#include "fuzz_fixture.h"
#include "fuzz_util.h"
#include "ground_texture_bow/core/database.h"

namespace {

// A small query touching the first, some middle and the last rows, with keypoints in several
// orientation bins.
gtbow::BowVector Probe(uint32_t rows) {
  gtbow::BowVector v;
  const uint32_t picks[] = {0, 1, rows / 3, rows / 2, rows - 1};
  for (uint32_t i = 0; i < 5; ++i) {
    v.entries.push_back({picks[i], 0.4f});
    v.keypoints.push_back({picks[i], static_cast<uint16_t>(i), 0.5f});
    v.angles.push_back(1.3f * static_cast<float>(i));
  }
  return v;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace gtbow;
  if (size == 0) return 0;
  const bool compact = (data[0] & 2) == 0, in_memory = (data[0] & 4) != 0;
  const auto vocab = fuzz::FixtureVocabulary();
  const BowOptions options = fuzz::FixtureOptions(compact).retrieval.bow;
  const uint32_t rows = vocab->size() * options.SizeBins();
  BowDatabase db(rows, options, vocab->fingerprint());
  db.set_query_threads(1);
  try {
    if (in_memory) {
      const std::string blob(reinterpret_cast<const char*>(data) + 1, size - 1);
      db.Deserialize(blob.data(), blob.size(), "fuzz input");
    } else {
      const auto& path = fuzz::ScratchFile("database");
      fuzz::WriteScratch(path, fuzz::FileFromInput(data, size, fuzz::RepairDatabase));
      db.Load(path, 1);
    }
  } catch (const std::runtime_error&) {
    ++fuzz::Rejected();
    return 0;
  }
  ++fuzz::Accepted();
  const BowVector probe = Probe(rows);
  const uint32_t images = db.next_id();
  for (const QueryResult& r : db.Query(probe, 10, true)) {
    GTBOW_FUZZ_CHECK(r.image < images);
    for (const MatchPair& m : r.matches) GTBOW_FUZZ_CHECK(m.query_keypoint < probe.angles.size());
  }
  const uint32_t id = db.Add(probe);
  GTBOW_FUZZ_CHECK(id == images);
  const auto after = db.Query(probe, 3, true);
  GTBOW_FUZZ_CHECK(!after.empty());
  const std::string s = db.Serialize();
  BowDatabase copy(rows, options, vocab->fingerprint());
  copy.Deserialize(s.data(), s.size(), "round trip");
  GTBOW_FUZZ_CHECK(copy.next_id() == db.next_id());
  GTBOW_FUZZ_CHECK(copy.num_entries() == db.num_entries());
  return 0;
}
