// services.test (Services.*): external mode, compressed images, the map services.
#include "rostest_util.h"

namespace {

using namespace rostest_util;

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
  ros::Publisher pub =
      nh.advertise<sensor_msgs::CompressedImage>("/camera/image_raw/compressed", 10);
  const auto mapping = ReadBag(g_data + "/mapping.bag");
  EXPECT_EQ(Info("/localizer").mode, "external");
  // ~preset is empty here: the documented default applies.
  const std::string preset = Info("/localizer").preset;
  EXPECT_EQ(fs::path(preset).filename(), "high_accuracy.yaml") << preset;

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
  EXPECT_EQ(Call("/localizer/add_keyframe", nan_pose).response.status.code,
            Status::INVALID_ARGUMENT);

  // Compressed images in: ranked candidates out, nothing inserted by the node itself.
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(20);
  while (pub.getNumSubscribers() == 0 && ros::WallTime::now() < deadline)
    ros::WallDuration(0.05).sleep();
  ASSERT_GT(pub.getNumSubscribers(), 0u);
  ros::WallDuration(0.5).sleep();  // the connection is up on both sides
  // Each image only once the node has dealt with the one before (none is replaced waiting).
  const uint64_t first_received = Info("/localizer").images_received;
  for (size_t i : {3u, 7u}) {
    pub.publish(Compress(*mapping[i].image));
    WaitUntilHandled("/localizer", first_received + (i == 3u ? 1 : 2));
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
  EXPECT_EQ(info.images_processed + info.images_dropped + info.images_rejected,
            info.images_received);
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
    const gtbow::Pose2D fix{
        p.position.x, p.position.y,
        gtbow_ros::YawOf(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)};
    within += PositionErrorMm(fix, f.truth) <= 4.8 && HeadingErrorDeg(fix, f.truth) <= 1.5;
  }
  std::printf(
      "~localize, day-30 images over the map and off its keyframes: %d, within tolerance %d\n",
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
  const auto before_info = Info("/localizer");
  const uint64_t before_mapping = before_info.images_processed;
  for (int k = 0; k < 10; ++k) {
    sensor_msgs::CompressedImage c = Compress(*mapping[k].image);
    c.header.frame_id = "camera_without_tf";
    pub.publish(c);
    WaitUntilHandled("/localizer", before_info.images_received + k + 1);
  }
  const ros::WallTime mapped = ros::WallTime::now() + ros::WallDuration(10);
  while (Info("/localizer").images_processed < before_mapping + 10 &&
         ros::WallTime::now() < mapped) {
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
