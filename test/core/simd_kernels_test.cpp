// Every SIMD kernel this CPU runs gives the answers of the portable one, bit for bit, end to
// end: the test renders a small floor and extracts its features once, then runs itself again
// under each value of GTBOW_SIMD (the kernels are chosen once per process). Each run trains a
// vocabulary of each kind that counts bits or byte distances (AKM Hamming with the binary IVF,
// AKM Hamming with FLANN's tree, HKM Hamming, AKM l2_bytes with the byte IVF), assigns words,
// encodes, queries a database and localizes with descriptor matching (Hamming distances in
// verification); it writes every answer (floats as hexadecimal) to a file, and the files must
// be identical to the portable run's.
#include <sys/wait.h>
#include <unistd.h>

#include <cinttypes>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include <gtest/gtest.h>

#include "byte_distance.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/pose.h"
#include "ground_texture_bow/core/simd.h"
#include "ground_texture_bow/eval/synth/generator.h"
#include "hamming_distance.h"
#include "test_scene.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace {

// ---------------------------------------------------------------------------------------------
// The features, written once by the test and read by each run.

struct Image {
  Pose2D pose;
  ImageFeatures features;
};

struct Inputs {
  ImageGeometry geometry;
  std::vector<Image> train, database, queries;
};

static_assert(std::is_trivially_copyable<Keypoint>::value, "Keypoint is written as bytes");
static_assert(std::is_trivially_copyable<Pose2D>::value, "Pose2D is written as bytes");
static_assert(std::is_trivially_copyable<ImageGeometry>::value,
              "ImageGeometry is written as bytes");

template <typename T>
void Put(std::ostream& o, const T& v) {
  o.write(reinterpret_cast<const char*>(&v), sizeof(T));
}
template <typename T>
T Get(std::istream& in) {
  T v{};
  in.read(reinterpret_cast<char*>(&v), sizeof(T));
  if (!in) throw std::runtime_error("features file: truncated");
  return v;
}

void WriteImages(std::ostream& o, const std::vector<Image>& images) {
  Put<uint32_t>(o, static_cast<uint32_t>(images.size()));
  for (const Image& im : images) {
    const cv::Mat& d = im.features.descriptors;
    Put(o, im.pose);
    Put<uint32_t>(o, static_cast<uint32_t>(im.features.size()));
    Put<int32_t>(o, d.cols);
    o.write(reinterpret_cast<const char*>(im.features.keypoints.data()),
            sizeof(Keypoint) * im.features.size());
    for (int r = 0; r < d.rows; ++r) o.write(d.ptr<char>(r), d.cols);
  }
}

std::vector<Image> ReadImages(std::istream& in) {
  std::vector<Image> images(Get<uint32_t>(in));
  for (Image& im : images) {
    im.pose = Get<Pose2D>(in);
    const uint32_t n = Get<uint32_t>(in);
    const int32_t cols = Get<int32_t>(in);
    im.features.keypoints.resize(n);
    in.read(reinterpret_cast<char*>(im.features.keypoints.data()), sizeof(Keypoint) * n);
    im.features.descriptors.create(static_cast<int>(n), cols, CV_8U);
    for (uint32_t r = 0; r < n; ++r) in.read(im.features.descriptors.ptr<char>(r), cols);
    if (!in) throw std::runtime_error("features file: truncated");
  }
  return images;
}

void WriteInputs(const fs::path& path, const Inputs& in) {
  std::ofstream o(path, std::ios::binary);
  Put(o, in.geometry);
  WriteImages(o, in.train);
  WriteImages(o, in.database);
  WriteImages(o, in.queries);
  if (!o) throw std::runtime_error("cannot write " + path.string());
}

Inputs ReadInputs(const fs::path& path) {
  std::ifstream f(path, std::ios::binary);
  Inputs in;
  in.geometry = Get<ImageGeometry>(f);
  in.train = ReadImages(f);
  in.database = ReadImages(f);
  in.queries = ReadImages(f);
  return in;
}

// A small floor: its training and database images, and revisits of every other database place
// 30 days later, a few millimetres and degrees off.
Inputs RenderInputs() {
  const synth::Scene scene = testing_util::SmallScene(0.3, 0.22, 12);
  const RetrievalConfig cfg;
  const FeatureExtractor fx(cfg.features);
  Inputs in;
  in.geometry = scene.options().camera.Geometry();
  for (const auto& im : scene.plan().images) {
    Image out{im.pose, fx.Extract(scene.Render(im))};
    (im.split == "train" ? in.train : in.database).push_back(std::move(out));
  }
  for (size_t d = 0; d < in.database.size(); d += 2) {
    synth::PlannedImage im;
    im.name = "revisit_" + std::to_string(d);
    const Pose2D& p = in.database[d].pose;
    im.pose = {p.x + 0.004, p.y - 0.003, p.theta + 0.05};
    im.day = 30;
    im.visit = 100;
    in.queries.push_back({im.pose, fx.Extract(scene.Render(im))});
  }
  return in;
}

// ---------------------------------------------------------------------------------------------
// One run: every answer that a kernel could change, as text.

std::string Hex(double v) {
  char b[64];
  std::snprintf(b, sizeof(b), "%a", v);
  return b;
}

std::unique_ptr<Vocabulary> Train(const Inputs& in, const VocabularyOptions& vo) {
  std::vector<cv::Mat> train;
  std::vector<uint32_t> image_of;
  for (const Image& im : in.train) {
    train.push_back(im.features.descriptors);
    image_of.insert(image_of.end(), im.features.size(), static_cast<uint32_t>(train.size() - 1));
  }
  cv::Mat desc;
  cv::vconcat(train, desc);
  return TrainVocabulary(vo, desc, image_of, false);
}

void WriteAnswers(const Inputs& in, const std::string& preset, const Vocabulary& vocab_ref,
                  const std::string& search, std::ostream& out) {
  const RetrievalConfig cfg = LoadRetrievalConfig(fs::path(GTBOW_CONFIG_DIR) / preset);
  const Vocabulary* vocab = &vocab_ref;
  out << "vocabulary " << VocabularyKindName(vocab->kind()) << " " << MetricName(vocab->metric())
      << " " << search << " words " << vocab->size() << " fingerprint " << std::hex
      << vocab->fingerprint() << std::dec << "\n";
  out << "idf";
  for (float f : vocab->idf()) out << " " << Hex(f);
  out << "\n";

  // Word assignment of every query descriptor: approximate (r nearest) and exact.
  const int r = std::min(3, vocab->max_neighbours());
  for (size_t q = 0; q < in.queries.size(); ++q) {
    std::vector<WordHit> hits, exact;
    vocab->Assign(in.queries[q].features.descriptors, r, &hits);
    vocab->AssignExact(in.queries[q].features.descriptors, &exact);
    out << "assign " << q;
    for (const WordHit& h : hits) out << " " << h.word << ":" << Hex(h.distance);
    out << "\nexact " << q;
    for (const WordHit& h : exact) out << " " << h.word << ":" << Hex(h.distance);
    out << "\n";
  }

  // Retrieval and localization with the descriptors' Hamming matches.
  const BowEncoder enc(*vocab, cfg.bow);
  BowDatabase db(enc.num_rows(), cfg.bow, vocab->fingerprint());
  for (const Image& im : in.database) db.Add(enc.Encode(im.features));
  MapAccess map;
  map.keypoints = [&](uint32_t i) { return in.database.at(i).features.keypoints; };
  map.descriptors = [&](uint32_t i) { return in.database.at(i).features.descriptors; };
  map.pose = [&](uint32_t i) { return in.database.at(i).pose; };
  LocalizationOptions lo = cfg.verification;
  lo.matches = MatchSource::kDescriptors;
  for (size_t q = 0; q < in.queries.size(); ++q) {
    const BowVector v = enc.Encode(in.queries[q].features);
    out << "query " << q;
    for (const QueryResult& res : db.Query(v, 5)) {
      out << " " << res.image << ":" << Hex(res.score) << ":" << res.orientation_bin << ":"
          << res.matches.size();
    }
    const Localization loc = Localize(db, v, map, in.geometry, lo);
    const Pose2D& p = loc.estimate.floor_from_query;
    out << "\nlocalize " << q << " " << loc.success << " " << loc.image << " " << loc.rank << " "
        << loc.estimate.inliers << " " << loc.estimate.matches << " " << Hex(p.x) << " " << Hex(p.y)
        << " " << Hex(p.theta) << " " << loc.reason << "\n";
  }
  // Descriptor matches of each query with the database image at its place.
  for (size_t q = 0; q < in.queries.size(); ++q) {
    const Image& d = in.database.at(2 * q);
    const auto m =
        DescriptorMatches(in.queries[q].features.keypoints, in.queries[q].features.descriptors,
                          d.features.keypoints, d.features.descriptors, 0.8);
    out << "matches " << q << " " << m.size();
    for (const PointMatch& pm : m) out << " " << Hex(pm.query.x) << "," << Hex(pm.database.y);
    out << "\n";
  }
}

// The l2_bytes words, trained once by the test (FLANN's kd-trees, which training uses for
// them, shuffle with std::random_device: their words differ from run to run). Each run builds
// the byte IVF over them and searches it with the byte kernels.
VocabularyOptions BytesOptions() {
  VocabularyOptions o;
  o.kind = VocabularyKind::kAkm;
  o.metric = Metric::kL2Bytes;
  o.num_words = 300;
  o.kmeans_iterations = 2;
  o.ann = AnnIndex::kFlann;
  o.num_trees = 2;
  o.train_checks = 64;
  o.seed = 3;
  return o;
}

int RunAnswers(const fs::path& dir, const fs::path& answers) {
  const Inputs in = ReadInputs(dir / "features.bin");
  std::ostringstream out;
  VocabularyOptions hamming;  // the authors' reading: Hamming words
  hamming.kind = VocabularyKind::kAkm;
  hamming.metric = Metric::kHamming;
  hamming.num_words = 300;
  hamming.kmeans_iterations = 4;
  hamming.ann = AnnIndex::kIvf;
  hamming.nprobe = 4;
  hamming.seed = 3;
  WriteAnswers(in, "authors.yaml", *Train(in, hamming), "ivf", out);
  VocabularyOptions flann = hamming;  // FLANN's hierarchical clustering tree
  flann.ann = AnnIndex::kFlann;
  flann.checks = 64;
  flann.train_checks = 64;
  flann.num_trees = 2;
  WriteAnswers(in, "authors.yaml", *Train(in, flann), "flann", out);
  VocabularyOptions hkm;  // the DBoW baseline's tree
  hkm.kind = VocabularyKind::kHkm;
  hkm.metric = Metric::kHamming;
  hkm.hkm_branching = 6;
  hkm.hkm_depth = 3;
  hkm.seed = 3;
  WriteAnswers(in, "dbow_baseline.yaml", *Train(in, hkm), "tree", out);
  // The high-accuracy preset's l2_bytes words through the byte IVF.
  const auto bytes = Vocabulary::Load(dir / "bytes.vocab");
  bytes->set_search(AnnIndex::kIvf, 4);
  WriteAnswers(in, "high_accuracy.yaml", *bytes, "ivf", out);
  std::ofstream f(answers);
  f << "kernels " << ActiveSimdKernels() << "\n" << out.str();
  return f ? 0 : 1;
}

// ---------------------------------------------------------------------------------------------
// The test: one run per GTBOW_SIMD value this CPU can execute.

std::string Slurp(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// Runs this program with GTBOW_SIMD=`simd`: its answers (without the first line, the kernels
// it ran, returned in *kernels); with `kernels_only` just that line.
std::string RunUnder(const std::string& simd, const fs::path& dir, std::string* kernels,
                     bool kernels_only = false) {
  const fs::path answers =
      dir / ("answers_" + (simd.empty() ? std::string("unset") : simd) + ".txt");
  const pid_t pid = fork();
  if (pid == 0) {
    setenv("GTBOW_SIMD", simd.c_str(), 1);
    execl("/proc/self/exe", "simd_kernels_test", kernels_only ? "--kernels" : "--write-answers",
          dir.c_str(), answers.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  int status = 0;
  waitpid(pid, &status, 0);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "GTBOW_SIMD=" << simd;
  std::string text = Slurp(answers);
  const size_t eol = text.find('\n');
  *kernels = text.substr(0, eol);
  return eol == std::string::npos ? std::string() : text.substr(eol + 1);
}

std::string FirstDifference(const std::string& a, const std::string& b) {
  std::istringstream x(a), y(b);
  std::string la, lb;
  for (int line = 1;; ++line) {
    const bool ga = static_cast<bool>(std::getline(x, la));
    const bool gb = static_cast<bool>(std::getline(y, lb));
    if (!ga && !gb) return "none";
    if (la != lb || ga != gb) {
      return "line " + std::to_string(line) + ":\n  portable: " + la.substr(0, 300) +
             "\n  this:     " + lb.substr(0, 300);
    }
  }
}

TEST(SimdKernels, EveryKernelGivesThePortableAnswersEndToEnd) {
  const fs::path dir = fs::temp_directory_path() / ("gtbow_simd_" + std::to_string(getpid()));
  fs::create_directories(dir);
  {
    const Inputs in = RenderInputs();
    WriteInputs(dir / "features.bin", in);
    Train(in, BytesOptions())->Save(dir / "bytes.vocab");
  }

  // Each value and the kernels it must run here.
  struct Run {
    std::string simd;
    bool runs;  // the CPU has the kernel the value names
    std::string kernels;
  };
  std::vector<Run> runs = {{"portable", true, "hamming portable, l2_bytes portable"}};
#if defined(__x86_64__)
  const bool avx512_bytes = SimdKernelSupported(SimdKernel::kAvx512);
  runs.push_back({"popcnt", HammingKernelSupported(HammingKernel::kPopcnt),
                  "hamming popcnt, l2_bytes portable"});
  runs.push_back(
      {"avx2",
       HammingKernelSupported(HammingKernel::kAvx2) && SimdKernelSupported(SimdKernel::kAvx2),
       "hamming avx2, l2_bytes avx2"});
  runs.push_back({"avx512", HammingKernelSupported(HammingKernel::kAvx512),
                  std::string("hamming avx512, l2_bytes ") + (avx512_bytes ? "avx512" : "avx2")});
#elif defined(__aarch64__)
  runs.push_back({"neon", true, "hamming neon, l2_bytes portable"});
#endif
  std::string portable, kernels;
  for (const Run& r : runs) {
    if (!r.runs) {
      std::printf("GTBOW_SIMD=%s: not on this CPU\n", r.simd.c_str());
      continue;
    }
    const std::string answers = RunUnder(r.simd, dir, &kernels);
    std::printf("GTBOW_SIMD=%s: %s, %zu bytes of answers\n", r.simd.c_str(), kernels.c_str(),
                answers.size());
    EXPECT_EQ(kernels, "kernels " + r.kernels);
    ASSERT_GT(answers.size(), 1000u);
    if (r.simd == "portable") {
      portable = answers;
      // The answers are worth comparing: revisits are localized.
      int localized = 0;
      for (size_t at = answers.find("\nlocalize "); at != std::string::npos;
           at = answers.find("\nlocalize ", at + 1)) {
        const size_t success = answers.find(' ', at + 10) + 1;
        localized += answers.compare(success, 2, "1 ") == 0 ? 1 : 0;
      }
      std::printf("portable: %d localizations\n", localized);
      EXPECT_GT(localized, 0);
      continue;
    }
    EXPECT_TRUE(answers == portable) << "GTBOW_SIMD=" << r.simd << " differs from portable at "
                                     << FirstDifference(portable, answers);
  }
  // Unset, empty or not a kernel's name (a warning on stderr): the widest kernels (for the
  // Hamming distances popcnt rather than avx2 on AMD's first Zen cores).
  HammingKernel hamming = HammingKernel::kPortable;
  for (HammingKernel k : {HammingKernel::kPopcnt, HammingKernel::kAvx2, HammingKernel::kAvx512,
                          HammingKernel::kNeon}) {
    if (HammingKernelSupported(k)) hamming = k;
  }
#if defined(__x86_64__)
  __builtin_cpu_init();
  if (hamming == HammingKernel::kAvx2 && __builtin_cpu_is("znver1"))
    hamming = HammingKernel::kPopcnt;
#endif
  SimdKernel bytes = SimdKernel::kPortable;
  for (SimdKernel k : {SimdKernel::kAvx2, SimdKernel::kAvx512}) {
    if (SimdKernelSupported(k)) bytes = k;
  }
  const std::string widest = std::string("kernels hamming ") + HammingKernelName(hamming) +
                             ", l2_bytes " + SimdKernelName(bytes);
  for (const char* simd : {"", "avx-512"}) {
    RunUnder(simd, dir, &kernels, true);
    std::printf("GTBOW_SIMD='%s': %s\n", simd, kernels.c_str());
    EXPECT_EQ(kernels, widest) << "GTBOW_SIMD='" << simd << "'";
  }
  if (::testing::Test::HasFailure()) {
    std::printf("answers kept in %s\n", dir.c_str());
  } else {
    fs::remove_all(dir);
  }
}

}  // namespace
}  // namespace gtbow

int main(int argc, char** argv) {
  // The runs of the test: `--write-answers DIR FILE` (DIR holds the features and the l2_bytes
  // words) and `--kernels DIR FILE` (the kernels' names only).
  if (argc == 4 && std::strcmp(argv[1], "--write-answers") == 0) {
    try {
      return gtbow::RunAnswers(argv[2], argv[3]);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "simd_kernels_test --write-answers: %s\n", e.what());
      return 1;
    }
  }
  if (argc == 4 && std::strcmp(argv[1], "--kernels") == 0) {
    std::ofstream(argv[3]) << "kernels " << gtbow::ActiveSimdKernels() << "\n";
    return 0;
  }
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
