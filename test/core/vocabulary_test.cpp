#include "ground_texture_bow/core/vocabulary.h"

#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>

#include <gtest/gtest.h>

#include "test_util.h"

#include "ground_texture_bow/core/file_util.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace {

// `clusters` planted centres with `per` noisy samples each: ORB-like bytes (l2_bytes and
// hamming) or floats. Returns samples, their true cluster, and fake image ids.
struct Planted {
  cv::Mat data;
  std::vector<int> truth;
  std::vector<uint32_t> image;
};

Planted MakeBinary(int clusters, int per, int flip_bits, uint64_t seed) {
  std::mt19937_64 rng(seed);
  Planted p;
  p.data.create(clusters * per, 32, CV_8U);
  for (int c = 0; c < clusters; ++c) {
    uint8_t centre[32];
    for (auto& b : centre) b = static_cast<uint8_t>(rng());
    for (int s = 0; s < per; ++s) {
      uint8_t* row = p.data.ptr<uint8_t>(c * per + s);
      std::copy(centre, centre + 32, row);
      for (int f = 0; f < flip_bits; ++f) {
        const int bit = static_cast<int>(rng() % 256);
        row[bit / 8] ^= static_cast<uint8_t>(1 << (bit % 8));
      }
      p.truth.push_back(c);
      p.image.push_back(static_cast<uint32_t>(s % 10));
    }
  }
  return p;
}

Planted MakeBytesL2(int clusters, int per, double noise, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n(0, noise);
  Planted p;
  p.data.create(clusters * per, 32, CV_8U);
  for (int c = 0; c < clusters; ++c) {
    double centre[32];
    for (auto& b : centre) b = 30 + static_cast<double>(rng() % 196);
    for (int s = 0; s < per; ++s) {
      for (int k = 0; k < 32; ++k) {
        p.data.at<uint8_t>(c * per + s, k) = cv::saturate_cast<uint8_t>(centre[k] + n(rng));
      }
      p.truth.push_back(c);
      p.image.push_back(static_cast<uint32_t>(s % 10));
    }
  }
  return p;
}

// Word purity: the share of samples whose word's majority cluster is their own cluster (1 when
// no word mixes clusters); `covered` tells whether every cluster owns at least one word.
double Purity(const Vocabulary& v, const Planted& p, int clusters, bool* covered) {
  std::vector<WordHit> hits;
  v.Assign(p.data, 1, &hits);
  std::map<uint32_t, std::map<int, int>> votes;  // word -> cluster -> samples
  for (size_t i = 0; i < hits.size(); ++i) ++votes[hits[i].word][p.truth[i]];
  int good = 0;
  std::set<int> owners;
  for (const auto& [word, m] : votes) {
    auto best =
        std::max_element(m.begin(), m.end(), [](auto& a, auto& b) { return a.second < b.second; });
    good += best->second;
    owners.insert(best->first);
  }
  *covered = static_cast<int>(owners.size()) == clusters;
  return double(good) / hits.size();
}

TEST(Vocabulary, AkmRecoversPlantedClustersInBothOrbMetrics) {
  VocabularyOptions o;
  o.num_words = 24;  // more words than clusters: no word may mix two clusters
  o.checks = 256;
  for (Metric m : {Metric::kL2Bytes, Metric::kHamming}) {
    o.metric = m;
    const Planted p =
        m == Metric::kHamming ? MakeBinary(16, 60, 12, 1) : MakeBytesL2(16, 60, 8.0, 1);
    const auto v = TrainVocabulary(o, p.data, p.image, false);
    EXPECT_EQ(v->size(), 24u);
    bool distinct = false;
    const double purity = Purity(*v, p, 16, &distinct);
    EXPECT_GT(purity, 0.97) << MetricName(m);
    EXPECT_TRUE(distinct) << MetricName(m);
  }
}

TEST(Vocabulary, IvfSearchAgreesWithExactNearestWord) {
  // 400 words from 4000 ORB-like byte vectors; queries are fresh samples.
  const Planted train = MakeBytesL2(400, 10, 20.0, 7);
  VocabularyOptions o;
  o.num_words = 400;
  o.kmeans_iterations = 3;
  auto v = TrainVocabulary(o, train.data, train.image, false);
  const Planted query = MakeBytesL2(400, 2, 20.0, 7);
  std::vector<WordHit> exact, approx;
  v->AssignExact(query.data, &exact);
  auto agreement = [&](AnnIndex ann, int nprobe) {
    v->set_search(ann, nprobe);
    v->Assign(query.data, 3, &approx);
    int same = 0;
    for (size_t i = 0; i < exact.size(); ++i) {
      same += approx[3 * i].word == exact[i].word ? 1 : 0;
      EXPECT_LE(approx[3 * i].distance, approx[3 * i + 1].distance);  // sorted
    }
    return double(same) / exact.size();
  };
  EXPECT_DOUBLE_EQ(agreement(AnnIndex::kIvf, 20), 1.0);  // all 20 lists: exhaustive
  const double half = agreement(AnnIndex::kIvf, 10);
  const double kd = agreement(AnnIndex::kFlann, 64);
  std::printf("first-word agreement: ivf nprobe 10 of 20: %.3f, flann checks 64: %.3f\n", half, kd);
  EXPECT_GT(half, 0.9);
  EXPECT_GT(kd, 0.5);
  // The IVF lists travel with the vocabulary file: the loaded one answers identically.
  v->set_search(AnnIndex::kIvf, 10);
  v->Assign(query.data, 3, &approx);
  const fs::path f =
      fs::temp_directory_path() / ("gtbow_ivf_" + std::to_string(::getpid()) + ".gtvoc");
  v->Save(f);
  auto back = Vocabulary::Load(f);
  fs::remove(f);
  back->set_search(AnnIndex::kIvf, 10);
  std::vector<WordHit> again;
  back->Assign(query.data, 3, &again);
  ASSERT_EQ(again.size(), approx.size());
  for (size_t i = 0; i < again.size(); ++i) ASSERT_EQ(again[i].word, approx[i].word);
}

TEST(Vocabulary, HammingIvfIsExactWithEveryListAndTravelsWithTheFile) {
  const Planted train = MakeBinary(300, 10, 30, 9);
  VocabularyOptions o;
  o.metric = Metric::kHamming;
  o.num_words = 300;
  o.kmeans_iterations = 4;
  o.ann = AnnIndex::kIvf;
  auto v = TrainVocabulary(o, train.data, train.image, false);
  const Planted query = MakeBinary(300, 2, 30, 9);
  std::vector<WordHit> exact, approx;
  v->AssignExact(query.data, &exact);
  v->set_search(AnnIndex::kIvf, 1000);  // every list
  v->Assign(query.data, 3, &approx);
  for (size_t i = 0; i < exact.size(); ++i) {
    ASSERT_FLOAT_EQ(approx[3 * i].distance, exact[i].distance) << i;  // the nearest word's distance
    EXPECT_LE(approx[3 * i].distance, approx[3 * i + 1].distance);
  }
  v->set_search(AnnIndex::kIvf, 6);
  v->Assign(query.data, 3, &approx);
  const fs::path f =
      fs::temp_directory_path() / ("gtbow_bivf_" + std::to_string(::getpid()) + ".gtvoc");
  v->set_extractor("features:\n  type: orb\n");
  v->Save(f);
  auto back = Vocabulary::Load(f);
  fs::remove(f);
  EXPECT_EQ(back->extractor(), "features:\n  type: orb\n");
  back->set_search(AnnIndex::kIvf, 6);
  std::vector<WordHit> again;
  back->Assign(query.data, 3, &again);
  ASSERT_EQ(again.size(), approx.size());
  for (size_t i = 0; i < again.size(); ++i) ASSERT_EQ(again[i].word, approx[i].word);
}

TEST(Vocabulary, KMeansStopsOnceFewDescriptorsChangeWord) {
  // Stopping at "fewer than 99.9% changed, after 2 iterations" gives exactly the vocabulary of
  // 3 iterations; a full run to convergence differs from it and quantises at least as well.
  const Planted p = MakeBinary(60, 20, 40, 5);
  VocabularyOptions o;
  o.metric = Metric::kHamming;
  o.num_words = 60;
  o.kmeans_iterations = 200;
  o.kmeans_stop_fraction = 0.999;
  o.kmeans_min_iterations = 2;
  const auto early = TrainVocabulary(o, p.data, p.image, false);
  VocabularyOptions three = o;
  three.kmeans_iterations = 3;
  three.kmeans_stop_fraction = 0.0;
  const auto fixed = TrainVocabulary(three, p.data, p.image, false);
  EXPECT_EQ(early->fingerprint(), fixed->fingerprint());
  VocabularyOptions one = three;
  one.kmeans_iterations = 1;
  VocabularyOptions conv = o;
  conv.kmeans_stop_fraction = 0.01;
  const auto first = TrainVocabulary(one, p.data, p.image, false);
  const auto converged = TrainVocabulary(conv, p.data, p.image, false);
  auto cost = [&](const Vocabulary& v) {
    std::vector<WordHit> hits;
    v.AssignExact(p.data, &hits);
    double c = 0;
    for (const auto& h : hits) c += h.distance;
    return c;
  };
  EXPECT_NE(converged->fingerprint(), first->fingerprint());
  EXPECT_LT(cost(*converged), cost(*first));
}

TEST(Vocabulary, HkmRecoversPlantedClustersAndBuildsATree) {
  VocabularyOptions o;
  o.kind = VocabularyKind::kHkm;
  o.metric = Metric::kHamming;
  o.hkm_branching = 4;
  o.hkm_depth = 3;  // up to 64 leaves for 16 clusters
  const Planted p = MakeBinary(16, 40, 10, 2);
  const auto v = TrainVocabulary(o, p.data, p.image, false);
  EXPECT_LE(v->size(), 64u);
  EXPECT_GE(v->size(), 16u);
  bool covered = false;
  EXPECT_GT(Purity(*v, p, 16, &covered), 0.97);
  EXPECT_TRUE(covered);
  EXPECT_EQ(v->max_neighbours(), 1);
  std::vector<WordHit> hits;
  EXPECT_THROW(v->Assign(p.data, 2, &hits), std::invalid_argument);
}

TEST(Vocabulary, IdfCountsTrainingImages) {
  // Two clusters: one in every image, one in half of them.
  Planted p = MakeBinary(2, 20, 4, 3);
  for (int s = 0; s < 20; ++s) p.image[s] = static_cast<uint32_t>(s % 10);      // images 0..9
  for (int s = 0; s < 20; ++s) p.image[20 + s] = static_cast<uint32_t>(s % 5);  // images 0..4
  VocabularyOptions o;
  o.num_words = 2;
  o.metric = Metric::kHamming;
  const auto v = TrainVocabulary(o, p.data, p.image, false);
  std::vector<WordHit> hits;
  v->Assign(p.data.rowRange(0, 1), 1, &hits);
  const uint32_t common = hits[0].word;
  EXPECT_NEAR(v->idf()[common], 0.0, 1e-6);                // log(10 / 10)
  EXPECT_NEAR(v->idf()[1 - common], std::log(2.0), 1e-6);  // log(10 / 5)
}

class VocabularyFiles : public testing_util::TempDirTest {};

TEST_F(VocabularyFiles, RoundTripAndCorruptFiles) {
  const Planted p = MakeBytesL2(8, 30, 6.0, 4);
  VocabularyOptions o;
  o.num_words = 8;
  auto v = TrainVocabulary(o, p.data, p.image, false);
  v->set_size_thresholds({3.0f, 7.5f});
  const fs::path f = dir_ / "v.gtvoc";
  v->Save(f);
  const auto back = Vocabulary::Load(f);
  EXPECT_EQ(back->size(), v->size());
  EXPECT_EQ(back->metric(), Metric::kL2Bytes);
  EXPECT_EQ(back->idf(), v->idf());
  EXPECT_EQ(back->size_thresholds(), v->size_thresholds());
  EXPECT_EQ(back->fingerprint(), v->fingerprint());
  std::vector<WordHit> a, b;
  v->Assign(p.data, 3, &a);
  back->Assign(p.data, 3, &b);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) EXPECT_EQ(a[i].word, b[i].word);

  // HKM round trip too.
  VocabularyOptions h;
  h.kind = VocabularyKind::kHkm;
  h.metric = Metric::kHamming;
  h.hkm_branching = 3;
  h.hkm_depth = 2;
  const Planted pb = MakeBinary(9, 20, 8, 5);
  auto hv = TrainVocabulary(h, pb.data, pb.image, false);
  hv->Save(dir_ / "h.gtvoc");
  auto hb = Vocabulary::Load(dir_ / "h.gtvoc");
  hv->Assign(pb.data, 1, &a);
  hb->Assign(pb.data, 1, &b);
  for (size_t i = 0; i < a.size(); ++i) EXPECT_EQ(a[i].word, b[i].word);

  const std::string good = ReadFile(f);
  auto expect_error = [&](const std::string& bytes, const std::string& what) {
    WriteFileAtomic(dir_ / "bad.gtvoc", bytes);
    try {
      Vocabulary::Load(dir_ / "bad.gtvoc");
      FAIL() << what;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("bad.gtvoc"), std::string::npos) << e.what();
    }
  };
  std::string corrupt = good;
  corrupt[corrupt.size() / 2] ^= 0x40;
  expect_error(corrupt, "checksum");
  expect_error(good.substr(0, good.size() - 9), "truncated");
  expect_error("GTBWDB\0\0" + good.substr(8), "wrong magic");
  std::string version = good;
  version[8] = 9;
  expect_error(version, "version 9");
  expect_error("", "too short");
  EXPECT_THROW(Vocabulary::Load(dir_ / "missing.gtvoc"), std::runtime_error);
}

TEST(Vocabulary, OptionsAndInputChecks) {
  VocabularyOptions o;
  o.num_words = 1;
  EXPECT_THROW(o.Check(), std::invalid_argument);
  o = {};
  o.num_words = 100;
  const Planted p = MakeBinary(2, 10, 2, 6);
  EXPECT_THROW(TrainVocabulary(o, p.data, p.image, false), std::invalid_argument);  // too few
  o.num_words = 4;
  o.metric = Metric::kL2;
  EXPECT_THROW(TrainVocabulary(o, p.data, p.image, false), std::invalid_argument);  // not float
  EXPECT_THROW(ParseMetric("cosine"), std::invalid_argument);
  EXPECT_EQ(ParseMetric(MetricName(Metric::kHamming)), Metric::kHamming);
}

}  // namespace
}  // namespace gtbow

namespace gtbow {
namespace {

// The Hamming search tree is built when a vocabulary is loaded; two builds must search alike
// (FLANN's random centre chooser drew from std::random_device, so results changed per run).
TEST_F(VocabularyFiles, HammingSearchIsTheSameAfterEveryLoad) {
  VocabularyOptions o;
  o.metric = Metric::kHamming;
  o.num_words = 400;
  o.kmeans_iterations = 2;
  const Planted p = MakeBinary(200, 20, 40, 5);
  const auto v = TrainVocabulary(o, p.data, p.image, false);
  const auto file = dir_ / "ham.gtvoc";
  v->Save(file);
  std::vector<std::vector<WordHit>> runs;
  for (int i = 0; i < 3; ++i) {
    const auto back = Vocabulary::Load(file);
    back->set_checks(4);  // an approximate search: it depends on the tree
    std::vector<WordHit> hits;
    back->Assign(p.data, 1, &hits);
    runs.push_back(hits);
  }
  for (int i = 1; i < 3; ++i) {
    for (size_t k = 0; k < runs[0].size(); ++k) ASSERT_EQ(runs[i][k].word, runs[0][k].word) << k;
  }
}

}  // namespace
}  // namespace gtbow
