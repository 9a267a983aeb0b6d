// The localizer node's parameters: defaults, checks and reading (server_options.h).
#include "ground_texture_bow/ros/server_options.h"

#include <stdexcept>

#include <ros/package.h>
#include <string>

#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/enum_names.h"

namespace gtbow_ros {

namespace {
constexpr gtbow::EnumName<Mode> kModes[] = {{"mapping", Mode::kMapping},
                                            {"localization", Mode::kLocalization},
                                            {"external", Mode::kExternal},
                                            {"maintenance", Mode::kMaintenance}};
}  // namespace

Mode ParseMode(const std::string& name) { return gtbow::ParseEnumName(name, "mode", kModes); }
std::string ModeName(Mode mode) { return gtbow::EnumValueName(mode, kModes); }

gtbow::LocalizerOptions ServerOptions::DefaultCore() {
  gtbow::LocalizerOptions core;
  core.threads = 2;
  core.meters_per_pixel = 0.00025;
  return core;
}

void CheckAbsolutePath(const std::string& path, const std::string& what) {
  if (!path.empty() && path[0] == '/') return;
  throw std::invalid_argument(
      what + " '" + path + "' is not an absolute path: the node runs in its manager's working " +
      "directory (ROS_HOME, by default ~/.ros), not in your shell's; give the whole path (in a " +
      "shell, $PWD/" + path + ")");
}

std::string DefaultPreset() {
  // The package's share directory, wherever it is (a devel or an install space); the source
  // tree's only when ROS cannot find the package (a binary run outside any workspace).
  const std::string share = ros::package::getPath("ground_texture_bow");
  return (share.empty() ? std::string(GTBOW_CONFIG_DIR) : share + "/config") +
         "/high_accuracy.yaml";
}

void ServerOptions::Check() const {
  auto need = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument("parameter " + what);
  };
  need(!vocabulary.empty() || !map.empty(), "~vocabulary (or ~map) must be set");
  need(!map_frame.empty(), "~map_frame must not be empty");
  need(!slam_backend || (!odom_frame.empty() && odom_frame != map_frame && use_tf),
       "~slam_backend needs ~use_tf and an ~odom_frame other than ~map_frame (the backend "
       "publishes map_frame -> odom_frame)");
  need(transport == "raw" || transport == "compressed", "~transport must be raw or compressed");
  need(tf_timeout >= 0, "~tf_timeout must be >= 0");
  need(localized_timeout > 0, "~localized_timeout must be > 0");
  need(planar_variance > 0, "~planar_variance must be > 0");
  need(meters_per_pixel >= 0, "~meters_per_pixel must be >= 0 (0: from camera_info)");
  need(camera_height >= 0, "~camera_height must be >= 0 (0: from TF)");
  need(scale_tolerance > 0 && scale_tolerance < 1, "~scale_tolerance must be in (0, 1)");
  need(min_position_variance >= 0 && min_yaw_variance >= 0,
       "~min_position_variance and ~min_yaw_variance must be >= 0");
  need(transform_tolerance >= 0, "~transform_tolerance must be >= 0");
  need(tf_rate > 0, "~tf_rate must be > 0");
  need(diagnostics_window > 0, "~diagnostics_window must be > 0");
  need(autosave_period >= 0, "~autosave_period must be >= 0 (0: only on shutdown)");
  need(autosave_period == 0 || !autosave_path.empty(), "~autosave_period needs ~autosave_path");
  for (const auto& [path, what] :
       {std::pair<const std::string&, const char*>{vocabulary, "~vocabulary"},
        {map, "~map"},
        {preset, "~preset"},
        {autosave_path, "~autosave_path"}}) {
    if (!path.empty()) CheckAbsolutePath(path, what);
  }
  try {
    gate.Check();
    sequence.Check();
    maintenance.Check();
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("parameter ~") + e.what());
  }
  try {
    mapper.Check();  // its messages name the parameter without the ~
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("parameter ~") + e.what());
  }
  try {
    core.Check();
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("parameter (~threads, ~meters_per_pixel, "
                                            "~save_rate_mb, ~candidates, ~min_inliers or the "
                                            "preset): ") +
                                e.what());
  }
}

ServerOptions ReadOptions(const ros::NodeHandle& pnh) {
  ServerOptions o;
  std::string mode = ModeName(o.mode);
  pnh.param("vocabulary", o.vocabulary, o.vocabulary);
  pnh.param("preset", o.preset, o.preset);
  if (o.preset.empty()) o.preset = DefaultPreset();
  pnh.param("map", o.map, o.map);
  pnh.param("mode", mode, mode);
  o.mode = ParseMode(mode);
  pnh.param("map_frame", o.map_frame, o.map_frame);
  pnh.param("odom_frame", o.odom_frame, o.odom_frame);
  pnh.param("slam_backend", o.slam_backend, o.slam_backend);
  pnh.param("camera_frame", o.camera_frame, o.camera_frame);
  pnh.param("transport", o.transport, o.transport);
  pnh.param("meters_per_pixel", o.meters_per_pixel, o.meters_per_pixel);
  if (o.meters_per_pixel > 0) o.core.meters_per_pixel = o.meters_per_pixel;
  pnh.param("scale_tolerance", o.scale_tolerance, o.scale_tolerance);
  pnh.param("rectify", o.rectify, o.rectify);
  pnh.param("base_frame", o.base_frame, o.base_frame);
  pnh.param("min_position_variance", o.min_position_variance, o.min_position_variance);
  pnh.param("min_yaw_variance", o.min_yaw_variance, o.min_yaw_variance);
  pnh.param("transform_tolerance", o.transform_tolerance, o.transform_tolerance);
  pnh.param("tf_rate", o.tf_rate, o.tf_rate);
  pnh.param("odom_gate", o.gate.enabled, o.gate.enabled);
  pnh.param("gate_distance", o.gate.distance, o.gate.distance);
  pnh.param("gate_angle", o.gate.angle, o.gate.angle);
  pnh.param("gate_distance_drift", o.gate.distance_drift, o.gate.distance_drift);
  pnh.param("gate_angle_drift", o.gate.angle_drift, o.gate.angle_drift);
  pnh.param("relocalize_after", o.gate.relocalize_after, o.gate.relocalize_after);
  pnh.param("sequence_length", o.sequence.length, o.sequence.length);
  pnh.param("sequence_max_span", o.sequence.max_span, o.sequence.max_span);
  pnh.param("sequence_single_first", o.sequence.single_first, o.sequence.single_first);
  pnh.param("maintenance_refresh_below_inliers", o.maintenance.refresh_below_inliers,
            o.maintenance.refresh_below_inliers);
  pnh.param("maintenance_min_inliers", o.maintenance.min_inliers, o.maintenance.min_inliers);
  pnh.param("maintenance_max_theta_sigma", o.maintenance.max_theta_sigma,
            o.maintenance.max_theta_sigma);
  pnh.param("maintenance_place_fraction", o.maintenance.place_fraction,
            o.maintenance.place_fraction);
  pnh.param("maintenance_views_per_place", o.maintenance.max_views_per_place,
            o.maintenance.max_views_per_place);
  pnh.param("diagnostics_window", o.diagnostics_window, o.diagnostics_window);
  pnh.param("autosave_path", o.autosave_path, o.autosave_path);
  pnh.param("autosave_period", o.autosave_period, o.autosave_period);
  pnh.param("save_on_shutdown", o.save_on_shutdown, o.save_on_shutdown);
  pnh.param("threads", o.core.threads, o.core.threads);
  pnh.param("keep_descriptors", o.core.keep_descriptors, o.core.keep_descriptors);
  pnh.param("save_rate_mb", o.core.save_rate_mb, o.core.save_rate_mb);
  pnh.param("use_tf", o.use_tf, o.use_tf);
  pnh.param("tf_timeout", o.tf_timeout, o.tf_timeout);
  pnh.param("keyframe_min_distance", o.mapper.keyframe_min_distance,
            o.mapper.keyframe_min_distance);
  pnh.param("keyframe_min_angle", o.mapper.keyframe_min_angle, o.mapper.keyframe_min_angle);
  pnh.param("keyframe_every_n", o.mapper.keyframe_every_n, o.mapper.keyframe_every_n);
  // K and the inliers a pose needs: the preset's unless set (> 0).
  int candidates = 0, min_inliers = 0;
  pnh.param("candidates", candidates, candidates);
  pnh.param("min_inliers", min_inliers, min_inliers);
  pnh.param("exclude_recent", o.mapper.exclude_recent, o.mapper.exclude_recent);
  pnh.param("temporal_consistency", o.mapper.temporal.required, o.mapper.temporal.required);
  pnh.param("temporal_distance", o.mapper.temporal.distance, o.mapper.temporal.distance);
  pnh.param("temporal_angle", o.mapper.temporal.angle, o.mapper.temporal.angle);
  pnh.param("temporal_max_motion", o.mapper.temporal.max_motion, o.mapper.temporal.max_motion);
  pnh.param("publish_tf", o.publish_tf, o.publish_tf);
  pnh.param("localized_timeout", o.localized_timeout, o.localized_timeout);
  pnh.param("planar_variance", o.planar_variance, o.planar_variance);
  pnh.param("camera_height", o.camera_height, o.camera_height);
  o.core.retrieval = gtbow::LoadRetrievalConfig(o.preset);
  if (candidates != 0) o.core.retrieval.verification.candidates = candidates;
  if (min_inliers != 0) o.core.retrieval.verification.pose.min_inliers = min_inliers;
  o.Check();
  return o;
}

}  // namespace gtbow_ros
