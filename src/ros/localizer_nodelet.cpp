// The localizer as a nodelet: reads parameters and builds one LocalizerServer. A start-up
// failure (bad parameter, unreadable vocabulary, preset or map, a map of another vocabulary)
// leaves the nodelet inert: it never takes the manager down, logs the error once and reports
// it on /diagnostics at ERROR, once a second, under its own name.
#include <memory>
#include <string>

#include <diagnostic_updater/diagnostic_updater.h>
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
      startup_error_ = e.what();
      NODELET_ERROR("ground_texture_bow: cannot start: %s", e.what());
      ros::NodeHandle pnh = getPrivateNodeHandle();
      failed_ =
          std::make_unique<diagnostic_updater::Updater>(getNodeHandle(), pnh, pnh.getNamespace());
      failed_->setHardwareID("ground_texture_bow");
      failed_->add("localizer", [this](diagnostic_updater::DiagnosticStatusWrapper& stat) {
        stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "cannot start: " + startup_error_);
      });
      failed_->force_update();
      failed_timer_ = getNodeHandle().createTimer(
          ros::Duration(1.0), [this](const ros::TimerEvent&) { failed_->update(); });
    }
  }
  std::unique_ptr<LocalizerServer> server_;
  // Only when the server could not start: its error, reported on /diagnostics.
  std::string startup_error_;
  std::unique_ptr<diagnostic_updater::Updater> failed_;
  ros::Timer failed_timer_;
};

}  // namespace gtbow_ros

PLUGINLIB_EXPORT_CLASS(gtbow_ros::LocalizerNodelet, nodelet::Nodelet)
