// gtbow map-info, gtbow convert-map and gtbow localize: what a map file holds, converting a map of
// the first format version (read whole into the heap) to the memory-mapped one, and localizing
// a dataset's images on a map offline, as the node in localization mode does (Localizer::Localize).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "commands.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/progress.h"
#include "ground_texture_bow/core/vocabulary.h"
#include "ground_texture_bow/eval/dataset.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace tools {

namespace {

struct ConvertArgs {
  std::string in, out, vocab;
  bool drop_descriptors = false;
};

struct LocalizeArgs {
  std::string map, dataset, split = "drive", vocab, out;
  int every = 1;
  double scale_tolerance = 0.02;
  bool quiet = false;
};

constexpr double kRightMm = 4.8, kRightDeg = 1.5;  // gtbow eval's tolerance

void PrintInfo(const std::string& path) {
  const MapFileInfo i = Localizer::ReadMapInfo(path);
  std::printf(
      "%s\n  format version  %u%s\n  keyframes       %llu\n  descriptors     %s\n"
      "  file size       %.1f MB (%.0f bytes per keyframe)\n  vocabulary      %s\n"
      "  meters/pixel    %g\n  pose frame      %s\n",
      path.c_str(), i.version, i.version == 1 ? " (convert it: gtbow convert-map)" : "",
      static_cast<unsigned long long>(i.keyframes), i.descriptors ? "kept" : "not kept",
      static_cast<double>(i.file_bytes) / 1e6,
      i.keyframes ? static_cast<double>(i.file_bytes) / static_cast<double>(i.keyframes) : 0.0,
      i.vocabulary_path.c_str(), i.meters_per_pixel,
      i.version < 3 ? "(not recorded before format version 3)"
                    : ((i.pose_frame.empty() ? std::string("(none given)") : i.pose_frame) +
                       (i.poses_optimised ? ", poses optimised by a SLAM backend"
                                          : ", poses as the keyframes were added"))
                          .c_str());
}

// A localizer for the map `path` (header `info`): the map's preset and scale, with the
// vocabulary it names or `vocab`.
std::unique_ptr<Localizer> LocalizerFor(const std::string& path, const MapFileInfo& info,
                                        const std::string& vocab, bool keep_descriptors) {
  const std::string vocab_path = vocab.empty() ? info.vocabulary_path : vocab;
  std::shared_ptr<Vocabulary> v;
  try {
    v = Vocabulary::Load(vocab_path);
  } catch (const std::exception& e) {
    throw std::runtime_error(std::string(e.what()) +
                             " (the map's vocabulary; give another path with --vocab)");
  }
  LocalizerOptions o;
  o.retrieval = ParseRetrievalConfig(info.retrieval_config, path + " (its preset)");
  o.meters_per_pixel = info.meters_per_pixel;
  o.keep_descriptors = keep_descriptors;
  return std::make_unique<Localizer>(v, vocab_path, o);
}

// Every keyframe's id, stamp and pose (map frame), as CSV.
void WritePoses(const std::string& path, const std::string& vocab, const std::string& out) {
  const MapFileInfo info = Localizer::ReadMapInfo(path);
  if (info.version < 2)
    throw std::invalid_argument(path + ": convert it first (gtbow convert-map)");
  const auto loc = LocalizerFor(path, info, vocab, info.descriptors);
  loc->Load(path);
  std::string csv = "id,stamp,has_pose,x,y,theta\n";
  char line[160];
  for (const Keyframe& k : loc->Keyframes()) {
    std::snprintf(line, sizeof(line), "%u,%.9f,%d,%.9g,%.9g,%.9g\n", k.id, k.stamp_ns * 1e-9,
                  k.has_pose ? 1 : 0, k.map_from_camera.x, k.map_from_camera.y,
                  k.map_from_camera.theta);
    csv += line;
  }
  WriteFileAtomic(out, csv);
  std::printf("  poses           %zu keyframes written to %s\n", loc->size(), out.c_str());
}

void Convert(const ConvertArgs& a) {
  if (fs::exists(a.out) && fs::equivalent(a.in, a.out)) {
    throw std::invalid_argument("--out must differ from --in (the old map is kept)");
  }
  const MapFileInfo info = Localizer::ReadMapInfo(a.in);
  if (info.version != 1) {
    throw std::invalid_argument(a.in + " is already format version " +
                                std::to_string(info.version) + "; nothing to convert");
  }
  const auto loc = LocalizerFor(a.in, info, a.vocab, !a.drop_descriptors);
  loc->ImportVersion1(a.in);
  loc->Save(a.out, /*paced=*/false);
  PrintInfo(a.out);
}

// Each image of a split localized on the map; the fixes against the dataset's poses (in the
// map's frame: a map and a dataset of the same floor and origin, as gtbow slam or the node made
// the map from the recording).
void Localize(const LocalizeArgs& a) {
  if (a.every < 1) throw std::invalid_argument("--every must be >= 1");
  const MapFileInfo info = Localizer::ReadMapInfo(a.map);
  if (info.version < 2)
    throw std::invalid_argument(a.map + ": convert it first (gtbow convert-map)");
  const Dataset ds = Dataset::Load(a.dataset);
  const double map_scale = info.meters_per_pixel, ds_scale = ds.info().geometry.meters_per_pixel;
  if (std::abs(ds_scale / map_scale - 1.0) > a.scale_tolerance) {
    char buf[256];
    std::snprintf(buf, sizeof(buf),
                  "the dataset's scale %.6g m/px differs from the map's %.6g m/px by more than "
                  "%.0f%% (--scale-tolerance): another camera, lens or height",
                  ds_scale, map_scale, 100 * a.scale_tolerance);
    throw std::invalid_argument(a.dataset + ": " + buf);
  }
  const auto loc = LocalizerFor(a.map, info, a.vocab, info.descriptors);
  loc->Load(a.map);
  const std::vector<std::string> all = ds.Split(a.split);
  std::vector<std::string> names;
  for (size_t i = 0; i < all.size(); i += static_cast<size_t>(a.every)) names.push_back(all[i]);
  std::string csv = "image,localized,x,y,theta,inliers,keyframe,error_mm,error_deg\n";
  size_t fixes = 0, right = 0, with_truth = 0;
  std::vector<double> errors;
  ProgressBar bar("localize", names.size(), !a.quiet);
  for (const std::string& n : names) {
    const Localization fix = loc->LocalizeImage(ds.LoadGray(n));
    char line[256];
    if (!fix.success) {
      csv += n + ",0,,,,,,,\n";
      bar.Add();
      continue;
    }
    ++fixes;
    const Pose2D& p = fix.estimate.floor_from_query;
    std::string err = ",";
    if (ds.HasImage(n)) {
      ++with_truth;
      const Pose2D& t = ds.PoseOf(n);
      const double mm = 1e3 * std::hypot(p.x - t.x, p.y - t.y);
      const double deg = std::abs(WrapAngle(p.theta - t.theta)) * 180 / M_PI;
      errors.push_back(mm);
      right += mm <= kRightMm && deg <= kRightDeg ? 1 : 0;
      std::snprintf(line, sizeof(line), "%.4f,%.4f", mm, deg);
      err = line;
    }
    std::snprintf(line, sizeof(line), ",1,%.7f,%.7f,%.7f,%d,%u,", p.x, p.y, p.theta,
                  fix.estimate.inliers, fix.image);
    csv += n + line + err + "\n";
    bar.Add();
  }
  bar.Finish();
  if (!a.out.empty()) WriteFileAtomic(a.out, csv);
  std::printf("%s on %s (%zu keyframes, poses in %s%s): %zu of %zu images of %s got a fix\n",
              a.split.c_str(), a.map.c_str(), loc->size(),
              info.pose_frame.empty() ? "an unnamed frame" : info.pose_frame.c_str(),
              info.poses_optimised ? ", optimised" : "", fixes, names.size(), a.dataset.c_str());
  if (!errors.empty()) {
    std::sort(errors.begin(), errors.end());
    double sq = 0;
    for (double e : errors) sq += e * e;
    std::printf(
        "against the dataset's poses: %zu of %zu images within %.1f mm and %.1f degrees "
        "(%.1f%%); fixes' position error median %.2f mm, RMSE %.2f mm, max %.2f mm\n",
        right, names.size(), kRightMm, kRightDeg, 100.0 * static_cast<double>(right) / names.size(),
        errors[errors.size() / 2], std::sqrt(sq / static_cast<double>(errors.size())),
        errors.back());
  }
  if (!a.out.empty()) std::printf("fixes written to %s\n", a.out.c_str());
}

}  // namespace

void RegisterMapCommands(CLI::App& app) {
  auto paths = std::make_shared<std::vector<std::string>>();
  auto poses = std::make_shared<std::string>();
  auto info_vocab = std::make_shared<std::string>();
  CLI::App* info = app.add_subcommand("map-info", "What a map file holds (either format version)");
  info->add_option("map", *paths, "Map files")->required()->check(CLI::ExistingFile);
  info->add_option("--poses", *poses,
                   "Also write every keyframe's id, stamp and pose (map frame) to this CSV (one "
                   "map only)");
  info->add_option("--vocab", *info_vocab,
                   "With --poses: the vocabulary (default: the path recorded in the map)");
  info->callback([paths, poses, info_vocab]() {
    if (!poses->empty() && paths->size() != 1) throw std::invalid_argument("--poses takes one map");
    for (const std::string& p : *paths) PrintInfo(p);
    if (!poses->empty()) WritePoses(paths->front(), *info_vocab, *poses);
  });

  auto a = std::make_shared<ConvertArgs>();
  CLI::App* cmd = app.add_subcommand(
      "convert-map",
      "Convert a map of format version 1 to the current one (memory-mapped loading)");
  cmd->add_option("--in", a->in, "Map file of version 1")->required()->check(CLI::ExistingFile);
  cmd->add_option("--out", a->out, "New map file (written atomically)")->required();
  cmd->add_option("--vocab", a->vocab, "Vocabulary file (default: the path recorded in the map)");
  cmd->add_flag("--drop-descriptors", a->drop_descriptors,
                "Keep no keyframe descriptors (8 KB a keyframe for ORB): smaller maps, "
                "verification from word pairs, no re-query by keyframe id");
  cmd->callback([a]() { Convert(*a); });

  auto l = std::make_shared<LocalizeArgs>();
  CLI::App* loc = app.add_subcommand(
      "localize",
      "Localize a dataset's images on a map, offline, as the node in localization mode does; the "
      "fixes against the dataset's poses");
  loc->add_option("--map", l->map, "Map file (.gtmap)")->required()->check(CLI::ExistingFile);
  loc->add_option("--dataset", l->dataset, "Dataset (docs/DATASET_FORMAT.md)")->required();
  loc->add_option("--split", l->split, "The split to localize")->capture_default_str();
  loc->add_option("--every", l->every, "Every Nth image of the split")->capture_default_str();
  loc->add_option("--vocab", l->vocab, "Vocabulary (default: the path recorded in the map)");
  loc->add_option("--scale-tolerance", l->scale_tolerance,
                  "Largest relative difference between the dataset's and the map's scale")
      ->capture_default_str();
  loc->add_option("-o,--out", l->out, "Also write every image's fix (and error) as CSV");
  loc->add_flag("-q,--quiet", l->quiet, "No progress bar");
  loc->callback([l]() { Localize(*l); });
}

}  // namespace tools
}  // namespace gtbow
