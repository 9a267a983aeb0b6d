#include "ground_texture_bow/eval/synth/generator.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <stdexcept>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "test_util.h"

#include "ground_texture_bow/core/file_util.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace synth {
namespace {

SynthOptions Small() {
  SynthOptions o;
  o.area_width = 0.3;
  o.area_height = 0.25;
  o.train_images = 6;
  o.queries_per_split = 4;
  o.query_days = {0, 60};
  o.camera.width = 160;  // small images keep the test fast; geometry scales with them
  o.camera.height = 120;
  o.camera.meters_per_pixel = 0.0005;
  return o;
}

TEST(Generator, PlanHasTheStandardSplitsAndGeometry) {
  SynthOptions o;  // the defaults: 1 x 1 m, 60% overlap
  const DatasetPlan plan = PlanDataset(o);
  EXPECT_EQ(plan.splits.at("train").size(), 200u);
  EXPECT_EQ(plan.splits.at("query_day000").size(), 100u);
  EXPECT_EQ(plan.splits.at("query_day180").size(), 100u);
  ASSERT_EQ(plan.splits.count("database"), 1u);
  EXPECT_EQ(plan.info.query_days.at("query_day090"), 90);
  const ImageGeometry g = o.camera.Geometry();
  std::vector<Pose2D> db, train;
  for (const auto& im : plan.images) {
    if (im.split == "database") db.push_back(im.pose);
    if (im.split == "train") train.push_back(im.pose);
  }
  // Lawnmower: consecutive images overlap by about 60%, and cover the area.
  double sum = 0;
  int n = 0;
  for (size_t i = 1; i < db.size(); ++i) {
    const double ov = Overlap(db[i], db[i - 1], g);
    if (ov > 0) {
      sum += ov;
      ++n;
    }
  }
  EXPECT_NEAR(sum / n, 0.6, 0.05);
  // The training area is kept apart: no training image overlaps any database image.
  for (const auto& t : train) {
    for (const auto& d : db) ASSERT_EQ(Overlap(t, d, g), 0.0);
  }
  // Every query has relevant database images.
  for (const auto& im : plan.images) {
    if (im.split.rfind("query_", 0) != 0) continue;
    int relevant = 0;
    for (const auto& d : db) relevant += IsRelevant(im.pose, d, g) ? 1 : 0;
    EXPECT_GT(relevant, 0) << im.name;
  }
}

TEST(Generator, NoEmptySplits) {
  SynthOptions o = Small();
  o.train_images = 0;
  o.queries_per_split = 0;
  const DatasetPlan plan = PlanDataset(o);
  EXPECT_EQ(plan.splits.size(), 1u);
  EXPECT_EQ(plan.splits.count("database"), 1u);
  EXPECT_TRUE(plan.info.query_days.empty());
}

TEST(Generator, OnlySomeSplitsKeepTheFullDatasetsPoses) {
  SynthOptions o = Small();
  const DatasetPlan full = PlanDataset(o);
  o.only = {"train", "queries"};
  const DatasetPlan part = PlanDataset(o);
  EXPECT_EQ(part.splits.count("database"), 0u);
  EXPECT_EQ(part.splits.at("train"), full.splits.at("train"));
  EXPECT_EQ(part.splits.at("query_day060"), full.splits.at("query_day060"));
  EXPECT_EQ(part.images.size(), full.images.size() - full.splits.at("database").size());
  o.only = {"walls"};
  EXPECT_THROW(o.Check(), std::invalid_argument);
}

// Later sessions of a drive: their own split and odometry file, on their day and in their own
// visit, the same laps started a third of a lap further on for each, and odometry that starts
// at the origin (a robot after it boots) while following the true motion.
TEST(Generator, LaterDrivesStartElsewhereWithOdometryFromTheOrigin) {
  SynthOptions o;
  o.area_width = 1.2;
  o.area_height = 0.8;
  o.drive_length = 4.0;
  o.drive_spacing = 0.02;
  o.later_drive_days = {30, 90};
  o.later_drive_length = 1.0;
  o.only = {"drive"};
  const DatasetPlan plan = PlanDataset(o);
  ASSERT_EQ(plan.splits.size(), 3u);
  ASSERT_EQ(plan.splits.at("drive").size(), 201u);
  std::map<std::string, const PlannedImage*> by_name;
  for (const auto& im : plan.images) by_name[im.name] = &im;
  const Pose2D first = by_name.at(plan.splits.at("drive")[0])->pose;
  std::set<uint64_t> visits;
  int k = 0;
  for (const char* split : {"drive_day030", "drive_day090"}) {
    const auto& names = plan.splits.at(split);
    const auto& odom = plan.later_drive_odometry.at(split);
    ASSERT_EQ(names.size(), 51u) << split;
    ASSERT_EQ(odom.size(), names.size());
    const PlannedImage& start = *by_name.at(names[0]);
    EXPECT_EQ(start.day, k == 0 ? 30.0 : 90.0);
    visits.insert(start.visit);
    // Elsewhere on the laps: a third (two thirds) of a lap from the first drive's start.
    EXPECT_GT(std::hypot(start.pose.x - first.x, start.pose.y - first.y), 0.2) << split;
    // Odometry from the origin, then the true motion up to its noise (a few mm over a metre).
    EXPECT_EQ(odom[0].pose.x, 0.0);
    EXPECT_EQ(odom[0].pose.y, 0.0);
    EXPECT_EQ(odom[0].pose.theta, 0.0);
    const Pose2D truth_rel = Compose(Inverse(start.pose), by_name.at(names.back())->pose);
    const Pose2D odom_rel = odom.back().pose;
    EXPECT_LT(std::hypot(truth_rel.x - odom_rel.x, truth_rel.y - odom_rel.y), 0.02) << split;
    EXPECT_GT(std::hypot(truth_rel.x, truth_rel.y), 0.5) << split;
    ++k;
  }
  EXPECT_EQ(visits.size(), 2u);
  SynthOptions bad = o;
  bad.drive_length = 0;
  EXPECT_THROW(PlanDataset(bad), std::invalid_argument);
  bad = o;
  bad.later_drive_days = {0};
  EXPECT_THROW(PlanDataset(bad), std::invalid_argument);
}

TEST(Generator, QueryTrailsLieBehindTheirQueriesInTheirSessionWithOdometry) {
  SynthOptions o = Small();
  o.query_trail = 3;
  o.trail_spacing = 0.02;
  const DatasetPlan plan = PlanDataset(o);
  std::map<std::string, const PlannedImage*> by_name;
  for (const auto& im : plan.images) by_name[im.name] = &im;
  for (const char* day : {"day000", "day060"}) {
    const auto& queries = plan.splits.at(std::string("query_") + day);
    const auto& trail = plan.splits.at(std::string("trail_") + day);
    const auto& odom = plan.trail_odometry.at(std::string("trail_") + day);
    ASSERT_EQ(trail.size(), 3 * queries.size());
    ASSERT_EQ(odom.size(), trail.size());
    for (size_t i = 0; i < queries.size(); ++i) {
      const PlannedImage& q = *by_name.at(queries[i]);
      for (size_t j = 1; j <= 3; ++j) {
        const PlannedImage& t = *by_name.at(trail[i * 3 + j - 1]);
        EXPECT_EQ(odom[i * 3 + j - 1].image, t.name);
        EXPECT_EQ(t.day, q.day);
        EXPECT_EQ(t.visit, q.visit);  // the same session: the same marks on the floor
        const double d = std::hypot(t.pose.x - q.pose.x, t.pose.y - q.pose.y);
        EXPECT_LE(d, 0.02 * j + 1e-6) << t.name;
        // Odometry relative to the query: the true relative pose up to its noise.
        const Pose2D truth = Compose(Inverse(q.pose), t.pose);
        const Pose2D& od = odom[i * 3 + j - 1].pose;
        EXPECT_LT(std::hypot(truth.x - od.x, truth.y - od.y), 0.002) << t.name;
        EXPECT_LT(std::abs(WrapAngle(truth.theta - od.theta)), 0.005) << t.name;
        EXPECT_GT(std::hypot(od.x, od.y), 0.0) << t.name;
      }
    }
  }
  // Trails go with the queries.
  o.only = {"database"};
  EXPECT_TRUE(PlanDataset(o).trail_odometry.empty());
  o.only = {"queries"};
  EXPECT_EQ(PlanDataset(o).trail_odometry.size(), 2u);
  o.query_trail = 21;
  EXPECT_THROW(PlanDataset(o), std::invalid_argument);
}

// Maintenance sessions (gtbow synth --session-days): their own splits on their days and visits;
// every other image of the plan is the same as without them.
TEST(Generator, SessionsAddTheirOwnSplitsAndChangeNothingElse) {
  SynthOptions o = Small();
  const DatasetPlan before = PlanDataset(o);
  o.session_days = {30, 90};
  o.session_images = 7;
  const DatasetPlan plan = PlanDataset(o);
  ASSERT_EQ(plan.images.size(), before.images.size() + 14);
  for (size_t i = 0; i < before.images.size(); ++i) {
    const PlannedImage &a = before.images[i], &b = plan.images[i];
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.visit, b.visit);
    EXPECT_EQ(a.pose.x, b.pose.x);
    EXPECT_EQ(a.pose.theta, b.pose.theta);
  }
  std::set<uint64_t> visits;
  for (const auto& im : before.images) visits.insert(im.visit);
  for (const char* split : {"session_day030", "session_day090"}) {
    ASSERT_EQ(plan.splits.at(split).size(), 7u) << split;
  }
  for (size_t i = before.images.size(); i < plan.images.size(); ++i) {
    const PlannedImage& im = plan.images[i];
    EXPECT_EQ(im.day, im.split == "session_day030" ? 30.0 : 90.0) << im.name;
    EXPECT_EQ(visits.count(im.visit), 0u) << "a session's own light and debris: " << im.name;
  }
  EXPECT_TRUE(plan.info.query_days.count("session_day030") == 0) << "not a query split";
  o.only = {"database"};
  EXPECT_EQ(PlanDataset(o).splits.count("session_day030"), 0u);
  o.only = {};
  o.session_days = {0};
  EXPECT_THROW(PlanDataset(o), std::invalid_argument);
}

TEST(Generator, SquareAreaForImages) {
  SynthOptions o;
  for (int n : {100, 32000}) {
    o.area_width = o.area_height = SquareAreaForImages(o, n);
    const size_t got = PlanDataset(o).splits.at("database").size();
    EXPECT_NEAR(double(got), n, 0.03 * n + 20);
  }
}

class GeneratorFiles : public testing_util::TempDirTest {};

TEST_F(GeneratorFiles, WritesALoadableDatasetByteIdenticallyForAnyThreadCount) {
  SynthOptions o = Small();
  o.threads = 1;
  const SynthSummary s = GenerateDataset(o, dir_ / "a", false, false);
  o.threads = 2;
  GenerateDataset(o, dir_ / "b", false, false);
  EXPECT_EQ(s.images, s.split_sizes.at("database") + 6 + 2 * 4);

  const Dataset d = Dataset::Load(dir_ / "a");
  EXPECT_EQ(d.info().geometry.width, 160);
  EXPECT_EQ(d.info().surface, "asphalt");
  EXPECT_EQ(d.SplitNames(),
            (std::vector<std::string>{"database", "query_day000", "query_day060", "train"}));
  for (const auto& split : d.SplitNames()) {
    for (const auto& name : d.Split(split)) {
      ASSERT_EQ(d.LoadGray(name).cols, 160);
      EXPECT_EQ(ReadFile(dir_ / "a" / "images" / name), ReadFile(dir_ / "b" / "images" / name));
    }
  }
  for (const char* f : {"dataset.yaml", "poses.csv", "sequences/database.txt"}) {
    EXPECT_EQ(ReadFile(dir_ / "a" / f), ReadFile(dir_ / "b" / f)) << f;
  }
  // A different seed gives a different floor.
  o.seed = 2;
  GenerateDataset(o, dir_ / "c", false, false);
  EXPECT_NE(ReadFile(dir_ / "a" / "images" / "database_000000.png"),
            ReadFile(dir_ / "c" / "images" / "database_000000.png"));
}

TEST_F(GeneratorFiles, BadInputNeverTouchesExistingOutput) {
  const fs::path out = dir_ / "out";
  fs::create_directories(out);
  std::ofstream(out / "precious.txt") << "keep";
  try {
    GenerateDataset(Small(), out, false, false);
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("not empty"), std::string::npos) << e.what();
  }
  EXPECT_EQ(ReadFile(out / "precious.txt"), "keep");

  SynthOptions bad = Small();
  bad.area_width = -1;
  try {
    GenerateDataset(bad, out, true, false);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("area_width"), std::string::npos);
  }
  EXPECT_EQ(ReadFile(out / "precious.txt"), "keep");

  // An output path below a regular file cannot be created.
  EXPECT_THROW(GenerateDataset(Small(), out / "precious.txt" / "x", false, false),
               std::runtime_error);
  // --force replaces the old output only once the new one is complete.
  GenerateDataset(Small(), out, true, false);
  EXPECT_FALSE(fs::exists(out / "precious.txt"));
  EXPECT_TRUE(fs::exists(out / "dataset.yaml"));
  // Nothing but the output is left in the parent directory.
  EXPECT_EQ(std::distance(fs::directory_iterator(dir_), fs::directory_iterator()), 1);
}

TEST(Generator, CheckNamesTheBadField) {
  auto expect_field = [](SynthOptions o, const std::string& field) {
    try {
      o.Check();
      FAIL() << field;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  SynthOptions o;
  o.area_height = 0;
  expect_field(o, "area_height");
  o = {};
  o.overlap = 1.0;
  expect_field(o, "overlap");
  o = {};
  o.query_days = {30, 30};
  expect_field(o, "query_days");
  o = {};
  o.train_images = -1;
  expect_field(o, "train_images");
}

// Writes an image of `w` x `h` pixels (rendered floor texture) as a photo file.
fs::path WritePhoto(const fs::path& dir, const std::string& name, int w, int h, uint64_t seed) {
  CameraOptions o;
  o.sensor_effects = false;
  o.width = w;
  o.height = h;
  o.meters_per_pixel = 0.0005;
  const cv::Mat img =
      Camera(o).Capture(Floor(Surface::kConcrete, seed), {3.0, 3.0, 0.0}, {}, {}, 1);
  const fs::path p = dir / name;
  cv::imwrite(p.string(), img);
  return p;
}

class PhotoFloor : public testing_util::TempDirTest {
 protected:
  SynthOptions Options() {
    SynthOptions o = Small();
    o.photos = {WritePhoto(dir_, "big.png", 600, 420, 1),
                WritePhoto(dir_, "small floor.jpg", 300, 260, 2)};
    o.train_photos = {WritePhoto(dir_, "other.png", 400, 300, 3)};
    o.camera.width = 160;
    o.camera.height = 120;
    o.camera.meters_per_pixel = 0.0005;
    o.queries_per_split = 12;
    return o;
  }
};

TEST_F(PhotoFloor, NoImageCrossesItsPhotosEdgeAndQueriesAreSplitPerPhoto) {
  SynthOptions o = Options();
  o.query_trail = 2;  // trails too stay on their query's photo
  const auto regions = LoadPhotoFloor(o);
  ASSERT_EQ(regions.size(), 3u);
  EXPECT_EQ(regions[1].label, "small_floor");
  const DatasetPlan plan = PlanPhotoDataset(o, regions);
  const ImageGeometry g = o.camera.Geometry();
  std::map<std::string, int> per_region_db;
  for (const auto& im : plan.images) {
    const auto fp = Footprint(im.pose, g);
    int inside = -1;
    for (size_t r = 0; r < regions.size(); ++r) {
      bool all = true;
      for (const auto& c : fp) {
        // With the 2% scale jitter of the camera, corners stay inside the photo.
        const double cx = im.pose.x + 1.02 * (c.x - im.pose.x),
                     cy = im.pose.y + 1.02 * (c.y - im.pose.y);
        all = all && cx >= regions[r].x0 && cx <= regions[r].x0 + regions[r].width() &&
              cy >= regions[r].y0 && cy <= regions[r].y0 + regions[r].height();
      }
      if (all) inside = static_cast<int>(r);
    }
    ASSERT_GE(inside, 0) << im.name << " crosses a photo's edge";
    if (im.split == "train") {
      EXPECT_EQ(inside, 2) << im.name;
    } else {
      EXPECT_LT(inside, 2) << im.name;
    }
    if (im.split == "database") ++per_region_db[regions[inside].label];
    if (im.split.rfind("query_", 0) == 0 || im.split.rfind("trail_", 0) == 0) {
      EXPECT_NE(im.split.find(regions[inside].label), std::string::npos) << im.split;
    }
  }
  EXPECT_GE(per_region_db["big"], 6);
  EXPECT_GE(per_region_db["small_floor"], 2);
  EXPECT_EQ(plan.splits.at("query_day000_big").size(), 12u);
  EXPECT_EQ(plan.splits.at("query_day060_small_floor").size(), 12u);
  EXPECT_EQ(plan.info.query_days.at("query_day060_big"), 60);
  // Random headings, and the same plan for the same seed.
  const DatasetPlan again = PlanPhotoDataset(o, regions);
  ASSERT_EQ(again.images.size(), plan.images.size());
  std::set<int> headings;
  for (size_t i = 0; i < plan.images.size(); ++i) {
    EXPECT_EQ(again.images[i].pose.x, plan.images[i].pose.x);
    EXPECT_EQ(again.images[i].pose.theta, plan.images[i].pose.theta);
    if (plan.images[i].split.rfind("query_", 0) == 0) {
      headings.insert(
          static_cast<int>(std::floor((plan.images[i].pose.theta + M_PI) / (M_PI / 2))));
    }
  }
  EXPECT_GE(headings.size(), 4u);
}

TEST_F(PhotoFloor, WritesADatasetAndBadPhotosAreNamed) {
  SynthOptions o = Options();
  o.queries_per_split = 3;
  o.train_images = 4;
  const fs::path out = dir_ / "ds";
  const SynthSummary s = GenerateDataset(o, out, false, false);
  EXPECT_EQ(s.split_sizes.at("query_day000_big"), 3u);
  const Dataset ds = Dataset::Load(out);
  EXPECT_EQ(ds.info().surface, "photo: big, small_floor");
  const std::string prov = ReadFile(out / "synth.yaml");
  EXPECT_NE(prov.find("file: \"small floor.jpg\", use: map"), std::string::npos) << prov;
  auto expect_error = [&](SynthOptions bad, const std::string& part) {
    try {
      PlanDataset(bad);
      ADD_FAILURE() << "accepted: " << part;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << e.what();
    }
  };
  SynthOptions tiny = Options();
  tiny.photos.push_back(WritePhoto(dir_, "tiny.png", 150, 100, 4));
  expect_error(tiny, "tiny.png: the photo is 150 x 100 px");
  SynthOptions text = Options();
  WriteFileAtomic(dir_ / "notes.png", "not an image");
  text.photos.push_back(dir_ / "notes.png");
  expect_error(text, "notes.png: not an image, or a format that cannot be decoded");
  SynthOptions missing = Options();
  missing.photos.push_back(dir_ / "gone.png");
  expect_error(missing, "gone.png: no such file");
  SynthOptions no_train = Options();
  no_train.train_photos.clear();
  expect_error(no_train, "train split needs training photos");
}

}  // namespace
}  // namespace synth
}  // namespace gtbow
