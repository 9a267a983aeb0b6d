// Crash-safe maps (what the save_map service runs: Localizer::Save):
//   - a save writes its temporary, fsyncs it, renames it over the map and fsyncs the directory,
//     in that order (the calls themselves are watched, below);
//   - a process killed with SIGKILL at each of those calls, and at random moments, leaves the
//     previous map or the complete new one, never anything else;
//   - a full disk (RLIMIT_FSIZE) fails the save with the path named and nothing lost;
//   - saves and queries during insertion see consistent maps.
// Every wait here is on an event (a call reached, a save finished), bounded in time only to
// fail instead of hanging: a slow disk or a busy machine changes how long, never the verdict.
#include <dlfcn.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstring>
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

// ---------------------------------------------------------------------------------------------
// What the saving code asks of the kernel, seen from inside this test binary: write, fsync,
// fdatasync and rename are defined here, so that the core library's calls (through its PLT)
// reach these first, and each one forwards to the next definition (the C library, or a
// preloaded shim such as make test-slow-disk's). Disarmed, they only forward. Armed, they
// record every call on a file whose name contains `watch` (the map's name: its temporaries
// and the file itself) or on the directory holding it, and can stop the process at the n-th
// such call, before or after the real one, after telling a pipe: a parent then kills it at
// exactly that point of the save.
namespace syscall_recorder {

enum Kind : int { kWrite, kFsync, kRename };

struct Call {
  Kind kind;
  bool on_directory;       // fsync of the directory that holds the file
  bool on_temporary;       // the call's file (for rename: its source) is a temporary
  long long size_at_call;  // the file's size when it was called (write, fsync)
};

constexpr int kMaxCalls = 1 << 16;
std::atomic<bool> armed{false};
char watch[256];       // the map's file name, e.g. "map.gtmap"
char watch_dir[4096];  // the directory that holds it
Call calls[kMaxCalls];
std::atomic<int> count{0};
int stop_at = -1;         // stop at this call (index into calls) ...
bool stop_after = false;  // ... after it returned instead of before it ran
int stop_pipe = -1;

bool Watched(const char* path, bool* temporary) {
  const char* base = std::strrchr(path, '/');
  base = base ? base + 1 : path;
  if (std::strstr(base, watch) == nullptr) return false;
  *temporary = std::strstr(base, ".tmp-") != nullptr;
  return true;
}

// The path of an open descriptor (async-signal-safe: no allocation).
bool PathOf(int fd, char* out, size_t size) {
  char link[64];
  std::snprintf(link, sizeof(link), "/proc/self/fd/%d", fd);
  const ssize_t n = ::readlink(link, out, size - 1);
  if (n <= 0) return false;
  out[n] = '\0';
  return true;
}

// Records the call if it concerns the watched file; returns its index, or -1.
int Record(Kind kind, int fd, const char* path) {
  if (!armed.load(std::memory_order_acquire)) return -1;
  char buf[4096];
  if (path == nullptr) {
    if (!PathOf(fd, buf, sizeof(buf))) return -1;
    path = buf;
  }
  Call c{kind, false, false, -1};
  if (!Watched(path, &c.on_temporary)) {
    if (kind != kFsync || std::strcmp(path, watch_dir) != 0) return -1;
    c.on_directory = true;
  }
  if (fd >= 0) {
    struct stat st {};
    if (::fstat(fd, &st) == 0) c.size_at_call = st.st_size;
  }
  const int i = count.fetch_add(1);
  if (i >= kMaxCalls) return -1;
  calls[i] = c;
  return i;
}

void MaybeStop(int index, bool after) {
  if (index < 0 || index != stop_at || after != stop_after) return;
  const char byte = 's';
  (void)!::write(stop_pipe, &byte, 1);  // our own write: not watched (a pipe)
  for (;;) ::pause();                   // the parent kills us here
}

template <class F>
F Next(const char* name) {
  return reinterpret_cast<F>(::dlsym(RTLD_NEXT, name));
}

void Arm(const std::filesystem::path& file) {
  std::snprintf(watch, sizeof(watch), "%s", file.filename().c_str());
  std::snprintf(
      watch_dir, sizeof(watch_dir), "%s",
      std::filesystem::weakly_canonical(std::filesystem::absolute(file).parent_path()).c_str());
  count = 0;
  armed.store(true, std::memory_order_release);
}

std::vector<Call> Disarm() {
  armed.store(false, std::memory_order_release);
  return std::vector<Call>(calls, calls + std::min(count.load(), kMaxCalls));
}

}  // namespace syscall_recorder

extern "C" {
ssize_t write(int fd, const void* data, size_t size) {
  using namespace syscall_recorder;
  static const auto next = Next<ssize_t (*)(int, const void*, size_t)>("write");
  const int i = Record(kWrite, fd, nullptr);
  MaybeStop(i, false);
  const ssize_t r = next(fd, data, size);
  MaybeStop(i, true);
  return r;
}
int fsync(int fd) {
  using namespace syscall_recorder;
  static const auto next = Next<int (*)(int)>("fsync");
  const int i = Record(kFsync, fd, nullptr);
  MaybeStop(i, false);
  const int r = next(fd);
  MaybeStop(i, true);
  return r;
}
int fdatasync(int fd) {
  using namespace syscall_recorder;
  static const auto next = Next<int (*)(int)>("fdatasync");
  const int i = Record(kFsync, fd, nullptr);
  MaybeStop(i, false);
  const int r = next(fd);
  MaybeStop(i, true);
  return r;
}
int rename(const char* from, const char* to) {
  using namespace syscall_recorder;
  static const auto next = Next<int (*)(const char*, const char*)>("rename");
  int i = -1;
  bool ignored = false;
  if (armed.load(std::memory_order_acquire) && Watched(to, &ignored)) {
    i = Record(kRename, -1, from);
  }
  MaybeStop(i, false);
  const int r = next(from, to);
  MaybeStop(i, true);
  return r;
}
}  // extern "C"

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

// The calls one save makes, in order, as the kernel sees them.
struct SaveCalls {
  std::vector<syscall_recorder::Call> calls;
  int last_write = -1, file_sync = -1, rename = -1, directory_sync = -1;
  long long file_size = 0;
};

SaveCalls RecordSave(const Localizer& map, const fs::path& path) {
  using namespace syscall_recorder;
  SaveCalls s;
  Arm(path);
  map.Save(path);
  s.calls = Disarm();
  s.file_size = static_cast<long long>(fs::file_size(path));
  for (int i = 0; i < static_cast<int>(s.calls.size()); ++i) {
    const Call& c = s.calls[i];
    if (c.kind == kWrite && c.on_temporary) s.last_write = i;
    if (c.kind == kFsync && c.on_temporary && s.rename < 0) s.file_sync = i;
    if (c.kind == kRename && c.on_temporary) s.rename = i;
    if (c.kind == kFsync && c.on_directory && s.rename >= 0 && s.directory_sync < 0) {
      s.directory_sync = i;
    }
  }
  return s;
}

// What makes the map durable, checked on the calls themselves (a killed process keeps the
// page cache, so no kill can tell whether the file was flushed): every byte is written to the
// temporary, the temporary is fsynced whole, only then renamed over the map, and the
// directory is fsynced after the rename. Over an existing map and onto a new name.
TEST_F(CrashSafety, ASaveSyncsTheWholeFileBeforeTheRenameAndTheDirectoryAfter) {
  const auto map = MapOf(2);
  for (const fs::path& path : {dir_ / "fresh.gtmap", dir_ / "fresh.gtmap"}) {
    const SaveCalls s = RecordSave(*map, path);
    ASSERT_GE(s.last_write, 0) << "no write to a temporary of " << path;
    ASSERT_GE(s.file_sync, 0) << "the temporary was never fsynced";
    ASSERT_GE(s.rename, 0) << "no rename onto " << path;
    ASSERT_GE(s.directory_sync, 0) << "the directory was not fsynced after the rename";
    EXPECT_GT(s.file_sync, s.last_write) << "a write came after the fsync";
    EXPECT_EQ(s.calls[s.file_sync].size_at_call, s.file_size) << "fsynced before it was whole";
    EXPECT_LT(s.file_sync, s.rename) << "renamed before the fsync";
    EXPECT_LT(s.rename, s.directory_sync);
    for (int i = s.rename + 1; i < static_cast<int>(s.calls.size()); ++i) {
      EXPECT_FALSE(s.calls[i].kind == syscall_recorder::kWrite) << "a write after the rename";
    }
  }
}

// A writer of `map` over `path` that stops at call `at` of its save (before it runs, or after
// it returned) and is killed there. Returns false, with a failure added, when it never got
// there.
bool KillSaveAt(const Localizer& map, const fs::path& path, int at, bool after) {
  int stopped[2];
  if (::pipe(stopped) != 0) {
    ADD_FAILURE() << "pipe: " << std::strerror(errno);
    return false;
  }
  const pid_t child = ::fork();
  if (child < 0) {
    ADD_FAILURE() << "fork: " << std::strerror(errno);
    return false;
  }
  if (child == 0) {
    ::close(stopped[0]);
    syscall_recorder::stop_pipe = stopped[1];
    syscall_recorder::stop_at = at;
    syscall_recorder::stop_after = after;
    syscall_recorder::Arm(path);
    try {
      map.Save(path);
    } catch (...) {
      ::_exit(3);
    }
    ::_exit(0);  // the save never made call `at`: the parent reads end-of-file
  }
  ::close(stopped[1]);
  pollfd p{stopped[0], POLLIN, 0};
  const int ready = ::poll(&p, 1, 120 * 1000);  // a bound, not a pace: the event ends the wait
  char byte = 0;
  const bool reached = ready == 1 && ::read(stopped[0], &byte, 1) == 1;
  ::close(stopped[0]);
  ::kill(child, SIGKILL);
  int status = 0;
  ::waitpid(child, &status, 0);
  if (!reached) {
    ADD_FAILURE() << "the writer never reached call " << at << (after ? " (after)" : " (before)")
                  << (ready == 0 ? ": no sign of it in 120 s" : ": it ended first");
  }
  return reached;
}

// A SIGKILL at each step of a save over the previous map: while the temporary is written
// (spread over its writes), at its fsync, at the rename and at the directory's fsync, each
// before and after the call. Up to the rename the previous map is there byte for byte, beside
// the killed writer's temporary; from the rename on the new map is there, complete.
TEST_F(CrashSafety, SigkillAtEveryStepOfASaveLeavesThePreviousMapOrTheNewOne) {
  const auto old_map = MapOf(3);
  const auto new_map = MapOf(6);
  const fs::path path = dir_ / "map.gtmap";
  const std::string new_answers = [&] {
    new_map->Save(path);
    return LoadedAnswers(path);
  }();
  const SaveCalls s = RecordSave(*new_map, path);
  ASSERT_GE(s.rename, 0);
  old_map->Save(path);
  const std::string old_bytes = ReadFile(path);
  const std::string old_answers = LoadedAnswers(path);
  ASSERT_EQ(old_answers, Answers(*old_map));
  ASSERT_NE(new_answers, old_answers);

  std::vector<std::pair<int, bool>> stops;  // (call, after)
  int writes = 0;
  for (const auto& c : s.calls) writes += c.kind == syscall_recorder::kWrite ? 1 : 0;
  for (int i = 0, w = 0; i < static_cast<int>(s.calls.size()); ++i) {
    if (s.calls[i].kind == syscall_recorder::kWrite) {
      // The first and the last write, and six between.
      if (w == 0 || w == writes - 1 || (w * 7) / writes != ((w + 1) * 7) / writes) {
        stops.emplace_back(i, false);
      }
      ++w;
    } else {
      stops.emplace_back(i, false);
      stops.emplace_back(i, true);
    }
  }
  // Every kill before the rename must find the previous map (the writer gathers small pieces
  // into 1 MB blocks, so a small map's temporary takes few writes: the first and the last at
  // least).
  ASSERT_GE(writes, 2);
  int before_rename = 0;
  for (const auto& [at, after] : stops) {
    before_rename += at < s.rename || (at == s.rename && !after) ? 1 : 0;
  }
  int kept_old = 0, got_new = 0;
  for (const auto& [at, after] : stops) {
    SCOPED_TRACE("call " + std::to_string(at) + (after ? " after" : " before"));
    if (!KillSaveAt(*new_map, path, at, after)) continue;
    const bool renamed = at > s.rename || (at == s.rename && after);
    if (!renamed) {
      EXPECT_EQ(ReadFile(path), old_bytes) << "the previous map changed before the rename";
      EXPECT_EQ(Temporaries(dir_).size(), 1u) << "the killed writer's temporary";
      ++kept_old;
    } else {
      EXPECT_EQ(LoadedAnswers(path), new_answers) << "not the complete new map";
      ++got_new;
      EXPECT_TRUE(Temporaries(dir_).empty()) << "a temporary left after the rename";
      old_map->Save(path);  // the next kill interrupts a save over the previous map again
    }
  }
  std::printf(
      "%zu kills at the %zu calls of a save (%d writes): %d left the previous map, %d "
      "the new one\n",
      stops.size(), s.calls.size(), writes, kept_old, got_new);
  EXPECT_EQ(kept_old, before_rename);
  EXPECT_GE(kept_old, 5);  // the writes, the fsync (before and after) and the rename (before)
  EXPECT_GE(got_new, 3);
  // Killed writers leave temporaries; the next save of the same file removes them.
  old_map->Save(path);
  EXPECT_TRUE(Temporaries(dir_).empty()) << Temporaries(dir_).front();
  EXPECT_EQ(LoadedAnswers(path), old_answers);
}

// The same at moments no step chooses: kills at random times during a save. Wherever one
// lands, the file is the previous map or the complete new one (how many land where depends on
// the machine's speed, and decides nothing).
TEST_F(CrashSafety, SigkillAtRandomMomentsOfASaveLeavesThePreviousMapOrTheNewOne) {
  const auto old_map = MapOf(3);
  const auto new_map = MapOf(6);
  const fs::path path = dir_ / "map.gtmap";
  const auto t0 = std::chrono::steady_clock::now();
  new_map->Save(path);
  const double save_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  const std::string new_answers = LoadedAnswers(path);
  old_map->Save(path);
  const std::string old_bytes = ReadFile(path);
  const std::string old_answers = LoadedAnswers(path);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> when(0.0, 1.2 * save_ms);
  int kept_old = 0, got_new = 0;
  constexpr int kRounds = 12;
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
    const std::string answers = LoadedAnswers(path);
    if (answers == old_answers) {
      EXPECT_EQ(ReadFile(path), old_bytes) << "round " << round;
      ++kept_old;
    } else {
      ASSERT_EQ(answers, new_answers) << "round " << round << ": neither map";
      ++got_new;
      old_map->Save(path);
    }
  }
  std::printf(
      "save of %zu keyframes: %.1f ms; of %d random kills, %d left the previous map, %d "
      "the new one\n",
      new_map->size(), save_ms, kRounds, kept_old, got_new);
  old_map->Save(path);
  EXPECT_TRUE(Temporaries(dir_).empty());
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
  // Every kCheckpoint insertions the inserter waits until two more saves have finished and a
  // query has run: the second of those saves began after the insertion, while the inserter
  // waited, so it holds exactly that many keyframes. Between checkpoints the three threads run
  // freely. The waits count events; the deadline only turns a hang into a failure.
  constexpr int kCheckpoint = 8;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::minutes(5);
  bool timed_out = false;
  for (int i = 0; i < kKeyframes && !timed_out; ++i) {
    live.Add(processed[i % processed.size()], i, Pose2D{0.01 * i, 0.0, 0.0});
    if ((i + 1) % kCheckpoint != 0) continue;
    const int saves0 = saves.load(), queries0 = queries.load();
    while (saves.load() < saves0 + 2 || queries.load() < queries0 + 1) {
      if (std::chrono::steady_clock::now() > deadline) {
        timed_out = true;
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
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
  ASSERT_FALSE(timed_out) << "no save or query finished for 5 minutes";
  for (int n = kCheckpoint; n <= kKeyframes; n += kCheckpoint) {
    EXPECT_EQ(sizes.count(static_cast<size_t>(n)), 1u)
        << "no save of the first " << n << " keyframes";
  }
}

}  // namespace
}  // namespace gtbow
