// gtbow map-info and gtbow convert-map: what a map file holds, and converting a map of the
// first format version (read whole into the heap) to the memory-mapped one.
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include "commands.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/vocabulary.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace tools {

namespace {

struct ConvertArgs {
  std::string in, out, vocab;
  bool drop_descriptors = false;
};

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
  loc->Save(a.out);
  PrintInfo(a.out);
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
}

}  // namespace tools
}  // namespace gtbow
