// The rostest client's entry point: reads ~data, spins two threads, runs the selected suite.
#include "rostest_util.h"

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "localizer_rostest");
  ros::NodeHandle pnh("~");
  if (!pnh.getParam("data", rostest_util::g_data)) {
    std::fprintf(stderr,
                 "localizer_rostest: the ~data parameter (test data directory) is not set\n");
    return 2;
  }
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
