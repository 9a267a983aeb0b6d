// The binary inverted file over Hamming words: exact when every list is searched, close to exact
// with a fraction of them, the same after a save and load, and damaged lists are refused; the
// triangle bound gives the same answers as the full scan, with fewer distances.
#include "binary_ivf.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <stdexcept>

#include "ground_texture_bow/core/binary_io.h"
#include "hamming_distance.h"

namespace gtbow {
namespace {

// Words with cluster structure (like a vocabulary) and queries near them.
struct Data {
  cv::Mat words, queries;
};

Data Make(int v, int nq, uint32_t seed) {
  std::mt19937 rng(seed);
  Data d;
  d.words.create(v, 32, CV_8U);
  const int centres = std::max(1, v / 20);
  cv::Mat c(centres, 32, CV_8U);
  for (int i = 0; i < c.rows; ++i) {
    for (int k = 0; k < 32; ++k) c.at<uint8_t>(i, k) = static_cast<uint8_t>(rng());
  }
  auto perturb = [&](const uint8_t* src, uint8_t* dst, int flips) {
    std::copy(src, src + 32, dst);
    for (int f = 0; f < flips; ++f) {
      const int bit = static_cast<int>(rng() % 256);
      dst[bit / 8] ^= static_cast<uint8_t>(1 << (bit % 8));
    }
  };
  for (int i = 0; i < v; ++i)
    perturb(c.ptr<uint8_t>(static_cast<int>(rng() % centres)), d.words.ptr<uint8_t>(i), 40);
  d.queries.create(nq, 32, CV_8U);
  for (int i = 0; i < nq; ++i)
    perturb(d.words.ptr<uint8_t>(static_cast<int>(rng() % v)), d.queries.ptr<uint8_t>(i), 30);
  return d;
}

// The r nearest words by brute force, ties by word id.
std::vector<WordHit> Brute(const cv::Mat& words, const cv::Mat& q, int r) {
  std::vector<WordHit> out;
  for (int i = 0; i < q.rows; ++i) {
    std::vector<WordHit> all;
    for (int w = 0; w < words.rows; ++w) {
      all.push_back({static_cast<uint32_t>(w), static_cast<float>(HammingDistance(
                                                   q.ptr<uint8_t>(i), words.ptr<uint8_t>(w), 32))});
    }
    std::stable_sort(all.begin(), all.end(),
                     [](const WordHit& a, const WordHit& b) { return a.distance < b.distance; });
    out.insert(out.end(), all.begin(), all.begin() + r);
  }
  return out;
}

TEST(BinaryIvf, EveryListSearchedIsExactWithTiesByWordId) {
  const Data d = Make(2000, 300, 3);
  const BinaryIvfIndex ivf(d.words, 1, 2);
  EXPECT_EQ(ivf.num_lists(), 45);  // about sqrt(V)
  std::vector<WordHit> got;
  ivf.Search(d.queries, 3, ivf.num_lists(), &got);
  const auto want = Brute(d.words, d.queries, 3);
  ASSERT_EQ(got.size(), want.size());
  for (size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].word, want[i].word) << i;
    EXPECT_EQ(got[i].distance, want[i].distance) << i;
  }
}

// With fewer lists than all, the lists searched are the nprobe nearest by (distance to the
// centre, list index), ties being frequent; the answer is the exact r nearest of their words.
// The reference reads the saved centres and lists, sorts the centres and scans by brute force.
TEST(BinaryIvf, TheNearestListsByDistanceThenIndexAreSearched) {
  const Data d = Make(2000, 200, 11);
  BinaryIvfIndex ivf(d.words, 3, 1);
  BinaryWriter w;
  ivf.Save(&w);
  BinaryReader saved(w.buffer().data(), w.buffer().size(), "lists");
  const int32_t nlist = saved.Get<int32_t>();
  const std::vector<uint8_t> centres = saved.GetVector<uint8_t>(static_cast<uint64_t>(nlist) * 32);
  std::vector<uint32_t> offsets, ids;
  ReadIvfLists(&saved, nlist, d.words.rows, "lists", &offsets, &ids);
  const int r = 3;
  for (bool bound : {false, true}) {
    ivf.set_bound(bound);
    for (int nprobe : {1, 2, 7, nlist / 3, nlist - 1}) {
      std::vector<WordHit> got;
      ivf.Search(d.queries, r, nprobe, &got);
      for (int i = 0; i < d.queries.rows; ++i) {
        const uint8_t* q = d.queries.ptr<uint8_t>(i);
        std::vector<std::pair<uint32_t, int>> lists;  // (distance, index)
        for (int c = 0; c < nlist; ++c)
          lists.emplace_back(HammingDistance(q, centres.data() + 32 * c, 32), c);
        std::sort(lists.begin(), lists.end());
        std::vector<std::pair<uint32_t, uint32_t>> words;  // (distance, word id)
        for (int p = 0; p < nprobe; ++p) {
          const int c = lists[p].second;
          for (uint32_t k = offsets[c]; k < offsets[c + 1]; ++k)
            words.emplace_back(HammingDistance(q, d.words.ptr<uint8_t>(ids[k]), 32), ids[k]);
        }
        std::sort(words.begin(), words.end());
        for (int j = 0; j < r && j < static_cast<int>(words.size()); ++j) {
          const WordHit& h = got[static_cast<size_t>(i) * r + j];
          ASSERT_EQ(h.word, words[j].second) << "nprobe " << nprobe << ", query " << i;
          ASSERT_EQ(h.distance, static_cast<float>(words[j].first)) << "nprobe " << nprobe;
        }
      }
    }
  }
}

TEST(BinaryIvf, AFractionOfTheListsFindsNearlyEveryNearestWord) {
  const Data d = Make(5000, 500, 4);
  const BinaryIvfIndex ivf(d.words, 1, 2);
  std::vector<WordHit> got;
  ivf.Search(d.queries, 1, ivf.num_lists() / 4, &got);
  const auto want = Brute(d.words, d.queries, 1);
  int same = 0;
  for (size_t i = 0; i < got.size(); ++i) same += got[i].distance == want[i].distance ? 1 : 0;
  const double agreement = static_cast<double>(same) / got.size();
  std::printf("nearest word found with a quarter of the lists: %.1f%%\n", 100 * agreement);
  EXPECT_GE(agreement, 0.95);
  EXPECT_LT(agreement, 1.0 + 1e-9);
}

TEST(BinaryIvf, SavedListsSearchTheSameAndDamagedListsAreRefused) {
  const Data d = Make(1500, 100, 5);
  const BinaryIvfIndex ivf(d.words, 7, 1);
  BinaryWriter w;
  ivf.Save(&w);
  BinaryReader r(w.buffer().data(), w.buffer().size(), "lists");
  const BinaryIvfIndex back(d.words, &r);
  std::vector<WordHit> a, b;
  ivf.Search(d.queries, 2, 8, &a);
  back.Search(d.queries, 2, 8, &b);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) EXPECT_EQ(a[i].word, b[i].word);
  // A word id out of range: the file is refused, naming the defect.
  std::string bad = w.buffer();
  const uint32_t huge = 999999;
  std::memcpy(&bad[bad.size() - 4], &huge, 4);
  BinaryReader rb(bad.data(), bad.size(), "lists");
  try {
    BinaryIvfIndex broken(d.words, &rb);
    ADD_FAILURE() << "damaged lists accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("word id"), std::string::npos) << e.what();
  }
  EXPECT_THROW(BinaryIvfIndex(cv::Mat(10, 32, CV_32F), 1, 1), std::invalid_argument);
}

// The triangle bound skips only words that cannot be among the r nearest: every answer, ties
// included, is that of the full scan, for exact and approximate searches, and it computes fewer
// distances. Ties are frequent here (a few hundred distinct distances over 256 bits).
TEST(BinaryIvf, TheTriangleBoundGivesTheFullScansAnswersWithFewerDistances) {
  const Data d = Make(4000, 400, 6);
  BinaryIvfIndex bounded(d.words, 2, 2), full(d.words, 2, 2);
  full.set_bound(false);
  ASSERT_TRUE(bounded.bound());
  for (int r : {1, 3, 8}) {
    for (int nprobe : {1, 5, 16, bounded.num_lists()}) {
      std::vector<WordHit> a, b;
      const uint64_t before_a = bounded.rows_scanned(), before_b = full.rows_scanned();
      bounded.Search(d.queries, r, nprobe, &a);
      full.Search(d.queries, r, nprobe, &b);
      const uint64_t scanned_a = bounded.rows_scanned() - before_a;
      const uint64_t scanned_b = full.rows_scanned() - before_b;
      ASSERT_EQ(a.size(), b.size());
      for (size_t i = 0; i < a.size(); ++i) {
        ASSERT_EQ(a[i].word, b[i].word) << "r " << r << ", nprobe " << nprobe << ", hit " << i;
        ASSERT_EQ(a[i].distance, b[i].distance) << "r " << r << ", nprobe " << nprobe;
      }
      std::printf("r %d, nprobe %d: %.1f%% of the full scan's distances\n", r, nprobe,
                  100.0 * scanned_a / scanned_b);
      EXPECT_LE(scanned_a, scanned_b);
      if (nprobe > 1) {
        EXPECT_LT(scanned_a, scanned_b);
      }
    }
  }
  // The exact search is still the brute force's.
  std::vector<WordHit> got;
  bounded.Search(d.queries, 3, bounded.num_lists(), &got);
  const auto want = Brute(d.words, d.queries, 3);
  for (size_t i = 0; i < got.size(); ++i) EXPECT_EQ(got[i].word, want[i].word) << i;
}

}  // namespace
}  // namespace gtbow
