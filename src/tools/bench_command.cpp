// gtbow bench-retrieval: the timings of the paper's Table II (feature extraction, BoW
// transform, database insertion, database query) on a dataset, plus map save/load times,
// memory per image and the first-word agreement of the approximate assignment.
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <numeric>
#include <random>
#include <string>
#include <thread>

#include "commands.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/progress.h"
#include "ground_texture_bow/core/simd.h"

#include <opencv2/core.hpp>
#include "image_source.h"
#include "paper_reference.h"
#include "timing.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace tools {

namespace {

struct BenchArgs {
  std::string vocab;
  std::vector<std::string> presets;
  std::string dataset;
  std::string split = "database";
  std::string query_split;
  size_t queries = 100;
  size_t max_images = 0;
  int checks = 0;
  int nprobe = 0;
  std::string ann;
  int threads = 0;
  std::string markdown;
  bool quiet = false;
};

void RunOne(const BenchArgs& a, const std::string& preset, const RetrievalConfig& c,
            Vocabulary* vocab, double vocab_load_ms, const ImageSource& db_src,
            const std::vector<ImageFeatures>& feats);

void RunBench(const BenchArgs& a) {
  std::vector<RetrievalConfig> configs;
  for (const auto& p : a.presets) configs.push_back(LoadRetrievalConfig(p));
  if (configs.empty()) configs.push_back(LoadRetrievalConfig(ConfigFile("high_accuracy.yaml")));
  if (!a.ann.empty()) {
    for (auto& c : configs) c.vocabulary.ann = ParseAnnIndex(a.ann);
  }
  for (const auto& c : configs) {
    const FeatureOptions& f = c.features;
    const FeatureOptions& g = configs[0].features;
    if (FormatFeatureOptions(f) != FormatFeatureOptions(g)) {
      throw std::invalid_argument("all --preset files must use the same features");
    }
  }
  auto t0 = std::chrono::steady_clock::now();
  const auto vocab = Vocabulary::Load(a.vocab);
  const double vocab_load_ms = Ms(std::chrono::steady_clock::now() - t0);
  if (a.checks > 0) vocab->set_checks(a.checks);
  CheckVocabularyExtractor(*vocab, a.vocab, configs[0].features);
  ImageSource db_src = ImageSource::FromDataset(a.dataset, a.split);
  db_src.Subsample(a.max_images);
  const auto feats =
      ExtractAllCached(db_src, configs[0].features, DefaultCacheDir(), a.threads, !a.quiet);
  for (size_t i = 0; i < configs.size(); ++i) {
    RunOne(a, a.presets.empty() ? std::string("high_accuracy") : a.presets[i], configs[i],
           vocab.get(), vocab_load_ms, db_src, feats);
  }
}

void RunOne(const BenchArgs& a, const std::string& preset, const RetrievalConfig& c,
            Vocabulary* vocab, double vocab_load_ms, const ImageSource& db_src,
            const std::vector<ImageFeatures>& feats) {
  auto ts = std::chrono::steady_clock::now();
  vocab->set_search(c.vocabulary.ann, a.nprobe > 0 ? a.nprobe : c.vocabulary.nprobe);
  vocab->set_search_bound(c.vocabulary.ivf_bound);
  const double search_setup_ms = Ms(std::chrono::steady_clock::now() - ts);
  const BowEncoder enc(*vocab, c.bow);
  auto t0 = std::chrono::steady_clock::now();

  // BoW transform of the database on all cores, then timed single-threaded insertion.
  const std::vector<BowVector> vecs = EncodeAll(enc, feats, a.threads, !a.quiet);
  BowDatabase db(enc.num_rows(), c.bow, vocab->fingerprint());
  std::vector<double> insert_ms;
  insert_ms.reserve(vecs.size());
  for (const auto& v : vecs) {
    const auto s = std::chrono::steady_clock::now();
    db.Add(v);
    insert_ms.push_back(Ms(std::chrono::steady_clock::now() - s));
  }
  const size_t mem = db.MemoryBytes();

  // Save and load the map.
  const fs::path tmp =
      fs::temp_directory_path() / ("gtbow_bench_" + std::to_string(::getpid()) + ".gtdb");
  t0 = std::chrono::steady_clock::now();
  db.Save(tmp);
  const double save_ms = Ms(std::chrono::steady_clock::now() - t0);
  const auto file_bytes = fs::file_size(tmp);
  BowDatabase loaded(enc.num_rows(), c.bow, vocab->fingerprint());
  t0 = std::chrono::steady_clock::now();
  loaded.Load(tmp);
  const double load_ms = Ms(std::chrono::steady_clock::now() - t0);
  const size_t loaded_mem = loaded.MemoryBytes();
  fs::remove(tmp);

  // Queries: random images of the query split (default: the database split itself).
  ImageSource q_src =
      a.query_split.empty() ? db_src : ImageSource::FromDataset(a.dataset, a.query_split);
  std::vector<size_t> order(q_src.size());
  std::iota(order.begin(), order.end(), 0);
  std::mt19937_64 rng(7);
  std::shuffle(order.begin(), order.end(), rng);
  order.resize(std::min(a.queries, order.size()));
  // Each query is timed once on one thread and once with both cores: OpenCV's own threads for
  // extraction, descriptor assignment split over threads, and the query's blocks split.
  const FeatureExtractor fx(c.features);
  BowEncoder penc(*vocab, c.bow);
  const int all = static_cast<int>(std::max(2u, std::thread::hardware_concurrency()));
  const int cv_threads = cv::getNumThreads();
  std::vector<double> ex_ms, tr_ms, q_ms, e2e_ms, pex_ms, ptr_ms, pq_ms, pe2e_ms;
  cv::Mat sample_desc;
  for (size_t i : order) {
    const cv::Mat img = q_src.LoadGray(i);
    for (int threads : {1, all}) {
      cv::setNumThreads(threads);
      penc.set_threads(threads);
      loaded.set_query_threads(threads);
      auto s = std::chrono::steady_clock::now();
      const ImageFeatures f = fx.Extract(img);
      const auto t1 = std::chrono::steady_clock::now();
      const BowVector v = penc.Encode(f);
      const auto t2 = std::chrono::steady_clock::now();
      const auto res = loaded.Query(v, 10, true);
      const auto t3 = std::chrono::steady_clock::now();
      (threads == 1 ? ex_ms : pex_ms).push_back(Ms(t1 - s));
      (threads == 1 ? tr_ms : ptr_ms).push_back(Ms(t2 - t1));
      (threads == 1 ? q_ms : pq_ms).push_back(Ms(t3 - t2));
      (threads == 1 ? e2e_ms : pe2e_ms).push_back(Ms(t3 - s));
      if (threads == 1 && sample_desc.rows < 2500 && !f.descriptors.empty())
        sample_desc.push_back(f.descriptors);
    }
  }
  cv::setNumThreads(cv_threads);
  // First-word agreement of the approximate assignment with the exact nearest word.
  std::vector<WordHit> approx, exact;
  vocab->Assign(sample_desc, 1, &approx);
  vocab->AssignExact(sample_desc, &exact);
  size_t agree = 0;
  for (size_t i = 0; i < approx.size(); ++i) agree += approx[i].word == exact[i].word ? 1 : 0;

  const PaperTiming& paper = PaperTimingFor(c);
  const TimingStats ex = Summarise(ex_ms), tr = Summarise(tr_ms), in = Summarise(insert_ms),
                    qu = Summarise(q_ms);
  char buf[4096];
  std::string md;
  auto line = [&](const char* fmt, auto... args) {
    std::snprintf(buf, sizeof(buf), fmt, args...);
    md += buf;
  };
  line("## Retrieval timing: %s (preset %s)\n\n", paper.name, preset.c_str());
  line(
      "Database: %zu images of `%s` (split `%s`), vocabulary %s/%s with %u words; %zu queries, "
      "one thread; times in ms.\n\n",
      db.size(), a.dataset.c_str(), a.split.c_str(), VocabularyKindName(vocab->kind()).c_str(),
      MetricName(vocab->metric()).c_str(), vocab->size(), order.size());
  line("| stage | paper (i7-13700), mean ± sd | here, mean ± sd | here, median | here, p95 |\n");
  line("| --- | --- | --- | --- | --- |\n");
  line("| feature extraction | %.1f ± %.1f | %.2f ± %.2f | %.2f | %.2f |\n", paper.extract[0],
       paper.extract[1], ex.mean, ex.sd, ex.median, ex.p95);
  line("| BoW transform | %.1f ± %.1f | %.2f ± %.2f | %.2f | %.2f |\n", paper.transform[0],
       paper.transform[1], tr.mean, tr.sd, tr.median, tr.p95);
  line("| database insertion | %.1f ± %.1f | %.3f ± %.3f | %.3f | %.3f |\n", paper.insert[0],
       paper.insert[1], in.mean, in.sd, in.median, in.p95);
  line("| database query | %.1f ± %.1f | %.2f ± %.2f | %.2f | %.2f |\n", paper.query[0],
       paper.query[1], qu.mean, qu.sd, qu.median, qu.p95);
  const TimingStats e2 = Summarise(e2e_ms), pex = Summarise(pex_ms), ptr = Summarise(ptr_ms),
                    pq = Summarise(pq_ms), pe2 = Summarise(pe2e_ms);
  line("| extraction + transform + query | - | %.2f ± %.2f | %.2f | %.2f |\n\n", e2.mean, e2.sd,
       e2.median, e2.p95);
  line(
      "Both cores (%d threads: OpenCV's threads in extraction, descriptor assignment split, query "
      "blocks split):\n\n",
      all);
  line(
      "| stage | one thread, median | %d threads, median | %d threads, p95 | change |\n| --- | --- "
      "| --- | --- | --- |\n",
      all, all);
  auto row = [&](const char* stage, const TimingStats& one, const TimingStats& par) {
    line("| %s | %.2f | %.2f | %.2f | %+.0f%% |\n", stage, one.median, par.median, par.p95,
         one.median > 0 ? 100.0 * (par.median - one.median) / one.median : 0.0);
  };
  row("feature extraction", ex, pex);
  row("BoW transform", tr, ptr);
  row("database query", qu, pq);
  row("extraction + transform + query", e2, pe2);
  line("\n");
  line("- first-word agreement with the exact nearest word: %.1f%% of %zu descriptors\n",
       100.0 * agree / std::max<size_t>(1, approx.size()), approx.size());
  line(
      "- index memory: %.2f KB per image (%.1f MB in all) after online insertion; %.2f KB per "
      "image after a reload\n",
      mem / 1024.0 / std::max<size_t>(1, db.size()), mem / 1e6,
      loaded_mem / 1024.0 / std::max<size_t>(1, db.size()));
  line(
      "- map file: %.1f MB; save %.0f ms; load %.0f ms; vocabulary load %.0f ms (+ %.0f ms search "
      "index)\n",
      file_bytes / 1e6, save_ms, load_ms, vocab_load_ms, search_setup_ms);
  line("- kernels: %s (GTBOW_SIMD caps them)\n", ActiveSimdKernels().c_str());
  line("- word search: %s (%s)\n", AnnIndexName(c.vocabulary.ann).c_str(),
       c.vocabulary.ann == AnnIndex::kIvf
           ? ("nprobe " + std::to_string(a.nprobe > 0 ? a.nprobe : c.vocabulary.nprobe)).c_str()
           : ("checks " + std::to_string(a.checks > 0 ? a.checks : c.vocabulary.checks)).c_str());
  std::fputs(md.c_str(), stdout);
  if (!a.markdown.empty()) {
    std::ofstream(a.markdown, std::ios::app) << md << "\n";
  }
}

}  // namespace

void RegisterBenchRetrieval(CLI::App& app) {
  auto a = std::make_shared<BenchArgs>();
  CLI::App* cmd = app.add_subcommand(
      "bench-retrieval", "Time extraction, transform, insertion and query (the paper's Table II)");
  cmd->add_option("--vocab", a->vocab, "Vocabulary file (gtbow train-vocab)")->required();
  cmd->add_option(
      "--preset", a->presets,
      "Retrieval configuration YAML (repeatable, same features); default: high accuracy");
  cmd->add_option("--dataset", a->dataset, "Dataset directory")->required();
  cmd->add_option("--split", a->split, "Split that forms the database")->capture_default_str();
  cmd->add_option("--query-split", a->query_split,
                  "Split to draw queries from (default: the database split)");
  cmd->add_option("--queries", a->queries, "Number of random queries")->capture_default_str();
  cmd->add_option("--max-images", a->max_images, "Use at most this many database images");
  cmd->add_option("--checks", a->checks, "Override the vocabulary's kd-tree checks per descriptor");
  cmd->add_option("--ann", a->ann, "Override the word search: flann or ivf");
  cmd->add_option("--nprobe", a->nprobe, "Override the IVF lists searched per descriptor");
  cmd->add_option("-j,--threads", a->threads, "Threads for the database build, 0 = all cores");
  cmd->add_option("--markdown", a->markdown, "Append the table to this Markdown file");
  cmd->add_flag("-q,--quiet", a->quiet, "No progress bars");
  cmd->callback([a]() { RunBench(*a); });
}

}  // namespace tools
}  // namespace gtbow
