// Crash-safe maps: a process killed with SIGKILL at random points while it saves a map (what
// the save_map service runs: Localizer::Save) never costs the map already on disk, and a full
// disk (simulated with RLIMIT_FSIZE) fails the save with the path named and nothing lost.
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <random>
#include <thread>

#include <gtest/gtest.h>

#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/synth/generator.h"
#include "test_util.h"

namespace gtbow {
namespace {

namespace fs = std::filesystem;

struct Scene {
  std::shared_ptr<Vocabulary> vocabulary;
  std::vector<cv::Mat> map_images, probes;
};

const Scene& TheScene() {
  static const Scene scene = [] {
    Scene s;
    // The fuzzers' 64-word fixture vocabulary: retrieval quality is beside the point here,
    // identical answers are.
    s.vocabulary = Vocabulary::Load(GTBOW_FUZZ_DATA "/tiny.gtvoc");
    synth::SynthOptions so;
    so.area_width = 0.25;
    so.area_height = 0.2;
    so.train_images = 0;
    so.queries_per_split = 0;
    const synth::DatasetPlan plan = synth::PlanDataset(so);
    const synth::Floor floor(so.surface, so.seed);
    const synth::Camera camera(so.camera);
    for (const auto& im : plan.images) {
      if (s.map_images.size() == 24) break;
      s.map_images.push_back(synth::RenderPlannedImage(floor, camera, so, im));
      if (s.map_images.size() % 4 == 0) {
        synth::PlannedImage q = im;
        q.pose.x += 0.003;
        q.day = 30;
        q.visit = 100;
        s.probes.push_back(synth::RenderPlannedImage(floor, camera, so, q));
      }
    }
    return s;
  }();
  return scene;
}

LocalizerOptions Options() {
  LocalizerOptions o;
  o.retrieval.vocabulary.num_words = 64;
  o.retrieval.vocabulary.nprobe = 4;
  o.meters_per_pixel = 0.00025;
  o.threads = 1;
  return o;
}

// A map of `copies` passes over the scene's images (so that saving it takes a while).
std::unique_ptr<Localizer> MapOf(int copies) {
  const Scene& s = TheScene();
  auto loc = std::make_unique<Localizer>(s.vocabulary, "tiny.gtvoc", Options());
  int64_t stamp = 0;
  for (int c = 0; c < copies; ++c) {
    for (const cv::Mat& img : s.map_images) {
      loc->Add(loc->Process(img), ++stamp, Pose2D{0.01 * stamp, 0.0, 0.0});
    }
  }
  return loc;
}

// Everything a query answers, for each probe image, as one comparable string.
std::string Answers(const Localizer& loc) {
  std::ostringstream out;
  out.precision(17);
  for (const cv::Mat& img : TheScene().probes) {
    for (const Candidate& c : loc.Query(loc.Process(img), 5, true)) {
      out << c.id << ' ' << c.score << ' ' << c.verified << ' ' << c.relative.floor_from_query.x
          << ' ' << c.relative.floor_from_query.y << ' ' << c.relative.inliers << '\n';
    }
    out << "--\n";
  }
  out << loc.size();
  return out.str();
}

std::string LoadedAnswers(const fs::path& path) {
  Localizer loc(TheScene().vocabulary, "tiny.gtvoc", Options());
  loc.Load(path);
  return Answers(loc);
}

std::vector<std::string> Temporaries(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.find(".tmp-") != std::string::npos) out.push_back(name);
  }
  return out;
}

class CrashSafety : public testing_util::TempDirTest {};

TEST_F(CrashSafety, SigkillAtRandomPointsOfASaveNeverCostsThePreviousMap) {
  const auto old_map = MapOf(3);
  const auto new_map = MapOf(6);
  const fs::path path = dir_ / "map.gtmap";
  old_map->Save(path);
  const std::string old_bytes = ReadFile(path);
  const std::string old_answers = Answers(*old_map);
  ASSERT_EQ(LoadedAnswers(path), old_answers);
  // How long a save of the new map takes here.
  std::vector<double> ms;
  for (int i = 0; i < 3; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    new_map->Save(dir_ / "timing.gtmap");
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(ms.begin(), ms.end());
  const double save_ms = ms[1];
  const std::string new_answers = LoadedAnswers(dir_ / "timing.gtmap");
  ASSERT_NE(new_answers, old_answers);
  fs::remove(dir_ / "timing.gtmap");

  std::mt19937 rng(7);
  std::uniform_real_distribution<double> when(0.0, 1.2 * save_ms);
  int kept_old = 0, got_new = 0;
  constexpr int kRounds = 40;
  for (int round = 0; round < kRounds; ++round) {
    const pid_t child = ::fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      try {
        new_map->Save(path);
      } catch (...) {
        ::_exit(3);
      }
      ::_exit(0);
    }
    std::this_thread::sleep_for(std::chrono::duration<double, std::milli>(when(rng)));
    ::kill(child, SIGKILL);
    int status = 0;
    ::waitpid(child, &status, 0);
    ASSERT_FALSE(WIFEXITED(status) && WEXITSTATUS(status) == 3) << "the save failed by itself";
    // Whatever the moment of the kill: the file is the previous map or the complete new one.
    const std::string answers = LoadedAnswers(path);
    if (answers == old_answers) {
      ++kept_old;
      EXPECT_EQ(ReadFile(path), old_bytes) << "round " << round;
    } else {
      ASSERT_EQ(answers, new_answers) << "round " << round << ": neither map";
      ++got_new;
      old_map->Save(path);  // the next round interrupts a save over the old map again
    }
  }
  std::printf("save of %zu keyframes: %.1f ms; %d kills before the new map was in place, %d after\n",
              new_map->size(), save_ms, kept_old, got_new);
  EXPECT_GT(kept_old, 0) << "no kill landed inside a save: the test proved nothing";
  // Killed writers leave temporaries; the next save of the same file removes them.
  old_map->Save(path);
  EXPECT_TRUE(Temporaries(dir_).empty()) << Temporaries(dir_).front();
  EXPECT_EQ(LoadedAnswers(path), old_answers);
}

TEST_F(CrashSafety, AFullDiskFailsTheSaveNamesThePathAndKeepsTheMap) {
  const auto map = MapOf(2);
  const fs::path path = dir_ / "map.gtmap";
  map->Save(path);
  const std::string bytes = ReadFile(path);
  ASSERT_GT(bytes.size(), 256u * 1024);
  // The child may write at most 64 KB per file: writes beyond fail as on a full disk (EFBIG
  // here, ENOSPC there: the same error path).
  int pipefd[2];
  ASSERT_EQ(::pipe(pipefd), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::close(pipefd[0]);
    ::signal(SIGXFSZ, SIG_IGN);
    const rlimit limit{64 * 1024, 64 * 1024};
    ::setrlimit(RLIMIT_FSIZE, &limit);
    std::string message = "saved";
    try {
      map->Save(path);
    } catch (const std::runtime_error& e) {
      message = e.what();
    }
    (void)!::write(pipefd[1], message.data(), message.size());
    ::_exit(0);
  }
  ::close(pipefd[1]);
  std::string message;
  char buf[512];
  ssize_t n;
  while ((n = ::read(pipefd[0], buf, sizeof(buf))) > 0) message.append(buf, static_cast<size_t>(n));
  ::close(pipefd[0]);
  int status = 0;
  ::waitpid(child, &status, 0);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_NE(message, "saved");
  EXPECT_NE(message.find(path.string()), std::string::npos) << message;
  EXPECT_NE(message.find("File too large"), std::string::npos) << message;
  EXPECT_EQ(ReadFile(path), bytes);
  EXPECT_TRUE(Temporaries(dir_).empty());
}

}  // namespace
}  // namespace gtbow
