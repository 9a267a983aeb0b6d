// Shared by the rostest suites (test/ros/*_rostest.cpp, one executable: localizer_rostest). Each
// .test file starts the node(s) and runs one suite with --gtest_filter:
//   mapping.test       Mapping.*     (mapping_rostest.cpp)    revisits get the right keyframes
//   localization.test  SaveLoad.*    (save_load_rostest.cpp)  a saved map loads into a fresh node,
//                                    which answers the same and localizes a later-day run
//   bad_input.test     BadInput.*    (bad_input_rostest.cpp)  bad input is counted, nothing lost
//   services.test      Services.*    (services_rostest.cpp)   external mode, compressed images,
//                                    the map services
//   soak.test          Soak.*        (soak_rostest.cpp)       `make soak`, and 60 s under TSan
//   large_map.test     LargeMap.*    (large_map_rostest.cpp)  a 2,000-keyframe map answers the
//                                    same after ~save_map, loaded or kept by the mapper
//   robot.test         Robot.*       (robot_rostest.cpp)      a robot's camera: scale from
//                                    camera_info, base pose, odometry gate, initialpose
// The suites replay the bags test/ros/make_test_data.sh generated (images and ground-truth TF of
// a small synthetic floor) and check what comes out against the ground truth.
#pragma once

#include <signal.h>
#include <sys/resource.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <mutex>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include <diagnostic_msgs/DiagnosticArray.h>
#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <gtest/gtest.h>
#include <image_transport/camera_common.h>
#include <nodelet/NodeletLoad.h>
#include <nodelet/NodeletUnload.h>
#include <ros/network.h>
#include <ros/ros.h>
#include <ros/topic.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>
#include <visualization_msgs/MarkerArray.h>
#include <xmlrpcpp/XmlRpcClient.h>

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/CompressedImage.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include "ground_texture_bow/AddKeyframe.h"
#include "ground_texture_bow/CandidateList.h"
#include "ground_texture_bow/GetInfo.h"
#include "ground_texture_bow/LoadMap.h"
#include "ground_texture_bow/Localize.h"
#include "ground_texture_bow/LoopClosure.h"
#include "ground_texture_bow/QueryCandidates.h"
#include "ground_texture_bow/Reset.h"
#include "ground_texture_bow/SaveMap.h"
#include "ground_texture_bow/SetMode.h"
#include "ground_texture_bow/Status.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/geometry.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/ros/conversions.h"

namespace rostest_util {

namespace fs = std::filesystem;
using ground_texture_bow::Status;

inline std::string g_data;  // the test data directory (~data parameter)
inline const gtbow::ImageGeometry kGeometry{640, 480, 0.00025};

struct Frame {
  sensor_msgs::ImageConstPtr image;
  tf2_msgs::TFMessageConstPtr tf;        // may be null (bag without TF)
  sensor_msgs::CameraInfoConstPtr info;  // may be null (bag without camera_info)
  gtbow::Pose2D truth;
};

inline std::vector<Frame> ReadBag(const std::string& path) {
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  std::map<ros::Time, Frame> by_stamp;
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    if (auto img = m.instantiate<sensor_msgs::Image>()) {
      by_stamp[img->header.stamp].image = img;
    } else if (auto info = m.instantiate<sensor_msgs::CameraInfo>()) {
      by_stamp[info->header.stamp].info = info;
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
    sub_ =
        ros::NodeHandle().subscribe<M>(topic, queue, [this](const boost::shared_ptr<const M>& msg) {
          std::lock_guard<std::mutex> lock(mutex_);
          messages_.push_back(*msg);
        });
  }
  std::vector<M> Get() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return messages_;
  }
  void Stop() { sub_.shutdown(); }
  // Waits until the subscription is connected to a publisher of the topic, so that what a node
  // publishes from then on reaches it (a busy machine connects late); false after 120 s.
  bool WaitForPublisher() const {
    const ros::WallTime cap = ros::WallTime::now() + ros::WallDuration(120);
    while (sub_.getNumPublishers() == 0) {
      if (ros::WallTime::now() > cap) return false;
      ros::WallDuration(0.02).sleep();
    }
    return true;
  }
  // Waits until at least `count` messages have come (what a node counts as published may still
  // be on its way here) and returns them all; fewer after 30 s, for the test's checks to name (a
  // count that is only an upper bound, or a message dropped, costs those 30 s, not a hang).
  std::vector<M> WaitFor(size_t count) const {
    const ros::WallTime cap = ros::WallTime::now() + ros::WallDuration(30);
    while (true) {
      std::vector<M> got = Get();
      if (got.size() >= count || ros::WallTime::now() > cap) return got;
      ros::WallDuration(0.02).sleep();
    }
  }

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

// get_info is read-only, so a call that the transport drops is made again (twice at most) and
// the drop is printed: once in 10 runs of make test-slow-disk (a load of 10 on 2 cores) roscpp
// returned false for it with nothing in the logs, while the node served every other call.
inline ground_texture_bow::GetInfo::Response Info(const std::string& node) {
  const std::string name = node + "/get_info";
  for (int attempt = 1;; ++attempt) {
    ground_texture_bow::GetInfo srv;
    EXPECT_TRUE(ros::service::waitForService(name, ros::Duration(30))) << name;
    if (ros::service::call(name, srv)) return srv.response;
    std::fprintf(stderr, "%s: the call failed (attempt %d of 3)\n", name.c_str(), attempt);
    if (attempt == 3) {
      ADD_FAILURE() << name << ": three calls failed";
      return srv.response;
    }
    ros::WallDuration(0.2).sleep();
  }
}

// Whether a node has received at least `count` images and dealt with (processed, dropped or
// rejected) every image it received.
inline bool Handled(const ground_texture_bow::GetInfo::Response& info, uint64_t count) {
  return info.images_received >= count &&
         info.images_processed + info.images_dropped + info.images_rejected >= info.images_received;
}

inline std::string Counters(const ground_texture_bow::GetInfo::Response& info) {
  return "received " + std::to_string(info.images_received) + ", processed " +
         std::to_string(info.images_processed) + ", dropped " +
         std::to_string(info.images_dropped) + ", rejected " +
         std::to_string(info.images_rejected) + "; last error: " + info.last_error;
}

// Polls `node`'s get_info until `done` holds and returns its answer then. No limit of its own but
// a generous cap against a hang (a failure naming the counters): it waits on the node's events,
// not on the machine's speed.
template <class Done>
ground_texture_bow::GetInfo::Response WaitForInfo(const std::string& node, Done done) {
  const ros::WallTime cap = ros::WallTime::now() + ros::WallDuration(120);
  while (true) {
    const auto info = Info(node);
    if (done(info)) return info;
    if (ros::WallTime::now() > cap) {
      ADD_FAILURE() << node << ": still waiting after 120 s: " << Counters(info);
      return info;
    }
    ros::WallDuration(0.02).sleep();
  }
}

// Waits until `node` has received at least `count` images and dealt with all it received.
inline ground_texture_bow::GetInfo::Response WaitUntilHandled(const std::string& node,
                                                              uint64_t count) {
  return WaitForInfo(node, [count](const auto& info) { return Handled(info, count); });
}

// Publishes each frame's TF, camera_info and image at `rate` Hz at most: each image only once
// the node has dealt with the previous one (so that a slow machine or a sanitizer build drops
// nothing), then waits until the node has dealt with every image it received. An image that
// overtakes the first camera_info waits for it in the node.
inline void Replay(const std::vector<Frame>& frames, const std::string& topic,
                   const std::string& node, double rate) {
  ros::NodeHandle nh;
  ros::Publisher img_pub = nh.advertise<sensor_msgs::Image>(topic, 10);
  ros::Publisher tf_pub = nh.advertise<tf2_msgs::TFMessage>("/tf", 100);
  const std::string info_topic = image_transport::getCameraInfoTopic(topic);
  ros::Publisher info_pub = nh.advertise<sensor_msgs::CameraInfo>(info_topic, 10);
  const bool with_info = std::any_of(frames.begin(), frames.end(),
                                     [](const Frame& f) { return static_cast<bool>(f.info); });
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(20);
  while ((img_pub.getNumSubscribers() == 0 || (with_info && info_pub.getNumSubscribers() == 0)) &&
         ros::WallTime::now() < deadline)
    ros::WallDuration(0.05).sleep();
  ASSERT_GT(img_pub.getNumSubscribers(), 0u) << "nobody subscribes to " << topic;
  if (with_info) {
    ASSERT_GT(info_pub.getNumSubscribers(), 0u) << "nobody subscribes to " << info_topic;
  }
  ros::WallDuration(0.5).sleep();
  const uint64_t before = Info(node).images_received;
  for (size_t i = 0; i < frames.size(); ++i) {
    const Frame& f = frames[i];
    if (f.tf) tf_pub.publish(f.tf);
    if (f.info) info_pub.publish(f.info);
    ros::WallDuration(0.01).sleep();  // usually enough for the TF and camera_info to go first
    img_pub.publish(f.image);
    ros::WallDuration(1.0 / rate).sleep();
    WaitUntilHandled(node, before + i + 1);
  }
}

// The map file a node saved, read back in this process with the map's own preset, scale and
// descriptors (its header) and the vocabulary `vocab`. Load verifies every checksum; it throws
// std::runtime_error naming the defect.
inline std::unique_ptr<gtbow::Localizer> LoadSavedMap(const std::string& path,
                                                      const std::string& vocab) {
  const gtbow::MapFileInfo mi = gtbow::Localizer::ReadMapInfo(path);
  gtbow::LocalizerOptions lo;
  lo.retrieval = gtbow::ParseRetrievalConfig(mi.retrieval_config, "the map");
  lo.meters_per_pixel = mi.meters_per_pixel;
  lo.keep_descriptors = mi.descriptors;
  auto loc =
      std::make_unique<gtbow::Localizer>(gtbow::Vocabulary::Load(vocab), mi.vocabulary_path, lo);
  loc->Load(path);
  return loc;
}

// The process id of a ROS node (the slave API's getPid), or -1.
inline pid_t PidOf(const std::string& node) {
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
inline NodeStatus LatestStatus(const std::vector<diagnostic_msgs::DiagnosticArray>& arrays,
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

// The number `key` holds in a status, or -1 when it holds none.
inline double StatusValue(const NodeStatus& st, const std::string& key) {
  const auto it = st.values.find(key);
  return it == st.values.end() || it->second.empty() ? -1 : std::stod(it->second);
}

// Waits up to `seconds` for the latest /diagnostics status of `node` that satisfies `pred` (a
// status is published once a second, later on a busy machine): the latest status seen, which
// the caller checks (unseen, or not satisfying `pred`, when the time ran out).
template <class Pred>
NodeStatus WaitForStatus(const Collector<diagnostic_msgs::DiagnosticArray>& diagnostics,
                         const std::string& node, Pred pred, double seconds) {
  NodeStatus st;
  for (const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
       ros::WallTime::now() < end; ros::WallDuration(0.05).sleep()) {
    st = LatestStatus(diagnostics.Get(), node);
    if (st.seen && pred(st)) break;
  }
  return st;
}

inline double PositionErrorMm(const gtbow::Pose2D& a, const gtbow::Pose2D& b) {
  return 1000.0 * std::hypot(a.x - b.x, a.y - b.y);
}
inline double HeadingErrorDeg(const gtbow::Pose2D& a, const gtbow::Pose2D& b) {
  return std::abs(std::remainder(a.theta - b.theta, 2 * M_PI)) * 180.0 / M_PI;
}

// The query's pose from a candidate's keyframe pose and its relative pose (optical frame).
inline gtbow::Pose2D Compose(const gtbow::Pose2D& keyframe, const geometry_msgs::Pose2D& optical) {
  // Back to the view from above (the optical frame is mirrored), then composed.
  return gtbow::Compose(keyframe, {optical.x, -optical.y, -optical.theta});
}

}  // namespace rostest_util
