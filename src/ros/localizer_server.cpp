#include "ground_texture_bow/ros/localizer_server.h"

#include <chrono>
#include <cmath>
#include <stdexcept>

#include <cv_bridge/cv_bridge.h>
#include <geometry_msgs/TransformStamped.h>
#include <visualization_msgs/MarkerArray.h>
#include <opencv2/imgproc.hpp>

#include "ground_texture_bow/CandidateList.h"
#include "ground_texture_bow/LoopClosure.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/enum_names.h"
#include "ground_texture_bow/ros/conversions.h"

namespace gtbow_ros {

using ground_texture_bow::Status;

namespace {
constexpr gtbow::EnumName<Mode> kModes[] = {{"mapping", Mode::kMapping},
                                            {"localization", Mode::kLocalization},
                                            {"external", Mode::kExternal}};
}  // namespace

Mode ParseMode(const std::string& name) { return gtbow::ParseEnumName(name, "mode", kModes); }
std::string ModeName(Mode mode) { return gtbow::EnumValueName(mode, kModes); }

gtbow::LocalizerOptions ServerOptions::DefaultCore() {
  gtbow::LocalizerOptions core;
  core.threads = 2;
  core.meters_per_pixel = 0.00025;
  return core;
}

std::string DefaultPreset() { return GTBOW_CONFIG_DIR "/high_accuracy.yaml"; }

void ServerOptions::Check() const {
  auto need = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument("parameter " + what);
  };
  need(!vocabulary.empty() || !map.empty(), "~vocabulary (or ~map) must be set");
  need(!map_frame.empty(), "~map_frame must not be empty");
  need(transport == "raw" || transport == "compressed", "~transport must be raw or compressed");
  need(tf_timeout >= 0, "~tf_timeout must be >= 0");
  need(keyframe_min_distance >= 0, "~keyframe_min_distance must be >= 0");
  need(keyframe_min_angle >= 0, "~keyframe_min_angle must be >= 0");
  need(keyframe_every_n >= 1, "~keyframe_every_n must be >= 1");
  need(exclude_recent >= 0, "~exclude_recent must be >= 0");
  need(localized_timeout > 0, "~localized_timeout must be > 0");
  need(planar_variance > 0, "~planar_variance must be > 0");
  try {
    temporal.Check();
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("parameter ~temporal_*: ") + e.what());
  }
  try {
    core.Check();
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("parameter (~threads, ~meters_per_pixel, ~candidates, "
                                            "~min_inliers or the preset): ") +
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
  pnh.param("camera_frame", o.camera_frame, o.camera_frame);
  pnh.param("transport", o.transport, o.transport);
  pnh.param("meters_per_pixel", o.core.meters_per_pixel, o.core.meters_per_pixel);
  pnh.param("threads", o.core.threads, o.core.threads);
  pnh.param("keep_descriptors", o.core.keep_descriptors, o.core.keep_descriptors);
  pnh.param("use_tf", o.use_tf, o.use_tf);
  pnh.param("tf_timeout", o.tf_timeout, o.tf_timeout);
  pnh.param("keyframe_min_distance", o.keyframe_min_distance, o.keyframe_min_distance);
  pnh.param("keyframe_min_angle", o.keyframe_min_angle, o.keyframe_min_angle);
  pnh.param("keyframe_every_n", o.keyframe_every_n, o.keyframe_every_n);
  // K and the inliers a pose needs: the preset's unless set (> 0).
  int candidates = 0, min_inliers = 0;
  pnh.param("candidates", candidates, candidates);
  pnh.param("min_inliers", min_inliers, min_inliers);
  pnh.param("exclude_recent", o.exclude_recent, o.exclude_recent);
  pnh.param("temporal_consistency", o.temporal.required, o.temporal.required);
  pnh.param("temporal_distance", o.temporal.distance, o.temporal.distance);
  pnh.param("temporal_angle", o.temporal.angle, o.temporal.angle);
  pnh.param("temporal_max_motion", o.temporal.max_motion, o.temporal.max_motion);
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
  temporal_ = gtbow::TemporalConsistency(options_.temporal);
  std::string vocab_path = options_.vocabulary;
  if (vocab_path.empty()) vocab_path = gtbow::Localizer::VocabularyPathOf(options_.map);
  std::shared_ptr<gtbow::Vocabulary> vocab = gtbow::Vocabulary::Load(vocab_path);
  localizer_ = std::make_unique<gtbow::Localizer>(std::move(vocab), vocab_path, options_.core);
  if (!options_.map.empty()) localizer_->Load(options_.map);

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

bool LocalizerServer::IsKeyframe(const std::optional<gtbow::Pose2D>& pose) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  ++frames_since_keyframe_;
  bool take;
  if (localizer_->size() == 0) {
    take = true;
  } else if (pose && last_keyframe_pose_) {
    const double d = std::hypot(pose->x - last_keyframe_pose_->x, pose->y - last_keyframe_pose_->y);
    const double a = std::abs(std::remainder(pose->theta - last_keyframe_pose_->theta, 2 * M_PI));
    take = d >= options_.keyframe_min_distance || a >= options_.keyframe_min_angle;
  } else {
    take = frames_since_keyframe_ >= static_cast<uint64_t>(options_.keyframe_every_n);
  }
  if (take) {
    frames_since_keyframe_ = 0;
    if (pose) last_keyframe_pose_ = pose;
  }
  return take;
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
    const uint32_t n = static_cast<uint32_t>(localizer_->size());
    // In mapping mode the newest keyframes are the robot's own recent past; in external mode
    // the backend inserts keyframes and filters candidates itself.
    const uint32_t recent =
        mode == Mode::kMapping ? static_cast<uint32_t>(options_.exclude_recent) : 0;
    const auto cands =
        localizer_->Query(img, static_cast<size_t>(options_.core.retrieval.verification.candidates),
                          true, n > recent ? n - recent : 0, n);
    uint32_t query_id = ground_texture_bow::CandidateList::NO_ID;
    if (mode == Mode::kMapping && IsKeyframe(pose)) {
      query_id = localizer_->Add(img, ToNanoseconds(header.stamp), pose);
    }
    ground_texture_bow::CandidateList list;
    list.header = header;
    list.query_id = query_id;
    for (const auto& c : cands) list.candidates.push_back(ToCandidateMsg(c));
    candidates_pub_.publish(list);
    // The loop closure, once ~temporal_consistency images in a row agree on the place: among
    // the verified candidates (the preset's choice first, then by inliers), the one that
    // continues the run.
    std::vector<size_t> order;
    const int preferred = gtbow::LoopClosureCandidate(cands, options_.core.retrieval.verification);
    if (preferred >= 0) order.push_back(static_cast<size_t>(preferred));
    std::vector<size_t> others;
    for (size_t i = 0; i < cands.size(); ++i) {
      if (cands[i].verified && static_cast<int>(i) != preferred) others.push_back(i);
    }
    std::stable_sort(others.begin(), others.end(), [&](size_t a, size_t b) {
      return cands[a].relative.inliers > cands[b].relative.inliers;
    });
    order.insert(order.end(), others.begin(), others.end());
    std::vector<gtbow::ClosureObservation> observed;
    for (size_t i : order) {
      const gtbow::Candidate& c = cands[i];
      observed.push_back(
          {c.id, c.has_pose ? std::optional<gtbow::Pose2D>(c.map_from_camera) : std::nullopt,
           c.relative.floor_from_query, pose});
    }
    std::optional<gtbow::ClosureObservation> seen;
    int chosen = -1;
    if (!observed.empty()) {
      const size_t pick = options_.temporal.required > 1 ? temporal_.Pick(observed) : 0;
      seen = observed[pick];
      chosen = static_cast<int>(order[pick]);
      const gtbow::Candidate& c = cands[static_cast<size_t>(chosen)];
      inliers = c.inliers;
      caption = "keyframe " + std::to_string(c.id) + ", " + std::to_string(c.relative.inliers) +
                " inliers";
    }
    if (temporal_.Next(seen)) {
      PublishLoopClosure(cands[static_cast<size_t>(chosen)], query_id, header);
    } else if (seen) {
      held_closures_++;
      caption += " (held: " + std::to_string(temporal_.run()) + " of " +
                 std::to_string(options_.temporal.required) + " in a row)";
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

void LocalizerServer::PublishDebugImage(const cv::Mat& floor_image,
                                        const gtbow::ProcessedImage& img,
                                        const std::vector<gtbow::Vec2>& inliers,
                                        const std::string& caption,
                                        const std_msgs::Header& header) {
  cv::Mat color;
  cv::Mat camera_view;
  cv::flip(floor_image, camera_view, 0);  // back to the camera's view
  cv::cvtColor(camera_view, color, cv::COLOR_GRAY2BGR);
  const float last_row = static_cast<float>(floor_image.rows - 1);
  for (const auto& k : img.features.keypoints) {
    cv::circle(color, cv::Point2f(k.x, last_row - k.y), std::max(2.0f, 0.5f * k.size),
               cv::Scalar(0, 200, 0), 1, cv::LINE_AA);
  }
  for (const auto& p : inliers) {
    cv::circle(color, cv::Point2f(static_cast<float>(p.x), last_row - static_cast<float>(p.y)), 4,
               cv::Scalar(0, 0, 255), 2, cv::LINE_AA);
  }
  cv::putText(color, caption, cv::Point(8, 24), cv::FONT_HERSHEY_SIMPLEX, 0.7,
              cv::Scalar(0, 255, 255), 2, cv::LINE_AA);
  debug_pub_.publish(cv_bridge::CvImage(header, "bgr8", color).toImageMsg());
  debug_images_++;
}

void LocalizerServer::PublishMarkers(const ros::TimerEvent&) {
  if (markers_pub_.getNumSubscribers() == 0) return;
  visualization_msgs::MarkerArray arr;
  visualization_msgs::Marker fp, edges;
  fp.header.frame_id = edges.header.frame_id = options_.map_frame;
  fp.header.stamp = edges.header.stamp = ros::Time::now();
  fp.ns = "keyframes";
  edges.ns = "loop_closures";
  fp.type = edges.type = visualization_msgs::Marker::LINE_LIST;
  fp.action = edges.action = visualization_msgs::Marker::ADD;
  fp.pose.orientation.w = edges.pose.orientation.w = 1.0;
  fp.scale.x = 0.002;
  edges.scale.x = 0.004;
  fp.color.g = 0.8f;
  fp.color.a = 0.6f;
  edges.color.r = 1.0f;
  edges.color.a = 0.9f;
  const auto kfs = localizer_->Keyframes();
  for (const auto& k : kfs) {
    if (!k.has_pose) continue;
    const auto corners =
        gtbow::Footprint(k.map_from_camera, {k.width, k.height, options_.core.meters_per_pixel});
    for (int i = 0; i < 4; ++i) {
      geometry_msgs::Point a, b;
      a.x = corners[i].x;
      a.y = corners[i].y;
      b.x = corners[(i + 1) % 4].x;
      b.y = corners[(i + 1) % 4].y;
      fp.points.push_back(a);
      fp.points.push_back(b);
    }
  }
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    for (const Edge& e : edges_) {
      if (e.from >= kfs.size() || e.to >= kfs.size()) continue;
      if (!kfs[e.from].has_pose || !kfs[e.to].has_pose) continue;
      geometry_msgs::Point a, b;
      a.x = kfs[e.from].map_from_camera.x;
      a.y = kfs[e.from].map_from_camera.y;
      b.x = kfs[e.to].map_from_camera.x;
      b.y = kfs[e.to].map_from_camera.y;
      edges.points.push_back(a);
      edges.points.push_back(b);
    }
  }
  if (fp.points.empty()) fp.action = visualization_msgs::Marker::DELETE;
  if (edges.points.empty()) edges.action = visualization_msgs::Marker::DELETE;
  arr.markers.push_back(fp);
  arr.markers.push_back(edges);
  markers_pub_.publish(arr);
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
