// gtbow bench-map: a warehouse-scale map (up to 1,000,000 keyframes) measured through the
// node's engine, gtbow::Localizer, where gtbow bench measures the raw index. What the node
// adds around the index (each keyframe's keypoints, descriptors and pose, the map file, one
// lock shared by insertions, queries and saves) is what a warehouse robot pays for.
//
// Per preset: keyframes inserted with Localizer::Add (each timed); localization and query
// answers of real query images; Localizer::Save timed while one thread keeps inserting
// keyframes and another keeps querying (the latency of every call, overlapping the save or
// not); the map loaded into a fresh Localizer with the file evicted from the page cache (cold)
// and again (warm), with the resident memory it takes; the same queries answered from the
// loaded map, which must give the answers given before the save.
//
// Keyframes up to the dataset's database split are real, posed at their ground truth. Beyond,
// they are synthetic (synthetic_images.h), carrying the keypoints and descriptors of the real
// image whose keypoint count they drew, so that every keyframe stores a real payload; they are
// posed 10 km from the real area, so that none can count as a right answer.
//
// Only the Localizer's public API is used: the figures are those of whichever map format and
// locking it has.
#include <malloc.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.h"
#include "commands.h"
#include "eval_results.h"
#include "ground_texture_bow/core/config.h"
#include "ground_texture_bow/core/database.h"
#include "ground_texture_bow/core/file_util.h"
#include "ground_texture_bow/core/localizer.h"
#include "ground_texture_bow/core/parallel.h"
#include "ground_texture_bow/core/progress.h"
#include "ground_texture_bow/core/simd.h"
#include "image_source.h"
#include "json_writer.h"
#include "synthetic_images.h"
#include "timing.h"

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace gtbow {
namespace tools {

namespace {

constexpr double kSyntheticOffsetMeters = 10000.0;  // synthetic keyframes lie this far east
constexpr int64_t kStampStepNs = 100000000;         // keyframe stamps: ten a second

// The save is measured under load: one client inserts keyframes, one queries, each pausing
// kClientPause between calls (a node inserts tens of keyframes a second; a call every
// millisecond or so catches every stall longer than that). The calls after the save (for as
// long as it took, within bounds) and the queries before it (kWindowBefore) are the figures
// without a save. The window after is as long as the save (up to kMaxWindowAfter) so that both
// sides hold about as many calls: the longest of more calls is longer by chance alone (30 s at
// most until December 2026, against saves of 35-90 s). Insertion starts only with the save, so that
// the file holds the map the first answers came from.
constexpr auto kClientPause = std::chrono::milliseconds(1);
constexpr Clock::duration kWindowBefore = std::chrono::milliseconds(500);
constexpr Clock::duration kMinWindowAfter = std::chrono::milliseconds(500);
constexpr Clock::duration kMaxWindowAfter = std::chrono::seconds(120);

struct BenchMapArgs {
  std::string dataset;
  std::string vocab;
  std::vector<std::string> presets;
  std::string keep_descriptors;  // yes | no | both; empty: see Variants()
  size_t keyframes = 1000000;
  std::vector<size_t> sizes;  // empty: the real count, 100000, 320000 and --keyframes
  std::string query_split;
  size_t queries = 100;
  int threads = 2;
  double save_rate_mb = LocalizerOptions().save_rate_mb;  // the node's default
  std::string out = "build/bench_map";
  std::string map_dir;  // empty: out
  std::string cache = DefaultCacheDir().string();
  bool no_cache = false;
  bool no_plot = false;
  bool keep_map = false;
  uint64_t seed = 1;
  bool quiet = false;
};

// One configuration measured: a preset, and whether keyframes keep their descriptors.
struct Variant {
  std::string name;  // the preset file's stem
  RetrievalConfig config;
  bool keep_descriptors = true;
  std::string label() const {
    return name + (keep_descriptors ? ", descriptors kept" : ", descriptors dropped");
  }
};

// The default presets pair as a warehouse map would run them (issue 17): high accuracy
// without descriptors (to fit its memory target), fast with them. --keep-descriptors
// overrides; presets given with --preset keep them unless told otherwise.
std::vector<Variant> Variants(const BenchMapArgs& a) {
  std::vector<Variant> base;
  for (const auto& p : a.presets)
    base.push_back({fs::path(p).stem().string(), LoadRetrievalConfig(p), true});
  if (base.empty()) {
    base.push_back({"fast", LoadRetrievalConfig(ConfigFile("fast.yaml")), true});
    base.push_back({"high_accuracy", LoadRetrievalConfig(ConfigFile("high_accuracy.yaml")), false});
  }
  std::vector<Variant> out;
  for (Variant v : base) {
    if (a.keep_descriptors == "both") {
      v.keep_descriptors = false;
      out.push_back(v);
      v.keep_descriptors = true;
    } else if (!a.keep_descriptors.empty()) {
      v.keep_descriptors = a.keep_descriptors == "yes";
    }
    out.push_back(v);
  }
  return out;
}

// What one query gave: the top K keyframes (Query, unverified) and the localization.
struct Answer {
  std::vector<uint32_t> ids;
  std::vector<float> scores;
  Localization loc;
};

// Bit for bit: a map that went through its file must answer exactly as before.
bool SameAnswer(const Answer& a, const Answer& b) {
  if (a.ids != b.ids || a.scores != b.scores || a.loc.success != b.loc.success) return false;
  if (!a.loc.success) return true;
  const Pose2D& p = a.loc.estimate.floor_from_query;
  const Pose2D& q = b.loc.estimate.floor_from_query;
  return a.loc.image == b.loc.image && a.loc.estimate.inliers == b.loc.estimate.inliers &&
         p.x == q.x && p.y == q.y && p.theta == q.theta;
}

// The queries answered once, in order: answers, times, and correctness against the truth.
struct QueryPass {
  std::vector<Answer> answers;
  TimingStats localize_ms, query_ms;
  size_t estimated = 0, localized = 0, wrong = 0;
};

QueryPass RunQueries(const Localizer& loc, const std::vector<ProcessedImage>& queries,
                     const std::vector<Pose2D>& truth) {
  QueryPass pass;
  const size_t k = static_cast<size_t>(loc.options().retrieval.verification.candidates);
  std::vector<double> localize_ms, query_ms;
  for (size_t i = 0; i < queries.size(); ++i) {
    Answer a;
    const auto t0 = Clock::now();
    const std::vector<Candidate> candidates = loc.Query(queries[i], k, false);
    const auto t1 = Clock::now();
    a.loc = loc.Localize(queries[i]);
    const auto t2 = Clock::now();
    query_ms.push_back(Ms(t1 - t0));
    localize_ms.push_back(Ms(t2 - t1));
    for (const Candidate& c : candidates) {
      a.ids.push_back(c.id);
      a.scores.push_back(c.score);
    }
    if (a.loc.success) {
      ++pass.estimated;
      ++(IsCorrectPose(a.loc.estimate.floor_from_query, truth[i]) ? pass.localized : pass.wrong);
    }
    pass.answers.push_back(std::move(a));
  }
  pass.localize_ms = Summarise(localize_ms);
  pass.query_ms = Summarise(query_ms);
  return pass;
}

// The map at one size during insertion.
struct Checkpoint {
  size_t keyframes = 0, synthetic = 0;
  size_t rss_online = 0;  // resident set growth since the empty Localizer
  TimingStats add_us;     // the insertions since the previous checkpoint
  QueryPass pass;
};

// One client call while the save was measured: its start (ms after the save began; negative
// before) and its latency (ms).
struct Call {
  double start = 0, ms = 0;
};

// Latencies of one kind of call, split by whether the call overlapped the save.
struct Overlap {
  TimingStats during, without;
  size_t n_during = 0, n_without = 0;
};

Overlap SplitBySave(const std::vector<Call>& calls, double save_ms) {
  std::vector<double> during, without;
  for (const Call& c : calls)
    (c.start < save_ms && c.start + c.ms > 0.0 ? during : without).push_back(c.ms);
  return {Summarise(during), Summarise(without), during.size(), without.size()};
}

// The two clients of the map that a node has: one answering queries (Query, then Localize, on
// each query image in turn), from construction, and one inserting keyframes, from
// StartAdding(). Both run until Stop().
class Clients {
 public:
  Clients(const Localizer* loc, const std::vector<ProcessedImage>* queries)
      : origin_(Clock::now()) {
    querier_ = std::thread([this, loc, queries] {
      Guard([&] {
        const size_t k = static_cast<size_t>(loc->options().retrieval.verification.candidates);
        for (size_t i = 0; !stop_; i = (i + 1) % queries->size()) {
          const auto t0 = Clock::now();
          (void)loc->Query((*queries)[i], k, false);
          const auto t1 = Clock::now();
          (void)loc->Localize((*queries)[i]);
          const auto t2 = Clock::now();
          query_.push_back({Ms(t0 - origin_), Ms(t1 - t0)});
          localize_.push_back({Ms(t1 - origin_), Ms(t2 - t1)});
          std::this_thread::sleep_for(kClientPause);
        }
      });
    });
  }
  // Inserts synthetic keyframes first_id, first_id + 1, ..., each after a pause (so the first
  // one lands after a save begun right after this call has taken the map).
  void StartAdding(Localizer* loc, std::function<ProcessedImage(uint64_t)> synthetic,
                   std::function<Pose2D(uint64_t)> pose, uint64_t first_id) {
    adder_ = std::thread([this, loc, synthetic, pose, first_id] {
      Guard([&] {
        for (uint64_t id = first_id; !stop_; ++id) {
          const ProcessedImage image = synthetic(id);
          std::this_thread::sleep_for(kClientPause);
          const auto t0 = Clock::now();
          loc->Add(image, static_cast<int64_t>(id) * kStampStepNs, pose(id));
          add_.push_back({Ms(t0 - origin_), Ms(Clock::now() - t0)});
        }
      });
    });
  }
  ~Clients() { Stop(); }
  Clients(const Clients&) = delete;
  Clients& operator=(const Clients&) = delete;

  // Stops both clients once their current calls return.
  void Stop() {
    stop_ = true;
    if (adder_.joinable()) adder_.join();
    if (querier_.joinable()) querier_.join();
  }
  // Rethrows the first failure of either client.
  void RethrowFailure() const {
    if (error_) std::rethrow_exception(error_);
  }

  // Calls, their starts shifted to be relative to `t` (after Stop()).
  std::vector<Call> add(Clock::time_point t) const { return Shift(add_, t); }
  std::vector<Call> query(Clock::time_point t) const { return Shift(query_, t); }
  std::vector<Call> localize(Clock::time_point t) const { return Shift(localize_, t); }

 private:
  template <typename F>
  void Guard(F&& body) {
    try {
      body();
    } catch (...) {
      std::lock_guard<std::mutex> lock(error_mutex_);
      if (!error_) error_ = std::current_exception();
    }
  }
  std::vector<Call> Shift(std::vector<Call> calls, Clock::time_point t) const {
    const double d = Ms(t - origin_);
    for (Call& c : calls) c.start -= d;
    return calls;
  }

  const Clock::time_point origin_;
  std::atomic<bool> stop_{false};
  std::vector<Call> add_, query_, localize_;  // each written by one client only
  std::mutex error_mutex_;
  std::exception_ptr error_;
  std::thread adder_, querier_;
};

struct VariantResult {
  Variant variant;
  std::string vocab_desc;
  size_t real = 0, synthetic = 0;  // keyframes inserted (step 2)
  size_t pool_keypoints = 0, pool_bytes = 0;
  TimingStats add_us;  // every insertion of step 2
  std::vector<Checkpoint> checkpoints;
  // The save under load.
  double save_ms = 0;
  SaveStats save_stats;         // the save's own account: lock held to seal, to swap; writing
  size_t client_keyframes = 0;  // inserted by the client during and after the save
  std::vector<Call> add_calls, query_calls, localize_calls;
  Overlap add, query, localize;
  size_t file_bytes = 0;
  size_t saved_keyframes = 0;  // in the loaded map
  // Loading.
  bool evicted = false;
  double load_cold_ms = 0, load_warm_ms = 0;
  size_t rss_before_load = 0;    // the process, bytes, with no map
  bool peak_measured = false;    // the kernel let the peak be reset before the load
  size_t rss_peak_load = 0;      // growth at the peak during the cold load
  size_t rss_after_load = 0;     // growth with the loaded map (cold load)
  size_t rss_after_queries = 0;  // growth with the loaded map (warm load) once queried
  QueryPass loaded;
  size_t identical = 0;
  std::vector<std::string> mismatches;  // one line each, for people
  std::vector<size_t> mismatch_queries;
};

std::string Ids(const Answer& a) {
  std::string s;
  for (uint32_t id : a.ids) s += (s.empty() ? "" : " ") + std::to_string(id);
  return "[" + s + "]";
}

std::string Fix(const Answer& a) {
  if (!a.loc.success) return "no fix (" + a.loc.reason + ")";
  const Pose2D& p = a.loc.estimate.floor_from_query;
  char b[160];
  std::snprintf(b, sizeof(b), "keyframe %u: %.17g %.17g %.17g, %d inliers", a.loc.image, p.x, p.y,
                p.theta, a.loc.estimate.inliers);
  return b;
}

VariantResult RunVariant(const BenchMapArgs& a, const Variant& v, const Dataset& ds,
                         const std::string& qsplit, const std::vector<size_t>& sizes,
                         const fs::path& map_file) {
  VariantResult r;
  r.variant = v;
  const RetrievalConfig& c = v.config;
  const ImageGeometry& geo = ds.info().geometry;
  const fs::path cache = a.no_cache ? fs::path() : fs::path(a.cache);
  if (!a.quiet) std::fprintf(stderr, "== %s\n", v.label().c_str());

  ImageSource db_src = ImageSource::FromDataset(a.dataset, "database");
  ImageSource q_src = ImageSource::FromDataset(a.dataset, qsplit);
  const std::vector<ImageFeatures> db_feats =
      ExtractAllCached(db_src, c.features, cache, a.threads, !a.quiet);
  std::vector<ImageFeatures> q_feats =
      ExtractAllCached(q_src, c.features, cache, a.threads, !a.quiet);
  if (q_feats.size() > a.queries) q_feats.resize(a.queries);

  VocabularyRequest vr;
  vr.file = a.vocab;
  vr.dataset = a.dataset;
  vr.cache = cache;
  vr.threads = a.threads;
  vr.progress = !a.quiet;
  const std::shared_ptr<Vocabulary> vocab = DatasetVocabulary(vr, c, &r.vocab_desc);
  const std::string vocab_path = a.vocab.empty() ? r.vocab_desc : a.vocab;
  LocalizerOptions lo;
  lo.retrieval = c;
  lo.meters_per_pixel = geo.meters_per_pixel;
  lo.threads = a.threads;
  lo.keep_descriptors = v.keep_descriptors;
  lo.save_rate_mb = a.save_rate_mb;
  // The synthetic keyframes' encoder: the Localizer's own is private, and one made from the
  // same vocabulary and options encodes alike.
  const BowEncoder synthetic_encoder(*vocab, c.bow);

  std::vector<ProcessedImage> queries;
  std::vector<Pose2D> truth;
  auto loc = std::make_unique<Localizer>(vocab, vocab_path, lo);
  for (size_t i = 0; i < q_feats.size(); ++i) {
    queries.push_back(loc->Encode(q_feats[i], geo.width, geo.height));
    truth.push_back(ds.PoseOf(q_src.name(i)));
  }

  KeypointPool pool;
  auto synthetic = [&](uint64_t id) {
    if (pool.empty()) throw std::runtime_error("the real keyframes have no keypoints to sample");
    ProcessedImage p;
    size_t from = 0;
    p.bow = pool.Sample(synthetic_encoder, a.seed * 1000003u + id, &from);
    p.features = db_feats[from];
    p.width = geo.width;
    p.height = geo.height;
    return p;
  };
  auto synthetic_pose = [](uint64_t id) {
    return Pose2D{kSyntheticOffsetMeters + 0.1 * static_cast<double>(id % 1000),
                  0.1 * static_cast<double>(id / 1000), 0.0};
  };

  // 1-2. Insertion: the real keyframes, then synthetic ones, with the queries at each size.
  const size_t n = sizes.back();
  r.real = std::min(n, db_feats.size());
  r.synthetic = n - r.real;
  malloc_trim(0);
  const size_t rss0 = ResidentBytes();
  std::vector<double> all_us, since_us;
  auto add = [&](const ProcessedImage& image, uint64_t id, const Pose2D& pose) {
    const auto t0 = Clock::now();
    loc->Add(image, static_cast<int64_t>(id) * kStampStepNs, pose);
    since_us.push_back(Ms(Clock::now() - t0) * 1000.0);
  };
  size_t next = 0;
  for (size_t target : sizes) {
    ProgressBar bar("  " + v.name + ": to " + std::to_string(target) + " keyframes", target - next,
                    !a.quiet);
    while (next < target && next < r.real) {
      const ProcessedImage p = loc->Encode(db_feats[next], geo.width, geo.height);
      add(p, next, ds.PoseOf(db_src.name(next)));
      pool.Add(p.bow);
      ++next;
      bar.Add();
    }
    // Synthetic keyframes are made in parallel, a batch at a time, and inserted one by one.
    constexpr size_t kBatch = 4096;
    std::vector<ProcessedImage> batch;
    while (next < target) {
      batch.assign(std::min(kBatch, target - next), ProcessedImage());
      ParallelForEach(batch.size(), a.threads, [&](size_t i) { batch[i] = synthetic(next + i); });
      for (const ProcessedImage& p : batch) {
        add(p, next, synthetic_pose(next));
        ++next;
      }
      bar.Add(batch.size());
    }
    bar.Finish();
    Checkpoint cp;
    cp.keyframes = target;
    cp.synthetic = target - std::min(target, r.real);
    cp.add_us = Summarise(since_us);
    all_us.insert(all_us.end(), since_us.begin(), since_us.end());
    since_us.clear();
    malloc_trim(0);  // as for the loaded map below
    cp.rss_online = ResidentBytes() - std::min(rss0, ResidentBytes());
    // 3. The answers at the final size are the reference for the loaded map's.
    cp.pass = RunQueries(*loc, queries, truth);
    if (!a.quiet) {
      std::fprintf(stderr,
                   "  %zu keyframes (%zu synthetic): localize %.2f ms, query %.2f ms (medians), "
                   "%zu of %zu localized, resident +%s\n",
                   target, cp.synthetic, cp.pass.localize_ms.median, cp.pass.query_ms.median,
                   cp.pass.localized, queries.size(),
                   Human(static_cast<double>(cp.rss_online)).c_str());
    }
    r.checkpoints.push_back(std::move(cp));
  }
  r.add_us = Summarise(all_us);
  r.pool_keypoints = pool.keypoints();
  r.pool_bytes = pool.bytes();
  const QueryPass& before = r.checkpoints.back().pass;

  // 4. The save, under load.
  if (!a.quiet) std::fprintf(stderr, "  saving to %s under load\n", map_file.c_str());
  Clock::time_point save_start, save_end;
  {
    Clients clients(loc.get(), &queries);
    std::this_thread::sleep_for(kWindowBefore);
    clients.StartAdding(loc.get(), synthetic, synthetic_pose, n);
    save_start = Clock::now();
    r.save_stats = loc->Save(map_file);
    save_end = Clock::now();
    std::this_thread::sleep_for(
        std::clamp(save_end - save_start, kMinWindowAfter, kMaxWindowAfter));
    clients.Stop();
    clients.RethrowFailure();
    r.add_calls = clients.add(save_start);
    r.query_calls = clients.query(save_start);
    r.localize_calls = clients.localize(save_start);
  }
  r.save_ms = Ms(save_end - save_start);
  r.client_keyframes = r.add_calls.size();
  r.add = SplitBySave(r.add_calls, r.save_ms);
  r.query = SplitBySave(r.query_calls, r.save_ms);
  r.localize = SplitBySave(r.localize_calls, r.save_ms);
  r.file_bytes = fs::file_size(map_file);

  // 5. Loading: cold (the file evicted from the page cache), then warm. Memory is measured
  // after malloc_trim: gtbow's mallopt (gtbow.cpp) keeps freed buffers in the heap, where a
  // node, with glibc's defaults, returns large ones to the kernel.
  loc.reset();
  malloc_trim(0);
  r.evicted = EvictFromPageCache(map_file);
  r.rss_before_load = ResidentBytes();
  auto growth = [](size_t from) { return ResidentBytes() - std::min(from, ResidentBytes()); };
  {
    Localizer cold(vocab, vocab_path, lo);
    r.peak_measured = ResetPeakResident();
    const auto t0 = Clock::now();
    cold.Load(map_file);
    r.load_cold_ms = Ms(Clock::now() - t0);
    r.rss_peak_load = PeakResidentBytes() - std::min(r.rss_before_load, PeakResidentBytes());
    malloc_trim(0);
    r.rss_after_load = growth(r.rss_before_load);
    r.saved_keyframes = cold.size();
  }
  malloc_trim(0);
  const size_t rss_warm0 = ResidentBytes();
  Localizer warm(vocab, vocab_path, lo);
  const auto t0 = Clock::now();
  warm.Load(map_file);
  r.load_warm_ms = Ms(Clock::now() - t0);

  // 6. The same queries on the loaded map.
  r.loaded = RunQueries(warm, queries, truth);
  malloc_trim(0);
  r.rss_after_queries = growth(rss_warm0);
  for (size_t i = 0; i < queries.size(); ++i) {
    const Answer& b = before.answers[i];
    const Answer& l = r.loaded.answers[i];
    if (SameAnswer(b, l)) {
      ++r.identical;
      continue;
    }
    // Keyframes the client inserted around the save were not there for the first answers.
    const bool newer =
        std::any_of(l.ids.begin(), l.ids.end(), [&](uint32_t id) { return id >= n; });
    r.mismatch_queries.push_back(i);
    r.mismatches.push_back(
        q_src.name(i) + ": before the save " + Ids(b) + ", " + Fix(b) + "; loaded " + Ids(l) +
        ", " + Fix(l) + (newer ? " (a keyframe inserted during the save test is among them)" : ""));
  }
  if (!a.quiet) {
    std::fprintf(stderr,
                 "  save %.2f s (%s), load cold %.2f s, warm %.2f s, resident +%s; longest Add "
                 "during the save %.2f ms; %zu of %zu answers identical\n",
                 r.save_ms / 1e3, Human(static_cast<double>(r.file_bytes)).c_str(),
                 r.load_cold_ms / 1e3, r.load_warm_ms / 1e3,
                 Human(static_cast<double>(r.rss_after_load)).c_str(), r.add.during.max,
                 r.identical, queries.size());
    for (const auto& m : r.mismatches) std::fprintf(stderr, "  DIFFERENT: %s\n", m.c_str());
  }
  return r;
}

void PutStats(Json& j, const std::string& key, const TimingStats& s) {
  j.Key(key).Open('{');
  j.Key("mean").Num(s.mean).Key("median").Num(s.median).Key("p95").Num(s.p95);
  j.Key("p99").Num(s.p99).Key("max").Num(s.max);
  j.Close('}');
}

void PutPass(Json& j, const std::string& key, const QueryPass& p) {
  j.Key(key).Open('{');
  PutStats(j, "localize_ms", p.localize_ms);
  PutStats(j, "query_ms", p.query_ms);
  j.Key("estimated").Int(p.estimated).Key("localized").Int(p.localized);
  j.Key("wrong").Int(p.wrong);
  j.Close('}');
}

void PutOverlap(Json& j, const std::string& key, const Overlap& o, const std::vector<Call>& calls) {
  j.Key(key).Open('{');
  j.Key("calls_during").Int(o.n_during).Key("calls_without").Int(o.n_without);
  PutStats(j, "during_ms", o.during);
  PutStats(j, "without_ms", o.without);
  j.Key("calls").Open('[');  // [start, latency] in ms, start relative to the save's
  for (const Call& c : calls) j.Open('[').Num(c.start).Num(c.ms).Close(']');
  j.Close(']');
  j.Close('}');
}

std::string ToJson(const BenchMapArgs& a, const std::vector<VariantResult>& results,
                   const std::string& qsplit, size_t real_available, size_t n_queries) {
  Json j;
  j.Open('{');
  j.Key("dataset").Str(a.dataset).Key("query_split").Str(qsplit).Key("queries").Int(n_queries);
  j.Key("real_keyframes_available").Int(real_available).Key("threads").Int(a.threads);
  j.Key("seed").Int(static_cast<long long>(a.seed));
  j.Key("save_rate_mb").Num(a.save_rate_mb);
  j.Key("kernels").Open('{').Key("hamming").Str(ActiveHammingKernelName());
  j.Key("l2_bytes").Str(ActiveByteDistanceKernelName()).Close('}');
  j.Key("synthetic_note")
      .Str(
          "keyframes beyond the real ones carry postings sampled from the real keypoints' rows, "
          "weights and orientations, and a real image's keypoints and descriptors; posed " +
          std::to_string(static_cast<int>(kSyntheticOffsetMeters)) + " m from the real area");
  j.Key("variants").Open('[');
  for (const VariantResult& r : results) {
    j.Open('{');
    j.Key("name").Str(r.variant.name).Key("keep_descriptors").Bool(r.variant.keep_descriptors);
    j.Key("soft_assignment").Int(r.variant.config.bow.soft_assignment);
    j.Key("vocabulary").Str(r.vocab_desc);
    j.Key("keyframes").Int(r.real + r.synthetic).Key("real").Int(r.real);
    j.Key("synthetic").Int(r.synthetic);
    j.Key("pool_keypoints").Int(r.pool_keypoints).Key("pool_bytes").Int(r.pool_bytes);
    PutStats(j, "add_us", r.add_us);
    j.Key("checkpoints").Open('[');
    for (const Checkpoint& cp : r.checkpoints) {
      j.Open('{');
      j.Key("keyframes").Int(cp.keyframes).Key("synthetic").Int(cp.synthetic);
      j.Key("rss_online_bytes").Int(cp.rss_online);
      PutStats(j, "add_us", cp.add_us);
      PutPass(j, "queries", cp.pass);
      j.Close('}');
    }
    j.Close(']');
    j.Key("save").Open('{');
    j.Key("ms").Num(r.save_ms);
    j.Key("seal_ms").Num(r.save_stats.seal_ms).Key("write_ms").Num(r.save_stats.write_ms);
    j.Key("swap_ms").Num(r.save_stats.swap_ms);
    j.Key("commit_ms").Num(r.save_stats.commit_ms).Key("populate_ms").Num(r.save_stats.populate_ms);
    j.Key("free_ms").Num(r.save_stats.free_ms);
    j.Key("client_keyframes").Int(r.client_keyframes);
    j.Key("file_bytes").Int(r.file_bytes).Key("saved_keyframes").Int(r.saved_keyframes);
    j.Key("bytes_per_keyframe")
        .Num(static_cast<double>(r.file_bytes) / std::max<size_t>(1, r.saved_keyframes));
    PutOverlap(j, "add", r.add, r.add_calls);
    PutOverlap(j, "query", r.query, r.query_calls);
    PutOverlap(j, "localize", r.localize, r.localize_calls);
    j.Close('}');
    j.Key("load").Open('{');
    j.Key("evicted").Bool(r.evicted).Key("cold_ms").Num(r.load_cold_ms);
    j.Key("warm_ms").Num(r.load_warm_ms).Key("rss_before_bytes").Int(r.rss_before_load);
    j.Key("rss_after_load_bytes").Int(r.rss_after_load);
    if (r.peak_measured) j.Key("rss_peak_during_load_bytes").Int(r.rss_peak_load);
    j.Key("rss_after_queries_bytes").Int(r.rss_after_queries);
    j.Close('}');
    PutPass(j, "before_save", r.checkpoints.back().pass);
    PutPass(j, "loaded", r.loaded);
    j.Key("queries").Int(n_queries).Key("identical_answers").Int(r.identical);
    j.Key("mismatches").Open('[');
    for (const auto& m : r.mismatches) j.Str(m);
    j.Close(']');
    j.Close('}');
  }
  j.Close(']');
  j.Close('}');
  return j.str();
}

std::string FormatRate(double mb_per_s) {
  char b[32];
  std::snprintf(b, sizeof(b), "%g MB/s", mb_per_s);
  return b;
}

std::string Percent(size_t part, size_t whole) {
  char b[32];
  std::snprintf(b, sizeof(b), "%.0f%%", 100.0 * part / std::max<size_t>(1, whole));
  return b;
}

std::string ToMarkdown(const std::vector<VariantResult>& results, const std::string& qsplit,
                       size_t real_available, size_t n_queries, double save_rate_mb) {
  std::ostringstream m;
  char b[512];
  m << "## Warehouse maps through the node (`gtbow bench-map`)\n\n";
  m << "The map is the node's own engine, `gtbow::Localizer`: keyframes inserted with `Add`, "
       "saved with `Save`, loaded with `Load`. The first "
    << real_available
    << " keyframes are the dataset's real database images at their true poses; the rest are "
       "**synthetic**: postings sampled from the real keypoints' rows, weights and orientations, "
       "each with a real image's keypoints and descriptors, posed "
    << static_cast<int>(kSyntheticOffsetMeters / 1000)
    << " km from the real area (never a right answer). Queries: " << n_queries
    << " real images of `" << qsplit
    << "`. The save runs while one thread keeps inserting keyframes and another keeps querying "
       "(`Query`, then `Localize`), each pausing 1 ms between calls; a call \"during the save\" "
       "overlapped it, the others (half a second before it, and after it for as long as the save "
       "took, at most 120 s) are the figures without a save. "
       "Resident memory is the process's growth from no map to the loaded map (cold load; its "
       "peak during the load in brackets) and to the warm-loaded map after the queries, freed "
       "heap returned to the kernel first. A cold load follows evicting the file from the page "
       "cache. Localization is correct within "
    << kSuccessMeters * 1000 << " mm and " << kSuccessRadians * 180 / M_PI
    << " degrees of the ground truth (as `gtbow eval`). The loaded map must answer every query "
       "(top-K ids, scores and the fix) exactly as the map did before the save. The save's "
       "writer is paced at "
    << (save_rate_mb > 0 ? FormatRate(save_rate_mb) : std::string("no rate (unpaced)"))
    << " (`LocalizerOptions::save_rate_mb`, the node's `~save_rate_mb`). Kernels: "
    << ActiveSimdKernels() << ".\n\n";
  for (const VariantResult& r : results) {
    const size_t n = r.real + r.synthetic;
    m << "### " << r.variant.name
      << ", `keep_descriptors = " << (r.variant.keep_descriptors ? "true" : "false")
      << "` (r = " << r.variant.config.bow.soft_assignment << ")\n\n";
    m << "| | |\n| --- | --- |\n";
    auto row = [&](const std::string& what, const std::string& value) {
      m << "| " << what << " | " << value << " |\n";
    };
    std::snprintf(b, sizeof(b), "%zu: %zu real, %zu synthetic", n, r.real, r.synthetic);
    row("keyframes", b);
    std::snprintf(b, sizeof(b), "%s (%zu bytes), %.0f bytes / keyframe (%zu keyframes saved%s)",
                  Human(static_cast<double>(r.file_bytes)).c_str(), r.file_bytes,
                  static_cast<double>(r.file_bytes) / std::max<size_t>(1, r.saved_keyframes),
                  r.saved_keyframes,
                  r.saved_keyframes == n ? "" : ": not the map at the save's start");
    row("map file", b);
    row("resident memory after load / after the queries (peak during the load)",
        Human(static_cast<double>(r.rss_after_load)) + " / " +
            Human(static_cast<double>(r.rss_after_queries)) + " (" +
            (r.peak_measured ? Human(static_cast<double>(r.rss_peak_load)) : "not measured") + ")");
    row("process resident set before the load (no map)",
        Human(static_cast<double>(r.rss_before_load)));
    std::snprintf(b, sizeof(b), "%.2f s%s / %.2f s", r.load_cold_ms / 1e3,
                  r.evicted ? "" : " (eviction from the page cache failed: not cold)",
                  r.load_warm_ms / 1e3);
    row("load cold / warm", b);
    std::snprintf(b, sizeof(b), "%.2f s (%zu keyframes inserted by the client meanwhile)",
                  r.save_ms / 1e3, r.add.n_during);
    row("save", b);
    std::snprintf(b, sizeof(b), "%.2f ms to seal, %.2f ms to swap in the file (writing: %.2f s)",
                  r.save_stats.seal_ms, r.save_stats.swap_ms, r.save_stats.write_ms / 1e3);
    row("the save's lock, held", b);
    std::snprintf(b, sizeof(b), "%.1f / %.1f / %.0f us", r.add_us.median, r.add_us.p95,
                  r.add_us.max);
    row("insertion (`Add`) median / p95 / max", b);
    auto overlap = [&](const char* what, const Overlap& o) {
      std::snprintf(b, sizeof(b), "%.2f ms (p99 %.2f, %zu calls) / %.2f ms (p99 %.2f, %zu calls)",
                    o.during.max, o.during.p99, o.n_during, o.without.max, o.without.p99,
                    o.n_without);
      row(std::string("longest `") + what + "` during the save / without", b);
    };
    overlap("Add", r.add);
    overlap("Query", r.query);
    overlap("Localize", r.localize);
    std::snprintf(b, sizeof(b), "%.2f / %.2f ms", r.loaded.localize_ms.median,
                  r.loaded.localize_ms.p95);
    row("localization (`Localize`: query + verification) median / p95, loaded map", b);
    std::snprintf(b, sizeof(b), "%.2f / %.2f ms", r.loaded.query_ms.median, r.loaded.query_ms.p95);
    row("query (`Query`, top K unverified) median / p95, loaded map", b);
    row("localized correctly / wrong, loaded map",
        Percent(r.loaded.localized, n_queries) + " (" + std::to_string(r.loaded.localized) +
            " of " + std::to_string(n_queries) + ") / " + std::to_string(r.loaded.wrong));
    row("answers identical to before the save",
        std::to_string(r.identical) + " of " + std::to_string(n_queries) +
            (r.identical == n_queries ? "" : " (**DIFFERENT**: listed below)"));
    m << "\n";
    for (const auto& d : r.mismatches) m << "- different: " << d << "\n";
    if (!r.mismatches.empty()) m << "\n";
    m << "While inserting (resident memory: growth since the empty map, the benchmark's "
         "sampling pool of "
      << Human(static_cast<double>(r.pool_bytes)) << " included):\n\n";
    m << "| keyframes | synthetic | resident | `Add` median / p95 / max (us) | `Localize` median "
         "/ p95 (ms) | `Query` median / p95 (ms) | localized / wrong |\n";
    m << "| --- | --- | --- | --- | --- | --- | --- |\n";
    for (const Checkpoint& cp : r.checkpoints) {
      std::snprintf(b, sizeof(b),
                    "| %zu | %zu | %s | %.1f / %.1f / %.0f | %.2f / %.2f | %.2f / %.2f | %s / "
                    "%zu |\n",
                    cp.keyframes, cp.synthetic, Human(static_cast<double>(cp.rss_online)).c_str(),
                    cp.add_us.median, cp.add_us.p95, cp.add_us.max, cp.pass.localize_ms.median,
                    cp.pass.localize_ms.p95, cp.pass.query_ms.median, cp.pass.query_ms.p95,
                    Percent(cp.pass.localized, n_queries).c_str(), cp.pass.wrong);
      m << b;
    }
    m << "\n";
  }
  return m.str();
}

void RunBenchMap(const BenchMapArgs& a) {
  if (a.keyframes == 0) throw std::invalid_argument("--keyframes: give at least 1");
  if (a.keyframes > BowDatabase::kMaxImages) {
    throw std::invalid_argument("--keyframes: at most " + std::to_string(BowDatabase::kMaxImages));
  }
  if (a.queries == 0) throw std::invalid_argument("--queries: give at least 1");
  for (size_t s : a.sizes) {
    if (s == 0) throw std::invalid_argument("--sizes: give positive sizes");
  }
  const std::vector<Variant> variants = Variants(a);  // every preset read before the work
  const fs::path out = a.out;
  const fs::path map_dir = a.map_dir.empty() ? out : fs::path(a.map_dir);
  CheckWritableDirectory(out, "--out");
  CheckWritableDirectory(map_dir, "--map-dir");
  const Dataset ds = Dataset::Load(a.dataset);
  const size_t real_available = ds.Split("database").size();
  const std::string qsplit = a.query_split.empty() ? FirstQuerySplit(ds) : a.query_split;
  if (qsplit.empty()) {
    throw std::runtime_error(
        a.dataset + ": no query split (sequences/query*.txt); name one with --query-split");
  }
  const size_t n_queries = std::min(a.queries, ds.Split(qsplit).size());
  // Checkpoints: the sizes asked for (by default the real count and the warehouse sizes) up
  // to --keyframes, which always ends the list.
  std::vector<size_t> sizes = a.sizes;
  if (sizes.empty()) sizes = {real_available, 100000, 320000};
  sizes.erase(std::remove_if(sizes.begin(), sizes.end(), [&](size_t s) { return s > a.keyframes; }),
              sizes.end());
  sizes.push_back(a.keyframes);
  std::sort(sizes.begin(), sizes.end());
  sizes.erase(std::unique(sizes.begin(), sizes.end()), sizes.end());

  std::vector<VariantResult> results;
  for (const Variant& v : variants) {
    std::string file = v.label();
    std::replace_if(
        file.begin(), file.end(),
        [](char ch) { return !std::isalnum(static_cast<unsigned char>(ch)); }, '_');
    const fs::path map_file = map_dir / ("bench_map_" + file + ".gtmap");
    try {
      results.push_back(RunVariant(a, v, ds, qsplit, sizes, map_file));
    } catch (...) {
      if (!a.keep_map) fs::remove(map_file);  // it can be 10 GB
      throw;
    }
    if (!a.keep_map) fs::remove(map_file);
  }
  WriteBenchResults(
      out, "bench_map",
      ToJson(a, results, qsplit, std::min(real_available, a.keyframes), n_queries),
      ToMarkdown(results, qsplit, std::min(real_available, a.keyframes), n_queries, a.save_rate_mb),
      "plot_bench_map.py", a.no_plot);
  // The loaded map must answer exactly as the map did before the save (README, docs/RESULTS.md):
  // the results are written first (the differences are listed in bench_map.md), then the run
  // fails.
  std::string differ;
  for (const VariantResult& r : results) {
    if (r.identical == n_queries) continue;
    differ += (differ.empty() ? "" : "; ") + r.variant.label() + ": " +
              std::to_string(n_queries - r.identical) + " of " + std::to_string(n_queries) +
              " answers differ";
  }
  if (!differ.empty()) {
    throw std::runtime_error("bench-map: answers after the save and load differ from before (" +
                             differ + "); listed in " + (out / "bench_map.md").string());
  }
}

}  // namespace

void RegisterBenchMap(CLI::App& app) {
  auto a = std::make_shared<BenchMapArgs>();
  CLI::App* cmd = app.add_subcommand(
      "bench-map",
      "Warehouse map through the node's Localizer: insertion, save under load, load, answers");
  cmd->add_option("--dataset", a->dataset, "Dataset with database and query splits (real images)")
      ->required();
  cmd->add_option("--vocab", a->vocab,
                  "Vocabulary file (default: train on the train split, cached)");
  cmd->add_option("--preset", a->presets,
                  "Retrieval configuration YAML (repeatable; default: high accuracy and fast)");
  cmd->add_option("--keep-descriptors", a->keep_descriptors,
                  "Keyframes keep their descriptors: yes, no or both (default: high accuracy no, "
                  "fast yes; yes for --preset files)")
      ->check(CLI::IsMember({"yes", "no", "both"}));
  cmd->add_option("--keyframes", a->keyframes,
                  "Keyframes in the map: the real images, then synthetic ones")
      ->capture_default_str();
  cmd->add_option("--sizes", a->sizes,
                  "Sizes at which the queries are timed while inserting (default: the real "
                  "count, 100000, 320000; --keyframes always)")
      ->delimiter(',');
  cmd->add_option("--query-split", a->query_split,
                  "Split to draw queries from (default: the first query split)");
  cmd->add_option("--queries", a->queries, "Query images (the first of the split)")
      ->capture_default_str();
  cmd->add_option("-j,--threads", a->threads,
                  "Localizer threads (LocalizerOptions::threads), also for extraction and "
                  "synthesis")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  cmd->add_option("--save-rate-mb", a->save_rate_mb,
                  "Pace of the save's writer, MB/s (LocalizerOptions::save_rate_mb; 0: unpaced)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("-o,--out", a->out, "Output directory: bench_map.json, bench_map.md, .png")
      ->capture_default_str();
  cmd->add_option("--map-dir", a->map_dir,
                  "Directory of the map file, which can be 10+ GB (default: --out)");
  cmd->add_option("--cache", a->cache, "Feature and vocabulary cache directory")
      ->capture_default_str();
  cmd->add_flag("--no-cache", a->no_cache, "Neither read nor write the cache");
  cmd->add_flag("--no-plot", a->no_plot, "Skip the PNG plot");
  cmd->add_flag("--keep-map", a->keep_map, "Keep the map file (deleted by default)");
  cmd->add_option("--seed", a->seed, "Seed of the synthetic keyframes")->capture_default_str();
  cmd->add_flag("-q,--quiet", a->quiet, "No progress bars");
  cmd->callback([a]() { RunBenchMap(*a); });
}

}  // namespace tools
}  // namespace gtbow
