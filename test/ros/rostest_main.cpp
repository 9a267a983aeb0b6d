// The rostest client's entry point: reads ~data, spins two threads, runs the selected suite.
// A --gtest_filter that selects no test (a suite renamed, a typo in a .test file) fails the
// run instead of passing with nothing tested.
#include <fnmatch.h>

#include <sstream>

#include "rostest_util.h"

namespace {

// Whether gtest's filter (positive patterns, then '-' and negative ones, ':'-separated globs)
// selects `name`.
bool Selects(const std::string& filter, const std::string& name) {
  const size_t dash = filter.find('-');
  auto any = [&name](const std::string& patterns) {
    std::istringstream in(patterns);
    for (std::string p; std::getline(in, p, ':');) {
      if (!p.empty() && ::fnmatch(p.c_str(), name.c_str(), 0) == 0) return true;
    }
    return false;
  };
  std::string positive = filter.substr(0, dash);
  if (positive.empty()) positive = "*";
  return any(positive) && !(dash != std::string::npos && any(filter.substr(dash + 1)));
}

class NoTestSelected : public ::testing::Test {
 public:
  explicit NoTestSelected(std::string filter) : filter_(std::move(filter)) {}
  void TestBody() override {
    ADD_FAILURE() << "--gtest_filter=" << filter_ << " selects none of this client's tests";
  }

 private:
  std::string filter_;
};

}  // namespace

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "localizer_rostest");
  ros::NodeHandle pnh("~");
  if (!pnh.getParam("data", rostest_util::g_data)) {
    std::fprintf(stderr,
                 "localizer_rostest: the ~data parameter (test data directory) is not set\n");
    return 2;
  }
  const std::string filter = ::testing::GTEST_FLAG(filter);
  bool selected = false;
  const auto* unit = ::testing::UnitTest::GetInstance();
  for (int i = 0; i < unit->total_test_suite_count(); ++i) {
    const auto* suite = unit->GetTestSuite(i);
    for (int j = 0; j < suite->total_test_count(); ++j) {
      selected |= Selects(filter, std::string(suite->name()) + "." + suite->GetTestInfo(j)->name());
    }
  }
  if (!selected) {
    ::testing::RegisterTest("NoTestSelected", "ByTheFilter", nullptr, nullptr, __FILE__, __LINE__,
                            [filter]() -> NoTestSelected* { return new NoTestSelected(filter); });
    ::testing::GTEST_FLAG(filter) = "NoTestSelected.*";
  }
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
