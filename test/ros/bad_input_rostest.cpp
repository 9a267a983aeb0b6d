// bad_input.test (BadInput.*): every kind of bad input is counted and reported; nothing is lost.
#include "../fuzz/fuzz_util.h"
#include "rostest_util.h"

namespace {

using namespace rostest_util;

TEST(BadInput, EachKindIsCountedReportedAndLosesNothing) {
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics("/diagnostics");
  // Waits up to 10 s for a node's /diagnostics status that satisfies `pred`.
  auto wait_status = [&](const std::string& node, auto pred) {
    return WaitForStatus(diagnostics, node, pred, 10);
  };
  auto is_error = [](const NodeStatus& s) {
    return s.status.level == diagnostic_msgs::DiagnosticStatus::ERROR;
  };
  // A nodelet that cannot start (no such vocabulary) in the same manager stays inert, says why
  // on /diagnostics, and does not take the manager, or this nodelet, down.
  {
    // Its first status may be diagnostic_updater's "Node starting up" (OK), published before
    // the start-up failed: the report that counts is the ERROR that follows.
    const NodeStatus broken = wait_status("/broken", is_error);
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
    const NodeStatus st = wait_status("/mismatched", is_error);
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
    big = boost::make_shared<sensor_msgs::Image>(
        *cv_bridge::CvImage(big->header, "mono8", large).toImageMsg());
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
    for (const auto& e : fs::directory_iterator(dir))
      entries.push_back(e.path().filename().string());
    EXPECT_EQ(entries, std::vector<std::string>{"map.gtmap"});
    EXPECT_EQ(::kill(manager, 0), 0) << "the manager died";
  }
  // A flipped byte in the index (a load checks the index and the records against their
  // checksums; a keyframe's stored keypoints are checked when they are read).
  std::string corrupt = good_bytes;
  const gtbow::fuzz::MapLayout layout = gtbow::fuzz::ParseMapLayout(good_bytes);
  ASSERT_TRUE(layout.ok);
  corrupt[layout.offset[1] + layout.size[1] / 2] ^= 0x10;
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
  // A transform that is missing or stale counts as missing, one that exists but cannot be used
  // (NaN, should tf2 pass it on) as unusable: four in all.
  auto transforms = [](const NodeStatus& st) {
    const double missing = StatusValue(st, "missing transforms");
    const double unusable =
        StatusValue(st, "unusable transforms (camera not looking down, bad rotation)");
    return missing < 0 || unusable < 0 ? -1 : static_cast<int>(missing + unusable);
  };
  const NodeStatus latest = wait_status("/localizer", [&](const NodeStatus& st) {
    return transforms(st) >= 4 && st.values.at("rejected images") == "3" &&
           st.values.at("rejected requests") == "7";
  });
  const bool seen = latest.seen && transforms(latest) >= 4 &&
                    latest.values.at("rejected images") == "3" &&
                    latest.values.at("rejected requests") == "7";
  EXPECT_TRUE(seen) << "diagnostics do not report the rejected images and requests and the "
                       "missing or unusable transforms (no transform, stale, NaN, stale)";
  // At WARN while the bad input is recent (~diagnostics_window, 10 s) ...
  auto at_level = [&](uint8_t level) {
    for (const auto& array : diagnostics.Get()) {
      diagnostic_msgs::DiagnosticArray one;
      one.status = array.status;
      const NodeStatus st = LatestStatus({one}, "/localizer");
      if (st.seen && st.status.level == level && transforms(st) >= 4 &&
          st.values.at("rejected requests") == "7")
        return true;
    }
    return false;
  };
  EXPECT_TRUE(at_level(diagnostic_msgs::DiagnosticStatus::WARN));
  // ... and back at OK after it, the counters (since the start) unchanged: one bad image does
  // not leave the node at WARN for good.
  const ros::WallTime calm = ros::WallTime::now() + ros::WallDuration(60);
  while (!at_level(diagnostic_msgs::DiagnosticStatus::OK) && ros::WallTime::now() < calm)
    ros::WallDuration(0.2).sleep();
  EXPECT_TRUE(at_level(diagnostic_msgs::DiagnosticStatus::OK))
      << "still not OK " << 60 << " s after the last bad input";
  fs::remove_all(dir);
}

}  // namespace
