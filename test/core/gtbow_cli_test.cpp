// Runs the gtbow binary as a user would and checks exit codes and messages.
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "test_util.h"

namespace fs = std::filesystem;

namespace {

struct Result {
  int code;
  std::string output;
};

Result RunGtbow(const std::string& args) {
  const std::string cmd = std::string(GTBOW_BIN) + " " + args + " 2>&1";
  FILE* p = ::popen(cmd.c_str(), "r");
  Result r{-1, ""};
  if (p == nullptr) return r;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) r.output.append(buf.data(), n);
  const int status = ::pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

class GtbowCli : public gtbow::testing_util::TempDirTest {
 protected:
  std::string Out(const std::string& name) { return (dir_ / name).string(); }
};

const char* kSmall = "--train 2 --queries 2 --days 0,30 --width 128 --height 96 "
                     "--meters-per-pixel 0.0005 -q";

TEST_F(GtbowCli, SynthPrintsASummary) {
  const Result r = RunGtbow("synth --out " + Out("d") + " --area 0.2 0.15 " + kSmall);
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("database"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("query_day030"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(dir_ / "d" / "poses.csv"));
}

TEST_F(GtbowCli, BadInputGivesAClearMessageAndNonZeroExit) {
  Result r = RunGtbow("synth --out " + Out("a") + " --surface marble --area 0.2 0.15 " + kSmall);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("unknown surface 'marble'"), std::string::npos) << r.output;

  r = RunGtbow("synth --out " + Out("a") + " " + kSmall + " --area -1 1");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("area_width"), std::string::npos) << r.output;

  r = RunGtbow("synth --out " + Out("a") + " " + kSmall + " --area 0.2 0.15 --width 0");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("width"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir_ / "a"));

  fs::create_directories(dir_ / "full");
  std::ofstream(dir_ / "full" / "notes.txt") << "mine";
  r = RunGtbow("synth --out " + Out("full") + " --area 0.2 0.15 " + kSmall);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("not empty"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("--force"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(dir_ / "full" / "notes.txt"));

  std::ofstream(dir_ / "file") << "x";
  r = RunGtbow("synth --out " + Out("file") + "/sub --area 0.2 0.15 " + kSmall);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("file"), std::string::npos) << r.output;

  r = RunGtbow("frobnicate");
  EXPECT_NE(r.code, 0);
}

TEST_F(GtbowCli, TrainEvaluateAndBenchmarkOnASyntheticFloor) {
  const std::string d = Out("floor");
  Result r = RunGtbow("synth --out " + d + " --area 0.4 0.3 --train 12 --queries 6 --days 0,90 -q");
  ASSERT_EQ(r.code, 0) << r.output;
  r = RunGtbow("train-vocab --dataset " + d + " --words 800 --out " + Out("v.gtvoc") + " -q");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("800 words"), std::string::npos) << r.output;
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + Out("eval") +
               " --timing-queries 4 --no-cache --no-plots --dump-rankings " + Out("rank.csv") +
               " --dump-poses " + Out("poses.csv") + " -q");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("| query_day090 | 90 | 6 |"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(dir_ / "eval" / "results.json"));
  EXPECT_TRUE(fs::exists(dir_ / "eval" / "summary.md"));
  std::ifstream poses(dir_ / "poses.csv");
  std::string header;
  std::getline(poses, header);
  EXPECT_EQ(header, "query,x,y,theta,inliers");
  std::ifstream rank(dir_ / "rank.csv");
  std::getline(rank, header);
  EXPECT_EQ(header, "query,rank,image,score");
  r = RunGtbow("bench-retrieval --dataset " + d + " --vocab " + Out("v.gtvoc") +
               " --preset " GTBOW_CONFIG_DIR "/fast.yaml --queries 5 -q");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("| database query | 31.9"), std::string::npos) << r.output;

  // Bad input: missing split, too many words, corrupt vocabulary file.
  r = RunGtbow("train-vocab --dataset " + d + " --split nope --out " + Out("x.gtvoc") + " -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("nope.txt does not exist"), std::string::npos) << r.output;
  r = RunGtbow("train-vocab --dataset " + d + " --words 1000000 --out " + Out("x.gtvoc") + " -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("fewer words"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir_ / "x.gtvoc"));
  std::ofstream(dir_ / "bad.gtvoc") << "GTBWVOC junk";
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("bad.gtvoc") + " --out " + Out("bad_eval") + " -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("bad.gtvoc"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir_ / "bad_eval"));  // no half-written results
}

}  // namespace
