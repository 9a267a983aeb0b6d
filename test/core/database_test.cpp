#include "ground_texture_bow/core/database.h"

#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <random>
#include <sstream>
#include <thread>

#include <gtest/gtest.h>

#include "test_util.h"

#include "ground_texture_bow/core/file_util.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace {

// Stored weights d_w * c_d: precise entries are 16-bit (steps of 1 / 65535), so a score built
// from a few entries is exact to a few steps; compact entries are 8-bit on a log scale (at most
// 2^(1/32) - 1 = 2.2% off each).
constexpr double kWeightTolerance = 4.0 / 65535.0;
constexpr double kCompactRelative = 0.022;

// A hand-made BoW vector: keypoint i sits on row rows[i] with angle angles[i]; each row's
// weight is given, and contributions split a row evenly among its keypoints.
BowVector Make(const std::vector<uint32_t>& rows, const std::vector<float>& angles,
               const std::map<uint32_t, float>& weight) {
  BowVector v;
  v.angles = angles;
  for (size_t i = 0; i < rows.size(); ++i)
    v.keypoints.push_back({rows[i], static_cast<uint16_t>(i), 0, 1});
  std::sort(v.keypoints.begin(), v.keypoints.end(),
            [](const KeypointEntry& a, const KeypointEntry& b) { return a.row < b.row; });
  std::map<uint32_t, int> count;
  for (uint32_t r : rows) ++count[r];
  for (auto& k : v.keypoints) k.contribution = 1.0f / count[k.row];
  for (const auto& [row, w] : weight) v.entries.push_back({row, w});
  return v;
}

BowOptions Ov(bool on = true, bool compact = true) {
  BowOptions o;
  o.orientation_verification = on;
  o.orientation_bins = 6;
  o.compact_postings = compact;
  return o;
}

// The value tests run on both entry layouts (parameter: compact).
class DatabaseLayout : public ::testing::TestWithParam<bool> {
 protected:
  BowOptions Opt(bool ov = true) const { return Ov(ov, GetParam()); }
  double Tol(double expected) const {
    return GetParam() ? kCompactRelative * expected + 1e-6 : kWeightTolerance;
  }
};

INSTANTIATE_TEST_SUITE_P(Layouts, DatabaseLayout, ::testing::Values(true, false),
                         [](const auto& info) { return info.param ? "compact" : "precise"; });

TEST_P(DatabaseLayout, OrientationVotesGoToTheDifferenceBin) {
  BowDatabase db(100, Opt(), 7);
  // Image 0: both keypoints turned by +1.0 rad relative to the query (bin 0 of 6).
  const uint32_t a = db.Add(Make({5, 7}, {1.1f, 1.2f}, {{5, 0.6f}, {7, 0.8f}}));
  // Image 1: the same rows, but inconsistent turns: +1.0 and +4.0 rad (bins 0 and 3).
  const uint32_t b = db.Add(Make({5, 7}, {1.1f, 4.2f}, {{5, 0.6f}, {7, 0.8f}}));
  const BowVector q = Make({5, 7}, {0.1f, 0.2f}, {{5, 0.6f}, {7, 0.8f}});
  const auto res = db.Query(q, 10);
  ASSERT_EQ(res.size(), 2u);
  EXPECT_EQ(res[0].image, a);
  EXPECT_NEAR(res[0].score, 0.36 + 0.64, Tol(1.0));
  EXPECT_EQ(res[0].orientation_bin, 0);
  EXPECT_EQ(res[0].matches.size(), 2u);
  EXPECT_EQ(res[1].image, b);
  EXPECT_NEAR(res[1].score, 0.64, Tol(0.64));  // only the row-7 vote survives, in bin 3
  EXPECT_EQ(res[1].orientation_bin, 3);
  ASSERT_EQ(res[1].matches.size(), 1u);
  EXPECT_EQ(res[1].matches[0].query_keypoint, 1);
  EXPECT_NEAR(res[1].matches[0].weight, 0.64, Tol(0.64));
}

TEST_P(DatabaseLayout, AngleDifferencesWrapAround) {
  BowDatabase db(10, Opt(), 7);
  // Query at 6.2 rad, database at 0.1 rad: the difference is +0.18 rad, bin 0, not bin 5.
  db.Add(Make({3}, {0.1f}, {{3, 1.0f}}));
  const auto res = db.Query(Make({3}, {6.2f}, {{3, 1.0f}}), 1);
  ASSERT_EQ(res.size(), 1u);
  EXPECT_EQ(res[0].orientation_bin, 0);
  // And -0.18 rad lands in the last bin.
  const auto back = db.Query(Make({3}, {0.28f}, {{3, 1.0f}}), 1);
  EXPECT_EQ(back[0].orientation_bin, 5);
}

TEST_P(DatabaseLayout, SeveralKeypointsOnOneRowVoteByContribution) {
  BowDatabase db(10, Opt(), 7);
  // Two database keypoints on row 2 (c = 0.5 each), turned by 0.5 and 3.5 rad.
  db.Add(Make({2, 2}, {0.5f, 3.5f}, {{2, 1.0f}}));
  const auto res = db.Query(Make({2}, {0.0f}, {{2, 1.0f}}), 1);
  EXPECT_NEAR(res[0].score, 0.5, Tol(0.5));  // the vote splits: each bin gets half
}

TEST_P(DatabaseLayout, WithoutOvTheScoreIsTheDotProductAndL1IsDbows) {
  BowDatabase dot(10, Opt(false), 7);
  dot.Add(Make({1, 2}, {0.0f, 3.0f}, {{1, 0.6f}, {2, 0.8f}}));
  const auto r = dot.Query(Make({1, 2}, {1.0f, 1.0f}, {{1, 0.8f}, {2, 0.6f}}), 1);
  EXPECT_NEAR(r[0].score, 0.6 * 0.8 + 0.8 * 0.6, Tol(0.96));
  EXPECT_EQ(r[0].orientation_bin, -1);
  EXPECT_EQ(r[0].matches.size(), 2u);

  BowOptions l1 = Opt(false);
  l1.scoring = Scoring::kDbowL1;
  BowDatabase dbow(10, l1, 7);
  dbow.Add(Make({1, 2, 3}, {0, 0, 0}, {{1, 0.5f}, {2, 0.3f}, {3, 0.2f}}));
  const auto s = dbow.Query(Make({1, 2, 4}, {0, 0, 0}, {{1, 0.2f}, {2, 0.4f}, {4, 0.4f}}), 1);
  EXPECT_NEAR(s[0].score, 0.2 + 0.3, Tol(0.5));  // 1 - |v - w|_1 / 2
}

TEST(Database, RemoveAndTopN) {
  BowDatabase db(10, Ov(), 7);
  for (int i = 0; i < 5; ++i) db.Add(Make({1}, {0.0f}, {{1, 0.1f * (i + 1)}}));
  EXPECT_EQ(db.size(), 5u);
  auto res = db.Query(Make({1}, {0.0f}, {{1, 1.0f}}), 3);
  ASSERT_EQ(res.size(), 3u);
  EXPECT_EQ(res[0].image, 4u);
  EXPECT_EQ(res[2].image, 2u);
  EXPECT_TRUE(db.Remove(4));
  EXPECT_FALSE(db.Remove(4));
  EXPECT_FALSE(db.Remove(99));
  EXPECT_EQ(db.size(), 4u);
  res = db.Query(Make({1}, {0.0f}, {{1, 1.0f}}), 1);
  EXPECT_EQ(res[0].image, 3u);
  EXPECT_EQ(db.Add(Make({1}, {0.0f}, {{1, 1.0f}})), 5u);  // ids are not reused
}

class DatabaseFiles : public testing_util::TempDirTest {};

TEST_F(DatabaseFiles, RoundTripGivesIdenticalAnswersAndBadFilesAreRejected) {
  BowDatabase db(50, Ov(), 42);
  for (uint32_t i = 0; i < 20; ++i) {
    db.Add(Make({i % 50, (i * 7) % 50, (i * 13) % 50}, {0.1f * i, 0.2f * i, 0.3f * i},
                {{i % 50, 0.5f}, {(i * 7) % 50, 0.3f}, {(i * 13) % 50, 0.2f}}));
  }
  db.Remove(3);
  const fs::path f = dir_ / "map.gtdb";
  db.Save(f);
  BowDatabase back(50, Ov(), 42);
  back.Load(f);
  EXPECT_EQ(back.size(), 19u);
  for (uint32_t i = 0; i < 20; ++i) {
    const BowVector q =
        Make({i % 50, (i * 7) % 50}, {0.5f, 1.0f}, {{i % 50, 0.7f}, {(i * 7) % 50, 0.7f}});
    const auto a = db.Query(q, 5), b = back.Query(q, 5);
    ASSERT_EQ(a.size(), b.size());
    for (size_t k = 0; k < a.size(); ++k) {
      EXPECT_EQ(a[k].image, b[k].image);
      EXPECT_EQ(a[k].score, b[k].score);
      EXPECT_EQ(a[k].matches.size(), b[k].matches.size());
    }
  }
  // Another vocabulary, other options, damaged files: errors, and the contents survive.
  BowDatabase other_vocab(50, Ov(), 43);
  EXPECT_THROW(other_vocab.Load(f), std::runtime_error);
  BowDatabase other_opts(50, Ov(false), 42);
  EXPECT_THROW(other_opts.Load(f), std::runtime_error);
  const std::string good = ReadFile(f);
  std::string bad = good;
  bad[good.size() / 3] ^= 1;
  WriteFileAtomic(dir_ / "bad.gtdb", bad);
  try {
    back.Load(dir_ / "bad.gtdb");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("checksum"), std::string::npos);
  }
  WriteFileAtomic(dir_ / "short.gtdb", good.substr(0, good.size() / 2));
  EXPECT_THROW(back.Load(dir_ / "short.gtdb"), std::runtime_error);
  EXPECT_EQ(back.size(), 19u);
}

// A random image: `n` keypoints on random rows of `rows`, random angles and weights.
BowVector RandomVector(std::mt19937* rng, uint32_t rows, int n) {
  std::uniform_int_distribution<uint32_t> row(0, rows - 1);
  std::uniform_real_distribution<float> angle(0.0f, 6.28f), weight(0.05f, 1.0f);
  std::vector<uint32_t> r;
  std::vector<float> a;
  std::map<uint32_t, float> w;
  for (int i = 0; i < n; ++i) {
    r.push_back(row(*rng));
    a.push_back(angle(*rng));
    w[r.back()] = weight(*rng);
  }
  float norm = 0.0f;
  for (const auto& [k, x] : w) norm += x * x;
  for (auto& [k, x] : w) x /= std::sqrt(norm);
  return Make(r, a, w);
}

// Queries running while one writer inserts (what the node does: its worker inserts keyframes
// while services query) each see the database as it was after some number of insertions:
// every answer equals, field for field, the answer of a database holding exactly the first n
// images, for an n between the sizes read just before and just after the query. A torn read
// (a row half appended, an image counted but not yet written) matches no such prefix. Run
// under ThreadSanitizer by make test-sanitize.
TEST(Database, ConcurrentQueriesSeeAPrefixOfTheInsertions) {
  constexpr uint32_t kRows = 300;
  constexpr uint32_t kImages = 400;
  std::mt19937 rng(11);
  std::vector<BowVector> images, queries;
  for (uint32_t i = 0; i < kImages; ++i) images.push_back(RandomVector(&rng, kRows, 40));
  for (int q = 0; q < 3; ++q) queries.push_back(RandomVector(&rng, kRows, 40));
  auto describe = [](const std::vector<QueryResult>& results) {
    std::ostringstream o;
    o.precision(9);
    for (const QueryResult& r : results) {
      o << r.image << ' ' << r.score << ' ' << r.orientation_bin << ' ' << r.matches.size() << ';';
    }
    return o.str();
  };
  // The answers of every prefix, computed one insertion at a time.
  std::vector<std::vector<std::string>> expected(queries.size());
  {
    BowDatabase seq(kRows, Ov(), 1);
    for (size_t q = 0; q < queries.size(); ++q)
      expected[q].push_back(describe(seq.Query(queries[q], 5)));
    for (const BowVector& v : images) {
      seq.Add(v);
      for (size_t q = 0; q < queries.size(); ++q) {
        expected[q].push_back(describe(seq.Query(queries[q], 5)));
      }
    }
  }
  BowDatabase db(kRows, Ov(), 1);
  std::atomic<bool> stop{false};
  std::atomic<int> queries_done{0}, mismatches{0}, overlapping{0};
  std::vector<std::thread> readers;
  for (int t = 0; t < 2; ++t) {
    readers.emplace_back([&, t]() {
      for (size_t k = t; !stop; ++k) {
        const size_t q = k % queries.size();
        const size_t before = db.size();
        const std::string got = describe(db.Query(queries[q], 5));
        const size_t after = db.size();
        bool ok = false;
        for (size_t n = before; n <= after && !ok; ++n) ok = expected[q][n] == got;
        mismatches += ok ? 0 : 1;
        overlapping += after > before ? 1 : 0;
        ++queries_done;
      }
    });
  }
  // The writer interleaves with the readers: it waits for their progress as it goes.
  for (uint32_t i = 0; i < kImages; ++i) {
    if (i % 20 == 0) {
      const int seen = queries_done.load();
      while (queries_done.load() < seen + 2) std::this_thread::yield();
    }
    db.Add(images[i]);
  }
  stop = true;
  for (auto& t : readers) t.join();
  std::printf("%d concurrent queries, %d overlapped an insertion, %d matched no prefix\n",
              queries_done.load(), overlapping.load(), mismatches.load());
  EXPECT_EQ(db.size(), kImages);
  EXPECT_GE(queries_done.load(), 40);
  EXPECT_EQ(mismatches.load(), 0);
  for (size_t q = 0; q < queries.size(); ++q) {
    EXPECT_EQ(describe(db.Query(queries[q], 5)), expected[q].back());
  }
}

// The paper's score computed naively from the vectors: per image, the best orientation bin of
// q_w c_q d_w c_d over keypoint pairs on shared rows.
float NaiveScore(const BowVector& q, const BowVector& d, int bins) {
  std::vector<double> acc(bins, 0.0);
  for (const KeypointEntry& kq : q.keypoints) {
    for (const KeypointEntry& kd : d.keypoints) {
      if (kq.row != kd.row) continue;
      float wq = 0, wd = 0;
      for (const auto& e : q.entries) wq = e.row == kq.row ? e.weight : wq;
      for (const auto& e : d.entries) wd = e.row == kd.row ? e.weight : wd;
      const int qa = static_cast<int>(std::lround(q.angles[kq.keypoint] / (2 * M_PI) * 256)) & 255;
      const int da = static_cast<int>(std::lround(d.angles[kd.keypoint] / (2 * M_PI) * 256)) & 255;
      acc[((da - qa) & 255) * bins / 256] += wq * kq.contribution * wd * kd.contribution;
    }
  }
  return static_cast<float>(*std::max_element(acc.begin(), acc.end()));
}

void ExpectSameResults(const std::vector<QueryResult>& a, const std::vector<QueryResult>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t k = 0; k < a.size(); ++k) {
    EXPECT_EQ(a[k].image, b[k].image) << "rank " << k;
    EXPECT_EQ(a[k].score, b[k].score) << "rank " << k;
    EXPECT_EQ(a[k].orientation_bin, b[k].orientation_bin) << "rank " << k;
    EXPECT_EQ(a[k].matches.size(), b[k].matches.size()) << "rank " << k;
  }
}

class DatabaseScale : public testing_util::TempDirTest,
                      public ::testing::WithParamInterface<bool> {};

INSTANTIATE_TEST_SUITE_P(Layouts, DatabaseScale, ::testing::Values(true, false),
                         [](const auto& info) { return info.param ? "compact" : "precise"; });

// 70,000 images span three query blocks (32,768 images each with R = 6). Whatever the thread
// count, and whether entries sit in a loaded (mapped) base, a deserialized block or the
// growable tail, the answers are the same, and they agree with the naive score.
TEST_P(DatabaseScale, BlocksThreadsAndStorageGiveIdenticalAnswers) {
  constexpr uint32_t kRows = 3000, kImages = 70000, kLater = 3000;
  const BowOptions o = Ov(true, GetParam());
  std::mt19937 rng(11);
  std::vector<BowVector> vecs;
  for (uint32_t i = 0; i < kImages + kLater; ++i) vecs.push_back(RandomVector(&rng, kRows, 6));
  BowDatabase online(kRows, o, 5);
  for (uint32_t i = 0; i < kImages; ++i) online.Add(vecs[i]);
  online.Remove(17);
  const fs::path f = dir_ / "big.gtdb";
  online.Save(f);
  BowDatabase mapped(kRows, o, 5), blob(kRows, o, 5);
  mapped.Load(f);
  blob.Deserialize(online.Serialize().data(), online.Serialize().size(), "blob");
  for (uint32_t i = kImages; i < kImages + kLater; ++i) {
    EXPECT_EQ(online.Add(vecs[i]), i);
    EXPECT_EQ(mapped.Add(vecs[i]), i);
    EXPECT_EQ(blob.Add(vecs[i]), i);
  }
  EXPECT_EQ(mapped.num_entries(), online.num_entries());
  // The mapped file may be replaced meanwhile: the mapping keeps the old contents.
  BowDatabase(kRows, o, 5).Save(f);
  for (int n = 0; n < 12; ++n) {
    // Half the queries are database images (found first), half are random.
    const uint32_t src = (n * 6151u) % (kImages + kLater);
    const BowVector q = n % 2 == 0 ? vecs[src] : RandomVector(&rng, kRows, 40);
    online.set_query_threads(1);
    const auto ref = online.Query(q, 20);
    for (int threads : {2, 3}) {
      online.set_query_threads(threads);
      ExpectSameResults(ref, online.Query(q, 20));
    }
    mapped.set_query_threads(2);
    ExpectSameResults(ref, mapped.Query(q, 20));
    ExpectSameResults(ref, blob.Query(q, 20));
    // Both scans of a block (every image's cells, or a list of the images voted for), forced.
    for (const char* dense : {"1", "0"}) {
      ::setenv("GTBOW_QUERY_DENSE", dense, 1);
      ExpectSameResults(ref, online.Query(q, 20));
      ExpectSameResults(ref, mapped.Query(q, 20));
      ::unsetenv("GTBOW_QUERY_DENSE");
    }
    ASSERT_FALSE(ref.empty());
    if (n % 2 == 0 && src != 17) {
      EXPECT_EQ(ref[0].image, src);
    }
    for (const auto& r : ref) {
      EXPECT_NE(r.image, 17u);
      const float naive = NaiveScore(q, vecs[r.image], 6);
      EXPECT_NEAR(r.score, naive, (GetParam() ? kCompactRelative : 1e-3) * naive + 1e-5);
    }
    // No image outside the results scores above the last one (beyond the rounding).
    float best_outside = 0.0f;
    for (uint32_t i = 0; i < kImages + kLater; i += 7) {
      if (i == 17 ||
          std::any_of(ref.begin(), ref.end(), [i](const auto& r) { return r.image == i; }))
        continue;
      best_outside = std::max(best_outside, NaiveScore(q, vecs[i], 6));
    }
    EXPECT_LE(best_outside,
              ref.back().score * (1.0 + (GetParam() ? 2 * kCompactRelative : 1e-3)) + 1e-5);
  }
  // Saving what was loaded and added gives the same index again.
  const fs::path g = dir_ / "again.gtdb";
  mapped.Save(g);
  BowDatabase again(kRows, o, 5);
  again.Load(g, 1);
  const BowVector q = vecs[kImages + 5];
  ExpectSameResults(online.Query(q, 10), again.Query(q, 10));
  const size_t entry = GetParam() ? 6 : 8;
  EXPECT_NEAR(static_cast<double>(fs::file_size(g)),
              static_cast<double>(again.num_entries() * entry), 0.2 * again.num_entries() * entry);
}

TEST(Database, CompactPostingsHoldAtMost256KeypointsPerImage) {
  std::vector<uint32_t> rows(300);
  std::vector<float> angles(300, 0.0f);
  for (uint32_t i = 0; i < 300; ++i) rows[i] = i % 10;
  std::map<uint32_t, float> w;
  for (uint32_t r = 0; r < 10; ++r) w[r] = 0.3f;
  const BowVector v = Make(rows, angles, w);
  BowDatabase compact(10, Ov(true, true), 1);
  try {
    compact.Add(v);
    FAIL() << "300 keypoints accepted by compact postings";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("compact_postings: false"), std::string::npos);
  }
  EXPECT_EQ(compact.size(), 0u);
  BowDatabase precise(10, Ov(true, false), 1);
  EXPECT_EQ(precise.Add(v), 0u);
  const auto r = precise.Query(v, 1);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_GT(r[0].matches.size(), 256u);
}

TEST_F(DatabaseFiles, LayoutsDoNotMixAndDamagedEntriesAreFound) {
  std::mt19937 rng(3);
  BowDatabase db(100, Ov(true, true), 8);
  for (int i = 0; i < 300; ++i) db.Add(RandomVector(&rng, 100, 20));
  const fs::path f = dir_ / "compact.gtdb";
  db.Save(f);
  BowDatabase precise(100, Ov(true, false), 8);
  EXPECT_THROW(precise.Load(f), std::runtime_error);
  std::string bytes = ReadFile(f);
  bytes[bytes.size() - 100] ^= 4;  // inside the entries
  WriteFileAtomic(dir_ / "bad.gtdb", bytes);
  try {
    db.Load(dir_ / "bad.gtdb");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("checksum mismatch in entries"), std::string::npos)
        << e.what();
  }
  EXPECT_EQ(db.size(), 300u);
}

}  // namespace
}  // namespace gtbow
