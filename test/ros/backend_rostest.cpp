// Backend.*: the pose-graph backend fed by the localizer on a small synthetic drive
// (test/ros/backend.test, data from test/ros/make_test_data.sh: drive.bag holds images, wheel
// odometry with drift, TF odom -> base_link -> camera and the ground truth). The localizer
// maps the drive in the odometry frame; four backends read its loop closures. Checked: the
// backend's trajectory is much closer to the ground truth than the odometry, and a wrong loop
// closure injected on the localizer's topic in the middle of a revisit stays out of the graph
// (its own state, by its stamps, after every later closure) and does not bend it, with the
// consistency check alone (no robust loss) as well as with the defaults; with neither defence
// it is accepted and bends the trajectory (the negative control showing the check matters).
#include <unistd.h>

#include <optional>

#include <nav_msgs/Odometry.h>

#include "ground_texture_bow/SaveTrajectory.h"
#include "ground_texture_bow/eval/dataset.h"
#include "rostest_util.h"

namespace {

using namespace rostest_util;
using ground_texture_bow::SaveTrajectory;

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

// A loop closure is wrong beyond these (as scripts/closure_precision.py counts).
constexpr double kWrongMm = 4.8, kWrongDeg = 1.5;
// The bounds a protected backend meets on this drive, and the fold it must stay within: the
// error of the injected wrong pair's distance.
constexpr double kMaxAte = 0.004, kMaxFold = 0.005;

// A closure's error against the ground truth (4.8 mm, 1.5 degrees: wrong beyond).
struct ClosureError {
  double position_mm, heading_deg;
  bool wrong() const { return position_mm > kWrongMm || heading_deg > kWrongDeg; }
};
ClosureError ErrorOf(const ground_texture_bow::LoopClosure& c,
                     const std::vector<gtbow::Pose2D>& truth,
                     const std::map<ros::Time, size_t>& index_of) {
  const gtbow::Pose2D& query = truth.at(index_of.at(c.query_stamp));
  const gtbow::Pose2D est = Compose(truth.at(index_of.at(c.match_stamp)), c.match_from_query);
  return {PositionErrorMm(est, query), HeadingErrorDeg(est, query)};
}

std::string StateName(uint8_t s) {
  switch (s) {
    case SaveTrajectory::Response::NOT_IN_GRAPH:
      return "not in the graph";
    case SaveTrajectory::Response::PENDING:
      return "pending";
    case SaveTrajectory::Response::ACCEPTED:
      return "accepted";
    case SaveTrajectory::Response::REJECTED:
      return "rejected";
  }
  return "state " + std::to_string(s);
}

TEST(Backend, ClosuresCorrectTheOdometryAndAWrongOneIsIgnored) {
  const Drive drive = ReadDrive(g_data + "/drive.bag");
  const auto& frames = drive.frames;
  ASSERT_GT(frames.size(), 100u);
  ASSERT_EQ(drive.statics.size(), 1u) << "drive.bag: one static transform base -> camera";
  for (const auto& f : frames) ASSERT_TRUE(f.odom && f.tf && f.image);
  const gtbow::Pose2D mount = gtbow_ros::FootprintFromTransform(drive.statics[0].transform);

  // The bag's image stamps are start + index / rate, as the scripts read them back.
  std::map<ros::Time, size_t> index_of;
  for (size_t i = 0; i < frames.size(); ++i) index_of[frames[i].image->header.stamp] = i;
  const double start = frames[0].image->header.stamp.toSec();
  const double rate = 1.0 / (frames[1].image->header.stamp.toSec() - start);
  for (size_t i = 0; i < frames.size(); ++i) {
    ASSERT_NEAR((frames[i].image->header.stamp.toSec() - start) * rate, double(i), 1e-4);
  }
  // Metres driven (truth) up to each image: the consistency window is in metres of driving.
  std::vector<double> driven(frames.size(), 0.0);
  for (size_t i = 1; i < frames.size(); ++i) {
    driven[i] = driven[i - 1] + std::hypot(frames[i].truth.x - frames[i - 1].truth.x,
                                           frames[i].truth.y - frames[i - 1].truth.y);
  }

  ros::NodeHandle nh;
  tf2_ros::StaticTransformBroadcaster statics;
  for (const auto& t : drive.statics) statics.sendTransform(t);
  ros::Publisher odom_pub = nh.advertise<nav_msgs::Odometry>("/odom", 1000);
  ros::Publisher tf_pub = nh.advertise<tf2_msgs::TFMessage>("/tf", 1000);
  ros::Publisher img_pub = nh.advertise<sensor_msgs::Image>("/camera/image_raw", 10);
  ros::Publisher loop_pub =
      nh.advertise<ground_texture_bow::LoopClosure>("/localizer/loop_closures", 10);
  Collector<ground_texture_bow::LoopClosure> closures("/localizer/loop_closures", 5000);
  const std::vector<std::string> nodes = {"backend", "backend_loss_only", "backend_check_only",
                                          "backend_unprotected"};
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(30);
  while ((img_pub.getNumSubscribers() == 0 || odom_pub.getNumSubscribers() < nodes.size() ||
          loop_pub.getNumSubscribers() < nodes.size() + 1) &&
         ros::WallTime::now() < deadline) {
    ros::WallDuration(0.05).sleep();
  }
  ASSERT_GE(odom_pub.getNumSubscribers(), nodes.size()) << "the backends subscribe to /odom";
  ros::WallDuration(0.5).sleep();

  // A wrong closure, injected in the middle of a revisit so that the true closures after it
  // could confirm it: the localizer's first closure past the drive's middle with its match
  // moved 30 images (about 0.3 m of driving, within the 0.5 m consistency window) on, towards
  // the matches of the closures to come. It claims the query is as close to that image as to
  // the true match, with the localizer's confident covariance.
  constexpr size_t kShift = 30;
  std::optional<ground_texture_bow::LoopClosure> wrong;
  auto inject = [&]() {
    std::optional<ground_texture_bow::LoopClosure> base;
    size_t base_query = 0;
    for (const auto& c : closures.Get()) {
      const size_t q = index_of.at(c.query_stamp), m = index_of.at(c.match_stamp);
      if (q >= frames.size() / 2 && m + kShift + 50 <= q && (!base || q < base_query)) {
        base = c;
        base_query = q;
      }
    }
    if (!base) return;
    wrong = *base;
    wrong->match_stamp = frames[index_of.at(base->match_stamp) + kShift].image->header.stamp;
    wrong->query_id = wrong->match_id = ground_texture_bow::LoopClosure::NO_ID;
    wrong->covariance = {1e-8, 0, 0, 0, 1e-8, 0, 0, 0, 1e-6};
    loop_pub.publish(*wrong);
  };

  // Replay: odometry and TF first, then the image; the next only once the localizer is done.
  // Polled through one persistent connection: a busy machine sometimes refuses one of the many
  // connections a call each would open, and a failed poll is only retried.
  ASSERT_TRUE(ros::service::waitForService("/localizer/get_info", ros::Duration(30)));
  ros::ServiceClient info_client =
      nh.serviceClient<ground_texture_bow::GetInfo>("/localizer/get_info", true);
  for (size_t i = 0; i < frames.size(); ++i) {
    odom_pub.publish(frames[i].odom);
    tf_pub.publish(frames[i].tf);
    ros::WallDuration(0.01).sleep();
    img_pub.publish(frames[i].image);
    const ros::WallTime limit = ros::WallTime::now() + ros::WallDuration(10);
    while (ros::WallTime::now() < limit) {
      ground_texture_bow::GetInfo srv;
      if (!info_client.isValid()) {
        info_client = nh.serviceClient<ground_texture_bow::GetInfo>("/localizer/get_info", true);
      }
      if (!info_client.call(srv)) {
        ros::WallDuration(0.05).sleep();
        continue;
      }
      const auto& info = srv.response;
      if (info.images_received >= i + 1 &&
          info.images_processed + info.images_dropped + info.images_rejected >=
              info.images_received) {
        break;
      }
      ros::WallDuration(0.01).sleep();
    }
    if (!wrong) inject();
  }
  const auto info = Info("/localizer");
  EXPECT_EQ(info.images_processed, frames.size());
  ros::WallDuration(1.0).sleep();
  ASSERT_TRUE(wrong) << "no closure past the drive's middle to build the wrong one from";
  const size_t q = index_of.at(wrong->query_stamp), m = index_of.at(wrong->match_stamp);
  const double true_distance =
      std::hypot(frames[m].truth.x - frames[q].truth.x, frames[m].truth.y - frames[q].truth.y);
  ASSERT_GT(true_distance, 0.1);

  const auto all = closures.Get();
  const size_t real_closures = all.size() - 1;
  EXPECT_GT(real_closures, 50u) << "the localizer found too few loop closures";
  // The true closures published after the wrong one with both ends in its consistency window:
  // each was checked against it (the test's premise).
  size_t later_neighbours = 0, wrong_closures = 0;
  bool after = false;
  std::vector<gtbow::Pose2D> truth;
  for (const auto& f : frames) truth.push_back(f.truth);
  for (const auto& c : all) {
    const size_t cq = index_of.at(c.query_stamp), cm = index_of.at(c.match_stamp);
    wrong_closures += ErrorOf(c, truth, index_of).wrong();
    if (c.query_stamp == wrong->query_stamp && c.match_stamp == wrong->match_stamp) {
      after = true;
    } else if (after && std::abs(driven[cq] - driven[q]) < 0.45 &&
               std::abs(driven[cm] - driven[m]) < 0.45) {
      ++later_neighbours;
    }
  }
  std::printf(
      "wrong closure: query image %zu, match image %zu (%.0f mm apart, claimed %.0f mm); "
      "%zu true closures after it with both ends within 0.45 m of driving\n",
      q, m, 1e3 * true_distance,
      1e3 * std::hypot(wrong->match_from_query.x, wrong->match_from_query.y), later_neighbours);
  EXPECT_GE(later_neighbours, 10u) << "too few true closures after the wrong one could confirm it";
  EXPECT_GE(wrong_closures, 1u) << "the injected closure is wrong";

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
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::map<std::string, Errors> ate;
  std::map<std::string, double> fold;  // error of the wrong pair's distance, metres
  std::map<std::string, uint8_t> wrong_state;
  for (const std::string& node : nodes) {
    SaveTrajectory srv;
    srv.request.path = (dir / (node + ".csv")).string();
    // The wrong closure's state first, then every closure received (the wrong one again).
    srv.request.closure_query_stamps.push_back(wrong->query_stamp);
    srv.request.closure_match_stamps.push_back(wrong->match_stamp);
    for (const auto& c : all) {
      srv.request.closure_query_stamps.push_back(c.query_stamp);
      srv.request.closure_match_stamps.push_back(c.match_stamp);
    }
    srv = Call("/" + node + "/save_trajectory", srv);
    ASSERT_EQ(srv.response.status.code, Status::OK) << node << ": " << srv.response.status.message;
    EXPECT_EQ(srv.response.closures_received, real_closures + 1) << node;
    ASSERT_EQ(srv.response.closure_states.size(), all.size() + 1) << node;
    wrong_state[node] = srv.response.closure_states[0];
    // The reply is per closure: its states add up to the graph's counts.
    const auto& st = srv.response.closure_states;
    EXPECT_EQ(std::count(st.begin() + 1, st.end(), SaveTrajectory::Response::ACCEPTED),
              srv.response.closures_accepted)
        << node;
    EXPECT_EQ(std::count(st.begin() + 1, st.end(), SaveTrajectory::Response::PENDING),
              srv.response.closures_pending)
        << node;
    const auto rows = ReadTrajectory(srv.request.path);
    ASSERT_EQ(rows.size(), frames.size()) << node;
    std::vector<gtbow::Pose2D> est;
    for (const auto& r : rows) est.push_back(r.camera);
    ate[node] = Ate(frames, est);
    fold[node] = std::abs(std::hypot(est[m].x - est[q].x, est[m].y - est[q].y) - true_distance);
    std::printf(
        "%-20s ATE rmse %.2f mm, max %.2f mm (odometry %.2f, %.2f); wrong closure %s, its pair "
        "off by %.2f mm; %u accepted, %u pending, %u beyond the loss scale\n",
        node.c_str(), 1e3 * ate[node].rmse, 1e3 * ate[node].max, 1e3 * odo.rmse, 1e3 * odo.max,
        StateName(wrong_state[node]).c_str(), 1e3 * fold[node], srv.response.closures_accepted,
        srv.response.closures_pending, srv.response.closures_downweighted);
    EXPECT_GT(srv.response.closures_accepted, real_closures / 2) << node;
  }
  // A closure nobody sent (the wrong one's stamps swapped) is not in the graph; stamp lists of
  // different lengths are refused.
  SaveTrajectory ask;
  ask.request.closure_query_stamps = {wrong->match_stamp};
  ask.request.closure_match_stamps = {wrong->query_stamp};
  ask = Call("/backend/save_trajectory", ask);
  EXPECT_EQ(ask.response.status.code, Status::OK) << ask.response.status.message;
  ASSERT_EQ(ask.response.closure_states.size(), 1u);
  EXPECT_EQ(ask.response.closure_states[0], SaveTrajectory::Response::NOT_IN_GRAPH);
  ask.request.closure_match_stamps.clear();
  ask = Call("/backend/save_trajectory", ask);
  EXPECT_EQ(ask.response.status.code, Status::INVALID_ARGUMENT) << ask.response.status.message;
  // The consistency check keeps the wrong closure itself out (after every later closure and
  // the final optimisation), with the Cauchy loss and without any loss.
  for (const std::string node : {"backend", "backend_check_only"}) {
    EXPECT_EQ(wrong_state[node], SaveTrajectory::Response::PENDING)
        << node << ": the wrong closure is " << StateName(wrong_state[node]);
  }
  // Without the check it is in the graph: the loss alone must hold it.
  for (const std::string node : {"backend_loss_only", "backend_unprotected"}) {
    EXPECT_EQ(wrong_state[node], SaveTrajectory::Response::ACCEPTED)
        << node << ": the wrong closure is " << StateName(wrong_state[node]);
  }
  for (const std::string node : {"backend", "backend_loss_only", "backend_check_only"}) {
    EXPECT_LT(ate[node].rmse, 0.25 * odo.rmse) << node;
    EXPECT_LT(ate[node].rmse, kMaxAte) << node;
    EXPECT_LT(fold[node], kMaxFold) << node << " folded the trajectory onto the wrong closure";
  }
  // The negative control (the check-only backend with the check off): the wrong closure bends
  // the trajectory beyond the bound.
  EXPECT_GT(fold["backend_unprotected"], 2 * kMaxFold);
  EXPECT_GT(fold["backend_unprotected"], 3.0 * fold["backend_check_only"] + kMaxFold);

  fs::remove_all(dir);
}

}  // namespace
