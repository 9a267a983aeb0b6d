// The localizer node's parameters (config/localizer.yaml documents each one) and how they are
// read: the ROS-only ones here, the engine's (gtbow::LocalizerOptions, gtbow::MapperOptions)
// checked by the engine.
#pragma once

#include <string>

#include <ros/ros.h>

#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/maintenance.h"
#include "ground_texture_bow/core/mapper.h"
#include "ground_texture_bow/core/odometry_gate.h"
#include "ground_texture_bow/core/sequence.h"

namespace gtbow_ros {

// kMaintenance: localization that keeps the map up with a floor that changes (core/maintenance.h);
// kLocalization never changes the map.
enum class Mode { kMapping, kLocalization, kExternal, kMaintenance };
// The modes that localize every image against the map (localization and maintenance).
inline bool Localizes(Mode m) { return m == Mode::kLocalization || m == Mode::kMaintenance; }
Mode ParseMode(const std::string& name);  // throws std::invalid_argument listing valid names
std::string ModeName(Mode mode);

// Every parameter of config/localizer.yaml (names and meanings are documented there).
struct ServerOptions {
  std::string vocabulary;  // vocabulary file (.gtvoc); or taken from `map`
  std::string preset;      // retrieval preset YAML; empty: config/high_accuracy.yaml
  std::string map;         // map file loaded at start (optional)
  // The engine's options, checked by the engine (LocalizerOptions::Check): the retrieval
  // options from the preset, and ~threads (threads per image: descriptor assignment, query
  // blocks), ~meters_per_pixel, ~candidates (K retrieved and verified) and ~min_inliers.
  gtbow::LocalizerOptions core = DefaultCore();
  Mode mode = Mode::kMapping;
  std::string map_frame = "map";
  std::string odom_frame = "odom";
  std::string camera_frame;       // overrides the image header's frame_id when set
  std::string transport = "raw";  // raw (image_transport) or compressed (<image>/compressed)
  bool use_tf = true;             // look up the camera pose in map_frame
  // Mapping beside a SLAM backend (pose_graph_backend) that publishes map -> odom and answers
  // ~keyframes with keyframe_poses: each keyframe is placed in map_frame through the latest
  // map -> odom and the odometry at the image's time (the keyframe policy measures motion in
  // odometry), then re-posed as the backend's optimised poses arrive.
  bool slam_backend = false;
  double tf_timeout = 0.05;          // seconds to wait for a transform
  bool publish_tf = false;           // publish map -> odom from fixes
  double localized_timeout = 2.0;    // seconds a fix counts as "localized" in diagnostics
  double diagnostics_window = 10.0;  // s: WARN for bad input in this recent window only
  double planar_variance = 1e-9;     // variance on z, roll and pitch of ~pose
  // The ground sampling distance: > 0 sets it; 0 takes it from the camera (camera_info's K and
  // the camera's height) or, failing that, from the loaded map.
  double meters_per_pixel = 0.0;
  double camera_height = 0.0;     // m above the floor; 0: from TF (base, odom or map frame)
  double scale_tolerance = 0.02;  // the camera's scale may differ from the map's by this ratio
  bool rectify = true;            // undistort images whose camera_info has distortion (plumb_bob,
                                  // rational_polynomial); off: images are used as they come
  std::string base_frame = "base_link";  // ~pose is this frame's pose; "": the camera's
  double min_position_variance = 1e-6;   // m^2: floor on x and y of the fixes' covariance
  double min_yaw_variance = 3e-6;        // rad^2: floor on yaw
  double transform_tolerance = 0.1;      // s: map -> odom is dated this far ahead (amcl's)
  double tf_rate = 20.0;                 // Hz: map -> odom republished (publish_tf)
  gtbow::OdometryGateOptions gate;       // ~odom_gate, ~gate_*, ~relocalize_after
  // Sequence queries in localization mode (core/sequence.h): each image with the ones before it
  // through odometry; ~sequence_length (1: single images), ~sequence_max_span (metres).
  gtbow::SequenceOptions sequence;
  // Maintenance mode's policy (core/maintenance.h): ~maintenance_refresh_below_inliers,
  // ~maintenance_min_inliers, ~maintenance_max_theta_sigma, ~maintenance_place_fraction,
  // ~maintenance_views_per_place.
  gtbow::MaintenanceOptions maintenance;
  // Nothing lost: the map is saved to autosave_path (absolute; "" = never) every
  // autosave_period seconds (0 = never periodically) and when the node shuts down
  // (save_on_shutdown), whenever keyframes were added since the last save.
  std::string autosave_path;
  double autosave_period = 0.0;
  bool save_on_shutdown = true;
  // The engine's mapping policy (gtbow::Mapper): ~keyframe_min_distance, ~keyframe_min_angle,
  // ~keyframe_every_n (without TF), ~exclude_recent, and ~temporal_consistency (N),
  // ~temporal_distance, ~temporal_angle, ~temporal_max_motion.
  gtbow::MapperOptions mapper;

  // The node's defaults for the engine's options: 2 threads, 0.25 mm per pixel (a placeholder
  // while ~meters_per_pixel is 0 and the scale is not known: nothing is verified with it), K = 5,
  // 6 inliers.
  static gtbow::LocalizerOptions DefaultCore();
  // Throws std::invalid_argument naming the bad parameter: the ROS-only ones here, the
  // engine's through LocalizerOptions::Check.
  void Check() const;
};

// Throws std::invalid_argument unless `path` is absolute: a node runs in its manager's working
// directory (ROS_HOME, by default ~/.ros), not in the shell's that launched it, so a relative
// path would silently land or be looked for there. `what` names the parameter or service.
void CheckAbsolutePath(const std::string& path, const std::string& what);

// The preset a node uses when ~preset is empty or unset.
std::string DefaultPreset();

// Reads ServerOptions from the private node handle, the preset file included. Throws
// std::invalid_argument (a bad parameter) or std::runtime_error (an unreadable preset).
ServerOptions ReadOptions(const ros::NodeHandle& pnh);

}  // namespace gtbow_ros
