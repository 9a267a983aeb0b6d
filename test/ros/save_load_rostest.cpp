// localization.test (SaveLoad.*): a saved map loads into a fresh node in localization mode.
#include "rostest_util.h"

namespace {

using namespace rostest_util;

TEST(SaveLoad, AFreshNodeLoadsTheMapAnswersAlikeAndLocalizesALaterDay) {
  const auto mapping = ReadBag(g_data + "/mapping.bag");
  Replay(mapping, "/map_camera/image_raw", "/mapper", 4.0);
  // The mapper's answers to a later day's images, recorded before the save: after it, the
  // mapper reads the file it wrote (a save swaps the map over to it), so a comparison of the
  // two nodes then would compare the file with itself.
  const auto later = ReadBag(g_data + "/localization.bag");
  auto ask = [](const std::string& node, const Frame& f) {
    ground_texture_bow::QueryCandidates q;
    q.request.image = *f.image;
    q.request.k = 5;
    q.request.verify = true;
    const auto r = Call(node + "/query_candidates", q).response;
    EXPECT_EQ(r.status.code, Status::OK) << node << ": " << r.status.message;
    return r.candidates;
  };
  std::vector<std::vector<ground_texture_bow::Candidate>> before;
  for (const Frame& f : later) {
    before.push_back(ask("/mapper", f));
    ASSERT_FALSE(before.back().empty());
  }

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

  // The answers of the map in memory before the save, from the fresh node that loaded the
  // file and from the mapper that now reads it: every field of every candidate (id, stamp,
  // score, pose, verification, relative pose, inliers, covariance, reason).
  for (size_t i = 0; i < later.size(); ++i) {
    for (const std::string node : {"/localizer", "/mapper"}) {
      const auto after = ask(node, later[i]);
      ASSERT_EQ(after.size(), before[i].size()) << node << ", image " << i;
      for (size_t k = 0; k < after.size(); ++k) {
        EXPECT_TRUE(after[k] == before[i][k]) << node << ", image " << i << ", before the save:\n"
                                              << before[i][k] << "after:\n"
                                              << after[k];
      }
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
  ASSERT_TRUE(fix_topic.WaitForPublisher());
  ASSERT_TRUE(debug_topic.WaitForPublisher());
  Replay(later_robot2, "/loc_camera/image_raw", "/localizer", 4.0);
  const auto info = Info("/localizer");  // at once: `localized` means a fix within 2 s
  std::map<ros::Time, gtbow::Pose2D> fixes;
  for (const auto& p : fix_topic.WaitFor(info.fixes)) {
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
    good +=
        PositionErrorMm(it->second, f.truth) <= 4.8 && HeadingErrorDeg(it->second, f.truth) <= 1.5;
  }
  std::printf("localization: %zu fixes for %zu images, %d within 4.8 mm / 1.5 deg\n", fixes.size(),
              later.size(), good);
  EXPECT_GE(good, static_cast<int>(later.size() * 9 / 10)) << good << " of " << later.size();
  int overlays_with_matches = 0;
  for (const auto& img : debug_topic.WaitFor(info.debug_images)) {
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
  // map -> odom -> camera reproduces the last fix (the latest map -> odom: it is republished at
  // ~tf_rate, dated ahead of now as amcl's).
  ASSERT_FALSE(fixes.empty());
  const auto& fix = fixes.rbegin()->second;
  const auto t =
      tf_buffer.lookupTransform("map", odom_cam.child_frame_id, ros::Time(0), ros::Duration(2));
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

}  // namespace
