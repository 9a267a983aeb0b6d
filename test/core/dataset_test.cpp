#include "ground_texture_bow/eval/dataset.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include "test_util.h"

#include "ground_texture_bow/core/file_util.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace {

// Expects `f` to throw std::runtime_error whose message contains every one of `parts`.
template <typename F>
void ExpectError(F&& f, std::initializer_list<std::string> parts) {
  try {
    f();
    FAIL() << "expected an error";
  } catch (const std::runtime_error& e) {
    for (const auto& p : parts) {
      EXPECT_NE(std::string(e.what()).find(p), std::string::npos)
          << "message '" << e.what() << "' lacks '" << p << "'";
    }
  }
}

class TempDir : public testing_util::TempDirTest {
 protected:
  void SetUp() override {
    TempDirTest::SetUp();
    fs::create_directories(dir_ / "images");
    fs::create_directories(dir_ / "sequences");
  }
  void Write(const std::string& rel, const std::string& text) {
    std::ofstream(dir_ / rel, std::ios::binary) << text;
  }
};

TEST(DatasetFormat, YamlRoundTrip) {
  DatasetInfo info;
  info.name = "asphalt_synth_seed7";
  info.surface = "asphalt";
  info.geometry = {320, 240, 0.0005};
  info.query_days = {{"query_day000", 0}, {"query_day030", 30}};
  const DatasetInfo back = ParseDatasetYaml(FormatDatasetYaml(info), "dataset.yaml");
  EXPECT_EQ(back.name, info.name);
  EXPECT_EQ(back.surface, info.surface);
  EXPECT_EQ(back.geometry.width, 320);
  EXPECT_EQ(back.geometry.height, 240);
  EXPECT_DOUBLE_EQ(back.geometry.meters_per_pixel, 0.0005);
  EXPECT_EQ(back.query_days, info.query_days);
}

TEST(DatasetFormat, YamlToleratesUnknownKeysAndFlowMaps) {
  const std::string text =
      "format_version: 1\nname: x\nsurface: carpet\nimage_width: 100\nimage_height: 80\n"
      "meters_per_pixel: 0.001\ncamera_model: acme\nquery_days: {q1: 5}\n";
  const DatasetInfo info = ParseDatasetYaml(text, "d.yaml");
  EXPECT_EQ(info.geometry.width, 100);
  EXPECT_DOUBLE_EQ(info.query_days.at("q1"), 5.0);
}

TEST(DatasetFormat, YamlRejectsMalformed) {
  ExpectError(
      [] {
        ParseDatasetYaml(
            "format_version: 2\nimage_width: 1\nimage_height: 1\nmeters_per_pixel: 1\n", "d.yaml");
      },
      {"d.yaml:1", "format_version 2"});
  ExpectError(
      [] {
        ParseDatasetYaml("format_version: 1\nimage_height: 1\nmeters_per_pixel: 1\n", "d.yaml");
      },
      {"d.yaml", "image_width"});
  ExpectError(
      [] {
        ParseDatasetYaml(
            "format_version: 1\nimage_width: 10\nimage_height: 10\nmeters_per_pixel: -1\n",
            "d.yaml");
      },
      {"d.yaml:4", "meters_per_pixel"});
  ExpectError(
      [] {
        ParseDatasetYaml(
            "format_version: 1\nimage_width: ten\nimage_height: 10\nmeters_per_pixel: 1\n",
            "d.yaml");
      },
      {"d.yaml:2", "image_width", "ten"});
  ExpectError([] { ParseDatasetYaml("format_version: 1\n  bad: [\n", "d.yaml"); },
              {"d.yaml:", "invalid YAML"});
}

TEST(DatasetFormat, CsvRoundTrip) {
  const std::vector<PoseRecord> poses = {{"a.png", {1.2345678, -0.5, 3.1}},
                                         {"sub/b.png", {0, 0, -3.14159}}};
  const auto back = ParsePosesCsv(FormatPosesCsv(poses), "poses.csv");
  ASSERT_EQ(back.size(), 2u);
  EXPECT_EQ(back[1].image, "sub/b.png");
  EXPECT_NEAR(back[0].pose.x, 1.2345678, 1e-12);
  EXPECT_NEAR(back[1].pose.theta, -3.14159, 1e-12);
}

TEST(DatasetFormat, CsvFindsColumnsByNameAndToleratesExtras) {
  const std::string text =
      "# exported by another tool\r\ntheta, image ,y,x,quality\r\n0.5,img 1.png,2,1,good\r\n\r\n"
      "# trailing comment\n-0.25,\"quoted,name.png\",4,3,bad\n";
  const auto poses = ParsePosesCsv(text, "poses.csv");
  ASSERT_EQ(poses.size(), 2u);
  EXPECT_EQ(poses[0].image, "img 1.png");
  EXPECT_DOUBLE_EQ(poses[0].pose.x, 1.0);
  EXPECT_DOUBLE_EQ(poses[0].pose.y, 2.0);
  EXPECT_DOUBLE_EQ(poses[0].pose.theta, 0.5);
  EXPECT_EQ(poses[1].image, "quoted,name.png");
  EXPECT_DOUBLE_EQ(poses[1].pose.theta, -0.25);
}

TEST(DatasetFormat, CsvRejectsMalformedNamingLine) {
  ExpectError([] { ParsePosesCsv("image,x,y\na.png,1,2\n", "poses.csv"); },
              {"poses.csv:1", "theta"});
  ExpectError([] { ParsePosesCsv("image,x,y,theta\na.png,1,2,0\nb.png,1,abc,0\n", "poses.csv"); },
              {"poses.csv:3", "column 'y'", "abc"});
  ExpectError([] { ParsePosesCsv("image,x,y,theta\na.png,1,2\n", "poses.csv"); },
              {"poses.csv:2", "expected 4 fields"});
  ExpectError([] { ParsePosesCsv("image,x,y,theta\na.png,1,2,0\na.png,3,4,0\n", "poses.csv"); },
              {"poses.csv:3", "already listed on line 2"});
  ExpectError([] { ParsePosesCsv("image,x,y,theta\na.png,nan,2,0\n", "poses.csv"); },
              {"poses.csv:2", "column 'x'"});
  ExpectError([] { ParsePosesCsv("image,x,y,theta\n../etc/passwd,1,2,0\n", "poses.csv"); },
              {"poses.csv:2", "leaves images/"});
  ExpectError([] { ParsePosesCsv("# only a comment\n", "poses.csv"); }, {"poses.csv", "header"});
}

// Found by the fuzzers (test/fuzz): split names that are no file name, text that YAML cannot
// carry, names the CSV writer did not quote, and coordinates too long for a fixed buffer.
TEST(DatasetFormat, FuzzFindingsAreRejectedOrRoundTrip) {
  const std::string head =
      "format_version: 1\nimage_width: 8\nimage_height: 8\nmeters_per_pixel: 1\n";
  ExpectError([&] { ParseDatasetYaml(head + "query_days: {../../etc: 0}\n", "d.yaml"); },
              {"d.yaml:5", "not a split name"});
  ExpectError([&] { ParseDatasetYaml(head + "query_days: {\"a\\0b\": 0}\n", "d.yaml"); },
              {"not a split name"});
  ExpectError([&] { ParseDatasetYaml(head + "query_days: {\"\xe0\x30\": 0}\n", "d.yaml"); },
              {"not a split name"});
  ExpectError([&] { ParseDatasetYaml(head + "name: \"a\\x01\"\n", "d.yaml"); },
              {"d.yaml:5", "'name'"});
  ExpectError([] { ParsePosesCsv(std::string("image,x,y,theta\na\0.png,1,2,0\n", 29), "p.csv"); },
              {"p.csv:2", "control character"});
  const std::vector<PoseRecord> poses = {{"#1, \"odd\".png", {1e300, -2.5e-8, 0.25}},
                                         {" lead.png", {0, 0, 0}}};
  const auto back = ParsePosesCsv(FormatPosesCsv(poses), "poses.csv");
  ASSERT_EQ(back.size(), 2u);
  EXPECT_EQ(back[0].image, poses[0].image);
  EXPECT_EQ(back[1].image, poses[1].image);
  EXPECT_EQ(back[0].pose.x, 1e300);
  EXPECT_THROW(FormatSequence({"a#b.png"}), std::invalid_argument);
  DatasetInfo info;
  info.query_days = {{"query_day030", 30.123456789012345}};
  EXPECT_EQ(ParseDatasetYaml(FormatDatasetYaml(info), "d.yaml").query_days, info.query_days);
}

TEST(DatasetFormat, SequenceCommentsAndBlanks) {
  const auto names = ParseSequence("# header\na.png\n\n  b.png  # inline\n#c.png\n", "s.txt");
  ASSERT_EQ(names.size(), 2u);
  EXPECT_EQ(names[0], "a.png");
  EXPECT_EQ(names[1], "b.png");
}

TEST_F(TempDir, LoadsDatasetAndConvertsColorImages) {
  DatasetInfo info;
  info.geometry = {64, 48, 0.001};
  WriteDatasetFiles(dir_, info, {{"a.jpg", {0, 0, 0}}, {"b.png", {0.01, 0, 0}}},
                    {{"database", {"a.jpg"}}, {"query_x", {"b.png"}}});
  cv::Mat color(48, 64, CV_8UC3, cv::Scalar(10, 200, 30));
  ASSERT_TRUE(cv::imwrite((dir_ / "images" / "a.jpg").string(), color));
  ASSERT_TRUE(
      cv::imwrite((dir_ / "images" / "b.png").string(), cv::Mat(48, 64, CV_8U, cv::Scalar(7))));
  const Dataset d = Dataset::Load(dir_);
  EXPECT_EQ(d.SplitNames(), (std::vector<std::string>{"database", "query_x"}));
  EXPECT_EQ(d.Split("database"), std::vector<std::string>{"a.jpg"});
  const cv::Mat gray = d.LoadGray("a.jpg");
  EXPECT_EQ(gray.type(), CV_8U);
  EXPECT_NEAR(gray.at<uint8_t>(10, 10), 0.114 * 10 + 0.587 * 200 + 0.299 * 30, 4.0);
  EXPECT_EQ(d.LoadGray("b.png").at<uint8_t>(0, 0), 7);
  EXPECT_DOUBLE_EQ(d.PoseOf("b.png").x, 0.01);
  EXPECT_THROW(d.PoseOf("zzz.png"), std::out_of_range);
}

TEST_F(TempDir, RejectsBadSplitsAndImages) {
  DatasetInfo info;
  info.geometry = {64, 48, 0.001};
  WriteDatasetFiles(dir_, info, {{"a.png", {0, 0, 0}}}, {{"database", {"a.png"}}});
  Write("sequences/empty.txt", "# nothing here\n\n");
  Write("sequences/bad.txt", "a.png\n# skip\nmissing.png\n");
  const Dataset d = Dataset::Load(dir_);
  ExpectError([&] { d.Split("empty"); }, {"empty.txt", "is empty"});
  ExpectError([&] { d.Split("bad"); }, {"bad.txt:3", "missing.png", "no pose"});
  ExpectError([&] { d.Split("nope"); }, {"nope", "not found"});
  ExpectError([&] { d.LoadGray("a.png"); }, {"a.png", "missing"});
  ASSERT_TRUE(cv::imwrite((dir_ / "images" / "a.png").string(), cv::Mat(10, 10, CV_8U)));
  ExpectError([&] { d.LoadGray("a.png"); }, {"a.png", "10x10", "64x48"});
  Write("images/a.png", "this is not a png");
  ExpectError([&] { d.LoadGray("a.png"); }, {"cannot decode", "a.png"});
}

TEST_F(TempDir, LoadNamesMissingFiles) {
  ExpectError([&] { Dataset::Load(dir_); }, {"dataset.yaml"});
  Write("dataset.yaml",
        "format_version: 1\nimage_width: 8\nimage_height: 8\nmeters_per_pixel: 0.1\n");
  ExpectError([&] { Dataset::Load(dir_); }, {"poses.csv"});
  ExpectError([&] { Dataset::Load(dir_ / "nothing"); }, {"not a directory"});
}

}  // namespace
}  // namespace gtbow
