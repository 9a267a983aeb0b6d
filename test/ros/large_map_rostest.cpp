// large_map.test (LargeMap.*): a map of a few thousand keyframes through ~save_map and
// ~load_map (map format version 3, src/core/localizer_map.cpp). The mapper takes every image of
// a 2,000-image run as a keyframe and answers each query image (~query_candidates, k = 5,
// verified, and ~localize); then it saves. A fresh node in localization mode loads the file
// (memory-mapped), and the mapper itself, which after the save answers from the file's mapping
// instead of its heap copy, must both give exactly the answers recorded before the save, field
// by field. A truncated copy of the file is refused with a clear status and the loaded map kept.
// Last, the mapper inserts behind the file's mapping and saves again: the same check. Then a node
// that shuts down (SIGINT) in the middle of a paced save finishes it unpaced, whole, and exits.
#include <signal.h>

#include <chrono>
#include <condition_variable>
#include <fstream>
#include <set>
#include <thread>

#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/eval/dataset.h"
#include "rostest_util.h"

namespace {

using namespace rostest_util;

struct Answers {
  std::vector<ground_texture_bow::QueryCandidates::Response> candidates;
  std::vector<ground_texture_bow::Localize::Response> fixes;
};

Answers Ask(const std::string& node, const std::vector<Frame>& queries) {
  Answers out;
  for (const Frame& f : queries) {
    ground_texture_bow::QueryCandidates q;
    q.request.image = *f.image;
    q.request.k = 5;
    q.request.verify = true;
    out.candidates.push_back(Call(node + "/query_candidates", q).response);
    ground_texture_bow::Localize l;
    l.request.image = *f.image;
    out.fixes.push_back(Call(node + "/localize", l).response);
  }
  return out;
}

// Every field of every answer: the status, each candidate (id, stamp, score, pose,
// verification, relative pose, inliers, covariance, reason) and the fix (pose with covariance,
// keyframe, inliers).
void ExpectSame(const Answers& before, const Answers& after, const std::string& who) {
  ASSERT_EQ(before.candidates.size(), after.candidates.size());
  for (size_t i = 0; i < before.candidates.size(); ++i) {
    const auto& a = before.candidates[i];
    const auto& b = after.candidates[i];
    EXPECT_TRUE(a.status == b.status) << who << ", query " << i << ":\n"
                                      << a.status << "before the save, now:\n"
                                      << b.status;
    ASSERT_EQ(a.candidates.size(), b.candidates.size()) << who << ", query " << i;
    for (size_t k = 0; k < a.candidates.size(); ++k) {
      EXPECT_TRUE(a.candidates[k] == b.candidates[k])
          << who << ", query " << i << ", candidate " << k << ": before the save\n"
          << a.candidates[k] << "now:\n"
          << b.candidates[k];
    }
    EXPECT_TRUE(before.fixes[i] == after.fixes[i])
        << who << ", query " << i << ": fix before the save\n"
        << before.fixes[i] << "now:\n"
        << after.fixes[i];
  }
}

// Replays a mapping run into a node in mapping mode as fast as it processes it: each image once
// the node has published the candidates of the previous one (~candidates: one list per processed
// image), without the fixed sleeps and polling of rostest_util's Replay (which would take most
// of the test on 2,000 images). Each image's transform goes out one image ahead, so that it has
// arrived when the node looks it up.
void ReplayMapping(const std::vector<Frame>& frames, const std::string& topic,
                   const std::string& node) {
  ros::NodeHandle nh;
  std::mutex mutex;
  std::condition_variable cv;
  std::set<ros::Time> done;
  ros::Subscriber sub = nh.subscribe<ground_texture_bow::CandidateList>(
      node + "/candidates", 100, [&](const ground_texture_bow::CandidateListConstPtr& msg) {
        std::lock_guard<std::mutex> lock(mutex);
        done.insert(msg->header.stamp);
        cv.notify_all();
      });
  ros::Publisher img_pub = nh.advertise<sensor_msgs::Image>(topic, 10);
  ros::Publisher tf_pub = nh.advertise<tf2_msgs::TFMessage>("/tf", 100);
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(20);
  while ((img_pub.getNumSubscribers() == 0 || sub.getNumPublishers() == 0) &&
         ros::WallTime::now() < deadline) {
    ros::WallDuration(0.05).sleep();
  }
  ASSERT_GT(img_pub.getNumSubscribers(), 0u) << "nobody subscribes to " << topic;
  ASSERT_GT(sub.getNumPublishers(), 0u) << "nobody publishes " << node << "/candidates";
  ros::WallDuration(0.5).sleep();  // the nodes' TF listeners connect too
  if (!frames.empty() && frames[0].tf) tf_pub.publish(frames[0].tf);
  for (size_t i = 0; i < frames.size(); ++i) {
    if (i + 1 < frames.size() && frames[i + 1].tf) tf_pub.publish(frames[i + 1].tf);
    img_pub.publish(frames[i].image);
    const ros::Time stamp = frames[i].image->header.stamp;
    std::unique_lock<std::mutex> lock(mutex);
    if (!cv.wait_for(lock, std::chrono::seconds(10), [&] { return done.count(stamp) > 0; })) {
      FAIL() << node << " published no candidates for image " << i << " of " << frames.size()
             << " within 10 s";
    }
  }
}

TEST(LargeMap, SavedAndLoadedAnswersAreThoseBeforeTheSave) {
  const auto mapping = ReadBag(g_data + "/many_mapping.bag");
  const auto queries = ReadBag(g_data + "/many_queries.bag");
  ASSERT_GE(mapping.size(), 2000u);
  ASSERT_FALSE(queries.empty());
  // The nodes' ground sampling distance is the data's.
  double mpp = 0;
  ASSERT_TRUE(ros::param::get("/mapper/meters_per_pixel", mpp));
  EXPECT_EQ(mpp, gtbow::Dataset::Load(g_data + "/many").info().geometry.meters_per_pixel);

  const ros::WallTime t0 = ros::WallTime::now();
  ReplayMapping(mapping, "/map_camera/image_raw", "/mapper");
  const ros::WallTime t1 = ros::WallTime::now();
  const auto mapped = Info("/mapper");
  // Every image became a keyframe, each with its pose (no transform missing).
  EXPECT_EQ(mapped.images_dropped, 0u);
  EXPECT_EQ(mapped.images_rejected, 0u);
  const uint32_t n = mapped.database_size;
  EXPECT_EQ(n, mapping.size());
  ASSERT_GE(n, 2000u);
  Collector<diagnostic_msgs::DiagnosticArray> diagnostics("/diagnostics");

  const Answers before = Ask("/mapper", queries);
  int verified = 0, fixes = 0;
  for (size_t i = 0; i < queries.size(); ++i) {
    ASSERT_EQ(before.candidates[i].status.code, Status::OK) << before.candidates[i].status.message;
    ASSERT_EQ(before.candidates[i].candidates.size(), 5u);
    for (const auto& c : before.candidates[i].candidates) {
      EXPECT_TRUE(c.has_pose);
      verified += c.verified;
    }
    fixes += before.fixes[i].localized;
  }
  const ros::WallTime t2 = ros::WallTime::now();

  const fs::path dir = fs::temp_directory_path() / ("gtbow_large_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string map_path = (dir / "map.gtmap").string();
  ground_texture_bow::SaveMap save;
  save.request.path = map_path;
  save = Call("/mapper/save_map", save);
  ASSERT_EQ(save.response.status.code, Status::OK) << save.response.status.message;
  const ros::WallTime t3 = ros::WallTime::now();
  const gtbow::MapFileInfo header = gtbow::Localizer::ReadMapInfo(map_path);
  EXPECT_EQ(header.version, 3u);
  EXPECT_EQ(header.keyframes, n);
  EXPECT_EQ(header.meters_per_pixel, mpp);
  EXPECT_TRUE(header.descriptors);

  ground_texture_bow::LoadMap load;
  load.request.path = map_path;
  load = Call("/localizer/load_map", load);
  ASSERT_EQ(load.response.status.code, Status::OK) << load.response.status.message;
  const ros::WallTime t4 = ros::WallTime::now();
  EXPECT_EQ(load.response.keyframes, n);
  EXPECT_EQ(Info("/mapper").database_size, n);
  EXPECT_EQ(Info("/localizer").database_size, n);

  // (a) the loaded map, (b) the mapper on the file's mapping: the answers of before the save.
  const Answers loaded = Ask("/localizer", queries);
  ExpectSame(before, loaded, "localizer (loaded map)");
  const Answers saved = Ask("/mapper", queries);
  ExpectSame(before, saved, "mapper (after its save)");
  const ros::WallTime t5 = ros::WallTime::now();

  // A truncated copy: refused, with a status that says so, and the loaded map kept.
  const std::string cut = (dir / "truncated.gtmap").string();
  fs::copy_file(map_path, cut);
  const uintmax_t bytes = fs::file_size(map_path);
  fs::resize_file(cut, bytes / 2);
  const uint64_t rejected = Info("/localizer").requests_rejected;
  ground_texture_bow::LoadMap bad;
  bad.request.path = cut;
  bad = Call("/localizer/load_map", bad);
  EXPECT_EQ(bad.response.status.code, Status::INVALID_ARGUMENT) << bad.response.status.message;
  EXPECT_NE(bad.response.status.message.find("truncated"), std::string::npos)
      << bad.response.status.message;
  EXPECT_NE(bad.response.status.message.find(cut), std::string::npos)
      << bad.response.status.message;
  const auto after_bad = Info("/localizer");
  EXPECT_EQ(after_bad.database_size, n);
  EXPECT_EQ(after_bad.requests_rejected, rejected + 1);
  ExpectSame(before, Ask("/localizer", queries), "localizer (after the refused load)");

  // The diagnostics agree: the mapper holds every image with a pose, nothing was rejected
  // except the truncated file. Waited for, not timed: the statuses that count the refused load
  // and the mapper's every image (diagnostic_updater publishes once a second, later on a busy
  // machine; a fixed 1.5 s wait once read the status from before the refusal).
  const std::string rejected_after = std::to_string(rejected + 1);
  auto value_is = [](const std::string& key, double want) {
    return [key, want](const NodeStatus& st) { return StatusValue(st, key) == want; };
  };
  const NodeStatus mapper_status =
      WaitForStatus(diagnostics, "/mapper", value_is("database size", n), 120);
  ASSERT_TRUE(mapper_status.seen);
  EXPECT_EQ(mapper_status.status.level, diagnostic_msgs::DiagnosticStatus::OK)
      << mapper_status.status.message;
  EXPECT_EQ(mapper_status.values.at("database size"), std::to_string(n));
  EXPECT_EQ(mapper_status.values.at("missing transforms"), "0");
  const NodeStatus localizer_status =
      WaitForStatus(diagnostics, "/localizer", value_is("rejected requests", rejected + 1), 120);
  ASSERT_TRUE(localizer_status.seen);
  EXPECT_EQ(localizer_status.values.at("database size"), std::to_string(n));
  EXPECT_EQ(localizer_status.values.at("rejected requests"), rejected_after);

  // After its save the mapper goes on mapping: a new keyframe goes behind the file's mapping,
  // and a second save, loaded, holds both.
  ground_texture_bow::AddKeyframe add;
  add.request.image = *queries[0].image;
  add.request.has_pose = true;
  add.request.pose = gtbow_ros::ToPose2DMsg(queries[0].truth);
  add = Call("/mapper/add_keyframe", add);
  ASSERT_EQ(add.response.status.code, Status::OK) << add.response.status.message;
  EXPECT_EQ(add.response.id, n);
  const Answers extended = Ask("/mapper", queries);
  ASSERT_FALSE(extended.candidates[0].candidates.empty());
  EXPECT_EQ(extended.candidates[0].candidates[0].id, n);  // the image finds itself first
  const std::string map2_path = (dir / "map2.gtmap").string();
  save.request.path = map2_path;
  save = Call("/mapper/save_map", save);
  ASSERT_EQ(save.response.status.code, Status::OK) << save.response.status.message;
  load.request.path = map2_path;
  load = Call("/localizer/load_map", load);
  ASSERT_EQ(load.response.status.code, Status::OK) << load.response.status.message;
  EXPECT_EQ(load.response.keyframes, n + 1);
  ExpectSame(extended, Ask("/localizer", queries), "localizer (second save)");
  ExpectSame(extended, Ask("/mapper", queries), "mapper (after its second save)");

  // A node shut down (SIGINT: Ctrl-C, the end of a roslaunch) while a paced save is under way:
  // the rest of the save goes out unpaced (LocalizerServer::StopPacingSaves), the file is the
  // whole map, and the node exits without waiting out the pace. /stopper saves at 1 MB/s, the
  // slowest pace allowed, so the map would take as many seconds as it has megabytes.
  {
    ground_texture_bow::LoadMap stopper_load;
    stopper_load.request.path = map2_path;
    ASSERT_EQ(Call("/stopper/load_map", stopper_load).response.status.code, Status::OK);
    const pid_t stopper = PidOf("/stopper");
    ASSERT_GT(stopper, 0) << "no process id of /stopper";
    const fs::path stopped = dir / "stopped.gtmap";
    std::thread saving([&] {
      ground_texture_bow::SaveMap s;
      s.request.path = stopped.string();
      (void)ros::service::call("/stopper/save_map", s);  // the node goes away during the call
    });
    // The writer is paced once its temporary file (".stopped.gtmap.tmp-<pid>-...") holds its
    // first megabyte: the rest would take a second per megabyte.
    const std::string prefix = ".stopped.gtmap.tmp-";
    auto written = [&]() -> uintmax_t {
      std::error_code ec;
      for (const auto& e : fs::directory_iterator(dir, ec)) {
        if (e.path().filename().string().rfind(prefix, 0) == 0) return fs::file_size(e, ec);
      }
      return 0;
    };
    const ros::WallTime cap = ros::WallTime::now() + ros::WallDuration(60);
    while (written() < (uintmax_t{1} << 20) && ros::WallTime::now() < cap) {
      ros::WallDuration(0.01).sleep();
    }
    const uintmax_t at_signal = written();
    ASSERT_GE(at_signal, uintmax_t{1} << 20) << "the paced save did not start";
    const uintmax_t map_bytes = fs::file_size(map2_path);
    const ros::WallTime signalled = ros::WallTime::now();
    ASSERT_EQ(::kill(stopper, SIGINT), 0);
    // Gone, or a zombie not reaped yet by roslaunch.
    auto exited = [&] {
      if (::kill(stopper, 0) != 0) return true;
      std::ifstream stat("/proc/" + std::to_string(stopper) + "/stat");
      std::string pid, comm, state;
      stat >> pid >> comm >> state;
      return state == "Z" || state == "X";
    };
    while (!exited() && ros::WallTime::now() < signalled + ros::WallDuration(120)) {
      ros::WallDuration(0.01).sleep();
    }
    const double took = (ros::WallTime::now() - signalled).toSec();
    ASSERT_TRUE(exited()) << "/stopper still runs 120 s after SIGINT";
    saving.join();
    // Paced, the rest would have taken (map - written) / 1 MB/s; unpaced it is a write of that
    // many megabytes, which any disk a robot has does at many times 1 MB/s: half the paced time
    // is the bound (a disk slower than 2 MB/s would fail it, and is near the pace anyway).
    const double paced_rest = static_cast<double>(map_bytes - std::min(map_bytes, at_signal)) / 1e6;
    EXPECT_LT(took, 0.5 * paced_rest)
        << "/stopper took " << took << " s to exit after SIGINT, " << (map_bytes - at_signal) / 1e6
        << " MB of its save unwritten: the save went on at its pace";
    // The whole map, every checksum verified, and no temporary file left.
    ASSERT_TRUE(fs::exists(stopped)) << "the save was not finished";
    const gtbow::MapFileInfo mi = gtbow::Localizer::ReadMapInfo(stopped.string());
    EXPECT_EQ(mi.keyframes, n + 1);
    std::unique_ptr<gtbow::Localizer> reloaded;
    EXPECT_NO_THROW(reloaded = LoadSavedMap(stopped.string(), g_data + "/vocab.gtvoc"));
    ASSERT_TRUE(reloaded);
    EXPECT_EQ(reloaded->size(), n + 1u);
    EXPECT_EQ(written(), 0u) << "a temporary file was left in " << dir;
    std::printf(
        "shutdown during a paced save: %.1f of %.1f MB written at SIGINT, exited %.2f s "
        "later (paced, the rest would have taken %.0f s)\n",
        at_signal / 1e6, map_bytes / 1e6, took, paced_rest);
  }

  std::printf(
      "large map: %u keyframes, %.1f MB file; replay %.1f s, %zu queries %.1f s, save %.2f s, "
      "load %.2f s, comparisons %.1f s; %d of %zu candidates verified, %d of %zu localized\n",
      n, bytes / 1e6, (t1 - t0).toSec(), queries.size(), (t2 - t1).toSec(), (t3 - t2).toSec(),
      (t4 - t3).toSec(), (t5 - t4).toSec(), verified, 5 * queries.size(), fixes, queries.size());
  EXPECT_GE(fixes, static_cast<int>(queries.size() / 2));  // the answers are not all failures
  fs::remove_all(dir);
}

}  // namespace
