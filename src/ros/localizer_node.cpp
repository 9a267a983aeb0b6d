// The localizer as a standalone node: the same LocalizerServer as the nodelet, with a
// multi-threaded spinner so that services are answered while images are processed.
#include <ros/ros.h>

#include "ground_texture_bow/ros/localizer_server.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "ground_texture_bow_localizer");
  ros::NodeHandle nh, pnh("~");
  try {
    gtbow_ros::LocalizerServer server(nh, pnh, gtbow_ros::ReadOptions(pnh));
    ros::AsyncSpinner spinner(3);
    spinner.start();
    ros::waitForShutdown();
    // The spinner, destroyed first, waits for a ~save_map in progress: unpaced from here.
    server.StopPacingSaves();
  } catch (const std::exception& e) {
    ROS_FATAL("ground_texture_bow: cannot start: %s", e.what());
    return 1;
  }
  return 0;
}
