// gtbow_bag_to_dataset on the rostests' drive bag (a robot's recording: images, camera_info,
// wheel odometry as TF odom -> base_link, the camera's static mount): the dataset it writes
// holds the recording's images and odometry exactly and the scale from camera_info and TF, and
// the package's tools take it from there (train-vocab, then slam: loop closures and a map, then
// localize: the drive's images on that map, against the ground truth).
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>
#include <opencv2/imgcodecs.hpp>

#include "../core/test_util.h"
#include "ground_texture_bow/eval/dataset.h"

namespace fs = std::filesystem;
using gtbow::testing_util::RunCommand;

namespace {

class BagToDataset : public gtbow::testing_util::TempDirTest {
 protected:
  std::string Out(const std::string& name) const { return (dir_ / name).string(); }
  static std::string Tool(const std::string& args) {
    return std::string(GTBOW_BAG_TO_DATASET) + " " + args;
  }
};

TEST_F(BagToDataset, ARecordingBecomesADatasetThatTheToolsMapFrom) {
  const std::string data = GTBOW_ROSTEST_DATA;
  auto r = RunCommand(Tool("--bag " + data + "/drive.bag --out " + Out("ds") + " --every 2 -q"));
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("from camera_info fx 800.00 px, height 0.2000 m (TF base_link ->"),
            std::string::npos)
      << r.output;
  const gtbow::Dataset got = gtbow::Dataset::Load(Out("ds"));
  const gtbow::Dataset truth = gtbow::Dataset::Load(data + "/drive");
  EXPECT_EQ(got.info().geometry.meters_per_pixel, truth.info().geometry.meters_per_pixel);
  EXPECT_EQ(got.info().geometry.width, 640);
  const auto drive = got.Split("drive");
  const auto original = truth.Split("drive");
  ASSERT_EQ(drive.size(), (original.size() + 1) / 2);
  // Every kept image is the recorded one, pixel for pixel (flipped back into the view from
  // above), and its pose is the odometry the bag was made from.
  const auto odom = gtbow::ParsePosesCsv(
      [&] {
        std::ifstream in(data + "/drive/drive_odometry.csv");
        return std::string(std::istreambuf_iterator<char>(in), {});
      }(),
      "drive_odometry.csv");
  for (size_t i = 0; i < drive.size(); i += 25) {
    const cv::Mat a = got.LoadGray(drive[i]), b = truth.LoadGray(original[2 * i]);
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(cv::countNonZero(a != b), 0) << drive[i];
    const gtbow::Pose2D p = got.PoseOf(drive[i]), q = odom[2 * i].pose;
    EXPECT_NEAR(p.x, q.x, 1e-6) << i;
    EXPECT_NEAR(p.y, q.y, 1e-6) << i;
    EXPECT_NEAR(std::remainder(p.theta - q.theta, 2 * M_PI), 0.0, 1e-6) << i;
  }
  EXPECT_TRUE(fs::exists(dir_ / "ds" / "drive_odometry.csv"));
  EXPECT_FALSE(fs::exists(Out("ds") + ".partial"));

  // The tools take it from there: a vocabulary, then the SLAM pipeline's closures and map.
  r = RunCommand(std::string(GTBOW_BIN) + " train-vocab --dataset " + Out("ds") +
                 " --words 800 --out " + Out("v.gtvoc") + " -q");
  ASSERT_EQ(r.code, 0) << r.output;
  r = RunCommand(std::string(GTBOW_BIN) + " slam --dataset " + Out("ds") + " --vocab " +
                 Out("v.gtvoc") + " --exclude-recent 10 --out " + Out("slam") +
                 " --no-cache --no-plots -q");
  ASSERT_EQ(r.code, 0) << r.output;
  const YAML::Node s = YAML::LoadFile((dir_ / "slam" / "summary.json").string());
  EXPECT_GE(s["closures"]["published"].as<int>(), 10) << r.output;
  EXPECT_TRUE(fs::exists(dir_ / "slam" / "map.gtmap"));

  // And the robot localizes on that map: every 4th image of the original drive (half of them
  // never in the bag's dataset, which kept every 2nd) against the drive's ground truth, in the
  // frame where the recording started.
  r = RunCommand(std::string(GTBOW_BIN) + " localize --map " + Out("slam/map.gtmap") +
                 " --dataset " + data + "/drive --every 4 --out " + Out("fixes.csv") + " -q");
  ASSERT_EQ(r.code, 0) << r.output;
  int right = 0, total = 0;
  ASSERT_EQ(std::sscanf(r.output.c_str() + r.output.find("against the dataset's poses: "),
                        "against the dataset's poses: %d of %d", &right, &total),
            2)
      << r.output;
  EXPECT_EQ(total, static_cast<int>((original.size() + 3) / 4));
  EXPECT_GE(right * 100, total * 95) << r.output;
  EXPECT_TRUE(fs::exists(dir_ / "fixes.csv"));
  // A dataset at another scale (the drive's, its dataset.yaml saying 0.3 mm per pixel) is
  // refused, naming both.
  fs::create_directories(dir_ / "scaled");
  for (const char* entry : {"images", "sequences", "poses.csv"}) {
    fs::create_symlink(fs::path(data) / "drive" / entry, dir_ / "scaled" / entry);
  }
  {
    YAML::Node y = YAML::LoadFile(data + "/drive/dataset.yaml");
    y["meters_per_pixel"] = 0.0003;
    std::ofstream(dir_ / "scaled" / "dataset.yaml") << y;
  }
  r = RunCommand(std::string(GTBOW_BIN) + " localize --map " + Out("slam/map.gtmap") +
                 " --dataset " + Out("scaled") + " -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("differs from the map's"), std::string::npos) << r.output;
}

TEST_F(BagToDataset, BadInputIsNamedAndLeavesNothing) {
  const std::string data = GTBOW_ROSTEST_DATA;
  // No such topic: the error lists the bag's topics.
  auto r = RunCommand(
      Tool("--bag " + data + "/localization.bag --image-topic /nope --out " + Out("a") + " -q"));
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.output.find("no image on /nope"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("/camera/image_raw (20)"), std::string::npos) << r.output;
  // No TF at all (a bag for global localization): no poses, unless asked for.
  r = RunCommand(Tool("--bag " + data + "/localization.bag --out " + Out("b") + " -q"));
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.output.find("no poses"), std::string::npos) << r.output;
  // ... and then no camera height either: the scale must be given.
  r = RunCommand(
      Tool("--bag " + data + "/localization.bag --out " + Out("b") + " --allow-no-poses -q"));
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.output.find("no camera height"), std::string::npos) << r.output;
  r = RunCommand(Tool("--bag " + data + "/localization.bag --out " + Out("b") +
                      " --allow-no-poses --camera-height 0.2 -q"));
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_EQ(gtbow::Dataset::Load(Out("b")).info().geometry.meters_per_pixel, 0.00025);
  // An existing output is not replaced without --force.
  r = RunCommand(Tool("--bag " + data + "/localization.bag --out " + Out("b") +
                      " --allow-no-poses --camera-height 0.2 -q"));
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.output.find("exists"), std::string::npos) << r.output;
  for (const char* d : {"a", "b.partial"}) EXPECT_FALSE(fs::exists(dir_ / d)) << d;
}

}  // namespace
