// gtbow bench-scaling (alias: gtbow bench): how the index scales from a thousand to a million
// database images. At each size it reports memory (resident set and bytes per image), insertion
// time, query time (median and p95, one and two threads) for every preset, and map save and load
// times.
//
// Images up to the dataset's database split are real. Beyond it, images are synthetic
// (synthetic_images.h: postings sampled from the real images' keypoint statistics). The output
// says how many images of each size are synthetic.
#include <malloc.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <sstream>
#include <string>
#include <thread>

#include "bench_util.h"
#include "commands.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/parallel.h"
#include "ground_texture_bow/core/progress.h"
#include "ground_texture_bow/core/simd.h"
#include "image_source.h"
#include "synthetic_images.h"
#include "timing.h"

namespace fs = std::filesystem;

namespace gtbow {
namespace tools {

namespace {

struct ScalingArgs {
  std::string dataset;
  std::string vocab;
  std::vector<std::string> presets;
  std::vector<size_t> sizes = {1000, 3200, 10000, 32000, 100000, 320000, 1000000};
  std::string query_split;
  size_t queries = 100;
  int threads = 0;
  std::string out = "build/bench_scaling";
  std::string cache = DefaultCacheDir().string();
  bool no_cache = false;
  bool no_plot = false;
  bool warm_only = false;
  uint64_t seed = 1;
  bool quiet = false;
};

struct QueryTiming {
  int threads;
  TimingStats ms;
};

struct SizeResult {
  size_t images = 0, real = 0, synthetic = 0;
  size_t entries = 0;
  size_t index_bytes = 0;  // MemoryBytes after online insertion (with spare capacity)
  size_t rss_online = 0;   // resident set growth with the online index
  size_t rss_loaded = 0;   // resident set growth with the loaded (mapped) index
  TimingStats insert_us;   // insertions since the previous size
  double save_ms = 0, load_cold_ms = -1, load_warm_ms = 0;
  size_t file_bytes = 0;
  std::vector<QueryTiming> query;
  double top1_agreement = -1;  // queries whose top result is the one at the largest real size
};

struct PresetResult {
  std::string name;
  RetrievalConfig config;
  std::string vocab_desc;
  size_t pool_keypoints = 0;
  std::vector<SizeResult> sizes;
};

PresetResult RunPreset(const ScalingArgs& a, const std::string& name, const RetrievalConfig& c,
                       const std::vector<ImageFeatures>& db_feats,
                       const std::vector<ImageFeatures>& q_feats, const fs::path& work) {
  PresetResult pr;
  pr.name = name;
  pr.config = c;
  VocabularyRequest vr;
  vr.file = a.vocab;
  vr.dataset = a.dataset;
  vr.cache = a.no_cache ? fs::path() : fs::path(a.cache);
  vr.threads = a.threads;
  vr.progress = !a.quiet;
  auto vocab = DatasetVocabulary(vr, c, &pr.vocab_desc);
  vocab->set_search(c.vocabulary.ann, c.vocabulary.nprobe);
  vocab->set_search_bound(c.vocabulary.ivf_bound);
  const BowEncoder enc(*vocab, c.bow);
  std::vector<BowVector> real = EncodeAll(enc, db_feats, a.threads, !a.quiet);
  std::vector<BowVector> queries = EncodeAll(enc, q_feats, a.threads, !a.quiet);
  for (auto& v : real) std::vector<Keypoint>().swap(v.source);
  const KeypointPool pool(real);
  pr.pool_keypoints = pool.keypoints();
  malloc_trim(0);
  const size_t rss0 = ResidentBytes();

  auto db = std::make_unique<BowDatabase>(enc.num_rows(), c.bow, vocab->fingerprint());
  std::vector<uint32_t> reference_top1;  // at the largest all-real size
  size_t next = 0;
  const fs::path file = work / ("scaling_" + name + ".gtdb");
  for (size_t target : a.sizes) {
    SizeResult sr;
    sr.images = target;
    sr.real = std::min(target, real.size());
    sr.synthetic = target - sr.real;
    std::vector<double> insert_us;
    std::unique_ptr<ProgressBar> bar;
    if (!a.quiet)
      bar = std::make_unique<ProgressBar>(
          "  " + name + ": to " + std::to_string(target) + " images", target - next);
    constexpr size_t kBatch = 8192;
    std::vector<BowVector> batch;
    while (next < target) {
      const size_t n = std::min(kBatch, target - next);
      batch.assign(n, BowVector());
      ParallelForEach(n, a.threads, [&](size_t i) {
        const size_t id = next + i;
        batch[i] = id < real.size() ? real[id] : pool.Sample(enc, a.seed * 1000003u + id);
      });
      for (const BowVector& v : batch) {
        const auto s = std::chrono::steady_clock::now();
        db->Add(v);
        insert_us.push_back(Ms(std::chrono::steady_clock::now() - s) * 1000.0);
      }
      next += n;
      if (bar) bar->Add(n);
    }
    bar.reset();
    sr.insert_us = Summarise(insert_us);
    sr.entries = db->num_entries();
    sr.index_bytes = db->MemoryBytes();
    sr.rss_online = ResidentBytes() - std::min(rss0, ResidentBytes());

    // Save, drop, load cold (page cache evicted) and warm; go on with the loaded index.
    auto t0 = std::chrono::steady_clock::now();
    db->Save(file);
    sr.save_ms = Ms(std::chrono::steady_clock::now() - t0);
    sr.file_bytes = fs::file_size(file);
    db.reset();
    malloc_trim(0);
    if (!a.warm_only && EvictFromPageCache(file)) {
      auto cold = std::make_unique<BowDatabase>(enc.num_rows(), c.bow, vocab->fingerprint());
      t0 = std::chrono::steady_clock::now();
      cold->Load(file);
      sr.load_cold_ms = Ms(std::chrono::steady_clock::now() - t0);
    }
    db = std::make_unique<BowDatabase>(enc.num_rows(), c.bow, vocab->fingerprint());
    t0 = std::chrono::steady_clock::now();
    db->Load(file);
    sr.load_warm_ms = Ms(std::chrono::steady_clock::now() - t0);
    fs::remove(file);  // the mapping keeps the contents
    malloc_trim(0);

    for (int threads : {1, 2}) {
      db->set_query_threads(threads);
      for (size_t i = 0; i < std::min<size_t>(3, queries.size()); ++i)
        db->Query(queries[i], 10, true);
      std::vector<double> ms;
      std::vector<uint32_t> top1;
      for (size_t i = 0; i < queries.size(); ++i) {
        const auto s = std::chrono::steady_clock::now();
        const auto res = db->Query(queries[i], 10, true);
        ms.push_back(Ms(std::chrono::steady_clock::now() - s));
        top1.push_back(res.empty() ? UINT32_MAX : res[0].image);
      }
      sr.query.push_back({threads, Summarise(ms)});
      if (threads == 1) {
        if (sr.synthetic == 0) reference_top1 = top1;
        if (!reference_top1.empty()) {
          size_t same = 0;
          for (size_t i = 0; i < top1.size(); ++i) same += top1[i] == reference_top1[i] ? 1 : 0;
          sr.top1_agreement = static_cast<double>(same) / std::max<size_t>(1, top1.size());
        }
      }
    }
    sr.rss_loaded = ResidentBytes() - std::min(rss0, ResidentBytes());
    if (!a.quiet) {
      std::fprintf(stderr,
                   "  %s %zu images (%zu synthetic): query %.2f ms (1 thread) %.2f ms (2), rss %s, "
                   "load %.0f ms\n",
                   name.c_str(), target, sr.synthetic, sr.query[0].ms.median, sr.query[1].ms.median,
                   Human(static_cast<double>(sr.rss_loaded)).c_str(),
                   sr.load_cold_ms >= 0 ? sr.load_cold_ms : sr.load_warm_ms);
    }
    pr.sizes.push_back(sr);
  }
  return pr;
}

std::string Json(const ScalingArgs& a, const std::vector<PresetResult>& results, size_t real_images,
                 size_t n_queries, const std::string& query_split) {
  std::ostringstream j;
  j.precision(6);
  j << "{\n  \"dataset\": \"" << a.dataset << "\",\n  \"real_images\": " << real_images
    << ",\n  \"query_split\": \"" << query_split << "\",\n  \"queries\": " << n_queries
    << ",\n  \"kernels\": {\"hamming\": \"" << ActiveHammingKernelName() << "\", \"l2_bytes\": \""
    << ActiveByteDistanceKernelName() << "\"}"
    << ",\n  \"synthetic_images_note\": \"images beyond real_images are synthetic postings sampled "
       "from "
       "keypoint rows, soft-assignment weights and orientations measured on the real images\",\n"
    << "  \"presets\": [\n";
  for (size_t p = 0; p < results.size(); ++p) {
    const PresetResult& r = results[p];
    j << "    {\"name\": \"" << r.name
      << "\", \"soft_assignment\": " << r.config.bow.soft_assignment
      << ", \"compact_postings\": " << (r.config.bow.compact_postings ? "true" : "false")
      << ", \"pool_keypoints\": " << r.pool_keypoints << ", \"sizes\": [\n";
    for (size_t s = 0; s < r.sizes.size(); ++s) {
      const SizeResult& x = r.sizes[s];
      j << "      {\"images\": " << x.images << ", \"real\": " << x.real
        << ", \"synthetic\": " << x.synthetic << ", \"entries\": " << x.entries
        << ", \"index_bytes\": " << x.index_bytes << ", \"rss_online_bytes\": " << x.rss_online
        << ", \"rss_loaded_bytes\": " << x.rss_loaded
        << ", \"insert_us\": {\"mean\": " << x.insert_us.mean
        << ", \"median\": " << x.insert_us.median << ", \"p95\": " << x.insert_us.p95
        << "}, \"save_ms\": " << x.save_ms << ", \"load_cold_ms\": " << x.load_cold_ms
        << ", \"load_warm_ms\": " << x.load_warm_ms << ", \"file_bytes\": " << x.file_bytes
        << ", \"top1_agreement\": " << x.top1_agreement << ", \"query_ms\": [";
      for (size_t q = 0; q < x.query.size(); ++q) {
        j << (q ? ", " : "") << "{\"threads\": " << x.query[q].threads
          << ", \"median\": " << x.query[q].ms.median << ", \"p95\": " << x.query[q].ms.p95
          << ", \"mean\": " << x.query[q].ms.mean << "}";
      }
      j << "]}" << (s + 1 < r.sizes.size() ? "," : "") << "\n";
    }
    j << "    ]}" << (p + 1 < results.size() ? "," : "") << "\n";
  }
  j << "  ]\n}\n";
  return j.str();
}

std::string Markdown(const std::vector<PresetResult>& results, size_t real_images, size_t n_queries,
                     const std::string& query_split) {
  std::ostringstream m;
  char b[512];
  m << "## Scaling: 1,000 to 1,000,000 database images (`gtbow bench-scaling`)\n\n";
  m << "The first " << real_images
    << " images of each size are real (the dataset's database split); the rest are **synthetic**: "
       "postings sampled from the rows, soft-assignment weights and orientations of the real "
       "images' "
       "keypoints (same surface), through the encoder's tf-idf. Queries: "
    << n_queries << " real images of `" << query_split
    << "`, top 10 with matches. Memory is the growth of the process's resident set once the saved "
       "index is loaded (memory-mapped) and queried; \"online index\" is the index's own size "
       "after "
       "insertion, spare capacity included. Load \"cold\" is after evicting the file from the page "
       "cache; every load verifies every checksum. \"top-1 same\": queries whose best image is the "
       "one found at the largest all-real size (synthetic images do not displace it). Kernels: "
    << ActiveSimdKernels() << ".\n\n";
  for (const PresetResult& r : results) {
    m << "### " << r.name << " (r = " << r.config.bow.soft_assignment << ", "
      << (r.config.bow.compact_postings ? "compact 6-byte" : "precise 8-byte") << " entries)\n\n";
    m << "| images | synthetic | memory (loaded) | bytes / image | online index | insert median / "
         "p95 (us) "
         "| query median / p95, 1 thread (ms) | query median / p95, 2 threads (ms) | save (s) | "
         "load cold / warm (s) | top-1 same |\n";
    m << "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
    for (const SizeResult& x : r.sizes) {
      std::snprintf(
          b, sizeof(b),
          "| %zu | %zu | %s | %.0f | %s | %.1f / %.1f | %.2f / %.2f | %.2f / %.2f | %.2f | %s / "
          "%.2f | %s |\n",
          x.images, x.synthetic, Human(static_cast<double>(x.rss_loaded)).c_str(),
          static_cast<double>(x.rss_loaded) / x.images,
          Human(static_cast<double>(x.index_bytes)).c_str(), x.insert_us.median, x.insert_us.p95,
          x.query[0].ms.median, x.query[0].ms.p95, x.query[1].ms.median, x.query[1].ms.p95,
          x.save_ms / 1000.0,
          x.load_cold_ms >= 0 ? (std::to_string(x.load_cold_ms / 1000.0).substr(0, 4)).c_str()
                              : "-",
          x.load_warm_ms / 1000.0,
          x.top1_agreement >= 0
              ? (std::to_string(static_cast<int>(std::lround(100 * x.top1_agreement))) + "%")
                    .c_str()
              : "-");
      m << b;
    }
    m << "\n";
  }
  return m.str();
}

void RunScaling(ScalingArgs a) {
  std::sort(a.sizes.begin(), a.sizes.end());
  a.sizes.erase(std::unique(a.sizes.begin(), a.sizes.end()), a.sizes.end());
  if (a.sizes.empty() || a.sizes.front() == 0)
    throw std::invalid_argument("--sizes: give positive sizes");
  if (a.sizes.back() > BowDatabase::kMaxImages) {
    throw std::invalid_argument("--sizes: at most " + std::to_string(BowDatabase::kMaxImages) +
                                " images");
  }
  std::vector<std::pair<std::string, RetrievalConfig>> presets;
  for (const auto& p : a.presets)
    presets.emplace_back(fs::path(p).stem().string(), LoadRetrievalConfig(p));
  if (presets.empty()) {
    presets.emplace_back("high_accuracy", LoadRetrievalConfig(ConfigFile("high_accuracy.yaml")));
    presets.emplace_back("fast", LoadRetrievalConfig(ConfigFile("fast.yaml")));
  }
  const fs::path out = a.out;
  CheckWritableDirectory(out, "--out");
  const Dataset ds = Dataset::Load(a.dataset);
  std::string qsplit = a.query_split.empty() ? FirstQuerySplit(ds) : a.query_split;
  if (qsplit.empty()) qsplit = "database";
  const FeatureOptions& f = presets[0].second.features;
  const fs::path cache = a.no_cache ? fs::path() : fs::path(a.cache);
  ImageSource db_src = ImageSource::FromDataset(a.dataset, "database");
  ImageSource q_src = ImageSource::FromDataset(a.dataset, qsplit);
  const auto db_feats = ExtractAllCached(db_src, f, cache, a.threads, !a.quiet);
  auto q_feats = ExtractAllCached(q_src, f, cache, a.threads, !a.quiet);
  if (q_feats.size() > a.queries) q_feats.resize(a.queries);
  std::vector<PresetResult> results;
  for (const auto& [name, c] : presets) {
    if (c.features.num_features != f.num_features || c.features.type != f.type) {
      throw std::invalid_argument("all --preset files must use the same features");
    }
    if (!a.quiet) std::fprintf(stderr, "preset %s\n", name.c_str());
    results.push_back(RunPreset(a, name, c, db_feats, q_feats, out));
  }
  WriteBenchResults(out, "scaling", Json(a, results, db_feats.size(), q_feats.size(), qsplit),
                    Markdown(results, db_feats.size(), q_feats.size(), qsplit), "plot_scaling.py",
                    a.no_plot);
}

}  // namespace

void RegisterBenchScaling(CLI::App& app) {
  auto a = std::make_shared<ScalingArgs>();
  // make bench-scaling runs it under the same name; `gtbow bench` stays as an alias.
  CLI::App* cmd = app.add_subcommand(
      "bench-scaling",
      "Scaling benchmark: memory, insertion, query, save and load from 1,000 to 1,000,000 images");
  cmd->alias("bench");
  cmd->add_option("--dataset", a->dataset, "Dataset with database and query splits (real images)")
      ->required();
  cmd->add_option("--vocab", a->vocab,
                  "Vocabulary file (default: train on the train split, cached)");
  cmd->add_option("--preset", a->presets,
                  "Retrieval configuration YAML (repeatable; default: high accuracy and fast)");
  cmd->add_option("--sizes", a->sizes, "Database sizes; beyond the real images, synthetic")
      ->delimiter(',')
      ->capture_default_str();
  cmd->add_option("--query-split", a->query_split,
                  "Split to draw queries from (default: the first query split)");
  cmd->add_option("--queries", a->queries, "Queries timed at each size")->capture_default_str();
  cmd->add_option("-j,--threads", a->threads, "Threads for encoding and synthesis, 0 = all cores");
  cmd->add_option("-o,--out", a->out, "Output directory: scaling.json, scaling.md, scaling.png")
      ->capture_default_str();
  cmd->add_option("--cache", a->cache, "Feature and vocabulary cache directory")
      ->capture_default_str();
  cmd->add_flag("--no-cache", a->no_cache, "Neither read nor write the cache");
  cmd->add_flag("--no-plot", a->no_plot, "Skip the PNG plot");
  cmd->add_flag("--warm-only", a->warm_only, "Skip the cold (page cache evicted) load");
  cmd->add_option("--seed", a->seed, "Seed of the synthetic images")->capture_default_str();
  cmd->add_flag("-q,--quiet", a->quiet, "No progress bars");
  cmd->callback([a]() { RunScaling(*a); });
}

}  // namespace tools
}  // namespace gtbow
