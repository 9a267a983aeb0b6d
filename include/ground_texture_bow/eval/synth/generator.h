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
  int threads = 0;                 // worker threads, 0 = all cores
  // Render only these kinds of split ("train", "database", "queries"); empty = all. Poses
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
};

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
