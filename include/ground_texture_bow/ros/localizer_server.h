// The ROS face of the core Localizer, shared by the nodelet and the standalone node: it reads
// parameters into ServerOptions, subscribes to a downward camera, builds the map online,
// answers services, and publishes fixes, loop closures, candidates, diagnostics and markers.
//
// Concurrency. Images arrive on the subscriber thread and wait in a one-image slot (a newer
// image replaces a waiting one, counted as a drop); one worker thread processes them. Services
// run on the node's spinner threads and call the Localizer directly; it locks internally only
// for bookkeeping and one query, so no service waits for the worker's extraction.
//   slot_mutex_   guards pending_ (the waiting image)
//   state_mutex_  guards edges_, last_fix_ (shared by worker, services, timer)
//   camera_mutex_ guards the latest camera_info; gate_mutex_ the odometry gate (worker,
//                 initialpose, the map -> odom timer)
//   counters are std::atomic; mode_ is std::atomic.
#pragma once

#include <atomic>
#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <diagnostic_updater/diagnostic_updater.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>

#include "ground_texture_bow/AddKeyframe.h"
#include "ground_texture_bow/GetInfo.h"
#include "ground_texture_bow/KeyframePoses.h"
#include "ground_texture_bow/LoadMap.h"
#include "ground_texture_bow/Localize.h"
#include "ground_texture_bow/QueryCandidates.h"
#include "ground_texture_bow/Reset.h"
#include "ground_texture_bow/SaveMap.h"
#include "ground_texture_bow/SetMode.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/mapper.h"
#include "ground_texture_bow/ros/conversions.h"
#include "ground_texture_bow/ros/server_options.h"

namespace gtbow_ros {

// A request that cannot be served in the node's state (Status::FAILED_PRECONDITION).
struct PreconditionFailed : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class LocalizerServer {
 public:
  // Throws std::runtime_error / std::invalid_argument when the vocabulary, preset or map
  // cannot be loaded (the nodelet reports it and stays inert).
  LocalizerServer(ros::NodeHandle nh, ros::NodeHandle pnh, const ServerOptions& options);
  ~LocalizerServer();
  // Saves from now on, the one under way included, go unpaced (~save_rate_mb): called as the
  // node shuts down, before anything waits for a service call or timer that may be saving.
  void StopPacingSaves() {
    if (localizer_) localizer_->StopPacingSaves();
  }
  LocalizerServer(const LocalizerServer&) = delete;
  LocalizerServer& operator=(const LocalizerServer&) = delete;

 private:
  struct Edge {
    uint32_t from, to;
  };

  // A received image, raw or compressed (exactly one is set).
  struct Pending {
    sensor_msgs::ImageConstPtr raw;
    sensor_msgs::CompressedImageConstPtr compressed;
    explicit operator bool() const { return raw || compressed; }
    const std_msgs::Header& header() const { return raw ? raw->header : compressed->header; }
  };

  void ImageCallback(const sensor_msgs::ImageConstPtr& msg);
  void CameraInfoCallback(const sensor_msgs::CameraInfoConstPtr& msg);
  // A SLAM backend's optimised keyframe poses (keyframe_poses): applied when they are in
  // ~map_frame, else counted and reported.
  void KeyframePosesCallback(const ground_texture_bow::KeyframePosesConstPtr& msg);
  // Throws std::runtime_error unless the map file at `path` records no pose frame or ~map_frame
  // (its poses would be published in the wrong frame).
  void CheckMapFrame(const std::string& path) const;
  // The camera's footprint in map_frame beside a SLAM backend: the latest map -> odom composed
  // with `odom` (the camera in odom_frame at the image's time); none while the backend has not
  // published map -> odom.
  std::optional<gtbow::Pose2D> BackendPose(const gtbow::Pose2D& odom);
  // amcl's initialpose: the base's pose in map_frame sets the odometry gate's map -> odom.
  void InitialPoseCallback(const geometry_msgs::PoseWithCovarianceStampedConstPtr& msg);
  // Makes sure the scale of an image from `frame`, whose camera_info is `info` (may be null), is
  // known and agrees with the map's (see ServerOptions::meters_per_pixel); throws
  // std::invalid_argument saying why not.
  void ResolveScale(const std::string& frame, const sensor_msgs::CameraInfoConstPtr& info);
  // The camera's height above the floor: ~camera_height, else its TF height in base_frame,
  // odom_frame or map_frame (the first that exists); `source` says which.
  std::optional<double> CameraHeight(const std::string& frame, std::string* source);
  // Services that verify need the scale: throws PreconditionFailed while it is unknown.
  void RequireScale() const;
  // The camera's footprint in odom_frame at the image's stamp, when odometry exists.
  std::optional<gtbow::Pose2D> LookupOdometry(const std_msgs::Header& header);
  // map -> odom from the gate's correction, dated now + ~transform_tolerance (amcl's way).
  void SendMapToOdom();
  // Saves the map to ~autosave_path when keyframes were added since the last save (never an
  // empty map, never in localization mode); `why` goes into the log. Errors are logged and
  // counted, never thrown.
  void AutoSave(const char* why, bool paced = true);  // paced: LocalizerOptions::save_rate_mb
  void CompressedCallback(const sensor_msgs::CompressedImageConstPtr& msg);
  void Enqueue(Pending p);
  void WorkerLoop();
  // Whether images must wait for the first camera_info: the scale comes from it (~meters_per_pixel
  // 0, no map) and none has arrived. The waiting image stays in the slot (a newer one replaces
  // it, counted as a drop); the first camera_info, or a map's scale, releases it.
  bool WaitsForCameraInfo() const {
    return options_.meters_per_pixel <= 0 && !scale_known_ && !camera_info_seen_;
  }
  void WakeWorker();                         // after something WaitsForCameraInfo() reads changed
  std::string WaitingForCameraInfo() const;  // what the node says while images wait
  void ProcessImage(const Pending& msg);
  std::optional<gtbow::Pose2D> LookupFootprint(const std::string& frame, const ros::Time& stamp,
                                               const std::string& target, bool warn);
  void PublishFix(const gtbow::Localization& fix, const std_msgs::Header& header);
  void PublishLoopClosure(const gtbow::Candidate& closure, uint32_t query_id,
                          const std_msgs::Header& header);
  // The camera image with its keypoints (green) and the verified matches of the winning
  // keyframe (red), captioned with the keyframe and inlier count.
  void PublishDebugImage(const cv::Mat& floor_image, const gtbow::ProcessedImage& img,
                         const std::vector<gtbow::Vec2>& inliers, const std::string& caption,
                         const std_msgs::Header& header);
  void PublishMarkers(const ros::TimerEvent&);
  void Diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);
  // Counts and reports bad input: an image from the topic, or a service request.
  void Reject(const std::string& what, bool image);

  // Runs a service body (returning its status) and turns exceptions into a status:
  // std::out_of_range -> NOT_FOUND; std::invalid_argument, or any error when `any_error_is_input`
  // (a bad path, a damaged map file) -> INVALID_ARGUMENT, counted as a rejected request;
  // anything else -> INTERNAL.
  template <typename Body>
  ground_texture_bow::Status Serve(const char* name, bool any_error_is_input, Body&& body);
  // Forgets the per-map bookkeeping (loop-closure edges, the mapper's keyframe policy and run).
  void ForgetMapState();

  // The service handlers: On<Service>, each one's body run through Serve.
  bool OnQueryCandidates(ground_texture_bow::QueryCandidates::Request& req,
                         ground_texture_bow::QueryCandidates::Response& res);
  bool OnAddKeyframe(ground_texture_bow::AddKeyframe::Request& req,
                     ground_texture_bow::AddKeyframe::Response& res);
  bool OnLocalize(ground_texture_bow::Localize::Request& req,
                  ground_texture_bow::Localize::Response& res);
  bool OnSaveMap(ground_texture_bow::SaveMap::Request& req,
                 ground_texture_bow::SaveMap::Response& res);
  bool OnLoadMap(ground_texture_bow::LoadMap::Request& req,
                 ground_texture_bow::LoadMap::Response& res);
  bool OnReset(ground_texture_bow::Reset::Request& req, ground_texture_bow::Reset::Response& res);
  bool OnGetInfo(ground_texture_bow::GetInfo::Request& req,
                 ground_texture_bow::GetInfo::Response& res);
  bool OnSetMode(ground_texture_bow::SetMode::Request& req,
                 ground_texture_bow::SetMode::Response& res);

  ros::NodeHandle nh_, pnh_;
  ServerOptions options_;
  std::unique_ptr<gtbow::Localizer> localizer_;
  std::unique_ptr<gtbow::Mapper> mapper_;  // the mapping pipeline (worker; Reset from services)

  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;
  image_transport::ImageTransport it_;
  image_transport::Subscriber image_sub_;
  ros::Subscriber compressed_sub_;  // transport: compressed (Debian has no compressed plugin)
  image_transport::Publisher debug_pub_;
  ros::Publisher pose_pub_, camera_pose_pub_, loop_pub_, candidates_pub_, markers_pub_,
      keyframes_pub_;
  ros::Subscriber info_sub_, initialpose_sub_, keyframe_poses_sub_;
  std::string info_topic_;
  ros::Timer tf_timer_;
  ros::WallTimer autosave_timer_;
  std::mutex autosave_mutex_;  // one autosave at a time
  std::atomic<uint64_t> changes_{0}, saved_changes_{0}, autosaves_{0}, autosave_errors_{0};
  std::atomic<bool> last_autosave_failed_{false};
  // The problem counters (rejected images, rejected requests, missing and unusable transforms)
  // at each diagnostics update over the last ~diagnostics_window: the status tells what went
  // wrong recently, the values what went wrong since the start.
  struct ProblemCounts {
    uint64_t rejected = 0, requests = 0, missing_tf = 0, unusable_tf = 0;
  };
  std::mutex diag_mutex_;
  std::deque<std::pair<ros::WallTime, ProblemCounts>> diag_history_;  // guarded by diag_mutex_
  std::vector<ros::ServiceServer> services_;
  ros::Timer markers_timer_;
  diagnostic_updater::Updater updater_;
  ros::Timer diag_timer_;

  std::atomic<Mode> mode_;
  std::atomic<uint64_t> received_{0}, processed_{0}, dropped_{0}, rejected_{0}, debug_images_{0},
      rejected_requests_{0}, missing_tf_{0}, fixes_{0}, loop_closures_{0}, failed_fixes_{0},
      held_closures_{0}, held_fixes_{0}, relocalizations_{0}, sequence_queries_{0},
      escalated_queries_{0}, first_passes_skipped_{0}, unusable_tf_{0}, views_added_{0},
      keyframes_retired_{0}, keyframes_reposed_{0}, pose_updates_refused_{0},
      keyframe_poses_stamp_ns_{0};             // header stamp of the newest keyframe_poses applied
  std::atomic<bool> scale_known_{false};       // explicit, from the map, or from camera_info
  std::atomic<bool> scale_from_map_{false};    // a loaded map's: the camera is checked against it
  std::atomic<bool> camera_info_seen_{false};  // a sensor_msgs/CameraInfo has arrived
  std::atomic<double> last_processing_ms_{0.0};
  std::atomic<double> input_rate_hz_{0.0};

  std::mutex slot_mutex_;
  std::condition_variable slot_cv_;
  Pending pending_;    // guarded by slot_mutex_
  bool stop_ = false;  // guarded by slot_mutex_
  std::thread worker_;

  std::mutex state_mutex_;
  std::vector<Edge> edges_;    // guarded by state_mutex_
  ros::Time last_fix_time_;    // guarded by state_mutex_
  ros::Time last_image_time_;  // guarded by state_mutex_
  std::string last_error_;     // guarded by state_mutex_
  std::string scale_source_;   // guarded by state_mutex_
  std::string camera_frame_;   // the latest image's frame (initialpose); state_mutex_

  std::mutex camera_mutex_;
  sensor_msgs::CameraInfoConstPtr camera_info_;  // the latest; guarded by camera_mutex_
  std::map<std::string, std::pair<double, std::string>> heights_;  // by frame; worker only
  bool warned_unchecked_scale_ = false;                            // worker only
  bool warned_unrectified_ = false;                                // worker only
  Rectifier rectifier_;                                            // worker only
  std::atomic<uint64_t> rectified_{0};

  gtbow::QuerySequence sequence_;  // localization mode's last images; worker only
  // Which of localization mode's single images try an escalating preset's first pass
  // (features.query_escalate_backoff); worker only. Started again when the map or the mode
  // changes (backoff_stale_).
  gtbow::EscalationBackoff backoff_;
  std::atomic<bool> backoff_stale_{false};
  // Maintenance mode (core/maintenance.h): made from the map on the first fix, made again when
  // the map is replaced (maintainer_stale_) or the image size or scale changes; worker only.
  std::unique_ptr<gtbow::MapMaintainer> maintainer_;
  gtbow::ImageGeometry maintainer_geometry_;
  std::atomic<bool> maintainer_stale_{true};
  // The view of a published fix, kept up in maintenance mode; worker only.
  void Maintain(const gtbow::Localization& fix, const cv::Mat& floor_image,
                const std_msgs::Header& header);
  std::mutex gate_mutex_;
  gtbow::OdometryGate gate_;  // guarded by gate_mutex_
  ros::Time last_tf_stamp_;   // of the last map -> odom sent; guarded by gate_mutex_
};

}  // namespace gtbow_ros
