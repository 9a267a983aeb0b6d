// robot.test (Robot.*): the node on a robot. The mapper learns its scale from camera_info and
// the camera's TF height; the localizer, on a robot whose camera is mounted 15 cm ahead of
// base_link and turned 90 degrees, with wheel odometry (TF odom -> base_link), publishes the
// base's pose (REP-105), holds a fix that disagrees with odometry, relocalises a kidnapped robot,
// republishes map -> odom between fixes, takes amcl's initialpose, and refuses a camera whose
// scale is not the map's. Images that come before the first camera_info wait for it.
#include <opencv2/calib3d.hpp>

#include "rostest_util.h"

namespace {

using namespace rostest_util;

const gtbow::Pose2D kMount{0.15, 0.0, M_PI / 2};  // the camera's footprint in base_link
const std::string kCamera = "robot_camera_optical";

struct MapToOdom {
  ros::Time stamp;
  gtbow::Pose2D pose;
};

// map -> odom as the localizer broadcasts it, in order of arrival.
class MapToOdomCollector {
 public:
  MapToOdomCollector() {
    sub_ = ros::NodeHandle().subscribe<tf2_msgs::TFMessage>(
        "/tf", 1000, [this](const tf2_msgs::TFMessageConstPtr& m) {
          for (const auto& t : m->transforms) {
            if (t.header.frame_id != "map" || t.child_frame_id != "odom") continue;
            const auto& q = t.transform.rotation;
            std::lock_guard<std::mutex> lock(mutex_);
            all_.push_back({t.header.stamp,
                            {t.transform.translation.x, t.transform.translation.y,
                             gtbow_ros::YawOf(q.x, q.y, q.z, q.w)}});
          }
        });
  }
  std::vector<MapToOdom> Get() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return all_;
  }
  // Waits (bounded) until one more message than `after` has come; returns the latest.
  std::optional<MapToOdom> Next(size_t after) const {
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(30);
    while (ros::WallTime::now() < end) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        if (all_.size() > after) return all_.back();
      }
      ros::WallDuration(0.02).sleep();
    }
    return std::nullopt;
  }

 private:
  mutable std::mutex mutex_;
  std::vector<MapToOdom> all_;
  ros::Subscriber sub_;
};

// The day-30 images as the robot sees them: its camera frame, stamps from `t0` (the robot's
// clock, which map -> odom is dated with too), and TF odom -> base_link from the ground truth
// seen through `map_from_odom` (odometry that has drifted by that much).
std::vector<Frame> RobotFrames(const std::vector<Frame>& later, const gtbow::Pose2D& map_from_odom,
                               ros::Time t0) {
  std::vector<Frame> out;
  for (size_t i = 0; i < later.size(); ++i) {
    Frame f = later[i];
    const ros::Time stamp = t0 + ros::Duration(0.25 * static_cast<double>(i));
    auto img = boost::make_shared<sensor_msgs::Image>(*f.image);
    img->header.frame_id = kCamera;
    img->header.stamp = stamp;
    f.image = img;
    auto info = boost::make_shared<sensor_msgs::CameraInfo>(*later[i].info);
    info->header = img->header;
    f.info = info;
    const gtbow::Pose2D base = gtbow::Compose(later[i].truth, gtbow::Inverse(kMount));
    const gtbow::Pose2D odom_base = gtbow::Compose(gtbow::Inverse(map_from_odom), base);
    geometry_msgs::TransformStamped t;
    t.header.stamp = stamp;
    t.header.frame_id = "odom";
    t.child_frame_id = "base_link";
    t.transform.translation.x = odom_base.x;
    t.transform.translation.y = odom_base.y;
    t.transform.rotation = gtbow_ros::QuaternionFromYaw(odom_base.theta);
    auto tf = boost::make_shared<tf2_msgs::TFMessage>();
    tf->transforms.push_back(t);
    f.tf = tf;
    f.truth = base;  // the base's ground truth from here on
    out.push_back(f);
  }
  return out;
}

// The base fixes on ~pose, by stamp.
std::map<ros::Time, gtbow::Pose2D> Fixes(
    const std::vector<geometry_msgs::PoseWithCovarianceStamped>& msgs) {
  std::map<ros::Time, gtbow::Pose2D> out;
  for (const auto& p : msgs) {
    const auto& q = p.pose.pose.orientation;
    out[p.header.stamp] = {p.pose.pose.position.x, p.pose.pose.position.y,
                           gtbow_ros::YawOf(q.x, q.y, q.z, q.w)};
  }
  return out;
}

bool Within(const gtbow::Pose2D& a, const gtbow::Pose2D& b) {
  return PositionErrorMm(a, b) <= 4.8 && HeadingErrorDeg(a, b) <= 1.5;
}

TEST(Robot, BaseFixesFromCameraInfoAndTfHeldWrongFixesAndAKidnappedRobot) {
  // The map, its scale from camera_info (f = 800 px) and the TF height of the camera (0.2 m).
  const auto mapping = ReadBag(g_data + "/mapping.bag");
  ASSERT_TRUE(mapping.front().info) << "the rostest bags carry camera_info";
  Replay(mapping, "/map_camera/image_raw", "/mapper", 4.0);
  const auto mapper = Info("/mapper");
  EXPECT_DOUBLE_EQ(mapper.meters_per_pixel, 0.00025);
  EXPECT_NE(mapper.scale_source.find("camera_info"), std::string::npos) << mapper.scale_source;
  EXPECT_EQ(mapper.images_rejected, 0u) << mapper.last_error;
  // ~autosave_period: within a few periods the file holds every keyframe.
  std::string autosave;
  ASSERT_TRUE(ros::param::get("/mapper/autosave_path", autosave));
  uint64_t saved = 0;
  for (const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(30);
       ros::WallTime::now() < end && saved != mapper.database_size;
       ros::WallDuration(0.1).sleep()) {
    if (fs::exists(autosave)) saved = gtbow::Localizer::ReadMapInfo(autosave).keyframes;
  }
  EXPECT_EQ(saved, mapper.database_size) << autosave;
  fs::remove(autosave);
  // A relative path is refused, with the reason.
  ground_texture_bow::SaveMap relative;
  relative.request.path = "map.gtmap";
  relative = Call("/mapper/save_map", relative);
  EXPECT_EQ(relative.response.status.code, Status::INVALID_ARGUMENT);
  EXPECT_NE(relative.response.status.message.find("not an absolute path"), std::string::npos)
      << relative.response.status.message;
  const fs::path dir = fs::temp_directory_path() / ("gtbow_robot_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  ground_texture_bow::SaveMap save;
  save.request.path = (dir / "map.gtmap").string();
  ASSERT_EQ(Call("/mapper/save_map", save).response.status.code, Status::OK);
  ground_texture_bow::LoadMap load;
  load.request.path = save.request.path;
  ASSERT_EQ(Call("/localizer/load_map", load).response.status.code, Status::OK);
  EXPECT_EQ(Info("/localizer").meters_per_pixel, 0.00025);  // the map's

  // The robot: the camera's mount is static (robot_state_publisher's part).
  tf2_ros::StaticTransformBroadcaster static_tf;
  geometry_msgs::TransformStamped mount;
  mount.header.stamp = ros::Time::now();
  mount.header.frame_id = "base_link";
  mount.child_frame_id = kCamera;
  mount.transform = gtbow_ros::TransformFromFootprint(kMount, 0.2);
  static_tf.sendTransform(mount);
  MapToOdomCollector map_to_odom;
  Collector<geometry_msgs::PoseWithCovarianceStamped> pose_topic("/localizer/pose");
  Collector<geometry_msgs::PoseWithCovarianceStamped> camera_topic("/localizer/camera_pose");
  ASSERT_TRUE(pose_topic.WaitForPublisher());
  ASSERT_TRUE(camera_topic.WaitForPublisher());

  // 1. Day 30 with odometry that has drifted: ~pose is the base, within the protocol's bound.
  const auto later = ReadBag(g_data + "/localization.bag");
  ASSERT_GE(later.size(), 20u);
  const gtbow::Pose2D drift_a{0.4, -0.3, 0.6};
  const auto day30 = RobotFrames(later, drift_a, ros::Time::now());
  Replay(day30, "/robot_camera/image_raw", "/localizer", 4.0);
  auto info = Info("/localizer");
  EXPECT_EQ(info.images_rejected, 0u) << "the camera's scale (camera_info, TF) is the map's";
  EXPECT_EQ(info.fixes_held, 0u) << "every fix agrees with the odometry";
  // Every fix published, on both topics, has come before they are counted (each fix goes out
  // on camera_pose; on pose when the base's transform was found).
  EXPECT_EQ(camera_topic.WaitFor(info.fixes).size(), info.fixes);
  const auto base_fixes = Fixes(pose_topic.WaitFor(info.fixes));
  int good = 0;
  for (const Frame& f : day30) {
    auto it = base_fixes.find(f.image->header.stamp);
    good += it != base_fixes.end() && Within(it->second, f.truth);
  }
  std::printf("robot: %zu base fixes for %zu images, %d within 4.8 mm / 1.5 deg\n",
              base_fixes.size(), day30.size(), good);
  EXPECT_GE(good, static_cast<int>(std::ceil(0.95 * static_cast<double>(day30.size()))));
  // The camera's own fix is 15 cm away from the base's, turned by 90 degrees; its covariance
  // has the floor, the base's the lever arm on top.
  const auto camera_fixes = camera_topic.Get();
  ASSERT_FALSE(camera_fixes.empty());
  const auto& c0 = camera_fixes.front();
  const auto base_fixes_msgs = pose_topic.Get();
  ASSERT_FALSE(base_fixes_msgs.empty());
  const auto& b0 = base_fixes_msgs.front();  // a copy: Get() returns one
  EXPECT_NEAR(std::hypot(c0.pose.pose.position.x - b0.pose.pose.position.x,
                         c0.pose.pose.position.y - b0.pose.pose.position.y),
              0.15, 1e-6);
  EXPECT_GE(c0.pose.covariance[0], 1e-6);
  EXPECT_GE(c0.pose.covariance[35], 3e-6);
  EXPECT_GT(b0.pose.covariance[0] + b0.pose.covariance[7],
            c0.pose.covariance[0] + c0.pose.covariance[7]);

  // 1b. Sequence queries (~sequence_length 3, ~sequence_max_span 0.1 m): the same images to a
  //     localizer that combines each with the two before it through odometry. The first half
  //     of the images follow a path 3 cm apart (combined), the rest are far apart (alone).
  {
    ground_texture_bow::LoadMap seq_load;
    seq_load.request.path = save.request.path;
    ASSERT_EQ(Call("/sequence/load_map", seq_load).response.status.code, Status::OK);
    Collector<geometry_msgs::PoseWithCovarianceStamped> seq_topic("/sequence/pose");
    ASSERT_TRUE(seq_topic.WaitForPublisher());
    const auto frames = RobotFrames(later, drift_a, ros::Time::now());
    Replay(frames, "/seq_camera/image_raw", "/sequence", 4.0);
    const auto seq_info = Info("/sequence");
    EXPECT_EQ(seq_info.images_processed, frames.size());
    EXPECT_GE(seq_info.sequence_queries, 5u) << "consecutive images 3 cm apart were combined";
    EXPECT_LT(seq_info.sequence_queries, frames.size()) << "images far apart are not combined";
    const auto seq_fixes = Fixes(seq_topic.WaitFor(seq_info.fixes));
    int seq_good = 0;
    for (const Frame& f : frames) {
      auto it = seq_fixes.find(f.image->header.stamp);
      seq_good += it != seq_fixes.end() && Within(it->second, f.truth);
    }
    std::printf(
        "sequence: %zu base fixes for %zu images (%lu combined), %d within 4.8 mm / "
        "1.5 deg\n",
        seq_fixes.size(), frames.size(), static_cast<unsigned long>(seq_info.sequence_queries),
        seq_good);
    EXPECT_GE(seq_good, static_cast<int>(std::ceil(0.95 * static_cast<double>(frames.size()))));
  }

  // 1c. Maintenance mode: every published fix adds its view at the fix (the refresh threshold
  //     is out of reach here), the map is saved as in mapping, and a view added gives the fix
  //     of its own image afterwards. Localization mode's map (1.) did not change.
  {
    ground_texture_bow::LoadMap m_load;
    m_load.request.path = save.request.path;
    ASSERT_EQ(Call("/maintainer/load_map", m_load).response.status.code, Status::OK);
    const uint32_t mapped = Info("/maintainer").database_size;
    Collector<geometry_msgs::PoseWithCovarianceStamped> m_topic("/maintainer/pose");
    ASSERT_TRUE(m_topic.WaitForPublisher());
    const auto frames = RobotFrames(later, drift_a, ros::Time::now());
    Replay(frames, "/maint_camera/image_raw", "/maintainer", 4.0);
    const auto m_info = Info("/maintainer");
    const size_t published = m_topic.WaitFor(m_info.fixes).size();
    EXPECT_GE(published, frames.size() - 1);
    // Views of one place retire each other (three per place), the map's keyframes stay.
    EXPECT_GT(m_info.database_size, mapped);
    EXPECT_LE(m_info.database_size, mapped + published);
    EXPECT_EQ(Info("/localizer").database_size, mapped) << "localization mode adds nothing";
    ground_texture_bow::SaveMap m_save;
    m_save.request.path = (dir / "maintained.gtmap").string();
    ASSERT_EQ(Call("/maintainer/save_map", m_save).response.status.code, Status::OK);
    const gtbow::MapFileInfo saved_info = gtbow::Localizer::ReadMapInfo(m_save.request.path);
    // Every view added has its record, retired ones too (ids are not reused).
    EXPECT_GE(saved_info.keyframes, m_info.database_size);
    EXPECT_LE(saved_info.keyframes, mapped + published);
    ground_texture_bow::Localize own;
    own.request.image = *frames.back().image;
    own = Call("/maintainer/localize", own);
    ASSERT_EQ(own.response.status.code, Status::OK) << own.response.status.message;
    EXPECT_GE(own.response.keyframe_id, mapped) << "a maintained view gives the fix";
    std::printf("maintenance: %zu fixes, %u keyframes live of %lu (%u mapped)\n", published,
                m_info.database_size, static_cast<unsigned long>(saved_info.keyframes), mapped);
  }

  // 2. A wrong fix: the image of one place while odometry says the robot is at another, 15 cm
  //    or more away. It is held, and map -> odom does not move.
  size_t far = 1;
  for (size_t i = 1; i < later.size(); ++i) {
    if (PositionErrorMm(later[i].truth, later[0].truth) >
        PositionErrorMm(later[far].truth, later[0].truth))
      far = i;
  }
  ASSERT_GT(PositionErrorMm(later[far].truth, later[0].truth), 150.0);
  auto wrong = RobotFrames({later[far], later[1], later[2]}, drift_a, ros::Time::now());
  {
    auto img = boost::make_shared<sensor_msgs::Image>(*later[0].image);  // place 0 ...
    img->header = wrong[0].image->header;                                // ... at far's odometry
    wrong[0].image = img;
  }
  const auto before_wrong = map_to_odom.Next(map_to_odom.Get().size() - 1);
  ASSERT_TRUE(before_wrong);
  Replay({wrong[0]}, "/robot_camera/image_raw", "/localizer", 4.0);
  EXPECT_EQ(Info("/localizer").fixes_held, 1u);
  const auto after_wrong = map_to_odom.Next(map_to_odom.Get().size());
  ASSERT_TRUE(after_wrong);
  EXPECT_EQ(after_wrong->pose.x, before_wrong->pose.x);
  EXPECT_EQ(after_wrong->pose.y, before_wrong->pose.y);
  EXPECT_EQ(after_wrong->pose.theta, before_wrong->pose.theta);
  EXPECT_EQ(Fixes(pose_topic.Get()).count(wrong[0].image->header.stamp), 0u);
  Replay({wrong[1], wrong[2]}, "/robot_camera/image_raw", "/localizer", 4.0);
  EXPECT_EQ(Info("/localizer").fixes_held, 1u) << "true fixes after it are accepted";

  // 3. Kidnapped: carried 0.3 m and turned 0.8 rad; odometry saw nothing. Relocalised within
  //    10 images, each fix after it right, map -> odom the new one.
  const gtbow::Pose2D drift_b = gtbow::Compose({0.3, 0.1, 0.8}, drift_a);
  const auto carried = RobotFrames(later, drift_b, ros::Time::now());
  const size_t fixes_before = Fixes(pose_topic.Get()).size();
  Replay(carried, "/robot_camera/image_raw", "/localizer", 4.0);
  info = Info("/localizer");
  EXPECT_EQ(info.relocalizations, 1u);
  const auto all_fixes = Fixes(pose_topic.Get());
  EXPECT_GT(all_fixes.size(), fixes_before);
  size_t first = carried.size();
  int carried_good = 0, carried_published = 0;
  for (size_t i = 0; i < carried.size(); ++i) {
    auto it = all_fixes.find(carried[i].image->header.stamp);
    if (it == all_fixes.end()) continue;
    first = std::min(first, i);
    carried_published++;
    carried_good += Within(it->second, carried[i].truth);
  }
  std::printf("kidnapped: first fix at image %zu; %d of %d published fixes right; %llu held\n",
              first, carried_good, carried_published,
              static_cast<unsigned long long>(info.fixes_held));
  EXPECT_LT(first, 10u);
  EXPECT_EQ(carried_good, carried_published) << "no wrong base fix is published";
  const auto now_odom = map_to_odom.Next(map_to_odom.Get().size());
  ASSERT_TRUE(now_odom);
  EXPECT_LT(PositionErrorMm(now_odom->pose, drift_b), 5.0);
  EXPECT_LT(HeadingErrorDeg(now_odom->pose, drift_b), 0.5);

  // 4. No images: map -> odom goes on at ~tf_rate (20 Hz), each dated ahead of the last, over
  //    5 s of its own stamps, with no gap a navigation stack would see as stale.
  const size_t mark = map_to_odom.Get().size();
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(60);
  std::vector<MapToOdom> quiet;
  while (ros::WallTime::now() < end) {
    const auto all = map_to_odom.Get();
    quiet.assign(all.begin() + static_cast<long>(mark), all.end());
    if (quiet.size() >= 2 && (quiet.back().stamp - quiet.front().stamp).toSec() >= 5.0) break;
    ros::WallDuration(0.1).sleep();
  }
  ASSERT_GE(quiet.size(), 2u);
  EXPECT_GE((quiet.back().stamp - quiet.front().stamp).toSec(), 5.0);
  double gap = 0;
  for (size_t i = 1; i < quiet.size(); ++i) {
    gap = std::max(gap, (quiet[i].stamp - quiet[i - 1].stamp).toSec());
    EXPECT_GT(quiet[i].stamp, quiet[i - 1].stamp);
  }
  std::printf("map -> odom without fixes: %zu in %.1f s, largest gap %.2f s\n", quiet.size(),
              (quiet.back().stamp - quiet.front().stamp).toSec(), gap);
  EXPECT_GE(quiet.size(), 50u);  // 5 s at 20 Hz is 100
  EXPECT_LT(gap, 1.0);
  EXPECT_EQ(Info("/localizer").images_received, info.images_received);

  // 5. amcl's initialpose: the base put 0.5 m away sets map -> odom to match.
  ros::Publisher initial = ros::NodeHandle().advertise<geometry_msgs::PoseWithCovarianceStamped>(
      "/initialpose", 1, true);
  const gtbow::Pose2D put = gtbow::Compose(carried.back().truth, {0.5, 0.0, 0.2});
  geometry_msgs::PoseWithCovarianceStamped ip;
  ip.header.frame_id = "map";
  ip.header.stamp = ros::Time::now();
  ip.pose.pose.position.x = put.x;
  ip.pose.pose.position.y = put.y;
  ip.pose.pose.orientation = gtbow_ros::QuaternionFromYaw(put.theta);
  initial.publish(ip);
  const auto& last_tf = carried.back().tf->transforms.at(0).transform;
  const gtbow::Pose2D odom_base{last_tf.translation.x, last_tf.translation.y,
                                gtbow_ros::YawOf(last_tf.rotation.x, last_tf.rotation.y,
                                                 last_tf.rotation.z, last_tf.rotation.w)};
  const gtbow::Pose2D expected = gtbow::Compose(put, gtbow::Inverse(odom_base));
  std::optional<MapToOdom> moved;
  const ros::WallTime until = ros::WallTime::now() + ros::WallDuration(30);
  while (ros::WallTime::now() < until) {
    const auto all = map_to_odom.Get();
    if (!all.empty() && PositionErrorMm(all.back().pose, expected) < 0.01) {
      moved = all.back();
      break;
    }
    ros::WallDuration(0.05).sleep();
  }
  ASSERT_TRUE(moved) << "map -> odom did not follow initialpose";
  EXPECT_LT(HeadingErrorDeg(moved->pose, expected), 1e-4);

  // 6. A camera whose focal length is 10% longer than the map's scale allows: refused, counted.
  const uint64_t rejected = Info("/localizer").images_rejected;
  auto zoomed = RobotFrames({later[3], later[4]}, drift_a, ros::Time::now());
  for (Frame& f : zoomed) {
    auto i = boost::make_shared<sensor_msgs::CameraInfo>(*f.info);
    i->K[0] *= 1.1;
    i->K[4] *= 1.1;
    f.info = i;
  }
  Replay(zoomed, "/robot_camera/image_raw", "/localizer", 4.0);
  EXPECT_EQ(Info("/localizer").images_rejected, rejected + 2);
  std::error_code ec;
  fs::remove_all(dir, ec);
}

// The pinhole image seen through a lens with distortion D (plumb_bob): each pixel of the
// distorted image takes the pinhole image at its undistorted position.
sensor_msgs::ImageConstPtr Distort(const sensor_msgs::Image& pinhole, const cv::Matx33d& k,
                                   const std::vector<double>& d) {
  const cv::Mat src = cv_bridge::toCvCopy(pinhole, "mono8")->image;
  std::vector<cv::Point2f> pixels;
  for (int v = 0; v < src.rows; ++v)
    for (int u = 0; u < src.cols; ++u)
      pixels.emplace_back(static_cast<float>(u), static_cast<float>(v));
  std::vector<cv::Point2f> undistorted;
  cv::undistortPoints(pixels, undistorted, k, d, cv::noArray(), k,
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-6));
  cv::Mat mx(src.size(), CV_32FC1), my(src.size(), CV_32FC1);
  for (int v = 0, i = 0; v < src.rows; ++v) {
    for (int u = 0; u < src.cols; ++u, ++i) {
      mx.at<float>(v, u) = undistorted[static_cast<size_t>(i)].x;
      my.at<float>(v, u) = undistorted[static_cast<size_t>(i)].y;
    }
  }
  cv::Mat out;
  cv::remap(src, out, mx, my, cv::INTER_LINEAR, cv::BORDER_CONSTANT, 0);
  auto msg = cv_bridge::CvImage(pinhole.header, "mono8", out).toImageMsg();
  return msg;
}

// A wide-angle lens: a focal length of 400 px (77 degrees across the 640 px, 10 cm above the
// floor, the same 0.25 mm per pixel) with k1 = -0.45, k2 = 0.15. With the distortion in
// camera_info the node rectifies and localizes as with the pinhole camera; without
// rectification (the negative control) it does not.
TEST(Robot, ADistortingLensIsRectifiedFromCameraInfo) {
  if (Info("/mapper").database_size == 0) {
    Replay(ReadBag(g_data + "/mapping.bag"), "/map_camera/image_raw", "/mapper", 4.0);
  }
  const fs::path dir = fs::temp_directory_path() / ("gtbow_lens_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  ground_texture_bow::SaveMap save;
  save.request.path = (dir / "map.gtmap").string();
  ASSERT_EQ(Call("/mapper/save_map", save).response.status.code, Status::OK);
  for (const std::string node : {"/rectifying", "/unrectified"}) {
    ground_texture_bow::LoadMap load;
    load.request.path = save.request.path;
    ASSERT_EQ(Call(node + "/load_map", load).response.status.code, Status::OK) << node;
  }
  tf2_ros::StaticTransformBroadcaster static_tf;
  geometry_msgs::TransformStamped mount;
  mount.header.stamp = ros::Time::now();
  mount.header.frame_id = "base_link";
  mount.child_frame_id = "lens_camera_optical";
  mount.transform = gtbow_ros::TransformFromFootprint(kMount, 0.1);
  static_tf.sendTransform(mount);

  const auto later = ReadBag(g_data + "/localization.bag");
  auto frames = RobotFrames(later, {0.4, -0.3, 0.6}, ros::Time::now());
  const std::vector<double> d = {-0.45, 0.15, 0.0, 0.0, 0.0};
  for (Frame& f : frames) {
    auto info = boost::make_shared<sensor_msgs::CameraInfo>(*f.info);
    info->K[0] = info->K[4] = 400.0;
    info->P[0] = info->P[5] = 400.0;
    info->D = d;
    info->header.frame_id = mount.child_frame_id;
    const auto& k = info->K;
    const cv::Matx33d km(k[0], k[1], k[2], k[3], k[4], k[5], k[6], k[7], k[8]);
    auto img = boost::make_shared<sensor_msgs::Image>(*Distort(*f.image, km, d));
    img->header.frame_id = mount.child_frame_id;
    f.image = img;
    f.info = info;
  }
  Collector<geometry_msgs::PoseWithCovarianceStamped> rect_topic("/rectifying/pose");
  Collector<geometry_msgs::PoseWithCovarianceStamped> raw_topic("/unrectified/pose");
  ASSERT_TRUE(rect_topic.WaitForPublisher());
  ASSERT_TRUE(raw_topic.WaitForPublisher());
  Replay(frames, "/rect_camera/image_raw", "/rectifying", 4.0);
  Replay(frames, "/raw_camera/image_raw", "/unrectified", 4.0);
  rect_topic.WaitFor(Info("/rectifying").fixes);
  raw_topic.WaitFor(Info("/unrectified").fixes);
  auto count = [&](const std::vector<geometry_msgs::PoseWithCovarianceStamped>& msgs) {
    const auto fixes = Fixes(msgs);
    int good = 0;
    for (const Frame& f : frames) {
      auto it = fixes.find(f.image->header.stamp);
      good += it != fixes.end() && Within(it->second, f.truth);
    }
    return good;
  };
  const int rect = count(rect_topic.Get()), raw = count(raw_topic.Get());
  std::printf("lens k1 %.2f k2 %.2f: %d of %zu right with rectification, %d without\n", d[0], d[1],
              rect, frames.size(), raw);
  EXPECT_GE(rect, static_cast<int>(std::ceil(0.95 * static_cast<double>(frames.size()))));
  EXPECT_LT(raw, static_cast<int>(std::ceil(0.95 * static_cast<double>(frames.size()))))
      << "the negative control: without rectification the distortion must show";
  EXPECT_EQ(Info("/rectifying").images_rejected, 0u);
  std::error_code ec;
  fs::remove_all(dir, ec);
}

// A camera whose first camera_info comes after its first images (the two travel on two
// connections; a driver may also start its camera_info late), on a node that takes its scale from
// camera_info: the image waits instead of being refused, and the node says what it waits for
// (get_info's last_error, a WARN on /diagnostics); a newer image replaces the waiting one (a
// drop); the first camera_info releases it, and the scale comes from it.
TEST(Robot, ImagesWaitForTheFirstCameraInfo) {
  const auto mapping = ReadBag(g_data + "/mapping.bag");
  ASSERT_TRUE(mapping[0].info && mapping[0].tf && mapping[1].tf);
  ros::NodeHandle nh;
  ros::Publisher img_pub = nh.advertise<sensor_msgs::Image>("/wait_camera/image_raw", 10);
  ros::Publisher info_pub = nh.advertise<sensor_msgs::CameraInfo>("/wait_camera/camera_info", 10);
  ros::Publisher tf_pub = nh.advertise<tf2_msgs::TFMessage>("/tf", 10);
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics("/diagnostics", 1000);
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(30);
  while ((img_pub.getNumSubscribers() == 0 || info_pub.getNumSubscribers() == 0) &&
         ros::WallTime::now() < deadline) {
    ros::WallDuration(0.05).sleep();
  }
  ASSERT_GT(img_pub.getNumSubscribers(), 0u);
  ASSERT_GT(info_pub.getNumSubscribers(), 0u);
  ros::WallDuration(0.5).sleep();
  tf_pub.publish(mapping[0].tf);
  img_pub.publish(mapping[0].image);
  auto info = WaitForInfo("/waiting", [](const auto& i) { return i.images_received >= 1; });
  ASSERT_EQ(info.images_received, 1u);
  EXPECT_EQ(info.images_processed, 0u);
  EXPECT_EQ(info.images_rejected, 0u) << info.last_error;
  EXPECT_EQ(info.meters_per_pixel, 0.0);
  EXPECT_NE(info.last_error.find("waiting for camera_info on /wait_camera/camera_info"),
            std::string::npos)
      << info.last_error;

  tf_pub.publish(mapping[1].tf);
  img_pub.publish(mapping[1].image);
  info = WaitForInfo("/waiting", [](const auto& i) { return i.images_dropped >= 1; });
  EXPECT_EQ(info.images_received, 2u);
  EXPECT_EQ(info.images_dropped, 1u) << "the newer image replaces the waiting one";
  EXPECT_EQ(info.images_processed, 0u);

  NodeStatus st = WaitForStatus(
      diagnostics, "/waiting",
      [](const NodeStatus& s) {
        return s.status.message.find("waiting for camera_info") != std::string::npos;
      },
      30);
  ASSERT_TRUE(st.seen) << "no /diagnostics status from /waiting";
  EXPECT_EQ(st.status.level, diagnostic_msgs::DiagnosticStatus::WARN);
  EXPECT_NE(st.status.message.find("waiting for camera_info on /wait_camera/camera_info"),
            std::string::npos)
      << st.status.message;

  info_pub.publish(mapping[1].info);
  info = WaitForInfo("/waiting", [](const auto& i) { return i.images_processed >= 1; });
  EXPECT_EQ(info.images_processed, 1u) << "the first camera_info releases the waiting image";
  EXPECT_EQ(info.images_dropped, 1u);
  EXPECT_EQ(info.images_rejected, 0u) << info.last_error;
  EXPECT_DOUBLE_EQ(info.meters_per_pixel, 0.00025);
  EXPECT_NE(info.scale_source.find("camera_info"), std::string::npos) << info.scale_source;
}

}  // namespace
