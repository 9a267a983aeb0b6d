#include "ground_texture_bow/core/file_util.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>
#include <stdexcept>
#include <thread>

#include <gtest/gtest.h>

#include "ground_texture_bow/core/binary_io.h"
#include "test_util.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace {

class FileUtil : public testing_util::TempDirTest {
 protected:
  size_t Entries(const fs::path& p) {
    return static_cast<size_t>(std::distance(fs::directory_iterator(p), fs::directory_iterator()));
  }
};

TEST_F(FileUtil, AtomicWriteCreatesAndReplaces) {
  const fs::path f = dir_ / "a.txt";
  WriteFileAtomic(f, "first");
  EXPECT_EQ(ReadFile(f), "first");
  WriteFileAtomic(f, "second, longer");
  EXPECT_EQ(ReadFile(f), "second, longer");
  EXPECT_EQ(Entries(dir_), 1u);  // no temporary left behind
}

TEST_F(FileUtil, FailedWriteLeavesOldFileAndNoTemporary) {
  const fs::path f = dir_ / "a.txt";
  WriteFileAtomic(f, "keep me");
  const auto mtime = fs::last_write_time(f);
  // A write over the very same file that fails half-way (a file-size limit: EFBIG, as a full
  // disk gives ENOSPC): the error names the file and the system's reason, the old contents and
  // time stamp stay, no temporary is left, and the process survives the SIGXFSZ.
  {
    testing_util::FileSizeLimit limit(4096);
    try {
      WriteFileAtomic(f, std::string(64 * 1024, 'x'));
      ADD_FAILURE() << "a write past the file-size limit succeeded";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(f.string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("File too large"), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(ReadFile(f), "keep me");
  EXPECT_EQ(fs::last_write_time(f), mtime);
  EXPECT_TRUE(testing_util::Temporaries(dir_).empty());
  // A failure at the last step (the rename: a directory is in the way) removes the complete
  // temporary and leaves what is at the path, here a directory with its contents.
  const fs::path blocked = dir_ / "blocked";
  fs::create_directories(blocked / "child");
  try {
    WriteFileAtomic(blocked, "x");
    ADD_FAILURE() << "a file replaced a directory";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("Is a directory"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(fs::is_directory(blocked / "child"));
  EXPECT_EQ(ReadFile(f), "keep me");
  EXPECT_EQ(Entries(dir_), 2u);
  // A parent that is a file cannot be written into.
  try {
    WriteFileAtomic(f / "sub.txt", "x");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("sub.txt"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("Not a directory"), std::string::npos) << e.what();
  }
}

TEST_F(FileUtil, LongestFileNamesAreWrittenToo) {
  // A file name of 255 bytes (NAME_MAX) is valid; its temporary's name must be too.
  const fs::path f = dir_ / std::string(255, 'm');
  WriteFileAtomic(f, "long");
  WriteFileAtomic(f, "longer");
  EXPECT_EQ(ReadFile(f), "longer");
  EXPECT_EQ(Entries(dir_), 1u);
}

TEST_F(FileUtil, StagedDirectoryReplacesOnlyWhenComplete) {
  const fs::path out = dir_ / "out";
  fs::create_directories(out);
  std::ofstream(out / "old.txt") << "old";
  EXPECT_THROW(StageDirectory(out, false), std::runtime_error);  // non-empty, no force
  EXPECT_TRUE(fs::exists(out / "old.txt"));

  const fs::path staging = StageDirectory(out, true);
  EXPECT_TRUE(fs::exists(out / "old.txt"));  // untouched until the commit
  std::ofstream(staging / "new.txt") << "new";
  CommitStagedDirectory(staging, out);
  EXPECT_TRUE(fs::exists(out / "new.txt"));
  EXPECT_FALSE(fs::exists(out / "old.txt"));
  EXPECT_EQ(Entries(dir_), 1u);  // staging and old copy are gone
}

TEST_F(FileUtil, StagingRejectsFilesAndUnwritableParents) {
  std::ofstream(dir_ / "file") << "x";
  EXPECT_THROW(StageDirectory(dir_ / "file", true), std::runtime_error);
  EXPECT_THROW(StageDirectory(dir_ / "file" / "sub", false), std::runtime_error);
  const fs::path staging = StageDirectory(dir_ / "fresh", false);
  DiscardStagedDirectory(staging);
  EXPECT_FALSE(fs::exists(staging));
  EXPECT_FALSE(fs::exists(dir_ / "fresh"));
}

TEST(Checksum64Builder, PiecesOfAnySizeGiveTheChecksumOfTheWhole) {
  std::mt19937 rng(3);
  for (size_t total : {0u, 1u, 7u, 8u, 9u, 63u, 64u, 1000u}) {
    std::string bytes(total, '\0');
    for (char& c : bytes) c = static_cast<char>(rng());
    for (int trial = 0; trial < 20; ++trial) {
      Checksum64Builder b(total);
      size_t at = 0;
      while (at < total) {
        const size_t n = std::min<size_t>(total - at, rng() % 13);
        b.Add(bytes.data() + at, n);
        at += n;
      }
      ASSERT_EQ(b.Finish(), Checksum64(bytes.data(), total)) << total << " bytes";
    }
  }
}

TEST_F(FileUtil, FramedFileWrittenInPiecesReadsBackAsOne) {
  const char magic[8] = {'T', 'E', 'S', 'T', 'F', 'R', 'M', '\0'};
  const std::string a = "head", b(100001, 'x'), c = "tail bytes";
  WriteFramedFile(dir_ / "f.bin", magic, 3, {a, b, c});
  const FramedPayload p = ReadFramedFile(dir_ / "f.bin", magic, 3, "test");
  EXPECT_EQ(std::string(p.data(), p.size()), a + b + c);
  WriteFramedFile(dir_ / "g.bin", magic, 3, a + b + c);
  EXPECT_EQ(ReadFile(dir_ / "f.bin"), ReadFile(dir_ / "g.bin"));
}

// Pieces of every size (single bytes, pieces that cross one or several buffer blocks, pieces that
// end on a block boundary) with write-behind between them: the file holds exactly the bytes given,
// in order, and written() counts them as they are given.
TEST_F(FileUtil, AtomicFileWriterKeepsEveryPieceInOrder) {
  constexpr size_t kBlock = AtomicFileWriter::kBlock;
  std::mt19937 rng(5);
  std::string all;
  const fs::path f = dir_ / "pieces.bin";
  std::shared_ptr<const MappedFile> mapped;
  {
    AtomicFileWriter w(f);
    const size_t sizes[] = {1, 7, kBlock - 8, 8, kBlock, 3, 2 * kBlock + 5, kBlock - 3, 0, 4096};
    for (int round = 0; round < 3; ++round) {
      for (size_t size : sizes) {
        std::string piece(size, '\0');
        for (char& c : piece) c = static_cast<char>(rng());
        w.Write(piece);
        all += piece;
        ASSERT_EQ(w.written(), all.size());
        if (rng() % 3 == 0) w.WriteBehind(0, w.written(), rng() % 2 == 0);
      }
      // Many small pieces, as a map's index comes.
      for (int i = 0; i < 3000; ++i) {
        std::string piece(1 + rng() % 1500, static_cast<char>('a' + i % 26));
        w.Write(piece);
        all += piece;
      }
    }
    mapped = w.CommitAndMap();
  }
  ASSERT_EQ(mapped->size(), all.size());
  EXPECT_TRUE(std::equal(all.begin(), all.end(), mapped->data()));
  EXPECT_EQ(ReadFile(f), all);
  EXPECT_EQ(Entries(dir_), 1u);
}

// A paced writer (the map's save beside a robot's queries) writes every byte as given, a large
// piece a block at a time, and takes at least the paced time: 6 MB at 60 MB/s, 100 ms or more.
// Only the lower bound is checked, which no slow disk or busy core can break; unpaced, the same
// bytes and the commit took 60 ms here (the test fails with the pause taken out).
TEST_F(FileUtil, PacedWriterTakesAtLeastThePacedTime) {
  constexpr size_t kBlock = AtomicFileWriter::kBlock;
  std::mt19937 rng(9);
  std::string all;
  const fs::path f = dir_ / "paced.bin";
  AtomicFileWriter w(f);
  w.Write(std::string(100, 'x'));  // before the pacing, but buffered: it goes out paced
  all += std::string(100, 'x');
  const auto start = std::chrono::steady_clock::now();
  w.Pace(60e6);
  for (size_t size : {3 * kBlock + 11, size_t{5}, kBlock - 116, 2 * kBlock}) {
    std::string piece(size, '\0');
    for (char& c : piece) c = static_cast<char>(rng());
    w.Write(piece);
    all += piece;
  }
  w.Commit();
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_EQ(all.size(), 6 * kBlock);
  EXPECT_GE(seconds, 6.0 * kBlock / 60e6 - 0.005);
  EXPECT_EQ(ReadFile(f), all);
}

// A writer that fell behind (here: idle for 0.3 s after the pace began) does not make the time up
// in a burst: of the 6 blocks that follow, the first finds it behind and restarts the reckoning
// with one block's time in hand, and the other 4 take at least their paced time (without that
// cap all 6 would go out at once, 0.3 s, 18 blocks' time, "in hand").
TEST_F(FileUtil, PacedWriterDoesNotMakeUpTimeSpentBehind) {
  constexpr size_t kBlock = AtomicFileWriter::kBlock;
  AtomicFileWriter w(dir_ / "behind.bin");
  w.Pace(60e6);
  w.Write(std::string(kBlock, 'a'));  // in step
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  const auto start = std::chrono::steady_clock::now();
  w.Write(std::string(6 * kBlock, 'b'));
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_GE(seconds, 4.0 * kBlock / 60e6);
  w.Commit();
}

// Once the hurry flag is set (a node shutting down), the rest goes out unpaced.
TEST_F(FileUtil, HurriedWriterStopsPacing) {
  constexpr size_t kBlock = AtomicFileWriter::kBlock;
  std::atomic<bool> hurry{false};
  const fs::path f = dir_ / "hurried.bin";
  AtomicFileWriter w(f);
  w.Pace(20e6, &hurry);
  w.Write(std::string(kBlock, 'a'));
  EXPECT_TRUE(w.paced());
  hurry = true;
  w.Write(std::string(kBlock, 'b'));
  EXPECT_FALSE(w.paced());
  w.Commit();
  EXPECT_EQ(ReadFile(f), std::string(kBlock, 'a') + std::string(kBlock, 'b'));
}

TEST_F(FileUtil, ReadFileNamesMissingPath) {
  try {
    ReadFile(dir_ / "missing.bin");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("missing.bin"), std::string::npos);
  }
}

}  // namespace
}  // namespace gtbow
