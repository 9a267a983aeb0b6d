// The small version of the benchmark (issue 4), inside `make test`: a small synthetic asphalt
// floor with day-0 and day-180 queries, every Table I row evaluated by `gtbow eval --ablation`,
// and the claims checked by scripts/check_benchmark.py on results.json.
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "test_util.h"

namespace {

using gtbow::testing_util::CommandResult;
using gtbow::testing_util::RunCommand;

class SmallBenchmark : public gtbow::testing_util::TempDirTest {};

TEST_F(SmallBenchmark, AblationRowsFastAndHighAccuracyBehaveAsThePaperSays) {
  const std::string floor = (dir_ / "floor").string(), out = (dir_ / "eval").string();
  CommandResult r = RunCommand(std::string(GTBOW_BIN) + " synth --out " + floor +
                               " --area 0.6 0.5 --train 60 --queries 30 --days 0,180 -q");
  ASSERT_EQ(r.code, 0) << r.output;
  r = RunCommand(std::string(GTBOW_BIN) + " eval --dataset " + floor +
                 " --ablation --words 5000 --out " + out +
                 " --no-cache --no-plots --timing-queries 10 -q");
  ASSERT_EQ(r.code, 0) << r.output;
  r = RunCommand("/usr/bin/python3 " GTBOW_SCRIPTS_DIR "/check_benchmark.py " + out +
                 "/results.json");
  std::printf("%s", r.output.c_str());
  EXPECT_EQ(r.code, 0) << r.output;
}

}  // namespace
