// Crash-safe maps: a process killed with SIGKILL at random points while it saves a map (what
// the save_map service runs: Localizer::Save) never costs the map already on disk, and a full
// disk (simulated with RLIMIT_FSIZE) fails the save with the path named and nothing lost.
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <map>
#include <random>
#include <set>
#include <thread>

#include <gtest/gtest.h>

#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/eval/synth/generator.h"
#include "test_scene.h"
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
    const synth::Scene floor = testing_util::SmallScene(0.25, 0.2, 0);
    for (const auto& im : floor.plan().images) {
      if (s.map_images.size() == 24) break;
      s.map_images.push_back(floor.Render(im));
      if (s.map_images.size() % 4 == 0) {
        synth::PlannedImage q = im;
        q.pose.x += 0.003;
        q.day = 30;
        q.visit = 100;
        s.probes.push_back(floor.Render(q));
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

using testing_util::Temporaries;

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
    ms.push_back(
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(ms.begin(), ms.end());
  const double save_ms = ms[1];
  const std::string new_answers = LoadedAnswers(dir_ / "timing.gtmap");
  ASSERT_NE(new_answers, old_answers);
  fs::remove(dir_ / "timing.gtmap");

  // Each round forks a writer, which reports on a pipe the moment its save begins; the kill
  // falls at a random time from then on. Where it fell is read from what it left: a temporary
  // of the killed process (it was writing), the new map in place (the rename was done), or
  // neither (it had not created its temporary yet).
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> when(0.0, 1.2 * save_ms);
  int before_temporary = 0, while_writing = 0, after_rename = 0;
  constexpr int kRounds = 40;
  for (int round = 0; round < kRounds; ++round) {
    int started[2];
    ASSERT_EQ(::pipe(started), 0);
    const pid_t child = ::fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      ::close(started[0]);
      (void)!::write(started[1], "s", 1);
      try {
        new_map->Save(path);
      } catch (...) {
        ::_exit(3);
      }
      ::_exit(0);
    }
    ::close(started[1]);
    char byte;
    ASSERT_EQ(::read(started[0], &byte, 1), 1);
    ::close(started[0]);
    std::this_thread::sleep_for(std::chrono::duration<double, std::milli>(when(rng)));
    ::kill(child, SIGKILL);
    int status = 0;
    ::waitpid(child, &status, 0);
    ASSERT_FALSE(WIFEXITED(status) && WEXITSTATUS(status) == 3) << "the save failed by itself";
    const std::string mine = ".map.gtmap.tmp-" + std::to_string(child) + "-";
    bool temporary = false;
    for (const std::string& name : Temporaries(dir_)) temporary |= name.rfind(mine, 0) == 0;
    // Whatever the moment of the kill: the file is the previous map or the complete new one.
    const std::string answers = LoadedAnswers(path);
    if (answers == old_answers) {
      EXPECT_EQ(ReadFile(path), old_bytes) << "round " << round;
      ++(temporary ? while_writing : before_temporary);
    } else {
      ASSERT_EQ(answers, new_answers) << "round " << round << ": neither map";
      ++after_rename;
      old_map->Save(path);  // the next round interrupts a save over the old map again
    }
  }
  std::printf(
      "save of %zu keyframes: %.1f ms; of %d kills, %d came before the temporary "
      "existed, %d while it was being written, %d after the rename\n",
      new_map->size(), save_ms, kRounds, before_temporary, while_writing, after_rename);
  // The test proves something only if kills landed inside writes: at least a quarter of them.
  EXPECT_GE(while_writing, kRounds / 4) << "too few kills landed while the file was written";
  // Killed writers leave temporaries; the next save of the same file removes them.
  old_map->Save(path);
  EXPECT_TRUE(Temporaries(dir_).empty()) << Temporaries(dir_).front();
  EXPECT_EQ(LoadedAnswers(path), old_answers);
}

TEST_F(CrashSafety, AFullDiskFailsTheSaveNamesThePathAndKeepsTheMap) {
  const auto old_map = MapOf(2);
  const auto new_map = MapOf(3);  // a different, larger map is saved over the old one
  const fs::path path = dir_ / "map.gtmap";
  old_map->Save(path);
  const std::string bytes = ReadFile(path);
  const auto mtime = fs::last_write_time(path);
  ASSERT_GT(bytes.size(), 256u * 1024);
  // This process may now write at most 64 KB per file: writes beyond fail as on a full disk
  // (EFBIG here, ENOSPC there: the same error path). SIGXFSZ keeps its default action (kill):
  // the writer itself must keep it from taking the process down.
  std::string message = "saved";
  {
    testing_util::FileSizeLimit limit(64 * 1024);
    try {
      new_map->Save(path);
    } catch (const std::runtime_error& e) {
      message = e.what();
    }
  }
  EXPECT_NE(message, "saved");
  EXPECT_NE(message.find(path.string()), std::string::npos) << message;
  EXPECT_NE(message.find("File too large"), std::string::npos) << message;
  EXPECT_EQ(ReadFile(path), bytes);
  EXPECT_EQ(fs::last_write_time(path), mtime);
  EXPECT_TRUE(Temporaries(dir_).empty());
  // With room again, the same save goes through.
  new_map->Save(path);
  EXPECT_EQ(LoadedAnswers(path), Answers(*new_map));
}

// What the node does at once: its worker inserts keyframes while service threads query by
// image and by keyframe id and save the map. Every saved file is a consistent snapshot: it
// loads and answers every probe exactly like a map of the first n keyframes. Queries by
// keyframe id never see a keyframe half inserted. Run under ThreadSanitizer by make
// test-sanitize.
TEST_F(CrashSafety, SavesAndQueriesDuringInsertionSeeConsistentMaps) {
  const Scene& s = TheScene();
  Localizer live(s.vocabulary, "tiny.gtvoc", Options());
  std::vector<ProcessedImage> processed;
  for (const cv::Mat& img : s.map_images) processed.push_back(live.Process(img));
  std::vector<ProcessedImage> probes;
  for (const cv::Mat& img : s.probes) probes.push_back(live.Process(img));
  constexpr int kKeyframes = 48;
  std::atomic<bool> stop{false};
  std::atomic<int> queries{0}, saves{0}, bad_ids{0};
  std::thread querier([&] {
    for (size_t k = 0; !stop; ++k) {
      const size_t n = live.size();
      for (const Candidate& c : live.Query(probes[k % probes.size()], 5, true)) {
        bad_ids += c.id >= live.size() ? 1 : 0;
      }
      if (n > 0) {
        const uint32_t id = static_cast<uint32_t>(k % n);
        for (const Candidate& c : live.QueryKeyframe(id, 3, true)) bad_ids += c.id == id ? 1 : 0;
      }
      ++queries;
    }
  });
  std::thread saver([&] {
    for (int i = 0; !stop; ++i) {
      live.Save(dir_ / ("snapshot_" + std::to_string(i) + ".gtmap"));
      ++saves;
    }
  });
  for (int i = 0; i < kKeyframes; ++i) {
    const int seen = queries.load() + saves.load();
    live.Add(processed[i % processed.size()], i, Pose2D{0.01 * i, 0.0, 0.0});
    // Let the other threads make progress between insertions.
    while (queries.load() + saves.load() < seen + 2) std::this_thread::yield();
  }
  stop = true;
  querier.join();
  saver.join();
  EXPECT_EQ(bad_ids.load(), 0);
  // Each snapshot against a map built sequentially to the same size.
  std::map<size_t, std::string> prefix_answers;
  {
    Localizer seq(s.vocabulary, "tiny.gtvoc", Options());
    prefix_answers[0] = Answers(seq);
    for (int i = 0; i < kKeyframes; ++i) {
      seq.Add(processed[i % processed.size()], i, Pose2D{0.01 * i, 0.0, 0.0});
      prefix_answers[seq.size()] = Answers(seq);
    }
  }
  std::set<size_t> sizes;
  int snapshots = 0;
  for (const auto& e : fs::directory_iterator(dir_)) {
    if (e.path().extension() != ".gtmap") continue;
    Localizer loaded(s.vocabulary, "tiny.gtvoc", Options());
    loaded.Load(e.path());
    sizes.insert(loaded.size());
    ++snapshots;
    EXPECT_EQ(Answers(loaded), prefix_answers.at(loaded.size())) << e.path().filename();
  }
  std::printf("%d queries and %d saves during %d insertions; the saves hold %zu different sizes\n",
              queries.load(), saves.load(), kKeyframes, sizes.size());
  EXPECT_GE(sizes.size(), 3u) << "the saves did not overlap the insertions";
}

}  // namespace
}  // namespace gtbow
