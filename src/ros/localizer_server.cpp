#include "ground_texture_bow/ros/localizer_server.h"

#include <chrono>
#include <cmath>
#include <stdexcept>

#include <geometry_msgs/TransformStamped.h>
#include <visualization_msgs/MarkerArray.h>

#include "ground_texture_bow/CandidateList.h"
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
      mode_(options.mode) {
  options_.Check();
  std::string vocab_path = options_.vocabulary;
  if (vocab_path.empty()) vocab_path = gtbow::Localizer::VocabularyPathOf(options_.map);
  std::shared_ptr<gtbow::Vocabulary> vocab = gtbow::Vocabulary::Load(vocab_path);
  localizer_ = std::make_unique<gtbow::Localizer>(std::move(vocab), vocab_path, options_.core);
  if (!options_.map.empty()) localizer_->Load(options_.map);
  mapper_ = std::make_unique<gtbow::Mapper>(localizer_.get(), options_.mapper);

  pose_pub_ = pnh_.advertise<geometry_msgs::PoseWithCovarianceStamped>("pose", 10);
  loop_pub_ = pnh_.advertise<ground_texture_bow::LoopClosure>("loop_closures", 50);
  candidates_pub_ = pnh_.advertise<ground_texture_bow::CandidateList>("candidates", 10);
  markers_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("markers", 1, true);
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

  worker_ = std::thread([this] { WorkerLoop(); });
  // The subscription goes last: callbacks may start at once.
  if (options_.transport == "compressed") {
    // Decoded here with OpenCV: Debian ships no compressed image_transport plugin.
    compressed_sub_ = nh_.subscribe(nh_.resolveName("image") + "/compressed", 5,
                                    &LocalizerServer::CompressedCallback, this);
  } else {
    image_sub_ = it_.subscribe("image", 5, &LocalizerServer::ImageCallback, this);
  }
  ROS_INFO("ground_texture_bow: %s mode, %zu keyframes, vocabulary %s (%u words), preset %s",
           ModeName(mode_).c_str(), localizer_->size(), vocab_path.c_str(),
           localizer_->vocabulary().size(), options_.preset.c_str());
}

LocalizerServer::~LocalizerServer() {
  image_sub_.shutdown();
  compressed_sub_.shutdown();
  {
    std::lock_guard<std::mutex> lock(slot_mutex_);
    stop_ = true;
  }
  slot_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
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
      slot_cv_.wait(lock, [this] { return stop_ || static_cast<bool>(pending_); });
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
  try {
    const auto t =
        tf_buffer_.lookupTransform(target, frame, stamp, ros::Duration(options_.tf_timeout));
    return FootprintFromTransform(t.transform);
  } catch (const std::exception& e) {
    if (warn) {
      missing_tf_++;
      ROS_WARN_THROTTLE(2.0, "ground_texture_bow: no usable transform %s -> %s at %.3f: %s",
                        target.c_str(), frame.c_str(), stamp.toSec(), e.what());
    }
    return std::nullopt;
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
  const cv::Mat floor_image = msg.raw ? ToFloorImage(*msg.raw) : ToFloorImage(*msg.compressed);
  const Mode mode = mode_.load();
  std::optional<gtbow::Pose2D> pose;
  if (options_.use_tf && mode == Mode::kMapping) {
    pose = LookupFootprint(header.frame_id, header.stamp, options_.map_frame, true);
  }
  const gtbow::ProcessedImage img = localizer_->Process(floor_image);
  std::vector<gtbow::Vec2> inliers;
  std::string caption = "no verified match";
  if (mode == Mode::kLocalization) {
    const gtbow::Localization fix = localizer_->Localize(img);
    if (fix.success) {
      PublishFix(fix, header);
      inliers = fix.inlier_pixels;
      caption = "fix from keyframe " + std::to_string(fix.image) + ", " +
                std::to_string(fix.estimate.inliers) + " inliers";
    } else {
      failed_fixes_++;
      ROS_DEBUG_THROTTLE(2.0, "ground_texture_bow: no fix: %s", fix.reason.c_str());
    }
  } else {
    // Mapping (keyframes added) or external (a backend adds them): the engine decides.
    const gtbow::MapperStep step =
        mapper_->Process(img, ToNanoseconds(header.stamp), pose, mode == Mode::kMapping);
    const uint32_t query_id =
        step.keyframe ? *step.keyframe : ground_texture_bow::CandidateList::NO_ID;
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
      if (step.publish) {
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
  pose_pub_.publish(ToPoseWithCovariance(fix.estimate.floor_from_query, fix.estimate.covariance,
                                         header.stamp, options_.map_frame,
                                         options_.planar_variance));
  if (!options_.publish_tf) return;
  // map -> odom such that map -> odom -> camera gives the fix (planar).
  const auto odom = LookupFootprint(header.frame_id, header.stamp, options_.odom_frame, true);
  if (!odom) return;
  const gtbow::Pose2D map_from_odom =
      gtbow::Compose(fix.estimate.floor_from_query, gtbow::Inverse(*odom));
  geometry_msgs::TransformStamped t;
  t.header.stamp = header.stamp;
  t.header.frame_id = options_.map_frame;
  t.child_frame_id = options_.odom_frame;
  t.transform.translation.x = map_from_odom.x;
  t.transform.translation.y = map_from_odom.y;
  t.transform.rotation = QuaternionFromYaw(map_from_odom.theta);
  tf_broadcaster_.sendTransform(t);
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
  if (rejected_ > 0 || rejected_requests_ > 0 || missing_tf_ > 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                 "rejected images: " + std::to_string(rejected_.load()) +
                     ", rejected requests: " + std::to_string(rejected_requests_.load()) +
                     ", missing transforms: " + std::to_string(missing_tf_.load()));
  } else if (mode == Mode::kLocalization && !localized) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "not localized");
  } else {
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, ModeName(mode));
  }
  stat.add("mode", ModeName(mode));
  stat.add("input rate (Hz)", input_rate_hz_.load());
  stat.add("processing time (ms)", last_processing_ms_.load());
  stat.add("database size", localizer_->size());
  stat.add("images received", received_.load());
  stat.add("images processed", processed_.load());
  stat.add("images dropped", dropped_.load());
  stat.add("rejected images", rejected_.load());
  stat.add("rejected requests", rejected_requests_.load());
  stat.add("missing transforms", missing_tf_.load());
  stat.add("fixes", fixes_.load());
  stat.add("failed fixes", failed_fixes_.load());
  stat.add("loop closures", loop_closures_.load());
  stat.add("loop closures held (temporal consistency)", held_closures_.load());
  stat.add("localized", localized);
  stat.add("last error", last_error);
}

}  // namespace gtbow_ros
