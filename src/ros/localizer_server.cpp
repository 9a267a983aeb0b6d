#include "ground_texture_bow/ros/localizer_server.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include <geometry_msgs/TransformStamped.h>
#include <image_transport/camera_common.h>
#include <visualization_msgs/MarkerArray.h>

#include "ground_texture_bow/CandidateList.h"
#include "ground_texture_bow/KeyframeStamp.h"
#include "ground_texture_bow/LoopClosure.h"
#include "ground_texture_bow/ros/conversions.h"

namespace gtbow_ros {

using ground_texture_bow::Status;

LocalizerServer::LocalizerServer(ros::NodeHandle nh, ros::NodeHandle pnh,
                                 const ServerOptions& options)
    : nh_(nh),
      pnh_(pnh),
      options_(options),
      tf_listener_(tf_buffer_),
      it_(nh),
      updater_(nh, pnh, pnh.getNamespace()),  // named after this nodelet, not its manager
      mode_(options.mode),
      sequence_(options.sequence),
      gate_(options.gate) {
  options_.Check();
  std::string vocab_path = options_.vocabulary;
  if (vocab_path.empty()) vocab_path = gtbow::Localizer::VocabularyPathOf(options_.map);
  std::shared_ptr<gtbow::Vocabulary> vocab = gtbow::Vocabulary::Load(vocab_path);
  localizer_ = std::make_unique<gtbow::Localizer>(std::move(vocab), vocab_path, options_.core);
  backoff_ = localizer_->NewBackoff();
  if (options_.meters_per_pixel > 0) {
    scale_known_ = true;
    scale_source_ = "~meters_per_pixel";
  }
  localizer_->SetPoseFrame(options_.map_frame);
  if (!options_.map.empty()) {
    CheckMapFrame(options_.map);
    // Without ~meters_per_pixel the map's scale is taken, and the camera's checked against it.
    localizer_->Load(options_.map, options_.meters_per_pixel <= 0);
    if (localizer_->pose_frame().empty()) localizer_->SetPoseFrame(options_.map_frame);
    if (!scale_known_) {
      scale_known_ = true;
      scale_from_map_ = true;
      scale_source_ = "the map " + options_.map;
    }
  }
  mapper_ = std::make_unique<gtbow::Mapper>(localizer_.get(), options_.mapper);

  pose_pub_ = pnh_.advertise<geometry_msgs::PoseWithCovarianceStamped>("pose", 10);
  camera_pose_pub_ = pnh_.advertise<geometry_msgs::PoseWithCovarianceStamped>("camera_pose", 10);
  loop_pub_ = pnh_.advertise<ground_texture_bow::LoopClosure>("loop_closures", 50);
  candidates_pub_ = pnh_.advertise<ground_texture_bow::CandidateList>("candidates", 10);
  markers_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("markers", 1, true);
  keyframes_pub_ = pnh_.advertise<ground_texture_bow::KeyframeStamp>("keyframes", 1000);
  image_transport::ImageTransport pit(pnh_);
  debug_pub_ = pit.advertise("debug_image", 1);

  services_.push_back(
      pnh_.advertiseService("query_candidates", &LocalizerServer::OnQueryCandidates, this));
  services_.push_back(pnh_.advertiseService("add_keyframe", &LocalizerServer::OnAddKeyframe, this));
  services_.push_back(pnh_.advertiseService("localize", &LocalizerServer::OnLocalize, this));
  services_.push_back(pnh_.advertiseService("save_map", &LocalizerServer::OnSaveMap, this));
  services_.push_back(pnh_.advertiseService("load_map", &LocalizerServer::OnLoadMap, this));
  services_.push_back(pnh_.advertiseService("reset", &LocalizerServer::OnReset, this));
  services_.push_back(pnh_.advertiseService("get_info", &LocalizerServer::OnGetInfo, this));
  services_.push_back(pnh_.advertiseService("set_mode", &LocalizerServer::OnSetMode, this));

  updater_.setHardwareID("ground_texture_bow");
  updater_.add("localizer", this, &LocalizerServer::Diagnose);
  diag_timer_ =
      nh_.createTimer(ros::Duration(1.0), [this](const ros::TimerEvent&) { updater_.update(); });
  markers_timer_ = nh_.createTimer(ros::Duration(1.0), &LocalizerServer::PublishMarkers, this);
  if (options_.publish_tf) {
    tf_timer_ = nh_.createTimer(ros::Duration(1.0 / options_.tf_rate),
                                [this](const ros::TimerEvent&) { SendMapToOdom(); });
  }
  if (options_.autosave_period > 0) {
    autosave_timer_ =
        nh_.createWallTimer(ros::WallDuration(options_.autosave_period),
                            [this](const ros::WallTimerEvent&) { AutoSave("periodic"); });
  }
  // amcl's topic, in the node's namespace (remap it like amcl's).
  initialpose_sub_ = nh_.subscribe("initialpose", 2, &LocalizerServer::InitialPoseCallback, this);
  keyframe_poses_sub_ =
      pnh_.subscribe("keyframe_poses", 10, &LocalizerServer::KeyframePosesCallback, this);

  worker_ = std::thread([this] { WorkerLoop(); });
  info_topic_ = image_transport::getCameraInfoTopic(nh_.resolveName("image"));
  // Described before the subscriptions: from then on the worker may set the scale.
  const std::string scale =
      scale_known_ ? std::to_string(localizer_->meters_per_pixel()) + " m/px from " + scale_source_
                   : "from camera_info on " + info_topic_;
  ROS_INFO(
      "ground_texture_bow: %s mode, %zu keyframes, vocabulary %s (%u words), preset %s, "
      "scale %s",
      ModeName(mode_).c_str(), localizer_->size(), vocab_path.c_str(),
      localizer_->vocabulary().size(), options_.preset.c_str(), scale.c_str());
  // The subscriptions go last: callbacks may start at once. camera_info is subscribed on its
  // own (not through a CameraSubscriber) so that a camera without one still works with
  // ~meters_per_pixel set.
  info_sub_ = nh_.subscribe(info_topic_, 2, &LocalizerServer::CameraInfoCallback, this);
  if (options_.transport == "compressed") {
    // Decoded here with OpenCV: Debian ships no compressed image_transport plugin.
    compressed_sub_ = nh_.subscribe(nh_.resolveName("image") + "/compressed", 5,
                                    &LocalizerServer::CompressedCallback, this);
  } else {
    image_sub_ = it_.subscribe("image", 5, &LocalizerServer::ImageCallback, this);
  }
}

LocalizerServer::~LocalizerServer() {
  // A paced save under way (~save_map, autosave) finishes unpaced, and so does the last one
  // below: the shutdown waits for them.
  StopPacingSaves();
  image_sub_.shutdown();
  compressed_sub_.shutdown();
  info_sub_.shutdown();
  initialpose_sub_.shutdown();
  keyframe_poses_sub_.shutdown();
  tf_timer_.stop();
  // The shutdowns wait for callbacks in progress; those wrote under these locks, and taking each
  // once orders their writes before the members are destroyed (ThreadSanitizer saw a camera_info
  // callback's write race with camera_info_'s destruction in a nodelet's teardown).
  {
    std::lock_guard<std::mutex> lock(camera_mutex_);
    camera_info_.reset();
  }
  { std::lock_guard<std::mutex> lock(gate_mutex_); }
  { std::lock_guard<std::mutex> lock(state_mutex_); }
  {
    std::lock_guard<std::mutex> lock(slot_mutex_);
    stop_ = true;
  }
  slot_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
  autosave_timer_.stop();
  if (options_.save_on_shutdown) AutoSave("shutdown", false);  // nothing left to slow down
}

void LocalizerServer::AutoSave(const char* why, bool paced) {
  if (options_.autosave_path.empty() || mode_.load() == Mode::kLocalization) return;  // read-only
  std::lock_guard<std::mutex> one(autosave_mutex_);
  const uint64_t changes = changes_.load();
  if (changes == saved_changes_.load() || localizer_->size() == 0) return;
  try {
    const gtbow::SaveStats s = localizer_->Save(options_.autosave_path, paced);
    saved_changes_ = changes;
    autosaves_++;
    last_autosave_failed_ = false;
    ROS_INFO("ground_texture_bow: %s save of %llu keyframes to %s", why,
             static_cast<unsigned long long>(s.keyframes), options_.autosave_path.c_str());
  } catch (const std::exception& e) {
    autosave_errors_++;
    last_autosave_failed_ = true;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      last_error_ = std::string(why) + " save: " + e.what();
    }
    ROS_ERROR("ground_texture_bow: %s save failed: %s", why, e.what());
  }
}

void LocalizerServer::Reject(const std::string& what, bool image) {
  (image ? rejected_ : rejected_requests_)++;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    last_error_ = what;
  }
  ROS_WARN_THROTTLE(2.0, "ground_texture_bow: %s", what.c_str());
}

void LocalizerServer::ImageCallback(const sensor_msgs::ImageConstPtr& msg) {
  Pending p;
  p.raw = msg;
  Enqueue(std::move(p));
}

void LocalizerServer::CameraInfoCallback(const sensor_msgs::CameraInfoConstPtr& msg) {
  {
    std::lock_guard<std::mutex> lock(camera_mutex_);
    camera_info_ = msg;
  }
  // The first one releases an image that came before it (the image and its camera_info travel
  // on two connections, so either may arrive first).
  if (!camera_info_seen_.exchange(true)) WakeWorker();
}

std::string LocalizerServer::WaitingForCameraInfo() const {
  return "waiting for camera_info on " + info_topic_ +
         ": the scale comes from it (~meters_per_pixel is 0, no map is loaded) and no "
         "sensor_msgs/CameraInfo has arrived; the newest image waits for it";
}

void LocalizerServer::WakeWorker() {
  // Under the lock: the worker reads the condition under it, so the wake-up is not lost.
  std::lock_guard<std::mutex> lock(slot_mutex_);
  slot_cv_.notify_one();
}

std::optional<double> LocalizerServer::CameraHeight(const std::string& frame, std::string* source) {
  if (options_.camera_height > 0) {
    *source = "~camera_height";
    return options_.camera_height;
  }
  if (auto it = heights_.find(frame); it != heights_.end()) {
    *source = it->second.second;
    return it->second.first;
  }
  // A robot's mount does not change: the height is kept per camera frame.
  const auto h = LookupCameraHeight(
      tf_buffer_, {options_.base_frame, options_.odom_frame, options_.map_frame}, frame);
  if (h) {
    heights_[frame] = {h->height, h->source};
    *source = h->source;
    return h->height;
  }
  return std::nullopt;
}

void LocalizerServer::ResolveScale(const std::string& frame,
                                   const sensor_msgs::CameraInfoConstPtr& info) {
  if (options_.meters_per_pixel > 0) return;  // explicit
  if (!info) {
    if (scale_known_) return;  // from the loaded map; nothing to check it against
    throw std::invalid_argument(
        "the scale is unknown: ~meters_per_pixel is 0 (take it from the camera) and no "
        "sensor_msgs/CameraInfo has arrived on " +
        info_topic_);
  }
  std::string height_source;
  const std::optional<double> height = CameraHeight(frame, &height_source);
  if (!height) {
    if (scale_known_) {
      if (!warned_unchecked_scale_) {
        ROS_WARN(
            "ground_texture_bow: the camera's scale cannot be checked against the map's "
            "(no camera height: set ~camera_height, or publish TF %s -> %s)",
            options_.base_frame.c_str(), frame.c_str());
        warned_unchecked_scale_ = true;
      }
      return;
    }
    throw std::invalid_argument(
        "the scale is unknown: no camera height (set ~camera_height, or "
        "publish TF from " +
        (options_.base_frame.empty() ? options_.map_frame : options_.base_frame) + " to " + frame +
        ")");
  }
  const double s = MetersPerPixelFromCameraInfo(*info, *height);
  auto describe = [&] {
    char buf[256];
    std::snprintf(buf, sizeof(buf), "%.6g m/px (camera_info fx %.2f px, height %.4f m from %s)", s,
                  info->K[0], *height, height_source.c_str());
    return std::string(buf);
  };
  if (localizer_->size() == 0 && !scale_from_map_) {
    // An empty map takes the camera's scale (SetMetersPerPixel refuses once keyframes exist).
    const double before = localizer_->meters_per_pixel();
    localizer_->SetMetersPerPixel(s);
    const bool first = !scale_known_.exchange(true);
    std::lock_guard<std::mutex> lock(state_mutex_);
    scale_source_ = "camera_info: " + describe();
    if (first || before != s) ROS_INFO("ground_texture_bow: scale %s", scale_source_.c_str());
    return;
  }
  const double current = localizer_->meters_per_pixel();
  if (std::abs(s - current) > options_.scale_tolerance * current) {
    char buf[160];
    std::snprintf(buf, sizeof(buf),
                  " differs from the map's %.6g m/px by %.1f%% (more than "
                  "~scale_tolerance %.1f%%)",
                  current, 100.0 * std::abs(s / current - 1.0), 100.0 * options_.scale_tolerance);
    throw std::invalid_argument("the camera's scale " + describe() + buf);
  }
}

void LocalizerServer::RequireScale() const {
  if (!scale_known_) {
    throw PreconditionFailed(
        "the scale is not known yet: ~meters_per_pixel is 0 and no image with camera_info (" +
        info_topic_ + ") and a camera height has arrived; set ~meters_per_pixel or load a map");
  }
}

std::optional<gtbow::Pose2D> LocalizerServer::LookupOdometry(const std_msgs::Header& header) {
  if (!options_.publish_tf && !options_.gate.enabled) return std::nullopt;
  if (!tf_buffer_._frameExists(options_.odom_frame)) {
    // No odometry at all: the gate has nothing to check against. map -> odom needs it.
    if (options_.publish_tf) {
      missing_tf_++;
      ROS_WARN_THROTTLE(2.0, "ground_texture_bow: publish_tf is on but frame %s does not exist",
                        options_.odom_frame.c_str());
    }
    return std::nullopt;
  }
  return LookupFootprint(header.frame_id, header.stamp, options_.odom_frame, true);
}

void LocalizerServer::SendMapToOdom() {
  if (!options_.publish_tf) return;
  std::optional<gtbow::Pose2D> c;
  const ros::Time stamp = ros::Time::now() + ros::Duration(options_.transform_tolerance);
  {
    std::lock_guard<std::mutex> lock(gate_mutex_);
    c = gate_.correction();
    // Once per stamp: a fix and the timer in the same instant of (simulated) time would send
    // the same stamp twice, which tf2 rejects with a TF_REPEATED_DATA warning each time.
    if (!c || stamp == last_tf_stamp_) return;  // (a clock that jumps back still publishes)
    last_tf_stamp_ = stamp;
  }
  geometry_msgs::TransformStamped t;
  t.header.stamp = stamp;
  t.header.frame_id = options_.map_frame;
  t.child_frame_id = options_.odom_frame;
  t.transform.translation.x = c->x;
  t.transform.translation.y = c->y;
  t.transform.rotation = QuaternionFromYaw(c->theta);
  tf_broadcaster_.sendTransform(t);
}

void LocalizerServer::InitialPoseCallback(
    const geometry_msgs::PoseWithCovarianceStampedConstPtr& msg) {
  try {
    std::string frame = msg->header.frame_id;
    if (!frame.empty() && frame[0] == '/') frame = frame.substr(1);
    if (frame != options_.map_frame) {
      throw std::invalid_argument("initialpose is in frame '" + msg->header.frame_id +
                                  "', not in " + options_.map_frame);
    }
    const auto& p = msg->pose.pose;
    const gtbow::Pose2D map_from_base{
        p.position.x, p.position.y,
        YawOf(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)};
    if (!std::isfinite(map_from_base.x) || !std::isfinite(map_from_base.y) ||
        !std::isfinite(map_from_base.theta)) {
      throw std::invalid_argument("initialpose has a non-finite value");
    }
    std::string camera;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      camera = options_.camera_frame.empty() ? camera_frame_ : options_.camera_frame;
    }
    if (camera.empty()) {
      throw std::invalid_argument("initialpose before any image: the camera frame is unknown");
    }
    gtbow::Pose2D base_from_camera{0, 0, 0};
    if (!options_.base_frame.empty()) {
      const auto b = LookupFootprint(camera, ros::Time(0), options_.base_frame, true);
      if (!b)
        throw std::invalid_argument("initialpose: no transform " + options_.base_frame + " -> " +
                                    camera);
      base_from_camera = *b;
    }
    const auto odom = LookupFootprint(camera, ros::Time(0), options_.odom_frame, true);
    if (!odom) {
      throw std::invalid_argument("initialpose: no odometry (" + options_.odom_frame + " -> " +
                                  camera + ")");
    }
    const gtbow::Pose2D map_from_camera = gtbow::Compose(map_from_base, base_from_camera);
    {
      std::lock_guard<std::mutex> lock(gate_mutex_);
      gate_.SetCorrection(gtbow::Compose(map_from_camera, gtbow::Inverse(*odom)), *odom);
    }
    ROS_INFO("ground_texture_bow: initial pose (%.3f, %.3f, %.1f deg) set", map_from_base.x,
             map_from_base.y, map_from_base.theta * 180.0 / M_PI);
    SendMapToOdom();
  } catch (const std::exception& e) {
    Reject(e.what(), false);
  }
}

void LocalizerServer::CompressedCallback(const sensor_msgs::CompressedImageConstPtr& msg) {
  Pending p;
  p.compressed = msg;
  Enqueue(std::move(p));
}

void LocalizerServer::Enqueue(Pending p) {
  received_++;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    const ros::Time now = ros::Time::now();
    if (!last_image_time_.isZero()) {
      const double dt = (now - last_image_time_).toSec();
      if (dt > 0) input_rate_hz_ = 0.8 * input_rate_hz_.load() + 0.2 / dt;
    }
    last_image_time_ = now;
    if (WaitsForCameraInfo()) {
      last_error_ = WaitingForCameraInfo();
      ROS_WARN_THROTTLE(5.0, "ground_texture_bow: %s", last_error_.c_str());
    }
  }
  // Notified under the lock: once the destructor holds the lock, no callback is still between
  // the hand-over and the notification (ThreadSanitizer found one signalling the condition
  // variable as an unloading nodelet destroyed it).
  std::lock_guard<std::mutex> lock(slot_mutex_);
  if (stop_) return;
  if (pending_) dropped_++;  // the waiting image is replaced by the newer one
  pending_ = std::move(p);
  slot_cv_.notify_one();
}

void LocalizerServer::WorkerLoop() {
  while (true) {
    Pending msg;
    {
      std::unique_lock<std::mutex> lock(slot_mutex_);
      while (!slot_cv_.wait_for(lock, std::chrono::milliseconds(100), [this] {
        return stop_ || (static_cast<bool>(pending_) && !WaitsForCameraInfo());
      })) {
        // ROS shuts down (Ctrl-C, the nodelet manager's end): a paced save under way (a
        // ~save_map call or an autosave, which the shutdown waits for) finishes unpaced. The
        // destructor does the same, but a nodelet's runs only after its callbacks have ended.
        if (!ros::ok()) StopPacingSaves();
      }
      if (stop_) return;
      msg = std::move(pending_);
      pending_ = Pending();
    }
    try {
      ProcessImage(msg);
    } catch (const std::exception& e) {  // never let an image take the manager down
      Reject(
          std::string("image at ") + std::to_string(msg.header().stamp.toSec()) + ": " + e.what(),
          true);
    }
  }
}

std::optional<gtbow::Pose2D> LocalizerServer::LookupFootprint(const std::string& frame,
                                                              const ros::Time& stamp,
                                                              const std::string& target,
                                                              bool warn) {
  geometry_msgs::TransformStamped t;
  try {
    t = tf_buffer_.lookupTransform(target, frame, stamp, ros::Duration(options_.tf_timeout));
  } catch (const tf2::TransformException& e) {
    if (warn) {
      missing_tf_++;
      ROS_WARN_THROTTLE(2.0, "ground_texture_bow: no transform %s -> %s at %.3f: %s",
                        target.c_str(), frame.c_str(), stamp.toSec(), e.what());
    }
    return std::nullopt;
  }
  try {
    return FootprintFromTransform(t.transform);
  } catch (const std::invalid_argument& e) {
    // The transform exists but cannot be used (a camera not looking down, a broken
    // quaternion): a configuration error, told apart from a missing transform.
    if (warn) {
      unusable_tf_++;
      {
        std::lock_guard<std::mutex> lock(state_mutex_);
        last_error_ = "transform " + target + " -> " + frame + ": " + e.what();
      }
      ROS_WARN_THROTTLE(2.0, "ground_texture_bow: unusable transform %s -> %s: %s", target.c_str(),
                        frame.c_str(), e.what());
    }
    return std::nullopt;
  }
}

std::optional<gtbow::Pose2D> LocalizerServer::BackendPose(const gtbow::Pose2D& odom) {
  if (!tf_buffer_._frameExists(options_.map_frame)) {
    // A session on an earlier map: the backend places the map frame once the images match it.
    ROS_INFO_THROTTLE(2.0,
                      "ground_texture_bow: waiting for the backend's %s -> %s (a session on an "
                      "earlier map is placed by its first fixes)",
                      options_.map_frame.c_str(), options_.odom_frame.c_str());
    return std::nullopt;
  }
  geometry_msgs::TransformStamped t;
  try {
    t = tf_buffer_.lookupTransform(options_.map_frame, options_.odom_frame, ros::Time(0),
                                   ros::Duration(options_.tf_timeout));
  } catch (const tf2::TransformException& e) {
    missing_tf_++;
    ROS_WARN_THROTTLE(2.0,
                      "ground_texture_bow: no %s -> %s from the SLAM backend yet (the keyframe "
                      "gets its pose from the backend's keyframe_poses): %s",
                      options_.map_frame.c_str(), options_.odom_frame.c_str(), e.what());
    return std::nullopt;
  }
  const auto& q = t.transform.rotation;
  const gtbow::Pose2D map_from_odom{t.transform.translation.x, t.transform.translation.y,
                                    YawOf(q.x, q.y, q.z, q.w)};
  return gtbow::Compose(map_from_odom, odom);
}

void LocalizerServer::CheckMapFrame(const std::string& path) const {
  const gtbow::MapFileInfo info = gtbow::Localizer::ReadMapInfo(path);
  if (!info.pose_frame.empty() && info.pose_frame != options_.map_frame) {
    throw std::runtime_error(path + ": the map's keyframe poses are in frame '" + info.pose_frame +
                             "' (" + (info.poses_optimised ? "optimised" : "not optimised") +
                             "), this node's ~map_frame is '" + options_.map_frame +
                             "': its fixes would be published in the wrong frame");
  }
}

void LocalizerServer::KeyframePosesCallback(const ground_texture_bow::KeyframePosesConstPtr& msg) {
  const std::string frame = localizer_->pose_frame();
  if (msg->header.frame_id != frame || msg->ids.size() != msg->stamps.size() ||
      msg->ids.size() != msg->poses.size()) {
    pose_updates_refused_++;
    ROS_WARN_THROTTLE(5.0,
                      "ground_texture_bow: keyframe_poses ignored: %zu ids, %zu stamps and %zu "
                      "poses in frame '%s'; the map's poses are in '%s'",
                      msg->ids.size(), msg->stamps.size(), msg->poses.size(),
                      msg->header.frame_id.c_str(), frame.c_str());
    return;
  }
  std::vector<gtbow::KeyframePose> poses;
  poses.reserve(msg->ids.size());
  try {
    for (size_t i = 0; i < msg->ids.size(); ++i) {
      poses.push_back({msg->ids[i], ToNanoseconds(msg->stamps[i]), FromPose2DMsg(msg->poses[i])});
    }
    keyframes_reposed_ += localizer_->UpdateKeyframePoses(poses);
    maintainer_stale_ = true;  // maintenance places by the new poses
    keyframe_poses_stamp_ns_ = msg->header.stamp.toNSec();
  } catch (const std::exception& e) {
    pose_updates_refused_++;
    ROS_WARN_THROTTLE(5.0, "ground_texture_bow: keyframe_poses ignored: %s", e.what());
  }
}

void LocalizerServer::Maintain(const gtbow::Localization& fix, const cv::Mat& floor_image,
                               const std_msgs::Header& header) {
  const gtbow::ImageGeometry g{floor_image.cols, floor_image.rows, localizer_->meters_per_pixel()};
  if (!maintainer_ || maintainer_stale_.exchange(false) || g.width != maintainer_geometry_.width ||
      g.height != maintainer_geometry_.height ||
      g.meters_per_pixel != maintainer_geometry_.meters_per_pixel) {
    maintainer_ = std::make_unique<gtbow::MapMaintainer>(options_.maintenance, g);
    maintainer_geometry_ = g;
    gtbow::TrackMap(*localizer_, maintainer_.get());
  }
  const int64_t stamp = ToNanoseconds(header.stamp);
  const gtbow::MaintenanceStep step = maintainer_->Observe(fix, stamp);
  if (!step.add) return;
  // The view is added as a keyframe is extracted (features.num_features), not as it was queried.
  const std::optional<uint32_t> id = gtbow::ApplyMaintenance(
      step, fix, localizer_->Process(floor_image, gtbow::Localizer::ImageUse::kKeyframe), stamp,
      localizer_.get(), maintainer_.get());
  keyframes_retired_ += step.retire.size();
  if (id) {
    views_added_++;
    changes_++;  // autosave
    ROS_DEBUG(
        "ground_texture_bow: maintenance: view added as keyframe %u (%d inliers), %zu retired", *id,
        fix.estimate.inliers, step.retire.size());
  }
}

void LocalizerServer::ProcessImage(const Pending& msg) {
  const auto t0 = std::chrono::steady_clock::now();
  std_msgs::Header header = msg.header();
  if (!options_.camera_frame.empty()) header.frame_id = options_.camera_frame;
  if (header.stamp.isZero()) throw std::invalid_argument("zero stamp");
  if (header.frame_id.empty() && options_.use_tf) {
    throw std::invalid_argument("no frame_id in the image header and ~camera_frame is not set");
  }
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    camera_frame_ = header.frame_id;
  }
  cv::Mat floor_image = msg.raw ? ToFloorImage(*msg.raw) : ToFloorImage(*msg.compressed);
  sensor_msgs::CameraInfoConstPtr info;  // the latest, for the scale and the rectification
  {
    std::lock_guard<std::mutex> lock(camera_mutex_);
    info = camera_info_;
  }
  ResolveScale(header.frame_id, info);
  if (info && HasDistortion(*info)) {
    if (options_.rectify) {
      floor_image = rectifier_.Rectify(floor_image, *info);
      rectified_++;
    } else if (!warned_unrectified_) {
      ROS_WARN(
          "ground_texture_bow: camera_info on %s has distortion but ~rectify is false: "
          "the images are used as they come",
          info_topic_.c_str());
      warned_unrectified_ = true;
    }
  }
  const Mode mode = mode_.load();
  std::optional<gtbow::Pose2D> pose, motion;
  if (options_.use_tf && mode == Mode::kMapping) {
    if (options_.slam_backend) {
      // Odometry at the image's time; map -> odom as the backend last corrected it.
      motion = LookupFootprint(header.frame_id, header.stamp, options_.odom_frame, true);
      if (motion) pose = BackendPose(*motion);
    } else {
      pose = LookupFootprint(header.frame_id, header.stamp, options_.map_frame, true);
    }
  }
  // Localization (and maintenance) only queries (features.query_num_features); mapping adds
  // the image. Single images in localization mode escalate when the preset says so
  // (features.query_escalate; Localizer::LocalizeImage): they are processed there.
  const bool escalating =
      mode == Mode::kLocalization && sequence_.options().length <= 1 && localizer_->escalates();
  gtbow::ProcessedImage img;
  if (!escalating) {
    img = localizer_->Process(floor_image, Localizes(mode) ? gtbow::Localizer::ImageUse::kQuery
                                                           : gtbow::Localizer::ImageUse::kKeyframe);
  }
  std::vector<gtbow::Vec2> inliers;
  std::string caption = "no verified match";
  if (Localizes(mode)) {
    const std::optional<gtbow::Pose2D> odom = LookupOdometry(header);
    // With the images just before it, related by odometry (core/sequence.h), when kept.
    if (sequence_.options().length > 1) sequence_.Push(img, odom);
    gtbow::Localization fix;
    if (escalating) {
      bool escalated = false;
      if (backoff_stale_.exchange(false)) backoff_ = localizer_->NewBackoff();
      const size_t skipped = backoff_.skipped();
      fix = localizer_->LocalizeImage(floor_image, &img, &escalated, &backoff_);
      if (backoff_.skipped() != skipped) {
        first_passes_skipped_++;  // straight to the full pass (the backoff)
      } else if (escalated) {
        escalated_queries_++;
      }
    } else if (sequence_.size() > 1) {
      bool combined = false;
      fix = gtbow::SequenceFix(
          sequence_.options(), [&] { return localizer_->Localize(img); },
          [&] {
            return localizer_->Localize(localizer_->Combine(sequence_.images(), sequence_.poses()));
          },
          &combined);
      if (combined) sequence_queries_++;
    } else {
      fix = localizer_->Localize(img);
    }
    if (fix.success) {
      // The gate (core/odometry_gate.h) decides whether the fix may be published and move
      // map -> odom; without odometry there is nothing to check it against.
      gtbow::GateVerdict verdict = gtbow::GateVerdict::kAccepted;
      double off_m = 0, off_rad = 0;
      if (odom) {
        std::lock_guard<std::mutex> lock(gate_mutex_);
        verdict = gate_.Offer(fix.estimate.floor_from_query, *odom);
        off_m = gate_.last_error_distance();
        off_rad = gate_.last_error_angle();
      }
      char off[96];
      std::snprintf(off, sizeof(off), "%.1f mm, %.2f deg from odometry", 1000 * off_m,
                    off_rad * 180 / M_PI);
      if (verdict == gtbow::GateVerdict::kHeld) {
        held_fixes_++;
        caption = std::string("fix held by the odometry gate: ") + off;
        ROS_WARN_THROTTLE(2.0, "ground_texture_bow: %s", caption.c_str());
      } else {
        if (verdict == gtbow::GateVerdict::kRelocalized) {
          relocalizations_++;
          ROS_WARN("ground_texture_bow: relocalized: %d fixes in a row agreed on a new place (%s)",
                   options_.gate.relocalize_after, off);
        }
        PublishFix(fix, header);
        if (odom) SendMapToOdom();
        inliers = fix.inlier_pixels;
        caption = "fix from keyframe " + std::to_string(fix.image) + ", " +
                  std::to_string(fix.estimate.inliers) + " inliers";
        if (mode == Mode::kMaintenance) Maintain(fix, floor_image, header);
      }
    } else {
      failed_fixes_++;
      if (odom) {
        std::lock_guard<std::mutex> lock(gate_mutex_);
        gate_.Drive(*odom);
      }
      ROS_DEBUG_THROTTLE(2.0, "ground_texture_bow: no fix: %s", fix.reason.c_str());
    }
  } else {
    // Mapping (keyframes added) or external (a backend adds them): the engine decides.
    const gtbow::MapperStep step =
        mapper_->Process(img, ToNanoseconds(header.stamp), pose, mode == Mode::kMapping, motion);
    const uint32_t query_id =
        step.keyframe ? *step.keyframe : ground_texture_bow::CandidateList::NO_ID;
    if (step.keyframe) {
      changes_++;
      ground_texture_bow::KeyframeStamp k;
      k.header = header;
      k.id = *step.keyframe;
      keyframes_pub_.publish(k);
    }
    ground_texture_bow::CandidateList list;
    list.header = header;
    list.query_id = query_id;
    for (const auto& c : step.candidates) list.candidates.push_back(ToCandidateMsg(c));
    candidates_pub_.publish(list);
    if (step.closure >= 0) {
      const gtbow::Candidate& c = step.candidates[static_cast<size_t>(step.closure)];
      inliers = c.inliers;
      caption = "keyframe " + std::to_string(c.id) + ", " + std::to_string(c.relative.inliers) +
                " inliers";
      if (step.publish && step.fix) {
        // A keyframe of a map made before this session: a fix in the map (~pose), which
        // anchors this session there (pose_graph_backend's fixes), not a loop closure.
        gtbow::Localization fix;
        fix.success = true;
        fix.image = c.id;
        fix.score = c.score;
        fix.estimate = *step.fix;
        PublishFix(fix, header);
        caption += " (a fix in the earlier map)";
      } else if (step.publish) {
        PublishLoopClosure(c, query_id, header);
      } else {
        held_closures_++;
        caption += " (held: " + std::to_string(step.run) + " of " +
                   std::to_string(options_.mapper.temporal.required) + " in a row)";
      }
    }
  }
  if (debug_pub_.getNumSubscribers() > 0) {
    PublishDebugImage(floor_image, img, inliers, caption, header);
  }
  processed_++;
  last_processing_ms_ =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

void LocalizerServer::PublishFix(const gtbow::Localization& fix, const std_msgs::Header& header) {
  fixes_++;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    last_fix_time_ = ros::Time::now();
  }
  const auto cov = FlooredCovariance(fix.estimate.covariance, options_.min_position_variance,
                                     options_.min_yaw_variance);
  const gtbow::Pose2D& camera = fix.estimate.floor_from_query;
  const auto camera_msg =
      ToPoseWithCovariance(camera, cov, header.stamp, options_.map_frame, options_.planar_variance);
  camera_pose_pub_.publish(camera_msg);
  if (options_.base_frame.empty()) {
    pose_pub_.publish(camera_msg);
    return;
  }
  // REP-105: ~pose is the robot's base, through the camera's mount.
  const auto base_from_camera =
      LookupFootprint(header.frame_id, header.stamp, options_.base_frame, true);
  if (!base_from_camera) return;
  const BasePose base = BaseFromCamera(camera, cov, *base_from_camera);
  pose_pub_.publish(ToPoseWithCovariance(base.pose, base.covariance, header.stamp,
                                         options_.map_frame, options_.planar_variance));
}

void LocalizerServer::PublishLoopClosure(const gtbow::Candidate& c, uint32_t query_id,
                                         const std_msgs::Header& header) {
  ground_texture_bow::LoopClosure lc;
  lc.header = header;
  lc.query_id = query_id;
  lc.query_stamp = header.stamp;
  lc.match_id = c.id;
  lc.match_stamp = FromNanoseconds(c.stamp_ns);
  lc.score = c.score;
  lc.inliers = static_cast<uint32_t>(c.relative.inliers);
  lc.match_from_query = ToOpticalPose2D(c.relative.floor_from_query);
  const auto cov = ToOpticalCovariance(c.relative.covariance);
  std::copy(cov.begin(), cov.end(), lc.covariance.begin());
  lc.status = ground_texture_bow::LoopClosure::VERIFIED;
  loop_pub_.publish(lc);
  loop_closures_++;
  if (query_id != ground_texture_bow::LoopClosure::NO_ID) {
    std::lock_guard<std::mutex> lock(state_mutex_);
    edges_.push_back({query_id, c.id});
  }
}

void LocalizerServer::Diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  bool localized = false;
  std::string last_error;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    localized = !last_fix_time_.isZero() &&
                (ros::Time::now() - last_fix_time_).toSec() <= options_.localized_timeout;
    last_error = last_error_;
  }
  const Mode mode = mode_.load();
  const ProblemCounts now{rejected_.load(), rejected_requests_.load(), missing_tf_.load(),
                          unusable_tf_.load()};
  ProblemCounts then;  // at the start of the window (zero while the node is younger)
  {
    std::lock_guard<std::mutex> lock(diag_mutex_);
    const ros::WallTime t = ros::WallTime::now();
    diag_history_.emplace_back(t, now);
    const ros::WallTime start = t - ros::WallDuration(options_.diagnostics_window);
    while (diag_history_.size() > 1 && diag_history_[1].first <= start) diag_history_.pop_front();
    if (diag_history_.front().first <= start) then = diag_history_.front().second;
  }
  const uint64_t recent_rejected = now.rejected - then.rejected;
  const uint64_t recent_requests = now.requests - then.requests;
  const uint64_t recent_missing = now.missing_tf - then.missing_tf;
  const uint64_t recent_unusable = now.unusable_tf - then.unusable_tf;
  char window[48];
  std::snprintf(window, sizeof(window), "in the last %.0f s: ", options_.diagnostics_window);
  if (last_autosave_failed_) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR,
                 "autosave to " + options_.autosave_path + " failed: " + last_error);
  } else if (WaitsForCameraInfo() && received_.load() > 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, WaitingForCameraInfo());
  } else if (recent_rejected > 0 || recent_requests > 0 || recent_missing > 0 ||
             recent_unusable > 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                 std::string(window) + "rejected images: " + std::to_string(recent_rejected) +
                     ", rejected requests: " + std::to_string(recent_requests) +
                     ", missing transforms: " + std::to_string(recent_missing) +
                     ", unusable transforms: " + std::to_string(recent_unusable));
  } else if (Localizes(mode) && !localized) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "not localized");
  } else {
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, ModeName(mode));
  }
  stat.add("mode", ModeName(mode));
  stat.add("input rate (Hz)", input_rate_hz_.load());
  stat.add("processing time (ms)", last_processing_ms_.load());
  stat.add("database size", localizer_->live_size());
  stat.add("images received", received_.load());
  stat.add("images processed", processed_.load());
  stat.add("images dropped", dropped_.load());
  stat.add("rejected images", rejected_.load());
  stat.add("rejected requests", rejected_requests_.load());
  stat.add("missing transforms", missing_tf_.load());
  stat.add("unusable transforms (camera not looking down, bad rotation)", unusable_tf_.load());
  stat.add("fixes", fixes_.load());
  stat.add("failed fixes", failed_fixes_.load());
  stat.add("loop closures", loop_closures_.load());
  stat.add("loop closures held (temporal consistency)", held_closures_.load());
  stat.add("fixes held (odometry gate)", held_fixes_.load());
  stat.add("relocalizations", relocalizations_.load());
  stat.add("sequence_queries", sequence_queries_.load());
  stat.add("escalated queries (features.query_escalate)", escalated_queries_.load());
  stat.add("first passes skipped (features.query_escalate_backoff)", first_passes_skipped_.load());
  stat.add("maintenance: views added", views_added_.load());
  stat.add("maintenance: keyframes retired", keyframes_retired_.load());
  stat.add("images rectified", rectified_.load());
  // The debug overlay is drawn only while someone subscribes (it costs a frame's drawing).
  stat.add("debug image subscribers", debug_pub_.getNumSubscribers());
  stat.add("pose frame", localizer_->pose_frame() +
                             (localizer_->poses_optimised() ? " (optimised by a backend)" : ""));
  stat.add("keyframes re-posed (keyframe_poses)", keyframes_reposed_.load());
  stat.add("keyframe_poses refused (frame, malformed)", pose_updates_refused_.load());
  stat.add("autosaves", autosaves_.load());
  stat.add("autosave errors", autosave_errors_.load());
  stat.add("meters per pixel", scale_known_ ? localizer_->meters_per_pixel() : 0.0);
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    stat.add("scale from", scale_known_ ? scale_source_ : "unknown");
  }
  stat.add("localized", localized);
  stat.add("last error", last_error);
}

}  // namespace gtbow_ros
