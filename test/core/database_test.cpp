#include "ground_texture_bow/core/database.h"

#include <unistd.h>

#include <atomic>
#include <cmath>
#include <map>
#include <filesystem>
#include <thread>

#include <gtest/gtest.h>

#include "test_util.h"

#include "ground_texture_bow/core/file_util.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace {

// Stored weights d_w * c_d are 16-bit (steps of 1 / 65535): a score built from a few entries is
// exact to a few steps.
constexpr double kWeightTolerance = 4.0 / 65535.0;

// A hand-made BoW vector: keypoint i sits on row rows[i] with angle angles[i]; each row's
// weight is given, and contributions split a row evenly among its keypoints.
BowVector Make(const std::vector<uint32_t>& rows, const std::vector<float>& angles,
               const std::map<uint32_t, float>& weight) {
  BowVector v;
  v.angles = angles;
  for (size_t i = 0; i < rows.size(); ++i) v.keypoints.push_back({rows[i], static_cast<uint16_t>(i), 0, 1});
  std::sort(v.keypoints.begin(), v.keypoints.end(),
            [](const KeypointEntry& a, const KeypointEntry& b) { return a.row < b.row; });
  std::map<uint32_t, int> count;
  for (uint32_t r : rows) ++count[r];
  for (auto& k : v.keypoints) k.contribution = 1.0f / count[k.row];
  for (const auto& [row, w] : weight) v.entries.push_back({row, w});
  return v;
}

BowOptions Ov(bool on = true) {
  BowOptions o;
  o.orientation_verification = on;
  o.orientation_bins = 6;
  return o;
}

TEST(Database, OrientationVotesGoToTheDifferenceBin) {
  BowDatabase db(100, Ov(), 7);
  // Image 0: both keypoints turned by +1.0 rad relative to the query (bin 0 of 6).
  const uint32_t a = db.Add(Make({5, 7}, {1.1f, 1.2f}, {{5, 0.6f}, {7, 0.8f}}));
  // Image 1: the same rows, but inconsistent turns: +1.0 and +4.0 rad (bins 0 and 3).
  const uint32_t b = db.Add(Make({5, 7}, {1.1f, 4.2f}, {{5, 0.6f}, {7, 0.8f}}));
  const BowVector q = Make({5, 7}, {0.1f, 0.2f}, {{5, 0.6f}, {7, 0.8f}});
  const auto res = db.Query(q, 10);
  ASSERT_EQ(res.size(), 2u);
  EXPECT_EQ(res[0].image, a);
  EXPECT_NEAR(res[0].score, 0.36 + 0.64, kWeightTolerance);
  EXPECT_EQ(res[0].orientation_bin, 0);
  EXPECT_EQ(res[0].matches.size(), 2u);
  EXPECT_EQ(res[1].image, b);
  EXPECT_NEAR(res[1].score, 0.64, kWeightTolerance);  // only the row-7 vote survives, in bin 3
  EXPECT_EQ(res[1].orientation_bin, 3);
  ASSERT_EQ(res[1].matches.size(), 1u);
  EXPECT_EQ(res[1].matches[0].query_keypoint, 1);
  EXPECT_NEAR(res[1].matches[0].weight, 0.64, kWeightTolerance);
}

TEST(Database, AngleDifferencesWrapAround) {
  BowDatabase db(10, Ov(), 7);
  // Query at 6.2 rad, database at 0.1 rad: the difference is +0.18 rad, bin 0, not bin 5.
  db.Add(Make({3}, {0.1f}, {{3, 1.0f}}));
  const auto res = db.Query(Make({3}, {6.2f}, {{3, 1.0f}}), 1);
  ASSERT_EQ(res.size(), 1u);
  EXPECT_EQ(res[0].orientation_bin, 0);
  // And -0.18 rad lands in the last bin.
  const auto back = db.Query(Make({3}, {0.28f}, {{3, 1.0f}}), 1);
  EXPECT_EQ(back[0].orientation_bin, 5);
}

TEST(Database, SeveralKeypointsOnOneRowVoteByContribution) {
  BowDatabase db(10, Ov(), 7);
  // Two database keypoints on row 2 (c = 0.5 each), turned by 0.5 and 3.5 rad.
  db.Add(Make({2, 2}, {0.5f, 3.5f}, {{2, 1.0f}}));
  const auto res = db.Query(Make({2}, {0.0f}, {{2, 1.0f}}), 1);
  EXPECT_NEAR(res[0].score, 0.5, kWeightTolerance);  // the vote splits: each bin gets half
}

TEST(Database, WithoutOvTheScoreIsTheDotProductAndL1IsDbows) {
  BowDatabase dot(10, Ov(false), 7);
  dot.Add(Make({1, 2}, {0.0f, 3.0f}, {{1, 0.6f}, {2, 0.8f}}));
  const auto r = dot.Query(Make({1, 2}, {1.0f, 1.0f}, {{1, 0.8f}, {2, 0.6f}}), 1);
  EXPECT_NEAR(r[0].score, 0.6 * 0.8 + 0.8 * 0.6, kWeightTolerance);
  EXPECT_EQ(r[0].orientation_bin, -1);
  EXPECT_EQ(r[0].matches.size(), 2u);

  BowOptions l1 = Ov(false);
  l1.scoring = Scoring::kDbowL1;
  BowDatabase dbow(10, l1, 7);
  dbow.Add(Make({1, 2, 3}, {0, 0, 0}, {{1, 0.5f}, {2, 0.3f}, {3, 0.2f}}));
  const auto s = dbow.Query(Make({1, 2, 4}, {0, 0, 0}, {{1, 0.2f}, {2, 0.4f}, {4, 0.4f}}), 1);
  EXPECT_NEAR(s[0].score, 0.2 + 0.3, kWeightTolerance);  // 1 - |v - w|_1 / 2
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
    const BowVector q = Make({i % 50, (i * 7) % 50}, {0.5f, 1.0f}, {{i % 50, 0.7f}, {(i * 7) % 50, 0.7f}});
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

TEST(Database, ConcurrentQueriesWithOneWriter) {
  BowDatabase db(1000, Ov(), 1);
  std::atomic<bool> stop{false};
  std::atomic<int> queries{0};
  std::vector<std::thread> readers;
  for (int t = 0; t < 2; ++t) {
    readers.emplace_back([&]() {
      while (!stop) {
        const auto r = db.Query(Make({1, 2}, {0.0f, 0.5f}, {{1, 0.6f}, {2, 0.8f}}), 5);
        for (const auto& x : r) ASSERT_LE(x.score, 1.0001f);
        ++queries;
      }
    });
  }
  // The writer interleaves with the readers: it waits for their progress as it goes.
  for (uint32_t i = 0; i < 2000; ++i) {
    if (i % 200 == 0) {
      const int seen = queries.load();
      while (queries.load() < seen + 2) std::this_thread::yield();
    }
    db.Add(Make({i % 1000, 1, 2}, {0.0f, 0.0f, 0.5f}, {{i % 1000, 0.5f}, {1, 0.5f}, {2, 0.5f}}));
  }
  stop = true;
  for (auto& t : readers) t.join();
  EXPECT_EQ(db.size(), 2000u);
  EXPECT_GE(queries.load(), 20);
  // After the writer: the top result holds all three rows' votes.
  const auto r = db.Query(Make({5, 1, 2}, {0.0f, 0.0f, 0.5f}, {{5, 0.5f}, {1, 0.5f}, {2, 0.5f}}), 1);
  EXPECT_NEAR(r[0].score, 0.75, kWeightTolerance);
}

}  // namespace
}  // namespace gtbow
