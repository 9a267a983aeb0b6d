// Backend.*: the pose-graph backend fed by the localizer on a small synthetic drive
// (test/ros/backend.test, data from test/ros/make_test_data.sh: drive.bag holds images, wheel
// odometry with drift, TF odom -> base_link -> camera and the ground truth). The localizer
// maps the drive in the odometry frame; three backends read its loop closures. Checked: the
// backend's trajectory is much closer to the ground truth than the odometry, and a wrong loop
// closure injected on the localizer's topic does not bend it (while it does bend the
// unprotected backend's, the negative control showing the injected closure matters).
#include <unistd.h>

#include <nav_msgs/Odometry.h>

#include "ground_texture_bow/SaveTrajectory.h"
#include "ground_texture_bow/eval/dataset.h"
#include "rostest_util.h"

namespace {

using namespace rostest_util;

struct DriveFrame {
  nav_msgs::OdometryConstPtr odom;
  tf2_msgs::TFMessageConstPtr tf;
  sensor_msgs::ImageConstPtr image;
  gtbow::Pose2D truth;
};

struct Drive {
  std::vector<DriveFrame> frames;
  std::vector<geometry_msgs::TransformStamped> statics;
};

Drive ReadDrive(const std::string& path) {
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  std::map<ros::Time, DriveFrame> by_stamp;
  Drive d;
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    if (auto img = m.instantiate<sensor_msgs::Image>()) {
      by_stamp[img->header.stamp].image = img;
    } else if (auto odom = m.instantiate<nav_msgs::Odometry>()) {
      by_stamp[odom->header.stamp].odom = odom;
    } else if (auto tf = m.instantiate<tf2_msgs::TFMessage>()) {
      if (m.getTopic() == "/tf_static") {
        d.statics.insert(d.statics.end(), tf->transforms.begin(), tf->transforms.end());
      } else {
        by_stamp[tf->transforms.at(0).header.stamp].tf = tf;
      }
    } else if (auto p = m.instantiate<geometry_msgs::PoseStamped>()) {
      const auto& q = p->pose.orientation;
      by_stamp[p->header.stamp].truth = {p->pose.position.x, p->pose.position.y,
                                         gtbow_ros::YawOf(q.x, q.y, q.z, q.w)};
    }
  }
  for (auto& [stamp, f] : by_stamp) d.frames.push_back(f);
  return d;
}

struct Row {
  double stamp;
  gtbow::Pose2D camera, odom_base;
};

std::vector<Row> ReadTrajectory(const std::string& path) {
  std::ifstream f(path);
  std::string line;
  std::getline(f, line);
  EXPECT_EQ(line.rfind("stamp,x,y,theta,camera_x", 0), 0u) << path << ": " << line;
  std::vector<Row> rows;
  while (std::getline(f, line)) {
    std::vector<double> v;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) v.push_back(std::stod(cell));
    if (v.size() != 10) {
      ADD_FAILURE() << path << ": a row with " << v.size() << " columns: " << line;
      continue;
    }
    rows.push_back({v[0], {v[4], v[5], v[6]}, {v[7], v[8], v[9]}});
  }
  return rows;
}

struct Errors {
  double rmse = 0, max = 0;
};

// Position error of the camera footprint against the ground truth at every image stamp.
Errors Ate(const std::vector<DriveFrame>& frames, const std::vector<gtbow::Pose2D>& est) {
  Errors e;
  for (size_t i = 0; i < frames.size(); ++i) {
    const double d = std::hypot(est[i].x - frames[i].truth.x, est[i].y - frames[i].truth.y);
    e.rmse += d * d;
    e.max = std::max(e.max, d);
  }
  e.rmse = std::sqrt(e.rmse / frames.size());
  return e;
}

TEST(Backend, ClosuresCorrectTheOdometryAndAWrongOneIsIgnored) {
  const Drive drive = ReadDrive(g_data + "/drive.bag");
  const auto& frames = drive.frames;
  ASSERT_GT(frames.size(), 100u);
  ASSERT_EQ(drive.statics.size(), 1u) << "drive.bag: one static transform base -> camera";
  for (const auto& f : frames) ASSERT_TRUE(f.odom && f.tf && f.image);
  const gtbow::Pose2D mount = gtbow_ros::FootprintFromTransform(drive.statics[0].transform);

  ros::NodeHandle nh;
  tf2_ros::StaticTransformBroadcaster statics;
  for (const auto& t : drive.statics) statics.sendTransform(t);
  ros::Publisher odom_pub = nh.advertise<nav_msgs::Odometry>("/odom", 1000);
  ros::Publisher tf_pub = nh.advertise<tf2_msgs::TFMessage>("/tf", 1000);
  ros::Publisher img_pub = nh.advertise<sensor_msgs::Image>("/camera/image_raw", 10);
  ros::Publisher loop_pub =
      nh.advertise<ground_texture_bow::LoopClosure>("/localizer/loop_closures", 10);
  Collector<ground_texture_bow::LoopClosure> closures("/localizer/loop_closures", 5000);
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(30);
  while ((img_pub.getNumSubscribers() == 0 || odom_pub.getNumSubscribers() < 3 ||
          loop_pub.getNumSubscribers() < 4) &&
         ros::WallTime::now() < deadline) {
    ros::WallDuration(0.05).sleep();
  }
  ASSERT_GE(odom_pub.getNumSubscribers(), 3u) << "the three backends subscribe to /odom";
  ros::WallDuration(0.5).sleep();

  // Replay: odometry and TF first, then the image; the next only once the localizer is done.
  for (size_t i = 0; i < frames.size(); ++i) {
    odom_pub.publish(frames[i].odom);
    tf_pub.publish(frames[i].tf);
    ros::WallDuration(0.01).sleep();
    img_pub.publish(frames[i].image);
    const ros::WallTime limit = ros::WallTime::now() + ros::WallDuration(10);
    while (ros::WallTime::now() < limit) {
      const auto info = Info("/localizer");
      if (info.images_received >= i + 1 &&
          info.images_processed + info.images_dropped + info.images_rejected >=
              info.images_received) {
        break;
      }
      ros::WallDuration(0.01).sleep();
    }
  }
  const auto info = Info("/localizer");
  EXPECT_EQ(info.images_processed, frames.size());

  // A wrong closure: the camera near the end "seen" 5 mm from where it was a third of the way
  // through, with a confident covariance like the localizer's. Pick a pair far apart in truth.
  const size_t q = frames.size() - 5;
  size_t m = frames.size() / 3;
  for (size_t k = 0; k + 30 < q; ++k) {
    const double d =
        std::hypot(frames[k].truth.x - frames[q].truth.x, frames[k].truth.y - frames[q].truth.y);
    if (d > 0.15 && d < 0.25) {
      m = k;
      break;
    }
  }
  const double true_distance =
      std::hypot(frames[m].truth.x - frames[q].truth.x, frames[m].truth.y - frames[q].truth.y);
  ASSERT_GT(true_distance, 0.1);
  ground_texture_bow::LoopClosure wrong;
  wrong.header = frames[q].image->header;
  wrong.query_id = wrong.match_id = ground_texture_bow::LoopClosure::NO_ID;
  wrong.query_stamp = frames[q].image->header.stamp;
  wrong.match_stamp = frames[m].image->header.stamp;
  wrong.inliers = 40;
  wrong.match_from_query.x = 0.005;
  wrong.covariance = {1e-8, 0, 0, 0, 1e-8, 0, 0, 0, 1e-6};
  wrong.status = ground_texture_bow::LoopClosure::VERIFIED;
  loop_pub.publish(wrong);
  ros::WallDuration(1.0).sleep();

  const size_t real_closures = closures.Get().size() - 1;
  EXPECT_GT(real_closures, 50u) << "the localizer found too few loop closures";

  std::vector<gtbow::Pose2D> odometry;
  for (const auto& f : frames) {
    const auto& p = f.odom->pose.pose;
    odometry.push_back(gtbow::Compose(
        {p.position.x, p.position.y,
         gtbow_ros::YawOf(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)},
        mount));
  }
  const Errors odo = Ate(frames, odometry);
  EXPECT_GT(odo.rmse, 0.005) << "the test drive's odometry should drift by centimetres";

  const fs::path dir = fs::temp_directory_path() / ("gtbow_backend_" + std::to_string(getpid()));
  fs::create_directories(dir);
  std::map<std::string, Errors> ate;
  std::map<std::string, double> fold;  // error of the wrong pair's distance, metres
  for (const std::string node : {"backend", "backend_loss_only", "backend_unprotected"}) {
    ground_texture_bow::SaveTrajectory srv;
    srv.request.path = (dir / (node + ".csv")).string();
    srv = Call("/" + node + "/save_trajectory", srv);
    ASSERT_EQ(srv.response.status.code, Status::OK) << node << ": " << srv.response.status.message;
    EXPECT_EQ(srv.response.closures_received, real_closures + 1) << node;
    const auto rows = ReadTrajectory(srv.request.path);
    ASSERT_EQ(rows.size(), frames.size()) << node;
    std::vector<gtbow::Pose2D> est;
    for (const auto& r : rows) est.push_back(r.camera);
    ate[node] = Ate(frames, est);
    fold[node] = std::abs(std::hypot(est[m].x - est[q].x, est[m].y - est[q].y) - true_distance);
    std::printf(
        "%-20s ATE rmse %.2f mm, max %.2f mm (odometry %.2f, %.2f); wrong pair off by %.2f mm; "
        "%u accepted, %u pending, %u beyond the loss scale\n",
        node.c_str(), 1e3 * ate[node].rmse, 1e3 * ate[node].max, 1e3 * odo.rmse, 1e3 * odo.max,
        1e3 * fold[node], srv.response.closures_accepted, srv.response.closures_pending,
        srv.response.closures_downweighted);
    if (node == "backend") {
      EXPECT_GT(srv.response.closures_accepted, real_closures / 2);
      EXPECT_GE(srv.response.closures_pending, 1u) << "the wrong closure must stay out";
    }
  }
  fs::remove_all(dir);
  for (const std::string node : {"backend", "backend_loss_only"}) {
    EXPECT_LT(ate[node].rmse, 0.25 * odo.rmse) << node;
    EXPECT_LT(ate[node].rmse, 0.004) << node;
    EXPECT_LT(fold[node], 0.005) << node << " folded the trajectory onto the wrong closure";
  }
  // The negative control: without either defence the wrong closure bends the trajectory.
  EXPECT_GT(fold["backend_unprotected"], 3.0 * fold["backend"] + 0.005);
}

}  // namespace
