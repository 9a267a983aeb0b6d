#include "ground_texture_bow/core/synth/generator.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <thread>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>

#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/progress.h"
#include "noise.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace synth {

namespace {

constexpr uint64_t kDatabaseVisit = 1;
constexpr uint64_t kTrainVisit = 2;
constexpr uint64_t kFirstQueryVisit = 100;

// FNV-1a: a stable string hash (std::hash may differ between standard libraries).
uint64_t Fnv1a(const std::string& s) {
  uint64_t h = 0xcbf29ce484222325ULL;
  for (unsigned char c : s) {
    h ^= c;
    h *= 0x100000001b3ULL;
  }
  return h;
}

double Round7(double v) { return std::round(v * 1e7) / 1e7; }

Pose2D Rounded(Pose2D p) {
  // Poses are written with 7 decimals; render from exactly what is written.
  return {Round7(p.x), Round7(p.y), Round7(WrapAngle(p.theta))};
}

std::string ImageName(const std::string& split, size_t index) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "_%06zu.png", index);
  return split + buf;
}

std::string QuerySplitName(int day) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "query_day%03d", day);
  return buf;
}

struct Layout {
  double fw, fh;    // footprint, metres
  double sx, sy;    // lawnmower steps, metres
  int cols, rows;
};

Layout LawnmowerLayout(const SynthOptions& o, double aw, double ah) {
  Layout l;
  l.fw = o.camera.width * o.camera.meters_per_pixel;
  l.fh = o.camera.height * o.camera.meters_per_pixel;
  l.sx = std::max(1e-6, (1.0 - o.overlap) * l.fw);
  l.sy = std::max(1e-6, (1.0 - o.overlap) * l.fh);
  l.cols = aw <= l.fw ? 1 : static_cast<int>(std::ceil((aw - l.fw) / l.sx - 1e-9)) + 1;
  l.rows = ah <= l.fh ? 1 : static_cast<int>(std::ceil((ah - l.fh) / l.sy - 1e-9)) + 1;
  return l;
}

// Random pose with its centre inside [x0, x1] x [y0, y1] and any heading.
Pose2D RandomPose(CellRng& rng, double x0, double x1, double y0, double y1) {
  return {rng.Uniform(x0, std::max(x0, x1)), rng.Uniform(y0, std::max(y0, y1)),
          rng.Uniform(-M_PI, M_PI)};
}

}  // namespace

void SynthOptions::Check() const {
  camera.Check();
  auto need = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument(what);
  };
  need(area_width > 0 && std::isfinite(area_width), "area_width must be a positive size in metres");
  need(area_height > 0 && std::isfinite(area_height),
       "area_height must be a positive size in metres");
  need(overlap >= 0 && overlap <= 0.95, "overlap must be in [0, 0.95]");
  need(train_images >= 0, "train_images must be >= 0");
  need(queries_per_split >= 0, "queries_per_split must be >= 0");
  for (int d : query_days) need(d >= 0 && d <= 100000, "query_days must be in [0, 100000]");
  std::vector<int> days = query_days;
  std::sort(days.begin(), days.end());
  need(std::adjacent_find(days.begin(), days.end()) == days.end(), "query_days must be distinct");
  need(path_fraction >= 0 && path_fraction <= 1, "path_fraction must be in [0, 1]");
  need(aging >= 0 && std::isfinite(aging), "aging must be >= 0");
  need(position_jitter >= 0, "position_jitter must be >= 0");
  need(heading_jitter >= 0, "heading_jitter must be >= 0");
  need(threads >= 0, "threads must be >= 0");
  for (const auto& k : only) {
    need(k == "train" || k == "database" || k == "queries",
         "only: unknown split kind '" + k + "' (valid: train, database, queries)");
  }
  const Layout l = LawnmowerLayout(*this, area_width, area_height);
  need(static_cast<double>(l.cols) * l.rows <= 5e7,
       "the database would exceed 50 million images; reduce the area or the overlap");
}

double SquareAreaForImages(const SynthOptions& o, int images) {
  if (images <= 0) throw std::invalid_argument("database image count must be positive");
  double lo = 1e-4, hi = 1e4;
  for (int it = 0; it < 100; ++it) {
    const double mid = std::sqrt(lo * hi);
    const Layout l = LawnmowerLayout(o, mid, mid);
    if (static_cast<double>(l.cols) * l.rows < images) lo = mid; else hi = mid;
  }
  return hi;
}

DatasetPlan PlanDataset(const SynthOptions& o) {
  o.Check();
  DatasetPlan plan;
  plan.info.format_version = 1;
  plan.info.surface = SurfaceName(o.surface);
  plan.info.name = plan.info.surface + "_synth_seed" + std::to_string(o.seed);
  plan.info.geometry = o.camera.Geometry();
  const Layout l = LawnmowerLayout(o, o.area_width, o.area_height);

  // Training area: same surface, to the right of the map with a 0.5 m gap.
  {
    CellRng rng(HashCombine(o.seed, 0x7a1));
    const double side = std::max(0.5, std::sqrt(o.train_images * l.fw * l.fh / 0.3));
    const double x0 = o.area_width + 0.5;
    std::vector<std::string> names;
    for (int i = 0; i < o.train_images; ++i) {
      PlannedImage im;
      im.split = "train";
      im.name = ImageName("train", i);
      im.pose = Rounded(RandomPose(rng, x0 + 0.5 * l.fw, x0 + side - 0.5 * l.fw, 0.5 * l.fh,
                                   side - 0.5 * l.fh));
      im.day = 0.0;
      im.visit = kTrainVisit;
      names.push_back(im.name);
      plan.images.push_back(im);
    }
    if (!names.empty()) plan.splits["train"] = std::move(names);
  }
  // Database: a boustrophedon (lawnmower) path; the camera heading follows the robot.
  {
    CellRng rng(HashCombine(o.seed, 0xdb));
    std::vector<std::string>& names = plan.splits["database"];
    size_t index = 0;
    for (int r = 0; r < l.rows; ++r) {
      const bool forward = (r % 2) == 0;
      for (int c = 0; c < l.cols; ++c) {
        const int cc = forward ? c : l.cols - 1 - c;
        PlannedImage im;
        im.split = "database";
        im.name = ImageName("database", index++);
        im.pose = Rounded({0.5 * l.fw + cc * l.sx + o.position_jitter * rng.Normal(),
                           0.5 * l.fh + r * l.sy + o.position_jitter * rng.Normal(),
                           (forward ? 0.0 : M_PI) + o.heading_jitter * rng.Normal()});
        im.day = 0.0;
        im.visit = kDatabaseVisit;
        names.push_back(im.name);
        plan.images.push_back(im);
      }
    }
  }
  // Queries: one split per day, half along smooth paths and half at random poses.
  const double qx0 = 0.5 * l.fw, qx1 = std::max(qx0, o.area_width - 0.5 * l.fw);
  const double qy0 = 0.5 * l.fh, qy1 = std::max(qy0, o.area_height - 0.5 * l.fh);
  for (size_t k = 0; k < o.query_days.size() && o.queries_per_split > 0; ++k) {
    const int day = o.query_days[k];
    const std::string split = QuerySplitName(day);
    plan.info.query_days[split] = day;
    CellRng rng(HashCombine(o.seed, 0x9e000 + static_cast<uint64_t>(day)));
    std::vector<std::string>& names = plan.splits[split];
    const int n_path = static_cast<int>(std::round(o.path_fraction * o.queries_per_split));
    Pose2D walker{};
    int left_on_path = 0;
    for (int i = 0; i < o.queries_per_split; ++i) {
      Pose2D p;
      if (i < n_path) {
        if (left_on_path == 0) {
          walker = RandomPose(rng, qx0, qx1, qy0, qy1);
          left_on_path = 20;
        } else {
          walker.theta += 0.15 * rng.Normal();
          const double step = 0.03;
          double nx = walker.x + step * std::cos(walker.theta);
          double ny = walker.y + step * std::sin(walker.theta);
          if (nx < qx0 || nx > qx1) { walker.theta = M_PI - walker.theta; nx = std::clamp(nx, qx0, qx1); }
          if (ny < qy0 || ny > qy1) { walker.theta = -walker.theta; ny = std::clamp(ny, qy0, qy1); }
          walker.x = nx;
          walker.y = ny;
        }
        --left_on_path;
        p = walker;
      } else {
        p = RandomPose(rng, qx0, qx1, qy0, qy1);
      }
      PlannedImage im;
      im.split = split;
      im.name = ImageName(split, i);
      im.pose = Rounded(p);
      im.day = day;
      im.visit = kFirstQueryVisit + k;
      names.push_back(im.name);
      plan.images.push_back(im);
    }
  }
  if (!o.only.empty()) {
    auto kind = [](const std::string& split) {
      return split.rfind("query_", 0) == 0 ? std::string("queries") : split;
    };
    auto wanted = [&](const std::string& split) {
      return std::find(o.only.begin(), o.only.end(), kind(split)) != o.only.end();
    };
    std::vector<PlannedImage> kept;
    for (auto& im : plan.images) {
      if (wanted(im.split)) kept.push_back(std::move(im));
    }
    plan.images.swap(kept);
    for (auto it = plan.splits.begin(); it != plan.splits.end();) {
      it = wanted(it->first) ? std::next(it) : plan.splits.erase(it);
    }
    for (auto it = plan.info.query_days.begin(); it != plan.info.query_days.end();) {
      it = wanted(it->first) ? std::next(it) : plan.info.query_days.erase(it);
    }
  }
  return plan;
}

Lighting VisitLighting(uint64_t seed, uint64_t visit) {
  if (visit == kDatabaseVisit || visit == kTrainVisit) return {};
  CellRng rng(HashCombine(HashCombine(seed, 0x11947), visit));
  Lighting l;
  l.gain = 1.0 + 0.1 * rng.Uniform(-1.0, 1.0);
  l.gradient_u = 0.12 * rng.Uniform(-1.0, 1.0);
  l.gradient_v = 0.12 * rng.Uniform(-1.0, 1.0);
  // Drawn after the fields above so that those keep their values.
  l.gamma = 1.0 + 0.15 * rng.Uniform(-1.0, 1.0);
  l.directional_scale = 1.0 + 0.25 * rng.Uniform(-1.0, 1.0);
  l.azimuth_offset = 0.25 * rng.Uniform(-1.0, 1.0);
  return l;
}

cv::Mat RenderPlannedImage(const Floor& floor, const Camera& camera, const SynthOptions& o,
                           const PlannedImage& im) {
  FloorState state;
  state.day = im.day;
  state.visit_seed = HashCombine(o.seed, im.visit);
  state.aging = o.aging;
  const uint64_t shot = HashCombine(HashCombine(o.seed, Fnv1a(im.name)), im.visit);
  return camera.Capture(floor, im.pose, state, VisitLighting(o.seed, im.visit), shot);
}

SynthSummary GenerateDataset(const SynthOptions& o, const fs::path& out, bool force,
                             bool progress) {
  const auto start = std::chrono::steady_clock::now();
  const DatasetPlan plan = PlanDataset(o);
  const Floor floor(o.surface, o.seed);
  const Camera camera(o.camera);
  const fs::path staging = StageDirectory(out, force);
  SynthSummary summary;
  try {
    fs::create_directories(staging / "images");
    const int threads = o.threads > 0 ? o.threads
                                      : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    std::atomic<size_t> next{0};
    std::atomic<bool> failed{false};
    std::string error;
    std::mutex error_mutex;
    ProgressBar bar("synth", plan.images.size(), progress);
    auto worker = [&]() {
      // Noisy texture barely compresses beyond entropy coding: Huffman-only is as small and fast.
      const std::vector<int> png = {cv::IMWRITE_PNG_COMPRESSION, 1, cv::IMWRITE_PNG_STRATEGY,
                                    cv::IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY};
      while (!failed) {
        const size_t i = next.fetch_add(1);
        if (i >= plan.images.size()) return;
        try {
          const cv::Mat img = RenderPlannedImage(floor, camera, o, plan.images[i]);
          const fs::path path = staging / "images" / plan.images[i].name;
          if (!cv::imwrite(path.string(), img, png)) {
            throw std::runtime_error("cannot write image " + path.string());
          }
        } catch (const std::exception& e) {
          std::lock_guard<std::mutex> lock(error_mutex);
          if (!failed) error = e.what();
          failed = true;
          return;
        }
        bar.Add();
      }
    };
    // Parallelism is across images: OpenCV's own threads would only oversubscribe the cores.
    const int cv_threads = cv::getNumThreads();
    cv::setNumThreads(1);
    std::vector<std::thread> pool;
    for (int t = 0; t < threads; ++t) pool.emplace_back(worker);
    for (auto& t : pool) t.join();
    cv::setNumThreads(cv_threads);
    bar.Finish();
    if (failed) throw std::runtime_error(error);

    std::vector<PoseRecord> poses;
    poses.reserve(plan.images.size());
    for (const auto& im : plan.images) poses.push_back({im.name, im.pose});
    WriteDatasetFiles(staging, plan.info, poses, plan.splits);
    // Provenance: how this dataset was made (an extra file the format allows).
    std::ostringstream prov;
    prov << "# gtbow synth parameters\nsurface: " << SurfaceName(o.surface) << "\nseed: " << o.seed
         << "\narea_width: " << o.area_width << "\narea_height: " << o.area_height
         << "\noverlap: " << o.overlap << "\ntrain_images: " << o.train_images
         << "\nqueries_per_split: " << o.queries_per_split << "\naging: " << o.aging
         << "\nsupersample: " << o.camera.supersample
         << "\nsensor_effects: " << (o.camera.sensor_effects ? "true" : "false")
         << "\nrenderer_version: " << kRendererVersion
         << "\nmotion_blur: " << o.camera.motion_blur
         << "\nlight_directional: " << o.camera.light_directional
         << "\nlight_azimuth: " << o.camera.light_azimuth
         << "\nlight_elevation: " << o.camera.light_elevation << "\n";
    WriteFileAtomic(staging / "synth.yaml", prov.str());
    for (const auto& entry : fs::recursive_directory_iterator(staging)) {
      if (entry.is_regular_file()) summary.bytes += entry.file_size();
    }
    CommitStagedDirectory(staging, out);
  } catch (...) {
    DiscardStagedDirectory(staging);
    throw;
  }
  for (const auto& [split, names] : plan.splits) summary.split_sizes[split] = names.size();
  summary.images = plan.images.size();
  // Mean overlap of consecutive database images along the path.
  const ImageGeometry g = o.camera.Geometry();
  double sum = 0.0;
  size_t n = 0;
  const PlannedImage* prev = nullptr;
  for (const auto& im : plan.images) {
    if (im.split != "database") continue;
    if (prev != nullptr) {
      const double ov = Overlap(im.pose, prev->pose, g);
      if (ov > 0.0) {  // skip the turns between lanes
        sum += ov;
        ++n;
      }
    }
    prev = &im;
  }
  summary.mean_neighbour_overlap = n > 0 ? sum / n : 0.0;
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace synth
}  // namespace gtbow
