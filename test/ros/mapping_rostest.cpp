// mapping.test (Mapping.*): the nodelet maps a replayed run; revisits, loop closures, overlays,
// markers.
#include "rostest_util.h"

namespace {

using namespace rostest_util;

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
  Replay(std::vector<Frame>(mapping.begin() + 5, mapping.end()), "/camera/image_raw", "/localizer",
         4.0);
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
  std::printf(
      "mapping: %u keyframes from %zu images; revisits: %d of %zu right, %d verified within "
      "4.8 mm / 1.5 deg\n",
      info.database_size, mapping.size(), right, revisits.size(), accurate);
  EXPECT_GE(right, static_cast<int>(revisits.size() * 9 / 10))
      << right << " of " << revisits.size();
  EXPECT_GE(accurate, static_cast<int>(revisits.size() * 9 / 10))
      << accurate << " of " << revisits.size();

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
  std::printf("loop closures: %zu, %d consistent with the ground truth\n", closures.size(),
              consistent);
  // A SLAM backend takes a verified loop closure as a fact: every one must agree with the truth.
  EXPECT_EQ(consistent, static_cast<int>(closures.size()));

  // RViz markers: one footprint (4 segments) per posed keyframe, one edge per loop closure.
  visualization_msgs::MarkerArrayConstPtr markers =
      ros::topic::waitForMessage<visualization_msgs::MarkerArray>("/localizer/markers",
                                                                  ros::Duration(5));
  ASSERT_TRUE(markers != nullptr);
  ASSERT_EQ(markers->markers.size(), 2u);
  EXPECT_EQ(markers->markers[0].header.frame_id, "map");
  EXPECT_EQ(markers->markers[0].points.size(), 8u * info.database_size);
  EXPECT_EQ(markers->markers[1].points.size(), 2u * closures.size());
}

}  // namespace
