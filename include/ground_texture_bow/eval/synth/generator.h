// Synthetic ground-texture datasets with exact ground truth (docs/DATASET_FORMAT.md):
// a training area kept apart from the map, a lawnmower-path database, and query splits
// recorded on later days while the floor ages.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "ground_texture_bow/eval/dataset.h"
#include "ground_texture_bow/eval/synth/camera.h"
#include "ground_texture_bow/eval/synth/floor.h"

namespace gtbow {
namespace synth {

// Changes whenever the same options and seed render different images (recorded in synth.yaml,
// so that `make benchmark` can tell a stale rendering). 2: relief shading by a camera-mounted
// light, motion blur, per-visit tone curve.
constexpr int kRendererVersion = 2;

// The odometry of the synthetic drive (gtbow synth --drive): wheel odometry integrated step by
// step from the true motion between consecutive drive images, with the errors a differential
// drive typically has. For a step of true length d (metres) and true turn dtheta (radians),
// expressed in the previous pose's frame as (dx, dy, dtheta):
//   (dx, dy) * (1 + scale_bias + scale_noise * n1)                      wheel radius / slip
//   dtheta * (1 + turn_bias) + heading_bias * d + heading_noise * sqrt(d) * n2
//                                                                         track width / drift
// with n1, n2 independent standard normals per step, drawn from the dataset's seed. The
// integrated poses start at the first true pose (the odometry frame is the floor frame at the
// start) and drift from there.
struct OdometryNoise {
  double scale_bias = 0.003;     // systematic distance scale error, fraction
  double scale_noise = 0.01;     // per-step distance scale noise, fraction (sd)
  double turn_bias = 0.002;      // systematic turn scale error, fraction
  double heading_bias = 0.0005;  // systematic heading drift, rad per metre driven
  double heading_noise = 0.001;  // random heading walk, rad per sqrt(metre) (sd)

  void Check() const;  // throws std::invalid_argument naming the first bad field
};

struct SynthOptions {
  Surface surface = Surface::kAsphalt;  // floor material
  uint64_t seed = 1;                    // same options and seed give byte-identical output
  double area_width = 1.0;              // database area along floor x, metres (> 0)
  double area_height = 1.0;             // database area along floor y, metres (> 0)
  double overlap = 0.6;                 // overlap of lawnmower neighbours, fraction [0, 0.95]
  int train_images = 200;               // images of the separate training area (>= 0)
  int queries_per_split = 100;          // images per query split (>= 0)
  std::vector<int> query_days = {0, 30, 90, 180};  // one query split per day, days >= 0
  double path_fraction = 0.5;      // share of queries taken along paths, rest random
  double aging = 1.0;              // rate of floor wear, 1 = default, 0 = none
  double position_jitter = 0.002;  // database pose noise around the path, metres (sd)
  double heading_jitter = 0.02;    // database heading noise, radians (sd)
  CameraOptions camera;            // image size, scale and sensor effects
  // A continuous drive (split "drive"): laps around a rounded rectangle inset in the database
  // area, each lap shifted sideways a little (up to 35% of the footprint height) so that
  // revisits overlap without repeating poses exactly, an image every drive_spacing metres, and
  // drive_odometry.csv beside poses.csv (OdometryNoise). 0 = no drive.
  double drive_length = 0.0;    // metres of path
  double drive_spacing = 0.01;  // metres between consecutive drive images (> 0)
  OdometryNoise odometry;       // noise model of drive_odometry.csv
  // Later sessions over the same floor (needs a drive): for each day D here (> 0) a split
  // drive_dayDDD of later_drive_length metres (0: drive_length) on the floor aged to day D, in
  // its own lighting, starting (k + 1) thirds of a lap further along the laps than the first
  // drive (k: its place in this list), and its wheel odometry in drive_dayDDD_odometry.csv,
  // which starts at the origin (a robot's odometry after it boots, not the map's frame).
  std::vector<double> later_drive_days;
  double later_drive_length = 0.0;
  // What a robot saw just before each query: query_trail images per query on a straight line
  // behind it (toward the middle of its area or photo), trail_spacing metres apart, heading as
  // the query's with a little turn, in the query's session (its day and visit). For query split
  // query_X they form split trail_X (query i's images at i * query_trail + j - 1, j = 1 the
  // nearest), and trail_X_odometry.csv holds each one's wheel odometry pose relative to its
  // query (the query at the origin; OdometryNoise over the trail, oldest first). 0 = none.
  int query_trail = 0;
  double trail_spacing = 0.03;
  // Maintenance sessions (gtbow eval --maintain): for each day D here (> 0) a split
  // session_dayDDD of session_images images per photo (0: queries_per_split), or over the
  // query area of a synthetic floor, at random poses, on the floor aged to day D in its own
  // lighting and debris: a robot's day of localizing over the floor, between the map and the
  // query days. Its own seed and visits: the other splits do not change.
  std::vector<int> session_days;
  int session_images = 0;
  int threads = 0;  // worker threads, 0 = all cores
  // Render only these kinds of split ("train", "database", "queries", "drive"); empty = all. Poses
  // are those of the full dataset, so partial datasets of one seed fit together.
  std::vector<std::string> only;
  // A photo floor instead of a procedural one (gtbow synth --photo): each photograph is one
  // bounded region of the map, laid side by side on the floor; no image crosses a region's
  // edge. The database is a lawnmower path over each region; every query split is split per
  // photo (query_dayNNN_<stem>, queries_per_split each) when there are several, at random
  // poses and headings; the train split comes from `train_photos`. The ageing model (grime,
  // stains, tyre marks, scuffs, debris) applies on top of the photos; relief shading does not.
  std::vector<std::filesystem::path> photos;
  std::vector<std::filesystem::path> train_photos;
  double photo_meters_per_pixel = 0.0;  // ground size of a photo pixel, metres; 0 = the camera's

  // Throws std::invalid_argument naming the first bad field.
  void Check() const;
};

// The area side (metres) of a square database area whose lawnmower path has about `images`
// images under `options` (overlap and camera).
double SquareAreaForImages(const SynthOptions& options, int images);

// One image to render.
struct PlannedImage {
  std::string name;    // file name under images/
  std::string split;   // sequence it belongs to
  Pose2D pose;         // exact ground truth
  double day = 0.0;    // floor age when taken, days
  uint64_t visit = 0;  // recording session (debris and lighting)
};

struct DatasetPlan {
  DatasetInfo info;
  std::vector<PlannedImage> images;
  std::map<std::string, std::vector<std::string>> splits;
  // The drive's odometry, one pose per image of split "drive" in its order (empty without a
  // drive).
  std::vector<PoseRecord> drive_odometry;
  // The later drives' odometry, by split (drive_dayDDD), each written as <split>_odometry.csv.
  std::map<std::string, std::vector<PoseRecord>> later_drive_odometry;
  // The query trails' odometry relative to their queries, by trail split (trail_X), each
  // written as <split>_odometry.csv.
  std::map<std::string, std::vector<PoseRecord>> trail_odometry;
};

// The true poses of the drive: `length` metres of laps around a rounded rectangle inset half a
// footprint diagonal into the area [0, width] x [0, height], one pose every `spacing` metres
// along the path, heading along the path (counter-clockwise), starting `start_laps` laps along
// it (a fraction starts part-way round).
std::vector<Pose2D> DrivePath(double width, double height, const ImageGeometry& geometry,
                              double length, double spacing, double start_laps = 0.0);

// Odometry integrated from consecutive true poses under `noise` (OdometryNoise), seeded.
std::vector<Pose2D> SimulateOdometry(const std::vector<Pose2D>& truth, const OdometryNoise& noise,
                                     uint64_t seed);

// Lays out every image and its pose without rendering anything (a photo floor's photographs
// are read for their sizes).
DatasetPlan PlanDataset(const SynthOptions& options);

// The photographs of a photo floor laid out side by side on the floor (the map's, then after a
// 0.5 m gap the training photos), each checked to hold at least one image. Throws
// std::invalid_argument naming the file of a missing, undecodable or too small photo.
std::vector<PhotoRegion> LoadPhotoFloor(const SynthOptions& options);
// PlanDataset for a photo floor whose regions are already loaded.
DatasetPlan PlanPhotoDataset(const SynthOptions& options, const std::vector<PhotoRegion>& regions);

// The lighting of a recording session.
Lighting VisitLighting(uint64_t seed, uint64_t visit);

// Renders one planned image.
cv::Mat RenderPlannedImage(const Floor& floor, const Camera& camera, const SynthOptions& options,
                           const PlannedImage& image);

// A synthetic floor ready to render in memory (tests, examples): the options, the plan, the
// floor and the camera. Not for photo floors (those need LoadPhotoFloor).
class Scene {
 public:
  explicit Scene(const SynthOptions& options);
  const SynthOptions& options() const { return options_; }
  const DatasetPlan& plan() const { return plan_; }
  // Any image, planned or not (another pose, day or visit of the same floor).
  cv::Mat Render(const PlannedImage& image) const;

 private:
  SynthOptions options_;
  DatasetPlan plan_;
  Floor floor_;
  Camera camera_;
};

struct SynthSummary {
  std::map<std::string, size_t> split_sizes;
  size_t images = 0;
  double seconds = 0.0;
  uint64_t bytes = 0;
  double mean_neighbour_overlap = 0.0;  // consecutive database images along the path
};

// Renders the dataset into `out` using all threads. The output appears atomically: it is built
// in a staging directory next to `out` and renamed into place when complete. An existing
// non-empty `out` is replaced only with `force`. Throws std::invalid_argument or
// std::runtime_error with a message naming the problem.
SynthSummary GenerateDataset(const SynthOptions& options, const std::filesystem::path& out,
                             bool force, bool progress);

}  // namespace synth
}  // namespace gtbow
