// mapping.test (Mapping.*): the nodelet maps a replayed run; revisits, loop closures, overlays,
// markers; temporal consistency through a second nodelet on the same images.
#include <diagnostic_msgs/DiagnosticArray.h>

#include "rostest_util.h"

namespace {

using namespace rostest_util;

// ~temporal_consistency 3 through the node: each loop closure it publishes comes after two
// processed images in a row that also verified a candidate, every other image that verified
// one is held and counted in /diagnostics ("loop closures held"), and the first image of each
// run is held. A node that ignored the parameter would publish a closure for every image that
// verified, and hold none.
void ExpectTemporalConsistency(const std::string& node,
                               const std::vector<ground_texture_bow::CandidateList>& lists,
                               const std::vector<ground_texture_bow::LoopClosure>& closures,
                               const Collector<diagnostic_msgs::DiagnosticArray>& diagnostics) {
  const auto info = Info(node);
  ASSERT_EQ(lists.size(), info.images_processed) << "a candidate list per processed image";
  std::map<ros::Time, size_t> index;
  std::vector<bool> verified;
  for (const auto& l : lists) {
    index[l.header.stamp] = verified.size();
    bool any = false;
    for (const auto& c : l.candidates) any |= c.verified;
    verified.push_back(any);
  }
  int published_after_run = 0;
  for (const auto& lc : closures) {
    ASSERT_EQ(index.count(lc.header.stamp), 1u);
    const size_t i = index.at(lc.header.stamp);
    ASSERT_TRUE(verified[i]);
    EXPECT_TRUE(i >= 2 && verified[i - 1] && verified[i - 2])
        << "a closure at image " << i << " without two verified images before it";
    published_after_run += i >= 2 && verified[i - 1] && verified[i - 2];
  }
  const int with_verified = static_cast<int>(std::count(verified.begin(), verified.end(), true));
  // The counter, from a /diagnostics status sent after the last image was processed.
  auto after_replay = [&](const NodeStatus& st) {
    return StatusValue(st, "images processed") == static_cast<double>(info.images_processed);
  };
  const NodeStatus st = WaitForStatus(diagnostics, node, after_replay, 30);
  const double held =
      after_replay(st) ? StatusValue(st, "loop closures held (temporal consistency)") : -1;
  std::printf(
      "%s: %zu images processed, %d verified a candidate, %zu closures published, %.0f "
      "held\n",
      node.c_str(), lists.size(), with_verified, closures.size(), held);
  if (held < 0) {
    std::set<std::string> names;
    const auto arrays = diagnostics.Get();
    for (const auto& a : arrays) {
      for (const auto& s : a.status) names.insert(s.name);
    }
    std::string seen;
    for (const auto& n : names) seen += " '" + n + "'";
    FAIL() << "no /diagnostics status of " << node << " after the replay (" << arrays.size()
           << " messages; statuses:" << seen << "; images processed "
           << StatusValue(st, "images processed") << " against " << info.images_processed << ")";
  }
  EXPECT_GE(closures.size(), 1u);
  EXPECT_EQ(info.loop_closures, closures.size());
  EXPECT_EQ(static_cast<int>(closures.size()) + static_cast<int>(held), with_verified);
  EXPECT_GE(held, 2) << "the first two images of a run are held";
  EXPECT_EQ(published_after_run, static_cast<int>(closures.size()));
}

TEST(Mapping, ReplayBuildsKeyframesAndRevisitsGetTheRightOnes) {
  Collector<ground_texture_bow::LoopClosure> closure_topic("/localizer/loop_closures");
  Collector<ground_texture_bow::LoopClosure> n3_closures("/localizer_n3/loop_closures", 1000);
  Collector<ground_texture_bow::CandidateList> n3_lists("/localizer_n3/candidates", 1000);
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics("/diagnostics", 1000);
  // The debug image is computed only with a subscriber: subscribe for the first part. The
  // node counts the overlays it draws (get_info: debug_images).
  Collector<sensor_msgs::Image> debug_topic("/localizer/debug_image", 10);
  const auto mapping = ReadBag(g_data + "/mapping.bag");
  ASSERT_GT(mapping.size(), 20u);
  Replay(std::vector<Frame>(mapping.begin(), mapping.begin() + 5), "/camera/image_raw",
         "/localizer", 4.0);
  // The node's own count of the overlay's subscribers (/diagnostics): seen at 1, then, after
  // the subscriber goes, at 0 in a later status, before the rest is replayed.
  auto subscribers = [](const NodeStatus& st) {
    return StatusValue(st, "debug image subscribers");
  };
  ASSERT_EQ(subscribers(WaitForStatus(
                diagnostics, "/localizer",
                [&](const NodeStatus& st) { return subscribers(st) == 1; }, 120.0)),
            1);
  debug_topic.Stop();
  ASSERT_EQ(subscribers(WaitForStatus(
                diagnostics, "/localizer",
                [&](const NodeStatus& st) { return subscribers(st) == 0; }, 120.0)),
            0)
      << "the node still counts the debug image's subscriber";
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
  EXPECT_EQ(info.images_rejected, 0u) << info.last_error;

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

  // The second nodelet saw the same images (some may have been dropped while it was busy:
  // it keeps the newest); wait until it has dealt with all it received.
  const ros::WallTime limit = ros::WallTime::now() + ros::WallDuration(60);
  for (;;) {
    const auto n3 = Info("/localizer_n3");
    if (n3.images_received > 0 &&
        n3.images_processed + n3.images_dropped + n3.images_rejected >= n3.images_received &&
        n3_lists.Get().size() >= n3.images_processed) {
      break;
    }
    ASSERT_LT(ros::WallTime::now(), limit) << "/localizer_n3 did not finish the replay";
    ros::WallDuration(0.05).sleep();
  }
  ExpectTemporalConsistency("/localizer_n3", n3_lists.Get(), n3_closures.Get(), diagnostics);

  // Nothing lost: unloading the nodelet (as a Ctrl-C does) saves its map to ~autosave_path,
  // every keyframe in it.
  std::string autosave;
  ASSERT_TRUE(ros::param::get("/localizer_n3/autosave_path", autosave));
  const uint32_t n3_keyframes = Info("/localizer_n3").database_size;
  ASSERT_GT(n3_keyframes, 0u);
  EXPECT_FALSE(fs::exists(autosave)) << "no periodic save was asked for";
  nodelet::NodeletUnload unload;
  unload.request.name = "/localizer_n3";
  EXPECT_TRUE(Call("/localizer_manager/unload_nodelet", unload).response.success);
  ASSERT_TRUE(fs::exists(autosave)) << autosave;
  EXPECT_EQ(gtbow::Localizer::ReadMapInfo(autosave).keyframes, n3_keyframes);
  fs::remove(autosave);
}

}  // namespace
