#include "ground_texture_bow/core/file_util.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>

#include <gtest/gtest.h>

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
  // A directory in the way of the rename makes the final step fail.
  const fs::path blocked = dir_ / "blocked";
  fs::create_directories(blocked / "child");
  EXPECT_THROW(WriteFileAtomic(blocked, "x"), std::runtime_error);
  EXPECT_EQ(ReadFile(f), "keep me");
  EXPECT_EQ(Entries(dir_), 2u);
  // A parent that is a file cannot be written into.
  try {
    WriteFileAtomic(f / "sub.txt", "x");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("sub.txt"), std::string::npos);
  }
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
