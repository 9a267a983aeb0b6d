// The test run's own tools, which decide a run's verdict: scripts/test_summary.py fails a run
// in which a result file holds no test case (a rostest whose --gtest_filter selects nothing),
// and scripts/sanitizer_reports.py fails on every report of a defect while it counts a
// sanitizer's own crash apart (shown whole, not failing).
#include <fstream>

#include <gtest/gtest.h>

#include "test_util.h"

namespace gtbow {
namespace {

namespace fs = std::filesystem;
using testing_util::RunCommand;

class TestTools : public testing_util::TempDirTest {
 protected:
  void Write(const fs::path& path, const std::string& text) {
    fs::create_directories(path.parent_path());
    std::ofstream(path) << text;
  }
  testing_util::CommandResult Run(const std::string& script, const fs::path& dir) {
    return RunCommand("/usr/bin/python3 " GTBOW_SCRIPTS_DIR "/" + script + " '" + dir.string() +
                      "'");
  }
};

const char* kPassingSuite =
    "<?xml version=\"1.0\"?>\n<testsuites tests=\"1\" failures=\"0\" name=\"AllTests\">\n"
    "<testsuite name=\"A\" tests=\"1\"><testcase name=\"B\" classname=\"A\" status=\"run\"/>"
    "</testsuite></testsuites>\n";

TEST_F(TestTools, ASuiteThatRanNoTestFailsTheRun) {
  Write(dir_ / "r" / "gtest-a.xml", kPassingSuite);
  auto r = Run("test_summary.py", dir_ / "r");
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("1 passed, 0 failed"), std::string::npos) << r.output;
  // A rostest's client run with a filter that matched nothing: an empty suite list.
  Write(dir_ / "r" / "rosunit-renamed.xml",
        "<?xml version=\"1.0\"?>\n<testsuites tests=\"0\" failures=\"0\" name=\"AllTests\">\n"
        "</testsuites>\n");
  r = Run("test_summary.py", dir_ / "r");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("rosunit-renamed.xml: no test ran"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("1 passed, 1 failed"), std::string::npos) << r.output;
}

TEST_F(TestTools, SanitizerReportsOfDefectsFailAndTheToolsOwnCrashIsShownApart) {
  const fs::path logs = dir_ / "sanitizer";
  fs::create_directories(logs);
  auto r = Run("sanitizer_reports.py", logs);
  EXPECT_EQ(r.code, 0) << r.output;
  // The tracer's fault at exit: shown whole and counted, not failing.
  Write(logs / "asan.nodelet.1234",
        "Tracer caught signal 11: addr=0x0 pc=0x7f1c687ae4f0 sp=0x7f1c6334ed00\n"
        "==1234==LeakSanitizer has encountered a fatal error.\n"
        "==1234==HINT: LeakSanitizer does not work under ptrace (strace, gdb, etc)\n");
  r = Run("sanitizer_reports.py", logs);
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("asan.nodelet.1234: the sanitizer's own crash"), std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("| Tracer caught signal 11"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("own (not defects; leak check incomplete): 1"), std::string::npos)
      << r.output;
  // Each kind of defect fails the run, beside the crash.
  for (const std::string& defect :
       {std::string("==99==ERROR: LeakSanitizer: detected memory leaks\n"
                    "Direct leak of 8 byte(s) in 1 object(s) allocated from:\n"),
        std::string("==99==ERROR: AddressSanitizer: heap-use-after-free on address 0x6\n"),
        std::string("src/core/bow.cpp:10:5: runtime error: signed integer overflow\n"),
        std::string("something this script cannot place\n")}) {
    Write(logs / "asan.localizer_test.99", defect);
    r = Run("sanitizer_reports.py", logs);
    EXPECT_EQ(r.code, 1) << defect << r.output;
    EXPECT_NE(r.output.find("asan.localizer_test.99"), std::string::npos) << r.output;
  }
}

// UBSan beside ASan writes to stderr whatever log_path says: the run's output is searched for
// defects, and its ordinary lines are no report.
TEST_F(TestTools, AnUndefinedBehaviourReportInTheTestOutputFailsTheRun) {
  const fs::path logs = dir_ / "sanitizer";
  fs::create_directories(logs);
  const fs::path out = dir_ / "test.log";
  Write(out, "[ RUN      ] Database.Query\n[       OK ] Database.Query (0 ms)\n");
  Write(dir_ / "ros_log" / "node-1-stdout.log", "localizer: map loaded\n");
  const std::string args =
      "'" + logs.string() + "' '" + out.string() + "' '" + (dir_ / "ros_log").string() + "'";
  auto r = RunCommand("/usr/bin/python3 " GTBOW_SCRIPTS_DIR "/sanitizer_reports.py " + args);
  EXPECT_EQ(r.code, 0) << r.output;
  Write(dir_ / "ros_log" / "node-1-stdout.log",
        "src/core/database_query.cpp:226:30: runtime error: null pointer passed as argument 1\n");
  r = RunCommand("/usr/bin/python3 " GTBOW_SCRIPTS_DIR "/sanitizer_reports.py " + args);
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("node-1-stdout.log"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("database_query.cpp:226:30"), std::string::npos) << r.output;
  fs::remove(dir_ / "ros_log" / "node-1-stdout.log");
  Write(out, "[ RUN      ] Database.Query\nsrc/a.cpp:1:2: runtime error: load of misaligned\n");
  r = RunCommand("/usr/bin/python3 " GTBOW_SCRIPTS_DIR "/sanitizer_reports.py " + args);
  EXPECT_EQ(r.code, 1) << r.output;
}

}  // namespace
}  // namespace gtbow
