// The reporting scripts' checks (scripts/write_*.py; targets in scripts/targets.py) on small
// fabricated inputs, script by script (test/core/report_check_test.py): each exits 0 when every
// claimed target holds, 1 when one is missed (an answer changed through save and load, plain
// ORB localizing smooth concrete, a wrong verified pose, a moved pose, ...), 2 when an expected
// input is absent (a surface, a split, a preset, a size). A few seconds; no gtbow run.
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "test_util.h"

namespace {

using gtbow::testing_util::CommandResult;
using gtbow::testing_util::RunCommand;

void RunCase(const std::string& unittest_class) {
  const CommandResult r =
      RunCommand("/usr/bin/python3 " GTBOW_REPORT_TEST " " GTBOW_SCRIPTS_DIR " " + unittest_class);
  std::printf("%s", r.output.c_str());
  EXPECT_EQ(r.code, 0) << r.output;
}

TEST(ReportCheck, Benchmark) { RunCase("Eval"); }
TEST(ReportCheck, BenchScaling) { RunCase("Scaling"); }
TEST(ReportCheck, BenchMap) { RunCase("BenchMap"); }
TEST(ReportCheck, BenchmarkReal) { RunCase("Real"); }
TEST(ReportCheck, RealFloorSmall) { RunCase("RealSmall"); }
TEST(ReportCheck, BenchmarkVerification) { RunCase("Verification"); }
TEST(ReportCheck, BenchmarkKeypoints) { RunCase("Keypoints"); }
TEST(ReportCheck, BenchmarkAuthors) { RunCase("Authors"); }
TEST(ReportCheck, Soak) { RunCase("Soak"); }
TEST(ReportCheck, BenchmarkKernels) { RunCase("Kernels"); }

}  // namespace
