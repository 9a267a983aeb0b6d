// The engine, the evaluation kit and the gtbow tool must stay ROS-free, and the engine must not
// use the evaluation kit; the build enforces both. These tests show that the enforcement itself
// works: the scan rejects a ROS include (and, for the engine, a kit include), and the guard
// headers make a ROS include fail to compile.
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

namespace fs = std::filesystem;

namespace {

int Shell(const std::string& cmd) { return std::system((cmd + " > /dev/null 2>&1").c_str()); }

class RosFreeGuard : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("gtbow_guard_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  int Scan(const std::string& roots, bool engine = false) {
    return Shell(std::string(GTBOW_CMAKE_COMMAND) + " \"-DROOTS=" + roots + "\" " +
                 (engine ? "-DENGINE=ON " : "") + "-P " + GTBOW_CHECK_SCRIPT);
  }
  fs::path dir_;
};

TEST_F(RosFreeGuard, TheRealSourcesPassTheScan) {
  EXPECT_EQ(Scan(GTBOW_CORE_ROOTS, true), 0);
  EXPECT_EQ(Scan(GTBOW_EVAL_ROOTS), 0);
}

TEST_F(RosFreeGuard, TheEngineMayNotUseTheEvaluationKit) {
  std::ofstream(dir_ / "engine.cpp") << "#include \"ground_texture_bow/eval/dataset.h\"\nint x;\n";
  EXPECT_NE(Scan(dir_.string(), true), 0);
  EXPECT_EQ(Scan(dir_.string(), false), 0);  // the kit and the tools may
}

TEST_F(RosFreeGuard, ScanRejectsRosIncludes) {
  for (const char* inc :
       {"#include <ros/ros.h>", "  #  include \"nodelet/nodelet.h\"",
        "#include <sensor_msgs/Image.h>", "#include <ground_texture_bow/Status.h>"}) {
    std::ofstream(dir_ / "bad.cpp") << "// core file\n" << inc << "\nint x;\n";
    EXPECT_NE(Scan(dir_.string()), 0) << inc;
  }
  std::ofstream(dir_ / "bad.cpp") << "#include <opencv2/core.hpp>\n// ros/ros.h in a comment\n";
  EXPECT_EQ(Scan(dir_.string()), 0);
}

TEST_F(RosFreeGuard, GuardHeadersFailTheCompile) {
  std::ofstream(dir_ / "ros.cpp") << "#include <ros/ros.h>\nint main() { return 0; }\n";
  std::ofstream(dir_ / "ok.cpp")
      << "#include <ground_texture_bow/core/geometry.h>\nint main() { return 0; }\n";
  const std::string cxx = std::string(GTBOW_CXX) + " -std=c++17 -fsyntax-only -I" +
                          GTBOW_GUARD_DIR + " -I" + GTBOW_INCLUDE_DIR + " ";
  EXPECT_NE(Shell(cxx + (dir_ / "ros.cpp").string()), 0);
  EXPECT_EQ(Shell(cxx + (dir_ / "ok.cpp").string()), 0);
}

}  // namespace
