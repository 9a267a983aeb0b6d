// gtbow synth: render a synthetic ground-texture dataset.
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "commands.h"
#include "ground_texture_bow/eval/synth/generator.h"

namespace gtbow {
namespace tools {

namespace {

struct SynthArgs {
  std::string out;
  std::string surface = "asphalt";
  std::vector<double> area;
  int database_images = 0;
  bool force = false;
  bool quiet = false;
  bool ideal = false;
  std::vector<std::string> photos, train_photos;
  bool surface_given = false, area_given = false;
  synth::SynthOptions options;
};

void RunSynth(SynthArgs& a) {
  synth::SynthOptions& o = a.options;
  o.camera.sensor_effects = !a.ideal;
  if (!a.photos.empty()) {
    if (a.surface_given || a.area_given || a.database_images != 0) {
      throw std::invalid_argument(
          "--photo makes the floor from photographs: --surface, --area and "
          "--database-images do not apply");
    }
    o.photos.assign(a.photos.begin(), a.photos.end());
    o.train_photos.assign(a.train_photos.begin(), a.train_photos.end());
    if (o.train_photos.empty() && o.train_images > 0) {
      throw std::invalid_argument(
          "--photo: give training photos with --train-photo (other photos of the "
          "same kind of floor), or --train 0");
    }
    o.Check();
    const synth::SynthSummary s = synth::GenerateDataset(o, a.out, a.force, !a.quiet);
    std::printf("Photo floor written to %s\n", a.out.c_str());
    std::printf(
        "  seed %llu, %zu map photo(s), %zu training photo(s), footprint %.1f x %.1f mm at %.3f "
        "mm/px\n",
        static_cast<unsigned long long>(o.seed), o.photos.size(), o.train_photos.size(),
        o.camera.width * o.camera.meters_per_pixel * 1e3,
        o.camera.height * o.camera.meters_per_pixel * 1e3, o.camera.meters_per_pixel * 1e3);
    for (const auto& [split, n] : s.split_sizes)
      std::printf("  %-28s %6zu images\n", split.c_str(), n);
    std::printf("  %zu images, %.1f MB, in %.1f s\n", s.images, s.bytes / 1e6, s.seconds);
    return;
  }
  if (!a.train_photos.empty()) throw std::invalid_argument("--train-photo needs --photo");
  o.surface = synth::ParseSurface(a.surface);
  if (!a.area.empty()) {
    if (a.area.size() != 2) throw std::invalid_argument("--area takes WIDTH HEIGHT in metres");
    o.area_width = a.area[0];
    o.area_height = a.area[1];
  }
  if (a.database_images != 0) {
    if (!a.area.empty()) throw std::invalid_argument("give --area or --database-images, not both");
    const double side = synth::SquareAreaForImages(o, a.database_images);
    o.area_width = o.area_height = side;
  }
  o.Check();
  const synth::SynthSummary s = synth::GenerateDataset(o, a.out, a.force, !a.quiet);
  std::printf("Synthetic %s floor written to %s\n", a.surface.c_str(), a.out.c_str());
  std::printf("  seed %llu, database area %.3f x %.3f m, footprint %.1f x %.1f mm at %.3f mm/px\n",
              static_cast<unsigned long long>(o.seed), o.area_width, o.area_height,
              o.camera.width * o.camera.meters_per_pixel * 1e3,
              o.camera.height * o.camera.meters_per_pixel * 1e3, o.camera.meters_per_pixel * 1e3);
  for (const auto& [split, n] : s.split_sizes) {
    std::printf("  %-14s %7zu images\n", split.c_str(), n);
  }
  if (s.split_sizes.count("database") > 0) {
    std::printf("  mean overlap of database neighbours: %.1f%%\n",
                100.0 * s.mean_neighbour_overlap);
  }
  std::printf("  %zu images, %.1f MB, in %.1f s (%.1f images/s)\n", s.images, s.bytes / 1e6,
              s.seconds, s.images / std::max(1e-9, s.seconds));
}

}  // namespace

void RegisterSynth(CLI::App& app) {
  auto args = std::make_shared<SynthArgs>();
  CLI::App* cmd = app.add_subcommand(
      "synth", "Render a synthetic ground-texture dataset with exact ground truth");
  synth::SynthOptions& o = args->options;
  cmd->add_option("-o,--out", args->out, "Output dataset directory")->required();
  cmd->add_option("--surface", args->surface, "asphalt, concrete, carpet, laminate (or flat)")
      ->capture_default_str()
      ->each([args](const std::string&) { args->surface_given = true; });
  cmd->add_option(
         "--photo", args->photos,
         "Make the floor from top-down photographs instead (repeatable): each is one bounded "
         "region of the map; queries are split per photo")
      ->check(CLI::ExistingFile);
  cmd->add_option(
         "--train-photo", args->train_photos,
         "Photographs for the train split (other photos of the same kind of floor; repeatable)")
      ->check(CLI::ExistingFile);
  cmd->add_option("--photo-mpp", o.photo_meters_per_pixel,
                  "Ground size of a photo pixel, metres (default: --meters-per-pixel)");
  cmd->add_option("--seed", o.seed, "Random seed; same arguments and seed give identical output")
      ->capture_default_str();
  cmd->add_option("--area", args->area, "Database area WIDTH HEIGHT in metres (default 1 1)")
      ->expected(2)
      ->each([args](const std::string&) { args->area_given = true; });
  cmd->add_option("--database-images", args->database_images,
                  "Choose a square area whose lawnmower path has about this many images");
  cmd->add_option("--overlap", o.overlap, "Overlap between lawnmower neighbours, fraction")
      ->capture_default_str();
  cmd->add_option("--train", o.train_images, "Images of the separate training area")
      ->capture_default_str();
  cmd->add_option("--queries", o.queries_per_split, "Images per query split")
      ->capture_default_str();
  cmd->add_option("--days", o.query_days, "Query days; one split query_dayNNN per day")
      ->delimiter(',')
      ->capture_default_str();
  cmd->add_option("--path-fraction", o.path_fraction,
                  "Share of queries taken along paths (rest at random poses)")
      ->capture_default_str();
  cmd->add_option("--aging", o.aging, "Rate of floor wear: 1 default, 0 none")
      ->capture_default_str();
  cmd->add_option("--width", o.camera.width, "Image width, pixels")->capture_default_str();
  cmd->add_option("--height", o.camera.height, "Image height, pixels")->capture_default_str();
  cmd->add_option("--meters-per-pixel", o.camera.meters_per_pixel, "Ground sampling distance")
      ->capture_default_str();
  cmd->add_option("--supersample", o.camera.supersample, "Anti-aliasing samples per axis (1-4)")
      ->capture_default_str();
  cmd->add_option("--light", o.camera.light_directional,
                  "Share of directional light from the camera-mounted lamp that shades the "
                  "floor's relief (0 = ambient only, no relief shading)")
      ->capture_default_str();
  cmd->add_option("--light-elevation", o.camera.light_elevation,
                  "Lamp elevation above the floor, radians")
      ->capture_default_str();
  cmd->add_option("--motion-blur", o.camera.motion_blur,
                  "Longest motion blur along the driving direction, pixels")
      ->capture_default_str();
  cmd->add_option("--drive", o.drive_length,
                  "Also render a continuous drive of this many metres (split 'drive'): laps "
                  "around the database area, plus drive_odometry.csv, wheel odometry with the "
                  "--odom-* noise model (docs/DATASET_FORMAT.md)")
      ->capture_default_str();
  cmd->add_option("--drive-spacing", o.drive_spacing, "Metres between drive images")
      ->capture_default_str();
  cmd->add_option("--later-drives", o.later_drive_days,
                  "Later sessions of the drive on these days (splits drive_dayDDD, each with "
                  "drive_dayDDD_odometry.csv from the origin), each starting a third of a lap "
                  "further along")
      ->delimiter(',');
  cmd->add_option("--later-drive-length", o.later_drive_length,
                  "Metres of each later drive (0: as --drive)")
      ->capture_default_str();
  cmd->add_option("--query-trail", o.query_trail,
                  "Also render what the robot saw just before each query: this many images on a "
                  "line behind it (split trail_X for query split query_X, query i's at "
                  "i * N + j - 1), with trail_X_odometry.csv, each one's odometry relative to its "
                  "query (--odom-* noise); for sequence queries (gtbow eval --sequence)")
      ->capture_default_str();
  cmd->add_option("--trail-spacing", o.trail_spacing, "Metres between a query's trail images")
      ->capture_default_str();
  cmd->add_option("--session-days", o.session_days,
                  "Also render a robot's localization sessions on these days (split "
                  "session_dayDDD: random poses over each photo or the query area, the floor aged "
                  "to that day), for a maintained map (gtbow eval --maintain)")
      ->delimiter(',');
  cmd->add_option("--session-images", o.session_images,
                  "Images per session (per photo on a photo floor); 0: as --queries")
      ->capture_default_str();
  cmd->add_option("--odom-scale-bias", o.odometry.scale_bias,
                  "Odometry: systematic distance scale error, fraction")
      ->capture_default_str();
  cmd->add_option("--odom-scale-noise", o.odometry.scale_noise,
                  "Odometry: per-step distance scale noise, fraction (sd)")
      ->capture_default_str();
  cmd->add_option("--odom-turn-bias", o.odometry.turn_bias,
                  "Odometry: systematic turn scale error, fraction")
      ->capture_default_str();
  cmd->add_option("--odom-heading-bias", o.odometry.heading_bias,
                  "Odometry: heading drift, rad per metre driven")
      ->capture_default_str();
  cmd->add_option("--odom-heading-noise", o.odometry.heading_noise,
                  "Odometry: random heading walk, rad per sqrt(metre) (sd)")
      ->capture_default_str();
  cmd->add_option("--only", o.only, "Render only these splits: train, database, queries, drive")
      ->delimiter(',');
  cmd->add_flag("--ideal", args->ideal, "No sensor effects (noise, blur, vignetting, jitter)");
  cmd->add_option("-j,--threads", o.threads, "Worker threads, 0 = all cores")
      ->capture_default_str();
  cmd->add_flag("-f,--force", args->force, "Replace an existing non-empty output directory");
  cmd->add_flag("-q,--quiet", args->quiet, "No progress bar");
  cmd->callback([args]() { RunSynth(*args); });
}

}  // namespace tools
}  // namespace gtbow
