// gtbow train-vocab: train a vocabulary on a dataset split or an image folder.
#include <chrono>
#include <cstdio>
#include <memory>
#include <string>

#include "commands.h"
#include "ground_texture_bow/core/config.h"
#include "image_source.h"

namespace gtbow {
namespace tools {

namespace {

struct TrainArgs {
  std::string preset;
  std::string dataset;
  std::string split = "train";
  std::string images;
  std::string out;
  int words = 0;
  int threads = 0;
  int64_t seed = -1;
  size_t max_images = 0;
  bool quiet = false;
};

void RunTrain(const TrainArgs& a) {
  const auto start = std::chrono::steady_clock::now();
  RetrievalConfig c =
      LoadRetrievalConfig(a.preset.empty() ? ConfigFile("high_accuracy.yaml") : a.preset);
  if (a.words > 0) c.vocabulary.num_words = a.words;
  if (a.seed >= 0) c.vocabulary.seed = static_cast<uint64_t>(a.seed);
  c.vocabulary.threads = a.threads;
  c.Check();
  if (a.dataset.empty() == a.images.empty()) {
    throw std::invalid_argument("give exactly one of --dataset DIR (with --split) or --images DIR");
  }
  ImageSource src = a.dataset.empty() ? ImageSource::FromFolder(a.images)
                                      : ImageSource::FromDataset(a.dataset, a.split);
  src.Subsample(a.max_images);
  const auto feats = ExtractAll(src, c.features, a.threads, !a.quiet);
  size_t total = 0;
  for (const auto& f : feats) total += f.size();
  auto vocab = TrainOnFeatures(c, feats, !a.quiet);
  vocab->Save(a.out);
  const double secs =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("Vocabulary written to %s\n", a.out.c_str());
  std::printf("  %s, metric %s, %u words, from %zu descriptors of %zu images, in %.1f s\n",
              VocabularyKindName(vocab->kind()).c_str(), MetricName(vocab->metric()).c_str(),
              vocab->size(), total, src.size(), secs);
}

}  // namespace

void RegisterTrainVocab(CLI::App& app) {
  auto a = std::make_shared<TrainArgs>();
  CLI::App* cmd =
      app.add_subcommand("train-vocab", "Train a vocabulary on a dataset split or an image folder");
  cmd->add_option("-o,--out", a->out, "Output vocabulary file")->required();
  cmd->add_option("--preset", a->preset,
                  "Retrieval configuration YAML (config/*.yaml); default: high accuracy");
  cmd->add_option("--dataset", a->dataset, "Dataset directory (docs/DATASET_FORMAT.md)");
  cmd->add_option("--split", a->split, "Dataset split to train on")->capture_default_str();
  cmd->add_option("--images", a->images, "Or: a folder of images");
  cmd->add_option("--words", a->words, "Override the number of words (AKM)");
  cmd->add_option("--seed", a->seed, "Override the seed");
  cmd->add_option("--max-images", a->max_images, "Use at most this many images (evenly spread)");
  cmd->add_option("-j,--threads", a->threads, "Threads, 0 = all cores")->capture_default_str();
  cmd->add_flag("-q,--quiet", a->quiet, "No progress bars");
  cmd->callback([a]() { RunTrain(*a); });
}

}  // namespace tools
}  // namespace gtbow
