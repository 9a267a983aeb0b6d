// The localizer as a nodelet: reads parameters and builds one LocalizerServer. A start-up
// failure (bad parameter, unreadable vocabulary, preset or map) is reported and leaves the
// nodelet inert; it never takes the manager down.
#include <memory>

#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>

#include "ground_texture_bow/ros/localizer_server.h"

namespace gtbow_ros {

class LocalizerNodelet : public nodelet::Nodelet {
 private:
  void onInit() override {
    try {
      server_ = std::make_unique<LocalizerServer>(getMTNodeHandle(), getMTPrivateNodeHandle(),
                                                  ReadOptions(getPrivateNodeHandle()));
    } catch (const std::exception& e) {
      NODELET_ERROR("ground_texture_bow: cannot start: %s", e.what());
    }
  }
  std::unique_ptr<LocalizerServer> server_;
};

}  // namespace gtbow_ros

PLUGINLIB_EXPORT_CLASS(gtbow_ros::LocalizerNodelet, nodelet::Nodelet)
