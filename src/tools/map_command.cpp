// gtbow map-info and gtbow convert-map: what a map file holds, and converting a map of the
// first format version (read whole into the heap) to the memory-mapped one.
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include "commands.h"
#include "ground_texture_bow/core/config.h"
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
      "  meters/pixel    %g\n",
      path.c_str(), i.version, i.version == 1 ? " (convert it: gtbow convert-map)" : "",
      static_cast<unsigned long long>(i.keyframes), i.descriptors ? "kept" : "not kept",
      static_cast<double>(i.file_bytes) / 1e6,
      i.keyframes ? static_cast<double>(i.file_bytes) / static_cast<double>(i.keyframes) : 0.0,
      i.vocabulary_path.c_str(), i.meters_per_pixel);
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
  const std::string vocab_path = a.vocab.empty() ? info.vocabulary_path : a.vocab;
  std::shared_ptr<Vocabulary> vocab;
  try {
    vocab = Vocabulary::Load(vocab_path);
  } catch (const std::exception& e) {
    throw std::runtime_error(std::string(e.what()) +
                             " (the map's vocabulary; give another path with --vocab)");
  }
  LocalizerOptions o;
  o.retrieval = ParseRetrievalConfig(info.retrieval_config, a.in + " (its preset)");
  o.meters_per_pixel = info.meters_per_pixel;
  o.keep_descriptors = !a.drop_descriptors;
  Localizer loc(vocab, vocab_path, o);
  loc.ImportVersion1(a.in);
  loc.Save(a.out);
  PrintInfo(a.out);
}

}  // namespace

void RegisterMapCommands(CLI::App& app) {
  auto paths = std::make_shared<std::vector<std::string>>();
  CLI::App* info = app.add_subcommand("map-info", "What a map file holds (either format version)");
  info->add_option("map", *paths, "Map files")->required()->check(CLI::ExistingFile);
  info->callback([paths]() {
    for (const std::string& p : *paths) PrintInfo(p);
  });

  auto a = std::make_shared<ConvertArgs>();
  CLI::App* cmd = app.add_subcommand(
      "convert-map", "Convert a map of format version 1 to version 2 (memory-mapped loading)");
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
