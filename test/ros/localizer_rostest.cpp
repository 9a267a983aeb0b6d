// rostest client for the localizer node(s) started by test/ros/*.test. It replays the bags that
// test/ros/make_test_data.sh generated (images and ground-truth TF of a small synthetic floor)
// and checks what comes out against the ground truth. Each .test runs one test suite:
//   mapping.test       Mapping.*     revisits are answered with the right keyframes
//   localization.test  SaveLoad.*    a saved map loads into a fresh node, which answers the same
//                                    and localizes a later-day run within 4.8 mm and 1.5 deg
//   bad_input.test     BadInput.*    bad input is counted and reported; nothing is lost
//   services.test      Services.*    external mode, compressed images, the map services
//   soak.test          Soak.*        `make soak` only: 10 minutes of 4x replay, concurrent calls
#include <signal.h>
#include <sys/resource.h>

#include <algorithm>
#include <atomic>
#include <random>
#include <thread>
#include <iterator>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include <diagnostic_msgs/DiagnosticArray.h>
#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <gtest/gtest.h>
#include <nodelet/NodeletLoad.h>
#include <nodelet/NodeletUnload.h>
#include <ros/network.h>
#include <xmlrpcpp/XmlRpcClient.h>
#include <ros/ros.h>
#include <ros/topic.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>
#include <visualization_msgs/MarkerArray.h>

#include "ground_texture_bow/GetInfo.h"
#include "ground_texture_bow/LoadMap.h"
#include "ground_texture_bow/LoopClosure.h"
#include "ground_texture_bow/QueryCandidates.h"
#include "ground_texture_bow/AddKeyframe.h"
#include "ground_texture_bow/CandidateList.h"
#include "ground_texture_bow/Localize.h"
#include "ground_texture_bow/Reset.h"
#include "ground_texture_bow/SetMode.h"
#include <cv_bridge/cv_bridge.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sensor_msgs/CompressedImage.h>
#include "ground_texture_bow/SaveMap.h"
#include "ground_texture_bow/Status.h"
#include "ground_texture_bow/core/geometry.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/ros/conversions.h"

namespace fs = std::filesystem;
using ground_texture_bow::Status;

namespace {

std::string g_data;  // the test data directory (~data parameter)
const gtbow::ImageGeometry kGeometry{640, 480, 0.00025};

struct Frame {
  sensor_msgs::ImageConstPtr image;
  tf2_msgs::TFMessageConstPtr tf;  // may be null (bag without TF)
  gtbow::Pose2D truth;
};

std::vector<Frame> ReadBag(const std::string& path) {
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  std::map<ros::Time, Frame> by_stamp;
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    if (auto img = m.instantiate<sensor_msgs::Image>()) {
      by_stamp[img->header.stamp].image = img;
    } else if (auto tf = m.instantiate<tf2_msgs::TFMessage>()) {
      by_stamp[tf->transforms.at(0).header.stamp].tf = tf;
    } else if (auto p = m.instantiate<geometry_msgs::PoseStamped>()) {
      const auto& q = p->pose.orientation;
      by_stamp[p->header.stamp].truth = {p->pose.position.x, p->pose.position.y,
                                         gtbow_ros::YawOf(q.x, q.y, q.z, q.w)};
    }
  }
  std::vector<Frame> out;
  for (auto& [stamp, f] : by_stamp) out.push_back(f);
  return out;
}

// Keeps every message received on a topic; the spinner thread appends, tests read copies.
template <typename M>
class Collector {
 public:
  explicit Collector(const std::string& topic, uint32_t queue = 100) {
    sub_ = ros::NodeHandle().subscribe<M>(topic, queue, [this](const boost::shared_ptr<const M>& msg) {
      std::lock_guard<std::mutex> lock(mutex_);
      messages_.push_back(*msg);
    });
  }
  std::vector<M> Get() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return messages_;
  }
  void Stop() { sub_.shutdown(); }

 private:
  mutable std::mutex mutex_;
  std::vector<M> messages_;
  ros::Subscriber sub_;
};

template <typename Srv>
Srv Call(const std::string& name, Srv srv = Srv()) {
  EXPECT_TRUE(ros::service::waitForService(name, ros::Duration(30))) << name;
  EXPECT_TRUE(ros::service::call(name, srv)) << name;
  return srv;
}

ground_texture_bow::GetInfo::Response Info(const std::string& node) {
  return Call<ground_texture_bow::GetInfo>(node + "/get_info").response;
}

// Publishes each frame's TF and image at `rate` Hz at most: each image only once the node has
// dealt with the previous one (so that a slow machine or a sanitizer build drops nothing), then
// waits until the node has dealt with every image it received.
void Replay(const std::vector<Frame>& frames, const std::string& topic, const std::string& node,
            double rate) {
  ros::NodeHandle nh;
  ros::Publisher img_pub = nh.advertise<sensor_msgs::Image>(topic, 10);
  ros::Publisher tf_pub = nh.advertise<tf2_msgs::TFMessage>("/tf", 100);
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(20);
  while (img_pub.getNumSubscribers() == 0 && ros::WallTime::now() < deadline) ros::WallDuration(0.05).sleep();
  ASSERT_GT(img_pub.getNumSubscribers(), 0u) << "nobody subscribes to " << topic;
  ros::WallDuration(0.5).sleep();
  const uint64_t before = Info(node).images_received;
  for (size_t i = 0; i < frames.size(); ++i) {
    const Frame& f = frames[i];
    if (f.tf) tf_pub.publish(f.tf);
    ros::WallDuration(0.01).sleep();  // the transform arrives before the image
    img_pub.publish(f.image);
    ros::WallDuration(1.0 / rate).sleep();
    const ros::WallTime limit = ros::WallTime::now() + ros::WallDuration(10);
    while (ros::WallTime::now() < limit) {
      const auto info = Info(node);
      if (info.images_received >= before + i + 1 &&
          info.images_processed + info.images_dropped + info.images_rejected >= info.images_received) {
        break;
      }
      ros::WallDuration(0.02).sleep();
    }
  }
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(30);
  while (ros::WallTime::now() < end) {
    const auto info = Info(node);
    if (info.images_received >= before + frames.size() &&
        info.images_processed + info.images_dropped + info.images_rejected >= info.images_received) {
      return;
    }
    ros::WallDuration(0.1).sleep();
  }
  ADD_FAILURE() << node << " did not finish processing the replay";
}

// The process id of a ROS node (the slave API's getPid), or -1.
pid_t PidOf(const std::string& node) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  args[1] = node;
  if (!ros::master::execute("lookupNode", args, result, payload, true)) return -1;
  std::string host;
  uint32_t port = 0;
  if (!ros::network::splitURI(static_cast<std::string>(payload), host, port)) return -1;
  XmlRpc::XmlRpcClient client(host.c_str(), static_cast<int>(port), "/");
  XmlRpc::XmlRpcValue call, reply;
  call[0] = ros::this_node::getName();
  if (!client.execute("getPid", call, reply) || reply.getType() != XmlRpc::XmlRpcValue::TypeArray ||
      reply.size() < 3) {
    return -1;
  }
  return static_cast<pid_t>(static_cast<int>(reply[2]));
}

// The latest /diagnostics status of a node, with its values. diagnostic_updater names a status
// "<node name without the leading slash>: <task>".
struct NodeStatus {
  bool seen = false;
  diagnostic_msgs::DiagnosticStatus status;
  std::map<std::string, std::string> values;
};
NodeStatus LatestStatus(const std::vector<diagnostic_msgs::DiagnosticArray>& arrays,
                        const std::string& node) {
  NodeStatus out;
  for (const auto& array : arrays) {
    for (const auto& st : array.status) {
      const std::string prefix = (node.rfind('/', 0) == 0 ? node.substr(1) : node) + ":";
      if (st.name.rfind(prefix, 0) != 0) continue;
      out.seen = true;
      out.status = st;
      out.values.clear();
      for (const auto& kv : st.values) out.values[kv.key] = kv.value;
    }
  }
  return out;
}

double PositionErrorMm(const gtbow::Pose2D& a, const gtbow::Pose2D& b) {
  return 1000.0 * std::hypot(a.x - b.x, a.y - b.y);
}
double HeadingErrorDeg(const gtbow::Pose2D& a, const gtbow::Pose2D& b) {
  return std::abs(std::remainder(a.theta - b.theta, 2 * M_PI)) * 180.0 / M_PI;
}

// The query's pose from a candidate's keyframe pose and its relative pose (optical frame).
gtbow::Pose2D Compose(const gtbow::Pose2D& keyframe, const geometry_msgs::Pose2D& optical) {
  const double x = optical.x, y = -optical.y, th = -optical.theta;  // back to the above view
  const double c = std::cos(keyframe.theta), s = std::sin(keyframe.theta);
  return {keyframe.x + c * x - s * y, keyframe.y + s * x + c * y, keyframe.theta + th};
}

// ---------------------------------------------------------------------------------------------

TEST(Mapping, ReplayBuildsKeyframesAndRevisitsGetTheRightOnes) {
  Collector<ground_texture_bow::LoopClosure> closure_topic("/localizer/loop_closures");
  // The debug image is computed only with a subscriber: subscribe for the first part. The
  // node counts the overlays it draws (get_info: debug_images).
  Collector<sensor_msgs::Image> debug_topic("/localizer/debug_image", 10);
  const auto mapping = ReadBag(g_data + "/mapping.bag");
  ASSERT_GT(mapping.size(), 20u);
  Replay(std::vector<Frame>(mapping.begin(), mapping.begin() + 5), "/camera/image_raw",
         "/localizer", 4.0);
  debug_topic.Stop();
  ros::WallDuration(1.0).sleep();  // the node sees the subscriber go
  const uint64_t drawn_while_subscribed = Info("/localizer").debug_images;
  Replay(std::vector<Frame>(mapping.begin() + 5, mapping.end()), "/camera/image_raw",
         "/localizer", 4.0);
  const auto debug = debug_topic.Get();
  EXPECT_GE(drawn_while_subscribed, 4u);  // the first may come before the subscription is up
  EXPECT_LE(drawn_while_subscribed, 5u);
  EXPECT_EQ(debug.size(), drawn_while_subscribed);
  EXPECT_EQ(Info("/localizer").debug_images, drawn_while_subscribed)
      << "overlays were drawn for " << mapping.size() - 5 << " images without a subscriber";
  if (!debug.empty()) {
    EXPECT_EQ(debug[0].width, mapping[0].image->width);
    EXPECT_EQ(debug[0].encoding, "bgr8");
    EXPECT_EQ(debug[0].header.stamp, mapping[0].image->header.stamp);
  }
  const auto info = Info("/localizer");
  EXPECT_EQ(info.mode, "mapping");
  EXPECT_GE(info.database_size, mapping.size() * 3 / 4) << "keyframes";
  EXPECT_EQ(info.images_rejected, 0u);

  // Revisits on day 30: by image, verified.
  const auto revisits = ReadBag(g_data + "/localization.bag");
  int right = 0, accurate = 0;
  for (const Frame& f : revisits) {
    ground_texture_bow::QueryCandidates q;
    q.request.image = *f.image;
    q.request.k = 3;
    q.request.verify = true;
    q = Call("/localizer/query_candidates", q);
    ASSERT_EQ(q.response.status.code, Status::OK) << q.response.status.message;
    if (q.response.candidates.empty()) continue;
    const auto& best = q.response.candidates[0];
    ASSERT_TRUE(best.has_pose);  // mapped with TF
    const gtbow::Pose2D kf{best.pose.x, best.pose.y, best.pose.theta};
    right += gtbow::IsRelevant(f.truth, kf, kGeometry) ? 1 : 0;
    if (best.verified) {
      const gtbow::Pose2D est = Compose(kf, best.match_from_query);
      accurate += PositionErrorMm(est, f.truth) <= 4.8 && HeadingErrorDeg(est, f.truth) <= 1.5;
    }
  }
  std::printf("mapping: %u keyframes from %zu images; revisits: %d of %zu right, %d verified within "
              "4.8 mm / 1.5 deg\n", info.database_size, mapping.size(), right, revisits.size(), accurate);
  EXPECT_GE(right, static_cast<int>(revisits.size() * 9 / 10)) << right << " of " << revisits.size();
  EXPECT_GE(accurate, static_cast<int>(revisits.size() * 9 / 10)) << accurate << " of " << revisits.size();

  // By keyframe id: never itself, and the best overlaps it.
  for (uint32_t id = 0; id < info.database_size; id += 5) {
    ground_texture_bow::QueryCandidates q;
    q.request.use_keyframe_id = true;
    q.request.keyframe_id = id;
    q.request.k = 3;
    q = Call("/localizer/query_candidates", q);
    ASSERT_EQ(q.response.status.code, Status::OK) << q.response.status.message;
    for (const auto& c : q.response.candidates) EXPECT_NE(c.id, id);
  }
  ground_texture_bow::QueryCandidates unknown;
  unknown.request.use_keyframe_id = true;
  unknown.request.keyframe_id = 100000;
  EXPECT_EQ(Call("/localizer/query_candidates", unknown).response.status.code, Status::NOT_FOUND);

  // Loop closures between lawnmower rows: each relative pose agrees with the ground truth.
  std::map<ros::Time, gtbow::Pose2D> truth;
  for (const Frame& f : mapping) truth[f.image->header.stamp] = f.truth;
  const auto closures = closure_topic.Get();
  EXPECT_GE(closures.size(), 3u);
  int consistent = 0;
  for (const auto& lc : closures) {
    ASSERT_EQ(lc.status, ground_texture_bow::LoopClosure::VERIFIED);
    const gtbow::Pose2D est = Compose(truth.at(lc.match_stamp), lc.match_from_query);
    const gtbow::Pose2D& q = truth.at(lc.query_stamp);
    consistent += PositionErrorMm(est, q) <= 4.8 && HeadingErrorDeg(est, q) <= 1.5;
  }
  std::printf("loop closures: %zu, %d consistent with the ground truth\n", closures.size(), consistent);
  // A SLAM backend takes a verified loop closure as a fact: every one must agree with the truth.
  EXPECT_EQ(consistent, static_cast<int>(closures.size()));

  // RViz markers: one footprint (4 segments) per posed keyframe, one edge per loop closure.
  visualization_msgs::MarkerArrayConstPtr markers =
      ros::topic::waitForMessage<visualization_msgs::MarkerArray>("/localizer/markers", ros::Duration(5));
  ASSERT_TRUE(markers != nullptr);
  ASSERT_EQ(markers->markers.size(), 2u);
  EXPECT_EQ(markers->markers[0].header.frame_id, "map");
  EXPECT_EQ(markers->markers[0].points.size(), 8u * info.database_size);
  EXPECT_EQ(markers->markers[1].points.size(), 2u * closures.size());
}

// ---------------------------------------------------------------------------------------------

TEST(SaveLoad, AFreshNodeLoadsTheMapAnswersAlikeAndLocalizesALaterDay) {
  const auto mapping = ReadBag(g_data + "/mapping.bag");
  Replay(mapping, "/map_camera/image_raw", "/mapper", 4.0);
  const fs::path dir = fs::temp_directory_path() / ("gtbow_rostest_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string map_path = (dir / "map.gtmap").string();
  ground_texture_bow::SaveMap save;
  save.request.path = map_path;
  save = Call("/mapper/save_map", save);
  ASSERT_EQ(save.response.status.code, Status::OK) << save.response.status.message;
  ground_texture_bow::LoadMap load;
  load.request.path = map_path;
  load = Call("/localizer/load_map", load);
  ASSERT_EQ(load.response.status.code, Status::OK) << load.response.status.message;
  EXPECT_EQ(load.response.keyframes, Info("/mapper").database_size);
  const std::string bytes = gtbow::ReadFile(map_path);
  const auto map_mtime = fs::last_write_time(map_path);

  // The same answers from both nodes.
  const auto later = ReadBag(g_data + "/localization.bag");
  for (const Frame& f : later) {
    ground_texture_bow::QueryCandidates q;
    q.request.image = *f.image;
    q.request.k = 5;
    q.request.verify = true;
    const auto a = Call("/mapper/query_candidates", q).response;
    const auto b = Call("/localizer/query_candidates", q).response;
    ASSERT_EQ(a.status.code, Status::OK) << a.status.message;
    ASSERT_EQ(b.status.code, Status::OK) << b.status.message;
    ASSERT_EQ(a.candidates.size(), b.candidates.size());
    ASSERT_FALSE(a.candidates.empty());
    // Every field of every candidate: id, stamp, score, pose, verification, relative pose,
    // inliers, covariance, reason.
    for (size_t k = 0; k < a.candidates.size(); ++k) {
      EXPECT_TRUE(a.candidates[k] == b.candidates[k]) << "mapper:\n"
                                                      << a.candidates[k] << "localizer:\n"
                                                      << b.candidates[k];
    }
  }

  // The robot's odometry frame: odom -> camera is static here, so that map -> odom from each fix
  // can be checked through TF (publish_tf is on for this node).
  tf2_ros::StaticTransformBroadcaster static_tf;
  geometry_msgs::TransformStamped odom_cam;
  odom_cam.header.stamp = ros::Time(1.0);
  odom_cam.header.frame_id = "odom";
  // Another camera frame than the mapping run's (whose TF made it a child of map).
  odom_cam.child_frame_id = "robot2_camera_optical";
  std::vector<Frame> later_robot2 = later;
  for (Frame& f : later_robot2) {
    auto img = boost::make_shared<sensor_msgs::Image>(*f.image);
    img->header.frame_id = odom_cam.child_frame_id;
    f.image = img;
  }
  odom_cam.transform = gtbow_ros::TransformFromFootprint({0.1, -0.2, 0.5}, 0.2);
  static_tf.sendTransform(odom_cam);
  tf2_ros::Buffer tf_buffer;
  tf2_ros::TransformListener tf_listener(tf_buffer);

  // Localization mode: a day-30 run without TF gets fixes within the protocol's tolerance, and
  // the match overlay draws the inliers in red over the camera image.
  Collector<geometry_msgs::PoseWithCovarianceStamped> fix_topic("/localizer/pose");
  Collector<sensor_msgs::Image> debug_topic("/localizer/debug_image");
  ros::WallDuration(0.5).sleep();
  Replay(later_robot2, "/loc_camera/image_raw", "/localizer", 4.0);
  ros::WallDuration(0.5).sleep();
  const auto info = Info("/localizer");  // at once: `localized` means a fix within 2 s
  std::map<ros::Time, gtbow::Pose2D> fixes;
  for (const auto& p : fix_topic.Get()) {
    const auto& q = p.pose.pose.orientation;
    EXPECT_EQ(p.header.frame_id, "map");
    EXPECT_GT(p.pose.covariance[0], 0.0);
    fixes[p.header.stamp] = {p.pose.pose.position.x, p.pose.pose.position.y,
                             gtbow_ros::YawOf(q.x, q.y, q.z, q.w)};
  }
  int good = 0;
  for (const Frame& f : later) {
    auto it = fixes.find(f.image->header.stamp);
    if (it == fixes.end()) continue;
    good += PositionErrorMm(it->second, f.truth) <= 4.8 && HeadingErrorDeg(it->second, f.truth) <= 1.5;
  }
  std::printf("localization: %zu fixes for %zu images, %d within 4.8 mm / 1.5 deg\n", fixes.size(),
              later.size(), good);
  EXPECT_GE(good, static_cast<int>(later.size() * 9 / 10)) << good << " of " << later.size();
  int overlays_with_matches = 0;
  for (const auto& img : debug_topic.Get()) {
    const cv::Mat bgr = cv_bridge::toCvCopy(img, "bgr8")->image;
    int red = 0;
    for (int v = 0; v < bgr.rows; ++v) {
      for (int u = 0; u < bgr.cols; ++u) {
        const cv::Vec3b px = bgr.at<cv::Vec3b>(v, u);
        red += px[2] > 200 && px[1] < 60 && px[0] < 60;
      }
    }
    overlays_with_matches += red > 100;
  }
  EXPECT_GE(overlays_with_matches, static_cast<int>(later.size() * 3 / 4));
  // map -> odom -> camera reproduces the last fix.
  ASSERT_FALSE(fixes.empty());
  const auto& [stamp, fix] = *fixes.rbegin();
  const auto t = tf_buffer.lookupTransform("map", odom_cam.child_frame_id, stamp, ros::Duration(2));
  const gtbow::Pose2D through_tf = gtbow_ros::FootprintFromTransform(t.transform);
  EXPECT_LT(PositionErrorMm(through_tf, fix), 0.01);
  EXPECT_LT(HeadingErrorDeg(through_tf, fix), 0.01);
  EXPECT_EQ(info.mode, "localization");
  EXPECT_EQ(info.fixes, fixes.size());
  EXPECT_TRUE(info.localized);
  // Localization mode is read-only: no insertion, and the map file is untouched.
  ground_texture_bow::AddKeyframe add;
  add.request.image = *later[0].image;
  EXPECT_EQ(Call("/localizer/add_keyframe", add).response.status.code, Status::FAILED_PRECONDITION);
  EXPECT_EQ(info.database_size, load.response.keyframes);
  // Localization mode never writes: save_map and reset are refused, and after the whole run
  // the map file is byte-identical, not even touched (mtime), and nothing else appeared.
  ground_texture_bow::SaveMap save_again;
  save_again.request.path = map_path;
  EXPECT_EQ(Call("/localizer/save_map", save_again).response.status.code,
            Status::FAILED_PRECONDITION);
  ground_texture_bow::Reset reset;
  EXPECT_EQ(Call("/localizer/reset", reset).response.status.code, Status::FAILED_PRECONDITION);
  EXPECT_EQ(Info("/localizer").database_size, load.response.keyframes);
  EXPECT_EQ(gtbow::ReadFile(map_path), bytes);
  EXPECT_EQ(fs::last_write_time(map_path), map_mtime);
  std::vector<std::string> entries;
  for (const auto& e : fs::directory_iterator(dir)) entries.push_back(e.path().filename().string());
  EXPECT_EQ(entries, std::vector<std::string>{"map.gtmap"});
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------

TEST(BadInput, EachKindIsCountedReportedAndLosesNothing) {
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics("/diagnostics");
  // Waits up to 10 s for a node's /diagnostics status that satisfies `pred`.
  auto wait_status = [&](const std::string& node, auto pred) {
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(10);
    NodeStatus st;
    while (ros::WallTime::now() < end) {
      st = LatestStatus(diagnostics.Get(), node);
      if (st.seen && pred(st)) break;
      ros::WallDuration(0.2).sleep();
    }
    return st;
  };
  // A nodelet that cannot start (no such vocabulary) in the same manager stays inert, says why
  // on /diagnostics, and does not take the manager, or this nodelet, down.
  {
    const NodeStatus broken = wait_status("/broken", [](const NodeStatus&) { return true; });
    ASSERT_TRUE(broken.seen) << "the nodelet that cannot start reports nothing on /diagnostics";
    EXPECT_EQ(broken.status.level, diagnostic_msgs::DiagnosticStatus::ERROR);
    EXPECT_NE(broken.status.message.find("no_such_vocabulary.gtvoc"), std::string::npos)
        << broken.status.message;
  }
  EXPECT_FALSE(ros::service::waitForService("/broken/get_info", ros::Duration(1.0)));
  EXPECT_EQ(Info("/localizer").mode, "mapping");
  // A small map to protect.
  auto mapping = ReadBag(g_data + "/mapping.bag");
  mapping.resize(6);
  Replay(mapping, "/camera/image_raw", "/localizer", 4.0);
  const uint32_t keyframes = Info("/localizer").database_size;
  ASSERT_GT(keyframes, 0u);
  const fs::path dir = fs::temp_directory_path() / ("gtbow_badinput_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string good_path = (dir / "map.gtmap").string();
  ground_texture_bow::SaveMap save;
  save.request.path = good_path;
  ASSERT_EQ(Call("/localizer/save_map", save).response.status.code, Status::OK);
  const std::string good_bytes = gtbow::ReadFile(good_path);

  // A nodelet started in the same manager with this map and another vocabulary (trained for
  // the same preset): it refuses the map, stays inert, reports the mismatch at ERROR, and the
  // manager and the running nodelet carry on.
  {
    ros::NodeHandle nh;
    nh.setParam("/mismatched/vocabulary", g_data + "/other_vocab.gtvoc");
    nh.setParam("/mismatched/map", good_path);
    nh.setParam("/mismatched/meters_per_pixel", 0.00025);
    nodelet::NodeletLoad load;
    load.request.name = "/mismatched";
    load.request.type = "ground_texture_bow/LocalizerNodelet";
    load = Call("/localizer_manager/load_nodelet", load);
    EXPECT_TRUE(load.response.success);
    const NodeStatus st = wait_status("/mismatched", [](const NodeStatus&) { return true; });
    ASSERT_TRUE(st.seen) << "the nodelet with the mismatched map reports nothing on /diagnostics";
    EXPECT_EQ(st.status.level, diagnostic_msgs::DiagnosticStatus::ERROR);
    EXPECT_NE(st.status.message.find("the map was built with another vocabulary than " + g_data +
                                     "/other_vocab.gtvoc"),
              std::string::npos)
        << st.status.message;
    EXPECT_NE(st.status.message.find(good_path), std::string::npos) << st.status.message;
    EXPECT_FALSE(ros::service::waitForService("/mismatched/get_info", ros::Duration(1.0)));
    nodelet::NodeletUnload unload;
    unload.request.name = "/mismatched";
    EXPECT_TRUE(Call("/localizer_manager/unload_nodelet", unload).response.success);
    EXPECT_EQ(Info("/localizer").database_size, keyframes);
  }

  // Bad images on the topic, 1 s apart (the 20-megapixel one last: it takes a while).
  // Rejected: a wrong encoding, an empty image, a 1x1 image. Processed without a pose (a
  // missing transform each): a frame without any transform, a stale one (its only transform is
  // 30 s older than the image), and a NaN one (tf2 refuses NaN transforms). Processed: 20 MP.
  const sensor_msgs::Image& base = *mapping[0].image;
  auto variant = [&](double dt, const std::string& frame) {
    auto img = boost::make_shared<sensor_msgs::Image>(base);
    img->header.stamp += ros::Duration(dt);
    if (!frame.empty()) img->header.frame_id = frame;
    return img;
  };
  auto transform_for = [&](const std::string& frame, const ros::Time& stamp, double value) {
    auto tf = boost::make_shared<tf2_msgs::TFMessage>();
    geometry_msgs::TransformStamped t;
    t.header.stamp = stamp;
    t.header.frame_id = "map";
    t.child_frame_id = frame;
    t.transform.translation.x = value;
    t.transform.rotation.w = 1.0;
    tf->transforms.push_back(t);
    return tf;
  };
  auto wrong = variant(100, "");
  wrong->encoding = "32FC1";
  auto empty = variant(101, "");
  empty->width = empty->height = 0;
  empty->data.clear();
  auto no_tf = variant(102, "unknown_camera");
  auto tiny = variant(103, "");
  tiny->width = tiny->height = 1;
  tiny->step = 1;
  tiny->data.assign(1, 128);
  auto stale = variant(104, "stale_camera");
  auto nan_frame = variant(105, "nan_camera");
  auto big = variant(106, "");
  {
    const cv::Mat small = cv_bridge::toCvCopy(base, "mono8")->image;
    cv::Mat large;
    cv::resize(small, large, cv::Size(5472, 3648), 0, 0, cv::INTER_LINEAR);
    big = boost::make_shared<sensor_msgs::Image>(*cv_bridge::CvImage(big->header, "mono8", large).toImageMsg());
  }
  std::vector<Frame> bad;
  for (const auto& img : {wrong, empty, no_tf, tiny, stale, nan_frame, big}) {
    Frame f;
    f.image = img;
    bad.push_back(f);
  }
  bad[4].tf = transform_for("stale_camera", stale->header.stamp - ros::Duration(30), 0.1);
  bad[5].tf = transform_for("nan_camera", nan_frame->header.stamp, std::nan(""));
  bad[6].tf = mapping[0].tf;  // the mapping run's camera frame, at an older stamp: stale too
  const auto before_bad = Info("/localizer");
  Replay(bad, "/camera/image_raw", "/localizer", 1.0);
  auto info = Info("/localizer");
  EXPECT_EQ(info.images_rejected, 3u);  // the encoding, the empty and the 1x1 image
  EXPECT_EQ(info.images_processed - before_bad.images_processed, 4u);  // the others, 20 MP too
  EXPECT_EQ(info.images_dropped, before_bad.images_dropped);
  const uint32_t keyframes_now = info.database_size;  // unposed ones may have become keyframes

  // A NaN pose through add_keyframe: refused, nothing inserted.
  ground_texture_bow::AddKeyframe nan_pose;
  nan_pose.request.image = base;
  nan_pose.request.has_pose = true;
  nan_pose.request.pose.x = std::nan("");
  nan_pose = Call("/localizer/add_keyframe", nan_pose);
  EXPECT_EQ(nan_pose.response.status.code, Status::INVALID_ARGUMENT);
  EXPECT_NE(nan_pose.response.status.message.find("non-finite"), std::string::npos)
      << nan_pose.response.status.message;
  EXPECT_EQ(Info("/localizer").database_size, keyframes_now);

  // A map path that cannot be written, and a corrupt map: errors, nothing lost.
  ground_texture_bow::SaveMap unwritable;
  unwritable.request.path = "/proc/gtbow_no_such_dir/map.gtmap";
  unwritable = Call("/localizer/save_map", unwritable);
  EXPECT_EQ(unwritable.response.status.code, Status::INVALID_ARGUMENT);
  EXPECT_NE(unwritable.response.status.message.find("/proc/gtbow_no_such_dir/map.gtmap': No such "
                                                    "file or directory"),
            std::string::npos)
      << unwritable.response.status.message;
  // A save over the saved map that fails half-way: the manager process may write files of at
  // most 4 KB for the call (its RLIMIT_FSIZE, set from here; the map is far larger), as on a
  // full disk. The error names the path and the reason, the file on disk is the old one, no
  // temporary is left, and the manager survives the SIGXFSZ that the kernel raises.
  {
    const pid_t manager = PidOf("/localizer_manager");
    ASSERT_GT(manager, 0) << "no pid for /localizer_manager";
    const auto mtime = fs::last_write_time(good_path);
    rlimit previous{};
    ASSERT_EQ(::prlimit(manager, RLIMIT_FSIZE, nullptr, &previous), 0);
    const rlimit small{4096, previous.rlim_max};
    ASSERT_EQ(::prlimit(manager, RLIMIT_FSIZE, &small, nullptr), 0);
    ground_texture_bow::SaveMap over;
    over.request.path = good_path;
    over = Call("/localizer/save_map", over);
    EXPECT_EQ(::prlimit(manager, RLIMIT_FSIZE, &previous, nullptr), 0);
    EXPECT_EQ(over.response.status.code, Status::INVALID_ARGUMENT) << over.response.status.message;
    EXPECT_NE(over.response.status.message.find(good_path + "': File too large"), std::string::npos)
        << over.response.status.message;
    EXPECT_EQ(gtbow::ReadFile(good_path), good_bytes);
    EXPECT_EQ(fs::last_write_time(good_path), mtime);
    std::vector<std::string> entries;
    for (const auto& e : fs::directory_iterator(dir)) entries.push_back(e.path().filename().string());
    EXPECT_EQ(entries, std::vector<std::string>{"map.gtmap"});
    EXPECT_EQ(::kill(manager, 0), 0) << "the manager died";
  }
  std::string corrupt = good_bytes;
  corrupt[corrupt.size() / 2] ^= 0x10;
  // A corrupt, a truncated and a foreign map file (the vocabulary): refused, naming the file
  // and the defect.
  const std::tuple<std::string, std::string, std::string> bad_maps[] = {
      {"corrupt.gtmap", corrupt, "checksum mismatch"},
      {"truncated.gtmap", good_bytes.substr(0, good_bytes.size() / 2), "truncated"},
      {"foreign.gtmap", gtbow::ReadFile(g_data + "/vocab.gtvoc"), "wrong magic number"}};
  for (const auto& [name, bytes, defect] : bad_maps) {
    gtbow::WriteFileAtomic(dir / name, bytes);
    ground_texture_bow::LoadMap load;
    load.request.path = (dir / name).string();
    load = Call("/localizer/load_map", load);
    EXPECT_EQ(load.response.status.code, Status::INVALID_ARGUMENT) << name;
    EXPECT_NE(load.response.status.message.find(name), std::string::npos)
        << load.response.status.message;
    EXPECT_NE(load.response.status.message.find(defect), std::string::npos)
        << load.response.status.message;
  }
  // A bad image through a service.
  ground_texture_bow::QueryCandidates q;
  q.request.image = *wrong;
  q = Call("/localizer/query_candidates", q);
  EXPECT_EQ(q.response.status.code, Status::INVALID_ARGUMENT);
  EXPECT_NE(q.response.status.message.find("32FC1"), std::string::npos);

  // Still alive, map intact in memory and on disk, counters and diagnostics tell the story.
  info = Info("/localizer");
  EXPECT_EQ(info.database_size, keyframes_now);
  EXPECT_EQ(info.images_rejected, 3u);
  EXPECT_EQ(info.requests_rejected, 7u);  // NaN pose, two saves, three loads, query
  EXPECT_EQ(gtbow::ReadFile(good_path), good_bytes);
  const NodeStatus latest = wait_status("/localizer", [](const NodeStatus& st) {
    const auto missing = st.values.find("missing transforms");
    return missing != st.values.end() && !missing->second.empty() &&
           std::stoi(missing->second) >= 4 && st.values.at("rejected images") == "3" &&
           st.values.at("rejected requests") == "7";
  });
  const bool seen = latest.seen && latest.values.count("missing transforms") &&
                    std::stoi(latest.values.at("missing transforms")) >= 4 &&
                    latest.values.at("rejected images") == "3" &&
                    latest.values.at("rejected requests") == "7";
  EXPECT_TRUE(seen) << "diagnostics do not report the rejected images and requests and the "
                       "missing transforms (no transform, stale, NaN, stale)";
  const diagnostic_msgs::DiagnosticStatus& status = latest.status;
  EXPECT_EQ(status.level, diagnostic_msgs::DiagnosticStatus::WARN);
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------

sensor_msgs::CompressedImage Compress(const sensor_msgs::Image& img) {
  sensor_msgs::CompressedImage c;
  c.header = img.header;
  c.format = "png";
  std::vector<uint8_t> buf;
  cv::imencode(".png", cv_bridge::toCvCopy(img, "mono8")->image, buf);
  c.data = buf;
  return c;
}

TEST(Services, ExternalModeCompressedImagesAndMapServices) {
  ros::NodeHandle nh;
  Collector<ground_texture_bow::CandidateList> list_topic("/localizer/candidates");
  ros::Publisher pub = nh.advertise<sensor_msgs::CompressedImage>("/camera/image_raw/compressed", 10);
  const auto mapping = ReadBag(g_data + "/mapping.bag");
  EXPECT_EQ(Info("/localizer").mode, "external");

  // The SLAM backend inserts keyframes (with poses) through the service.
  for (size_t i = 0; i < 12; ++i) {
    ground_texture_bow::AddKeyframe add;
    add.request.image = *mapping[i].image;
    add.request.has_pose = true;
    add.request.pose = gtbow_ros::ToPose2DMsg(mapping[i].truth);
    add = Call("/localizer/add_keyframe", add);
    ASSERT_EQ(add.response.status.code, Status::OK) << add.response.status.message;
    EXPECT_EQ(add.response.id, i);
  }
  ground_texture_bow::AddKeyframe nan_pose;
  nan_pose.request.image = *mapping[0].image;
  nan_pose.request.has_pose = true;
  nan_pose.request.pose.x = NAN;
  EXPECT_EQ(Call("/localizer/add_keyframe", nan_pose).response.status.code, Status::INVALID_ARGUMENT);

  // Compressed images in: ranked candidates out, nothing inserted by the node itself.
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(20);
  while (pub.getNumSubscribers() == 0 && ros::WallTime::now() < deadline) ros::WallDuration(0.05).sleep();
  ASSERT_GT(pub.getNumSubscribers(), 0u);
  ros::WallDuration(0.5).sleep();  // the connection is up on both sides
  for (size_t i : {3u, 7u}) {
    pub.publish(Compress(*mapping[i].image));
    ros::WallDuration(0.5).sleep();
  }
  sensor_msgs::CompressedImage garbage;
  garbage.header = mapping[0].image->header;
  garbage.format = "jpeg";
  garbage.data = {1, 2, 3};
  pub.publish(garbage);
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(10);
  while (ros::WallTime::now() < end) {
    if (list_topic.Get().size() >= 2 && Info("/localizer").images_rejected >= 1) break;
    ros::WallDuration(0.1).sleep();
  }
  const auto lists = list_topic.Get();
  ASSERT_EQ(lists.size(), 2u);
  ASSERT_FALSE(lists[0].candidates.empty());
  ASSERT_FALSE(lists[1].candidates.empty());
  EXPECT_EQ(lists[0].candidates[0].id, 3u);  // the same image was keyframe 3
  EXPECT_EQ(lists[1].candidates[0].id, 7u);
  EXPECT_EQ(lists[0].query_id, ground_texture_bow::CandidateList::NO_ID);
  auto info = Info("/localizer");
  EXPECT_EQ(info.database_size, 12u);
  EXPECT_EQ(info.images_rejected, 1u);    // the undecodable image
  EXPECT_EQ(info.requests_rejected, 1u);  // the NaN pose

  // A burst faster than the node can process: waiting images are replaced, and counted. (On a
  // loaded machine roscpp's own subscriber queue may drop some before the node sees them.)
  const uint64_t received_before = info.images_received;
  const uint64_t processed_before = info.images_processed;
  const uint64_t dropped_before = info.images_dropped;
  for (int k = 0; k < 10; ++k) pub.publish(Compress(*mapping[k].image));
  const ros::WallTime burst_end = ros::WallTime::now() + ros::WallDuration(10);
  uint64_t last_received = 0;
  while (ros::WallTime::now() < burst_end) {
    ros::WallDuration(0.5).sleep();
    info = Info("/localizer");
    const bool settled =
        info.images_processed + info.images_dropped + info.images_rejected >= info.images_received;
    if (settled && info.images_received == last_received) break;  // nothing more arriving
    last_received = info.images_received;
  }
  EXPECT_GT(info.images_received, received_before);
  EXPECT_LE(info.images_received, received_before + 10);
  EXPECT_LT(info.images_processed - processed_before, 10u);  // no backlog was worked through
  std::printf("burst of 10 images: %lu received, %lu processed, %lu dropped\n",
              static_cast<unsigned long>(info.images_received - received_before),
              static_cast<unsigned long>(info.images_processed - processed_before),
              static_cast<unsigned long>(info.images_dropped - dropped_before));
  EXPECT_GE(info.images_received - received_before, 3u);
  EXPECT_GT(info.images_dropped, dropped_before) << "no waiting image was replaced";
  EXPECT_EQ(info.images_received - received_before,
            (info.images_processed - processed_before) + (info.images_dropped - dropped_before));
  EXPECT_EQ(info.images_processed + info.images_dropped + info.images_rejected, info.images_received);
  EXPECT_EQ(info.database_size, 12u);  // external mode never inserts on its own

  // ~localize against the posed keyframes, with day-30 images that are not in the map (a later
  // visit at other poses): each one that overlaps a keyframe by at least 25% and lies at least
  // 10 mm from every keyframe must be localized within the protocol's tolerance, so returning a
  // keyframe's pose instead of estimating one fails.
  const auto later = ReadBag(g_data + "/localization.bag");
  int tried = 0, within = 0;
  for (const Frame& f : later) {
    bool seen = false;
    double nearest_mm = 1e9;
    for (size_t i = 0; i < 12; ++i) {
      seen = seen || gtbow::IsRelevant(f.truth, mapping[i].truth, kGeometry);
      nearest_mm = std::min(nearest_mm, PositionErrorMm(mapping[i].truth, f.truth));
    }
    if (!seen || nearest_mm < 10.0) continue;
    ++tried;
    ground_texture_bow::Localize loc;
    loc.request.image = *f.image;
    loc = Call("/localizer/localize", loc);
    ASSERT_EQ(loc.response.status.code, Status::OK) << loc.response.status.message;
    if (!loc.response.localized) continue;
    const auto& p = loc.response.pose.pose.pose;
    const gtbow::Pose2D fix{p.position.x, p.position.y,
                            gtbow_ros::YawOf(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)};
    within += PositionErrorMm(fix, f.truth) <= 4.8 && HeadingErrorDeg(fix, f.truth) <= 1.5;
  }
  std::printf("~localize, day-30 images over the map and off its keyframes: %d, within tolerance %d\n",
              tried, within);
  ASSERT_GE(tried, 3);
  EXPECT_EQ(within, tried);

  // Modes: a bad name is refused; localization is read-only; reset in external mode clears.
  ground_texture_bow::SetMode mode;
  mode.request.mode = "surveying";
  EXPECT_EQ(Call("/localizer/set_mode", mode).response.status.code, Status::INVALID_ARGUMENT);
  mode.request.mode = "localization";
  mode = Call("/localizer/set_mode", mode);
  EXPECT_EQ(mode.response.previous_mode, "external");
  ground_texture_bow::AddKeyframe add;
  add.request.image = *mapping[20].image;
  EXPECT_EQ(Call("/localizer/add_keyframe", add).response.status.code, Status::FAILED_PRECONDITION);
  EXPECT_EQ(Call<ground_texture_bow::Reset>("/localizer/reset").response.status.code,
            Status::FAILED_PRECONDITION);
  EXPECT_EQ(Info("/localizer").database_size, 12u);
  mode.request.mode = "external";
  Call("/localizer/set_mode", mode);
  EXPECT_EQ(Call<ground_texture_bow::Reset>("/localizer/reset").response.status.code, Status::OK);
  EXPECT_EQ(Info("/localizer").database_size, 0u);

  // Mapping without TF: the first image and then every keyframe_every_n-th (3 here) becomes a
  // keyframe, without a pose.
  mode.request.mode = "mapping";
  Call("/localizer/set_mode", mode);
  const uint64_t before_mapping = Info("/localizer").images_processed;
  for (int k = 0; k < 10; ++k) {
    sensor_msgs::CompressedImage c = Compress(*mapping[k].image);
    c.header.frame_id = "camera_without_tf";
    pub.publish(c);
    ros::WallDuration(0.3).sleep();
  }
  const ros::WallTime mapped = ros::WallTime::now() + ros::WallDuration(10);
  while (Info("/localizer").images_processed < before_mapping + 10 && ros::WallTime::now() < mapped) {
    ros::WallDuration(0.1).sleep();
  }
  info = Info("/localizer");
  ASSERT_EQ(info.images_processed, before_mapping + 10) << "images were dropped";
  EXPECT_EQ(info.database_size, 4u);  // images 1, 4, 7 and 10
  ground_texture_bow::QueryCandidates by_id;
  by_id.request.use_keyframe_id = true;
  by_id.request.keyframe_id = 1;
  by_id = Call("/localizer/query_candidates", by_id);
  ASSERT_EQ(by_id.response.status.code, Status::OK);
  for (const auto& c : by_id.response.candidates) EXPECT_FALSE(c.has_pose);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Soak (test/ros/soak.test, `make soak`; not in CI): rosbag play --loop --rate 4 feeds the
// nodelet in mapping mode for ~seconds while this process calls every read service and
// save_map concurrently. Passes when the manager never dies, no call fails or hangs, images
// keep being processed, and the manager's memory grows no more than the map does.

// The resident set of the process whose command line holds `needle` (0 when none).
pid_t FindProcess(const std::string& needle) {
  for (const auto& e : fs::directory_iterator("/proc")) {
    const std::string name = e.path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream f(e.path() / "cmdline", std::ios::binary);
    std::string cmd((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    std::replace(cmd.begin(), cmd.end(), '\0', ' ');
    if (cmd.find(needle) != std::string::npos && cmd.find("localizer_rostest") == std::string::npos) {
      return static_cast<pid_t>(std::stol(name));
    }
  }
  return 0;
}

double RssMb(pid_t pid) {
  std::ifstream f("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
  }
  return -1.0;
}

struct CallStats {
  std::string name;
  std::atomic<uint64_t> calls{0}, failures{0};
  std::atomic<double> max_ms{0.0};
  std::atomic<double> last_done{0.0};  // wall seconds
  std::vector<double> ms;               // every latency (one writer)
  std::string last_failure;
};

// A persistent connection to a service, as a SLAM backend keeps one (a fresh connection per
// call asks the master each time). A failed call is reported and the connection remade.
template <typename Srv>
class Client {
 public:
  explicit Client(std::string name) : name_(std::move(name)) { Connect(); }
  bool Call(Srv& srv) {
    if (client_.call(srv)) return true;
    Connect();
    return false;
  }

 private:
  void Connect() {
    ros::service::waitForService(name_, ros::Duration(5));
    client_ = ros::NodeHandle().serviceClient<Srv>(name_, true);
  }
  std::string name_;
  ros::ServiceClient client_;
};

TEST(Soak, ReplayAtFourTimesRealTimeWithConcurrentServiceCalls) {
  ros::NodeHandle pnh("~");
  double seconds = 600, save_every = 30;
  bool check_memory = true;  // off under ThreadSanitizer, whose shadow memory swamps the RSS
  std::string out = "/tmp/gtbow_soak";
  pnh.param("seconds", seconds, seconds);
  pnh.param("save_every", save_every, save_every);
  pnh.param("check_memory", check_memory, check_memory);
  pnh.param("out", out, out);
  fs::create_directories(out);
  ASSERT_TRUE(ros::service::waitForService("/localizer/get_info", ros::Duration(60)));
  const pid_t manager = FindProcess("__name:=localizer_manager");
  ASSERT_GT(manager, 0) << "no localizer_manager process";
  const auto probes = ReadBag(g_data + "/localization.bag");
  ASSERT_FALSE(probes.empty());
  const auto wall = [] { return ros::WallTime::now().toSec(); };
  const double t0 = wall();
  std::atomic<bool> stop{false};

  CallStats query, by_id, localize, info_stats, save;
  query.name = "query_candidates (image, k=5, verified)";
  by_id.name = "query_candidates (keyframe id)";
  localize.name = "localize";
  info_stats.name = "get_info";
  save.name = "save_map (every " + std::to_string(static_cast<int>(save_every)) + " s)";
  auto record = [&](CallStats& st, double start, bool ok, const std::string& why) {
    const double ms = 1000.0 * (wall() - start);
    st.calls++;
    st.ms.push_back(ms);
    if (ms > st.max_ms) st.max_ms = ms;
    if (!ok) {
      st.failures++;
      st.last_failure = why.empty() ? "the call itself failed (connection)" : why;
    }
    st.last_done = wall();
  };
  std::vector<std::thread> callers;
  callers.emplace_back([&] {
    Client<ground_texture_bow::QueryCandidates> client("/localizer/query_candidates");
    for (size_t i = 0; !stop; ++i) {
      ground_texture_bow::QueryCandidates q;
      q.request.image = *probes[i % probes.size()].image;
      q.request.k = 5;
      q.request.verify = true;
      const double s0 = wall();
      const bool ok = client.Call(q);
      record(query, s0, ok && q.response.status.code == Status::OK, q.response.status.message);
    }
  });
  callers.emplace_back([&] {
    std::mt19937 rng(1);
    Client<ground_texture_bow::GetInfo> info_client("/localizer/get_info");
    Client<ground_texture_bow::QueryCandidates> client("/localizer/query_candidates");
    while (!stop) {
      ground_texture_bow::GetInfo gi;
      info_client.Call(gi);
      ground_texture_bow::QueryCandidates q;
      q.request.use_keyframe_id = true;
      q.request.keyframe_id = gi.response.database_size > 0 ? rng() % gi.response.database_size : 0;
      q.request.k = 5;
      q.request.verify = true;
      const double s0 = wall();
      const bool ok = client.Call(q);
      // NOT_FOUND only for an empty map.
      record(by_id, s0, ok && (q.response.status.code == Status::OK ||
                               (gi.response.database_size == 0 && q.response.status.code == Status::NOT_FOUND)),
             q.response.status.message);
    }
  });
  callers.emplace_back([&] {
    Client<ground_texture_bow::Localize> client("/localizer/localize");
    for (size_t i = 0; !stop; ++i) {
      ground_texture_bow::Localize l;
      l.request.image = *probes[(i * 7) % probes.size()].image;
      const double s0 = wall();
      const bool ok = client.Call(l);
      // NOT_FOUND: answered, but no candidate verified (a fix needs posed keyframes nearby).
      record(localize, s0, ok && (l.response.status.code == Status::OK ||
                                  l.response.status.code == Status::NOT_FOUND),
             l.response.status.message);
    }
  });
  callers.emplace_back([&] {
    Client<ground_texture_bow::GetInfo> client("/localizer/get_info");
    while (!stop) {
      ground_texture_bow::GetInfo gi;
      const double s0 = wall();
      const bool ok = client.Call(gi);
      record(info_stats, s0, ok && gi.response.status.code == Status::OK, gi.response.status.message);
      ros::WallDuration(0.1).sleep();
    }
  });
  callers.emplace_back([&] {
    double next = wall() + save_every;
    save.last_done = wall();
    Client<ground_texture_bow::SaveMap> client("/localizer/save_map");
    while (!stop) {
      if (wall() < next) {
        ros::WallDuration(0.2).sleep();
        save.last_done = wall();  // idle is not hung
        continue;
      }
      next += save_every;
      ground_texture_bow::SaveMap sm;
      sm.request.path = out + "/soak.gtmap";
      const double s0 = wall();
      const bool ok = client.Call(sm);
      record(save, s0, ok && sm.response.status.code == Status::OK, sm.response.status.message);
    }
  });

  // Every second: the manager's memory and the node's counters.
  struct Sample {
    double t, rss_mb;
    uint32_t keyframes;
    uint64_t received, processed, dropped, rejected;
  };
  std::vector<Sample> samples;
  bool hung = false, died = false;
  while (wall() - t0 < seconds) {
    ros::WallDuration(1.0).sleep();
    const double now = wall();
    if (::kill(manager, 0) != 0) {
      died = true;
      break;
    }
    for (CallStats* st : {&query, &by_id, &localize, &info_stats, &save}) {
      if (st->last_done > 0 && now - st->last_done > 60) {
        ADD_FAILURE() << st->name << ": no answer for 60 s (deadlock?)";
        hung = true;
      }
    }
    if (hung) break;
    ground_texture_bow::GetInfo gi;
    if (!ros::service::call("/localizer/get_info", gi)) continue;
    const auto& r = gi.response;
    samples.push_back({now - t0, RssMb(manager), r.database_size, r.images_received,
                       r.images_processed, r.images_dropped, r.images_rejected});
    if (samples.size() % 60 == 0) {
      std::printf("soak %4.0f s: %u keyframes, %llu images processed, RSS %.0f MB\n", now - t0,
                  r.database_size, static_cast<unsigned long long>(r.images_processed),
                  samples.back().rss_mb);
      std::fflush(stdout);
    }
  }
  stop = true;
  if (hung || died) {
    ADD_FAILURE() << (died ? "the nodelet manager died" : "a service hung");
    std::fflush(nullptr);
    std::_Exit(1);  // a hung call cannot be joined
  }
  for (auto& th : callers) th.join();
  ASSERT_GE(samples.size(), 10u);

  // The map at the end, and memory growth against map growth after a one-minute warm-up.
  ground_texture_bow::SaveMap final_save;
  final_save.request.path = out + "/soak.gtmap";
  ASSERT_EQ(Call("/localizer/save_map", final_save).response.status.code, Status::OK);
  const double map_mb = static_cast<double>(fs::file_size(out + "/soak.gtmap")) / (1024.0 * 1024.0);
  const Sample& last = samples.back();
  const Sample& warm = *std::find_if(samples.begin(), samples.end(),
                                     [&](const Sample& s) { return s.t >= std::min(60.0, seconds / 4); });
  const double map_growth_mb = map_mb * (last.keyframes - warm.keyframes) / std::max<uint32_t>(last.keyframes, 1);
  const double rss_growth_mb = last.rss_mb - warm.rss_mb;
  double peak = 0;
  for (const Sample& s : samples) peak = std::max(peak, s.rss_mb);
  const double allowed_mb = 2.0 * map_growth_mb + 64.0;
  if (check_memory) {
    EXPECT_LE(rss_growth_mb, allowed_mb) << "memory grew " << rss_growth_mb
                                         << " MB while the map grew " << map_growth_mb << " MB";
  }
  // Images kept flowing: every minute saw processing.
  for (size_t i = 60; i < samples.size(); i += 60) {
    EXPECT_GT(samples[i].processed, samples[i - 60].processed) << "no image processed in minute " << i / 60;
  }
  for (CallStats* st : {&query, &by_id, &localize, &info_stats}) {
    EXPECT_GT(st->calls, 10u) << st->name;
  }
  for (CallStats* st : {&query, &by_id, &localize, &info_stats, &save}) {
    EXPECT_EQ(st->failures, 0u) << st->name << ": " << st->last_failure;
  }

  // Results for docs/RESULTS.md (scripts/write_soak.py).
  auto pct = [](std::vector<double> v, double p) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, static_cast<size_t>(p * (v.size() - 1) + 0.5))];
  };
  std::ofstream js(out + "/soak.json");
  js << "{\n  \"seconds\": " << (last.t) << ",\n  \"rate\": 4,\n  \"images_received\": " << last.received
     << ",\n  \"images_processed\": " << last.processed << ",\n  \"images_dropped\": " << last.dropped
     << ",\n  \"images_rejected\": " << last.rejected << ",\n  \"keyframes\": " << last.keyframes
     << ",\n  \"map_mb\": " << map_mb << ",\n  \"rss_warm_mb\": " << warm.rss_mb
     << ",\n  \"rss_end_mb\": " << last.rss_mb << ",\n  \"rss_peak_mb\": " << peak
     << ",\n  \"rss_growth_mb\": " << rss_growth_mb << ",\n  \"map_growth_mb\": " << map_growth_mb
     << ",\n  \"allowed_growth_mb\": " << allowed_mb << ",\n  \"warmup_s\": " << warm.t
     << ",\n  \"services\": [\n";
  bool first = true;
  for (CallStats* st : {&query, &by_id, &localize, &info_stats, &save}) {
    js << (first ? "" : ",\n") << "    {\"name\": \"" << st->name << "\", \"calls\": " << st->calls
       << ", \"failures\": " << st->failures << ", \"median_ms\": " << pct(st->ms, 0.5)
       << ", \"p99_ms\": " << pct(st->ms, 0.99) << ", \"max_ms\": " << st->max_ms.load() << "}";
    first = false;
  }
  js << "\n  ],\n  \"samples\": [\n";
  for (size_t i = 0; i < samples.size(); ++i) {
    const Sample& s = samples[i];
    js << "    [" << s.t << ", " << s.rss_mb << ", " << s.keyframes << ", " << s.processed << ", "
       << s.dropped << "]" << (i + 1 < samples.size() ? ",\n" : "\n");
  }
  js << "  ]\n}\n";
  uint64_t failed = 0;
  for (CallStats* st : {&query, &by_id, &localize, &info_stats, &save}) failed += st->failures;
  std::printf("soak: %.0f s, %llu images processed, %u keyframes (map %.1f MB), RSS %.0f -> %.0f MB "
              "(growth %.1f MB, allowed %.1f MB), %llu + %llu + %llu + %llu service calls, %llu failed\n",
              last.t, static_cast<unsigned long long>(last.processed), last.keyframes, map_mb, warm.rss_mb,
              last.rss_mb, rss_growth_mb, allowed_mb, static_cast<unsigned long long>(query.calls.load()),
              static_cast<unsigned long long>(by_id.calls.load()),
              static_cast<unsigned long long>(localize.calls.load()),
              static_cast<unsigned long long>(info_stats.calls.load()),
              static_cast<unsigned long long>(failed));
}

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "localizer_rostest");
  ros::NodeHandle pnh("~");
  if (!pnh.getParam("data", g_data)) {
    std::fprintf(stderr, "localizer_rostest: the ~data parameter (test data directory) is not set\n");
    return 2;
  }
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
