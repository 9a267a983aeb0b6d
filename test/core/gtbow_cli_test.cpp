// Runs the gtbow binary as a user would and checks exit codes and messages.
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <string>

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "../fuzz/fuzz_fixture.h"
#include "ground_texture_bow/core/file_util.h"
#include "map_v1.h"
#include "test_scene.h"
#include "test_util.h"

namespace fs = std::filesystem;

namespace {

using Result = gtbow::testing_util::CommandResult;

Result RunGtbow(const std::string& args) {
  return gtbow::testing_util::RunCommand(std::string(GTBOW_BIN) + " " + args);
}

class GtbowCli : public gtbow::testing_util::TempDirTest {
 protected:
  std::string Out(const std::string& name) { return (dir_ / name).string(); }
};

const char* kSmall =
    "--train 2 --queries 2 --days 0,30 --width 128 --height 96 "
    "--meters-per-pixel 0.0005 -q";

TEST_F(GtbowCli, SynthPrintsASummary) {
  const Result r = RunGtbow("synth --out " + Out("d") + " --area 0.2 0.15 " + kSmall);
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("database"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("query_day030"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(dir_ / "d" / "poses.csv"));
}

TEST_F(GtbowCli, BadInputGivesAClearMessageAndNonZeroExit) {
  Result r = RunGtbow("synth --out " + Out("a") + " --surface marble --area 0.2 0.15 " + kSmall);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("unknown surface 'marble'"), std::string::npos) << r.output;

  r = RunGtbow("synth --out " + Out("a") + " " + kSmall + " --area -1 1");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("area_width"), std::string::npos) << r.output;

  r = RunGtbow("synth --out " + Out("a") + " " + kSmall + " --area 0.2 0.15 --width 0");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("width"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir_ / "a"));

  fs::create_directories(dir_ / "full");
  std::ofstream(dir_ / "full" / "notes.txt") << "mine";
  r = RunGtbow("synth --out " + Out("full") + " --area 0.2 0.15 " + kSmall);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("not empty"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("--force"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(dir_ / "full" / "notes.txt"));

  std::ofstream(dir_ / "file") << "x";
  r = RunGtbow("synth --out " + Out("file") + "/sub --area 0.2 0.15 " + kSmall);
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("file"), std::string::npos) << r.output;

  r = RunGtbow("frobnicate");
  EXPECT_NE(r.code, 0);
}

TEST_F(GtbowCli, TrainEvaluateAndBenchmarkOnASyntheticFloor) {
  const std::string d = Out("floor");
  Result r = RunGtbow("synth --out " + d +
                      " --area 0.4 0.3 --train 12 --queries 6 --days 0,90 --query-trail 2" +
                      " --session-days 45 --session-images 6 -q");
  ASSERT_EQ(r.code, 0) << r.output;
  r = RunGtbow("train-vocab --dataset " + d + " --words 800 --out " + Out("v.gtvoc") + " -q");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("800 words"), std::string::npos) << r.output;
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + Out("eval") +
               " --timing-queries 4 --no-cache --no-plots --dump-rankings " + Out("rank.csv") +
               " --dump-poses " + Out("poses.csv") + " -q");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("| query_day090 | 90 | 6 |"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(dir_ / "eval" / "results.json"));
  EXPECT_TRUE(fs::exists(dir_ / "eval" / "summary.md"));
  // What a backend reads (issue 15): every verified pose of the top K counted, the wrong ones
  // among them, and recall at 100% precision; consistent with the localization figures.
  EXPECT_NE(r.output.find("| split | R@100P top-1 (BoW score) | R@100P verified (inliers) |"),
            std::string::npos)
      << r.output;
  const YAML::Node res = YAML::LoadFile((dir_ / "eval" / "results.json").string());
  for (const YAML::Node& split : res["presets"][0]["splits"]) {
    const YAML::Node b = split["backend"];
    ASSERT_TRUE(b.IsMap());
    const double verified = b["verified_poses"].as<double>();
    const double wrong = b["wrong_verified_poses"].as<double>();
    const double estimated = split["localization"]["estimated"].as<double>();
    const double localized = split["localization"]["correct"].as<double>();
    const double counted = split["queries_with_relevant"].as<double>();
    EXPECT_GE(verified, estimated);  // each estimate is a verified pose; later candidates add
    EXPECT_LE(wrong, verified);
    EXPECT_GE(wrong, estimated - localized);  // a wrong estimate is a wrong verified pose
    const double r100 = b["recall_at_100_precision_verified"].as<double>();
    if (estimated == localized) {
      EXPECT_DOUBLE_EQ(r100, localized / counted);
    }
    const double r100_bow = b["recall_at_100_precision_bow_top1"].as<double>();
    EXPECT_GE(r100_bow, 0.0);
    EXPECT_LE(r100_bow, 1.0);
    EXPECT_EQ(b["pr_verified"]["precision"].size(), b["pr_verified"]["recall"].size());
  }
  // Two presets timed side by side (--timing-alternate): each timed query through both in turn;
  // everything but the timing is what the presets give one after the other.
  for (const char* mode : {"seq2", "alt2"}) {
    r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + Out(mode) +
                 " --preset " GTBOW_CONFIG_DIR "/high_accuracy.yaml --preset " GTBOW_CONFIG_DIR
                 "/fast.yaml --query-splits query_day000 --timing-queries 3 --no-cache" +
                 " --no-plots -q" + (std::string(mode) == "alt2" ? " --timing-alternate" : ""));
    ASSERT_EQ(r.code, 0) << r.output;
  }
  {
    const YAML::Node one = YAML::LoadFile((dir_ / "seq2" / "results.json").string());
    const YAML::Node alt = YAML::LoadFile((dir_ / "alt2" / "results.json").string());
    ASSERT_EQ(alt["presets"].size(), 2u);
    for (size_t k = 0; k < 2; ++k) {
      const YAML::Node a = alt["presets"][k], o = one["presets"][k];
      EXPECT_EQ(a["name"].as<std::string>(), o["name"].as<std::string>());
      EXPECT_EQ(a["timing"]["queries"].as<int>(), 3);
      EXPECT_TRUE(a["timing"]["presets_side_by_side"].as<bool>());
      EXPECT_FALSE(o["timing"]["presets_side_by_side"].as<bool>());
      EXPECT_GT(a["timing"]["end_to_end"]["median_ms"].as<double>(), 0.0);
      EXPECT_EQ(YAML::Dump(a["splits"]), YAML::Dump(o["splits"]));
    }
    auto text = [](const fs::path& p) {
      std::ifstream in(p);
      return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    };
    EXPECT_FALSE(text(dir_ / "alt2" / "verifications.csv").empty());
    EXPECT_EQ(text(dir_ / "alt2" / "verifications.csv"), text(dir_ / "seq2" / "verifications.csv"));
  }
  // A kernel timed side by side (--timing-kernels): afterwards the cap is the one before, so the
  // kernels reported (and run) are those of the plain run. (The cap is not always the active
  // kernel's name: on AMD's first Zen cores the Hamming distances run popcnt with no cap.)
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + Out("kern") +
               " --preset " GTBOW_CONFIG_DIR "/high_accuracy.yaml --query-splits query_day000" +
               " --timing-queries 2 --timing-kernels portable --no-cache --no-plots -q");
  ASSERT_EQ(r.code, 0) << r.output;
  {
    const YAML::Node kern = YAML::LoadFile((dir_ / "kern" / "results.json").string());
    const YAML::Node one = YAML::LoadFile((dir_ / "seq2" / "results.json").string());
    const YAML::Node t = kern["presets"][0]["timing"];
    EXPECT_EQ(YAML::Dump(t["kernels"]), YAML::Dump(one["presets"][0]["timing"]["kernels"]));
    ASSERT_EQ(t["by_kernel"].size(), 1u);
    EXPECT_EQ(t["by_kernel"][0]["hamming"].as<std::string>(), "portable");
  }
  // Sequence queries: each query with the two images of its trail, through their odometry.
  EXPECT_TRUE(fs::exists(fs::path(d) / "trail_day090_odometry.csv"));
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + Out("seq") +
               " --sequence 3 --query-splits query_day000 --timing-queries 0 --no-cache" +
               " --no-plots -q");
  ASSERT_EQ(r.code, 0) << r.output;
  const YAML::Node seq = YAML::LoadFile((dir_ / "seq" / "results.json").string());
  EXPECT_EQ(seq["protocol"]["sequence"].as<int>(), 3);
  EXPECT_GE(seq["presets"][0]["splits"][0]["localization"]["success_rate"].as<double>(), 0.5);
  // Each query's views in an eval's verifications.csv (its last column) and the number of rows.
  auto views_of = [&](const std::string& run, size_t* rows) {
    std::map<std::string, std::set<std::string>> views;  // query -> its rows' views
    std::ifstream csv(dir_ / run / "verifications.csv");
    std::string line;
    std::getline(csv, line);
    EXPECT_EQ(line.substr(line.rfind(',') + 1), "view") << run;
    *rows = 0;
    while (std::getline(csv, line)) {
      const size_t a = line.find(','), b = line.find(',', a + 1), c = line.find(',', b + 1);
      views[line.substr(b + 1, c - b - 1)].insert(line.substr(line.rfind(',') + 1));
      ++*rows;
    }
    return views;
  };
  // Each query's rows are of one view only: `one` or `other`. With a preset whose consensus is on
  // (high_accuracy, changing_floors), a pass whose candidates verify gives a fix, so a query
  // whose first view verified never ran the second.
  auto one_view_each = [](const std::map<std::string, std::set<std::string>>& views,
                          const std::string& one, const std::string& other) {
    size_t with_one = 0;
    for (const auto& [query, v] : views) {
      EXPECT_TRUE(v == std::set<std::string>{one} || v == std::set<std::string>{other}) << query;
      with_one += v.count(one);
    }
    return with_one;
  };
  {
    // The verified poses counted are those the node verifies: the query alone's, and the
    // combined view's only where the query alone gave no fix.
    size_t rows = 0;
    const auto views = views_of("seq", &rows);
    EXPECT_EQ(static_cast<double>(rows),
              seq["presets"][0]["splits"][0]["backend"]["verified_poses"].as<double>());
    EXPECT_GT(one_view_each(views, "alone", "combined"), 0u);
  }
  // Trail images beyond the node's ~sequence_max_span are not combined (ImagesInSpan): with the
  // trail 3 cm apart and a 1 cm span no query has one, and each is localized alone, as the node
  // localizes an image its sequence holds alone, even with --sequence-always.
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + Out("span") +
               " --sequence 3 --sequence-always --sequence-max-span 0.01" +
               " --query-splits query_day000 --timing-queries 2 --no-cache --no-plots -q");
  ASSERT_EQ(r.code, 0) << r.output;
  {
    const YAML::Node span = YAML::LoadFile((dir_ / "span" / "results.json").string());
    EXPECT_EQ(span["protocol"]["sequence_max_span_m"].as<double>(), 0.01);
    size_t rows = 0;
    const auto views = views_of("span", &rows);
    EXPECT_GT(rows, 0u);
    EXPECT_EQ(static_cast<double>(rows),
              span["presets"][0]["splits"][0]["backend"]["verified_poses"].as<double>());
    for (const auto& [query, v] : views) EXPECT_EQ(v, std::set<std::string>{"alone"}) << query;
  }
  // An escalating preset: a query's full pass counts only where the node runs it (the first
  // pass gave no fix that stands, or the backoff skipped it).
  r = RunGtbow("train-vocab --dataset " + d +
               " --words 800 --preset " GTBOW_CONFIG_DIR "/changing_floors.yaml --out " +
               Out("cf.gtvoc") + " -q");
  ASSERT_EQ(r.code, 0) << r.output;
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("cf.gtvoc") + " --out " + Out("esc") +
               " --preset " GTBOW_CONFIG_DIR "/changing_floors.yaml --query-splits query_day000" +
               " --timing-queries 0 --no-cache --no-plots -q");
  ASSERT_EQ(r.code, 0) << r.output;
  {
    const YAML::Node esc = YAML::LoadFile((dir_ / "esc" / "results.json").string());
    const YAML::Node s = esc["presets"][0]["splits"][0];
    size_t rows = 0;
    const auto views = views_of("esc", &rows);
    EXPECT_EQ(static_cast<double>(rows), s["backend"]["verified_poses"].as<double>());
    EXPECT_GT(one_view_each(views, "first_pass", "full_pass"), 0u);
    size_t full = 0;
    for (const auto& [query, v] : views) full += v.count("full_pass");
    EXPECT_LE(full, s["escalated_queries"].as<size_t>() + s["first_passes_skipped"].as<size_t>());
  }
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + Out("seq4") +
               " --sequence 4 --query-splits query_day000 --no-cache --no-plots -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("2 images per query"), std::string::npos) << r.output;
  // A maintained map: the session of day 45 keeps it up (every fix adds its view here), then
  // day 90 queries it; a split that is not there is named.
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + Out("maint") +
               " --maintain session_day045 --maintain-refresh 100000 --query-splits query_day090" +
               " --timing-queries 0 --no-cache --no-plots -q");
  ASSERT_EQ(r.code, 0) << r.output;
  const YAML::Node maint = YAML::LoadFile((dir_ / "maint" / "results.json").string());
  const YAML::Node session = maint["presets"][0]["maintenance"]["sessions"][0];
  ASSERT_TRUE(session.IsMap());
  EXPECT_EQ(session["split"].as<std::string>(), "session_day045");
  EXPECT_EQ(session["day"].as<double>(), 45.0);
  EXPECT_EQ(session["images"].as<int>(), 6);
  EXPECT_GE(session["added"].as<int>(), 3);
  EXPECT_EQ(session["added_wrong"].as<int>(), 0);
  EXPECT_EQ(session["keyframes_after"].as<int>(), maint["presets"][0]["database_images"].as<int>() +
                                                      session["added"].as<int>() -
                                                      session["retired"].as<int>());
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + Out("maint2") +
               " --maintain session_day046 --no-cache --no-plots -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("session_day046"), std::string::npos) << r.output;
  std::ifstream poses(dir_ / "poses.csv");
  std::string header;
  std::getline(poses, header);
  EXPECT_EQ(header, "query,x,y,theta,inliers");
  std::ifstream rank(dir_ / "rank.csv");
  std::getline(rank, header);
  EXPECT_EQ(header, "query,rank,image,score");
  r = RunGtbow("bench-retrieval --dataset " + d + " --vocab " + Out("v.gtvoc") +
               " --preset " GTBOW_CONFIG_DIR "/fast.yaml --queries 5 -q");
  ASSERT_EQ(r.code, 0) << r.output;
  {
    // The measured columns (mean ± sd, median) beside the paper's 31.9 ms: numbers, positive.
    std::smatch m;
    const std::regex row(
        R"(\| database query \| 31\.9 ± 3\.7 \| ([0-9.]+) ± ([0-9.]+) \| ([0-9.]+) \|)");
    ASSERT_TRUE(std::regex_search(r.output, m, row)) << r.output;
    const double mean = std::stod(m[1]), median = std::stod(m[3]);
    EXPECT_GE(median, 0.0);
    EXPECT_LT(mean, 31.9);  // a query of this tiny database: far below the paper's 32k-image figure
  }

  // The map through the node's Localizer: the real keyframes, then synthetic ones, saved while
  // a client inserts and another queries, loaded again; every answer survives the round trip
  // and the map file is deleted.
  r = RunGtbow("bench-map --dataset " + d + " --vocab " + Out("v.gtvoc") +
               " --keyframes 300 --queries 4 --threads 1 --no-cache --no-plot --out " +
               Out("bench_map") + " -q");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("## Warehouse maps through the node"), std::string::npos) << r.output;
  {
    const YAML::Node bm = YAML::LoadFile((dir_ / "bench_map" / "bench_map.json").string());
    ASSERT_EQ(bm["variants"].size(), 2u);  // high accuracy and fast
    for (const YAML::Node& v : bm["variants"]) {
      EXPECT_EQ(v["queries"].as<int>(), 4);
      EXPECT_EQ(v["identical_answers"].as<int>(), 4) << v["mismatches"];
      EXPECT_EQ(v["keyframes"].as<int>(), 300);
      EXPECT_GT(v["synthetic"].as<int>(), 0);
      EXPECT_GT(v["save"]["file_bytes"].as<double>(), 0.0);
      EXPECT_GE(v["save"]["saved_keyframes"].as<int>(), 300);
    }
    for (const auto& e : fs::directory_iterator(dir_ / "bench_map"))
      EXPECT_NE(e.path().extension(), ".gtmap") << e.path();
  }

  // Bad input: missing split, too many words, corrupt vocabulary file.
  r = RunGtbow("train-vocab --dataset " + d + " --split nope --out " + Out("x.gtvoc") + " -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("nope.txt does not exist"), std::string::npos) << r.output;
  r = RunGtbow("train-vocab --dataset " + d + " --words 1000000 --out " + Out("x.gtvoc") + " -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("fewer words"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir_ / "x.gtvoc"));
  std::ofstream(dir_ / "bad.gtvoc") << "GTBWVOC junk";
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("bad.gtvoc") + " --out " +
               Out("bad_eval") + " -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("bad.gtvoc"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir_ / "bad_eval"));  // no half-written results
  // --out replaces an earlier run's results, never another directory (the dataset, a mistake).
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + d + " -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("holds the dataset"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(fs::path(d) / "dataset.yaml"));
  fs::create_directories(dir_ / "mine");
  std::ofstream(dir_ / "mine" / "notes.txt") << "mine";
  r = RunGtbow("eval --dataset " + d + " --vocab " + Out("v.gtvoc") + " --out " + Out("mine") +
               " -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("no earlier gtbow eval results"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(dir_ / "mine" / "notes.txt"));
}

}  // namespace

namespace {

std::string ReadAll(const fs::path& p) {
  std::ifstream in(p);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void WriteAll(const fs::path& p, const std::string& s) { std::ofstream(p) << s; }

std::string Replace(std::string s, const std::string& from, const std::string& to) {
  for (size_t i = 0; (i = s.find(from, i)) != std::string::npos; i += to.size())
    s.replace(i, from.size(), to);
  return s;
}

// A dataset in the shared format that gtbow did not make: another image size, colour JPEG
// images, extra CSV columns, no synth.yaml, and only one of the standard query splits.
TEST_F(GtbowCli, EvalRunsOnAForeignDatasetAndTrainsItsOwnVocabulary) {
  const fs::path d = dir_ / "foreign";
  Result r = RunGtbow("synth --out " + d.string() +
                      " --area 0.25 0.2 --train 10 --queries 5 --days 0,90 --width 400 --height 300"
                      " --meters-per-pixel 0.0004 -q");
  ASSERT_EQ(r.code, 0) << r.output;
  fs::remove(d / "synth.yaml");
  fs::remove(d / "sequences" / "query_day090.txt");
  for (const auto& e : fs::directory_iterator(d / "images")) {
    const cv::Mat gray = cv::imread(e.path().string(), cv::IMREAD_GRAYSCALE);
    cv::Mat colour;
    cv::cvtColor(gray, colour, cv::COLOR_GRAY2BGR);
    colour.col(0).setTo(cv::Scalar(0, 0, 255));  // not quite gray
    fs::path jpg = e.path();
    jpg.replace_extension(".jpg");
    ASSERT_TRUE(cv::imwrite(jpg.string(), colour, {cv::IMWRITE_JPEG_QUALITY, 95}));
    fs::remove(e.path());
  }
  std::string poses = Replace(ReadAll(d / "poses.csv"), ".png", ".jpg");
  poses = Replace(poses, "image,x,y,theta", "theta,note,image,y,x");  // reordered, extra column
  std::string reordered;
  std::istringstream in(poses);
  std::string line;
  std::getline(in, line);
  reordered = line + "\n";
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::array<std::string, 4> f;  // image,x,y,theta
    std::istringstream ls(line);
    for (auto& x : f) std::getline(ls, x, ',');
    reordered += f[3] + ",seen," + f[0] + "," + f[2] + "," + f[1] + "\n";
  }
  WriteAll(d / "poses.csv", reordered);
  for (const auto& e : fs::directory_iterator(d / "sequences")) {
    WriteAll(e.path(), Replace(ReadAll(e.path()), ".png", ".jpg"));
  }

  r = RunGtbow("eval --dataset " + d.string() + " --words 600 --out " + Out("eval") +
               " --timing-queries 3 --no-cache --no-plots -q");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("| query_day000 | 0 | 5 |"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("query_day090"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("trained on the train split (10 images)"), std::string::npos) << r.output;
  EXPECT_NE(ReadAll(dir_ / "eval" / "results.json").find("\"image_width\": 400"),
            std::string::npos);

  // Bad datasets: a missing image, a split naming an image without a pose, an empty split.
  std::string first;
  std::istringstream seq(ReadAll(d / "sequences" / "query_day000.txt"));
  while (first.empty() || first[0] == '#') std::getline(seq, first);
  fs::rename(d / "images" / first, dir_ / "moved.jpg");
  r = RunGtbow("eval --dataset " + d.string() + " --words 600 --out " + Out("e2") +
               " --no-cache -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find(first), std::string::npos) << r.output;
  fs::rename(dir_ / "moved.jpg", d / "images" / first);
  WriteAll(d / "sequences" / "query_day000.txt", "nowhere.jpg\n");
  r = RunGtbow("eval --dataset " + d.string() + " --words 600 --out " + Out("e2") +
               " --no-cache -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("nowhere.jpg"), std::string::npos) << r.output;
  WriteAll(d / "sequences" / "query_day000.txt", "");
  r = RunGtbow("eval --dataset " + d.string() + " --words 600 --out " + Out("e2") +
               " --no-cache -q");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("query_day000"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir_ / "e2"));
}

}  // namespace

namespace {

// A map of format version 1 (the fuzzers' 64-word fixture, four keyframes) converted by
// `gtbow convert-map`; map-info tells both versions; bad input is refused by name.
// gtbow slam on a small drive (two laps with drifting odometry): loop closures, all right,
// a trajectory and keyframes closer to the truth than odometry alone, and a map with the
// optimised poses that map-info reads.
TEST_F(GtbowCli, SlamClosesLoopsAndWritesAMapWithTheOptimisedPoses) {
  const std::string d = Out("drive");
  Result r = RunGtbow("synth --out " + d +
                      " --area 0.4 0.3 --train 12 --queries 0 --drive 2.4 --drive-spacing 0.02 "
                      "--width 320 --height 240 --meters-per-pixel 0.0005 --only train,drive -q");
  ASSERT_EQ(r.code, 0) << r.output;
  r = RunGtbow("train-vocab --dataset " + d + " --words 800 --out " + Out("v.gtvoc") + " -q");
  ASSERT_EQ(r.code, 0) << r.output;
  r = RunGtbow("slam --dataset " + d + " --vocab " + Out("v.gtvoc") + " --exclude-recent 5 --out " +
               Out("slam") + " --no-cache --no-plots -q");
  ASSERT_EQ(r.code, 0) << r.output;
  const YAML::Node s = YAML::LoadFile((dir_ / "slam" / "summary.json").string());
  EXPECT_EQ(s["images"].as<int>(), 121);
  const int published = s["closures"]["published"].as<int>();
  EXPECT_GE(published, 20) << r.output;
  EXPECT_EQ(s["closures"]["correct"].as<int>(), published) << r.output;
  EXPECT_LT(s["keyframe_error"]["optimised"]["rmse_mm"].as<double>(),
            s["keyframe_error"]["odometry"]["rmse_mm"].as<double>())
      << r.output;
  EXPECT_LT(s["ate"]["optimised"]["rmse_mm"].as<double>(), 1.0) << r.output;
  for (const char* f : {"trajectory.csv", "keyframes.csv", "closures.csv", "summary.md"})
    EXPECT_TRUE(fs::exists(dir_ / "slam" / f)) << f;
  // The map holds every keyframe at its optimised pose (keyframes.csv's x, y, theta).
  r = RunGtbow("map-info " + Out("slam/map.gtmap") + " --poses " + Out("map_poses.csv"));
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("keyframes       " + std::to_string(s["keyframes"].as<int>())),
            std::string::npos)
      << r.output;
  auto read_csv = [](const fs::path& p) {
    std::vector<std::map<std::string, std::string>> rows;
    std::ifstream f(p);
    std::string line;
    std::vector<std::string> head;
    auto split = [](const std::string& l) {
      std::vector<std::string> out;
      std::stringstream ss(l);
      std::string c;
      while (std::getline(ss, c, ',')) out.push_back(c);
      return out;
    };
    std::getline(f, line);
    head = split(line);
    while (std::getline(f, line)) {
      const auto cells = split(line);
      std::map<std::string, std::string> row;
      for (size_t i = 0; i < head.size() && i < cells.size(); ++i) row[head[i]] = cells[i];
      rows.push_back(row);
    }
    return rows;
  };
  const auto in_map = read_csv(dir_ / "map_poses.csv");
  const auto optimised = read_csv(dir_ / "slam" / "keyframes.csv");
  ASSERT_EQ(in_map.size(), optimised.size());
  double moved = 0;  // how far optimisation moved the keyframes from their odometry poses
  for (size_t k = 0; k < in_map.size(); ++k) {
    EXPECT_NEAR(std::stod(in_map[k].at("x")), std::stod(optimised[k].at("x")), 1e-8) << k;
    EXPECT_NEAR(std::stod(in_map[k].at("y")), std::stod(optimised[k].at("y")), 1e-8) << k;
    moved = std::max(
        moved, std::hypot(std::stod(in_map[k].at("x")) - std::stod(optimised[k].at("odom_x")),
                          std::stod(in_map[k].at("y")) - std::stod(optimised[k].at("odom_y"))));
  }
  EXPECT_GT(moved, 1e-4);  // not the odometry poses
}

TEST_F(GtbowCli, ConvertMapTurnsAVersionOneMapIntoOneThatLoads) {
  using namespace gtbow;
  const synth::Scene scene = testing_util::SmallScene(0.3, 0.2, 0);
  Localizer built(fuzz::FixtureVocabulary(), fuzz::FixtureVocabularyPath(), fuzz::FixtureOptions());
  std::vector<testing_util::Version1Keyframe> v1;
  for (const auto& im : scene.plan().images) {
    if (v1.size() == 4) break;
    ProcessedImage p = built.Process(scene.Render(im));
    built.Add(p, 7, im.pose);
    v1.push_back({p.features, p.width, p.height, 7, im.pose});
  }
  testing_util::WriteVersion1Map(dir_ / "old.gtmap", *fuzz::FixtureVocabulary(),
                                 fuzz::FixtureVocabularyPath(), fuzz::FixtureOptions(), v1);
  Result r = RunGtbow("map-info " + Out("old.gtmap"));
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("format version  1 (convert it: gtbow convert-map)"), std::string::npos)
      << r.output;
  r = RunGtbow("convert-map --in " + Out("old.gtmap") + " --out " + Out("new.gtmap"));
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("format version  3"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("keyframes       4"), std::string::npos) << r.output;
  Localizer loaded(fuzz::FixtureVocabulary(), fuzz::FixtureVocabularyPath(),
                   fuzz::FixtureOptions());
  loaded.Load(dir_ / "new.gtmap");
  ASSERT_EQ(loaded.size(), 4u);
  for (uint32_t id = 0; id < 4; ++id) {
    const auto a = built.QueryKeyframe(id, 3, true), b = loaded.QueryKeyframe(id, 3, true);
    ASSERT_EQ(a.size(), b.size());
    for (size_t k = 0; k < a.size(); ++k) {
      EXPECT_EQ(a[k].id, b[k].id);
      EXPECT_EQ(a[k].score, b[k].score);
      EXPECT_EQ(a[k].relative.floor_from_query.x, b[k].relative.floor_from_query.x);
    }
  }
  // Already converted; the same file in and out; a damaged input: each refused, nothing written.
  r = RunGtbow("convert-map --in " + Out("new.gtmap") + " --out " + Out("again.gtmap"));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("already format version 3"), std::string::npos) << r.output;
  r = RunGtbow("convert-map --in " + Out("old.gtmap") + " --out " + Out("old.gtmap"));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("--out must differ from --in"), std::string::npos) << r.output;
  std::string bytes = ReadFile(dir_ / "old.gtmap");
  bytes[bytes.size() / 2] ^= 1;
  WriteFileAtomic(dir_ / "bad.gtmap", bytes);
  r = RunGtbow("convert-map --in " + Out("bad.gtmap") + " --out " + Out("bad_new.gtmap"));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("bad.gtmap"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("checksum"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir_ / "again.gtmap"));
  EXPECT_FALSE(fs::exists(dir_ / "bad_new.gtmap"));
}

}  // namespace
